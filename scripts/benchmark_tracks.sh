#!/usr/bin/env bash
# Regenerates results/tracks.md: KLT tracks against descriptor matching.
#  * How precisely each places a point: a camera turning on the spot over
#    real photographs (the first image of each Strecha scene and of
#    lund_door) and over the renderer's room, the truth a homography
#    (rotavg_track_precision).
#  * The node on the renderer's rig as a 20 Hz driver publishes it (600
#    captures, 30 s; one, two and four cameras), `keyframe_selection:
#    motion`, with `tracks: true` and `tracks: false` (the default); the
#    two-camera stream also rendered with four other noise seeds, and at
#    half the turn rate (1200 captures, 60 s, results/keyframe_selection.md's
#    stream), there also with tracks for the keyframe decision alone.
#  * EuRoC's raw stereo stream (real, distorted; the vehicle stands still):
#    the solved cam0 -> cam1 rotation against the calibration's.
#   bash scripts/benchmark_tracks.sh        (about fifteen minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_tracks
mkdir -p "$OUT" build/demo

IMAGES=(render)
for s in fountain-P11 castle-P19 entry-P10; do
  [ -f "$DATA/strecha/$s/images/0000.jpg" ] && IMAGES+=("$DATA/strecha/$s/images/0000.jpg")
done
LUND_IMAGE=$(find "$DATA/lund_door/images" -maxdepth 1 -iname '*.jpg' 2>/dev/null | sort | head -1)
[ -n "$LUND_IMAGE" ] && IMAGES+=("$LUND_IMAGE")
"$BIN/rotavg_track_precision" "${IMAGES[@]}" > "$OUT/precision.md"

replay() {  # name bag config-lines...
  local name=$1 bag=$2
  shift 2
  { grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:\|^image_topics:'; printf '%s\n' "$@"; } > "$OUT/$name.yaml"
  "$BIN/rotation_averaging_replay" --bag "$bag" --config "$OUT/$name.yaml" --gt "$bag" --output-dir "$OUT/$name" \
    --no-progress > "$OUT/$name.txt"
}
NAMES=(cam_front cam_left cam_back cam_right)  # the renderer's cameras, in the order --cameras adds them
for cameras in 1 2 4; do
  bag="build/demo/demo_20hz_600_${cameras}cam.bag"  # benchmark_budget.sh plays these too
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --captures 600 --period 0.05 \
    --cameras "$cameras" > /dev/null 2>&1
  topics=$(printf '"/%s/image_raw", ' "${NAMES[@]:0:$cameras}")
  for tracks in true false; do
    replay "stream_${cameras}cam_tracks_$tracks" "$bag" "image_topics: [${topics%, }]" "keyframe_selection: motion" \
      "tracks: $tracks"
  done
done
SLOW=build/demo/demo_20hz_1200.bag  # benchmark_keyframe_selection.sh plays it too
if [ ! -f "$SLOW" ]; then
  "$BIN/rotation_averaging_make_demo_bag" --output "$SLOW.tmp" --captures 1200 --period 0.05 --cameras 2 > /dev/null 2>&1
  mv "$SLOW.tmp" "$SLOW"
fi
TWO='image_topics: ["/cam_front/image_raw", "/cam_left/image_raw"]'
replay slow_tracks_true "$SLOW" "$TWO" "keyframe_selection: motion" "tracks: true"
replay slow_tracks_false "$SLOW" "$TWO" "keyframe_selection: motion" "tracks: false"
replay slow_tracks_selection "$SLOW" "$TWO" "keyframe_selection: motion" "tracks: true" "min_track_matches: 1000000"
SEEDS=(1 2 3 4 5)
for seed in "${SEEDS[@]:1}"; do
  bag="$OUT/seed$seed.bag"
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --captures 600 --period 0.05 --cameras 2 \
    --noise-seed "$seed" > /dev/null 2>&1
  for tracks in true false; do
    replay "seed${seed}_tracks_$tracks" "$bag" 'image_topics: ["/cam_front/image_raw", "/cam_left/image_raw"]' \
      "keyframe_selection: motion" "tracks: $tracks"
  done
  rm -f "$bag"
done

EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
  for tracks in true false; do
    printf '%s\n' 'image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' "use_rig_extrinsics: false" \
      "keyframe_selection: motion" "keyframe_max_interval_s: 0.5" "tracks: $tracks" > "$OUT/euroc_tracks_$tracks.yaml"
    "$BIN/rotation_averaging_replay" --bag "$OUT/euroc.bag" --config "$OUT/euroc_tracks_$tracks.yaml" \
      --output-dir "$OUT/euroc_tracks_$tracks" --no-progress > "$OUT/euroc_tracks_$tracks.txt"
  done
fi

python3 scripts/tracks_report.py "$OUT" "$EUROC" "$(IFS=,; echo "${SEEDS[*]}")" > results/tracks.md
echo "wrote results/tracks.md"
