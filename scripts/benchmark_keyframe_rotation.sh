#!/usr/bin/env bash
# Regenerates results/keyframe_rotation.md: keyframes made by the camera's
# rotation (keyframe_min_rotation_deg) as well as by its corners' motion.
#  * Photographs played as a camera stream (keyframe_selection: motion, one
#    image a second): the Strecha scenes and lund_door at a quarter of full
#    width, each camera circling what it looks at, against every image a
#    keyframe (keyframe_selection: all).
#  * The demo renderer's two-camera rig as a 20 Hz driver publishes it: one
#    loop of the room in 30 s and in 60 s; its forward camera alone over one
#    loop in 30 s under three noise seeds.
#  * EuRoC's raw stereo stream (the vehicle stands still).
# Each at several rotation thresholds (0: motion and tracking alone).
#   bash scripts/benchmark_keyframe_rotation.sh        (about ten minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_keyframe_rotation
mkdir -p "$OUT" build/demo
ROTATIONS=(0 4 6 8)

PHOTOS=()
for s in castle-P19 entry-P10 fountain-P11; do
  [ -d "$DATA/strecha/$s" ] || continue
  [ -f "$OUT/$s.bag" ] || strecha_bag "$DATA/strecha/$s" "$OUT/$s.bag"
  PHOTOS+=("$s")
done
if [ -d "$DATA/lund_door" ]; then
  [ -f "$OUT/lund_door.bag" ] || lund_door_bag "$OUT/lund_door.bag"
  PHOTOS+=(lund_door)
fi
PHOTO_CONFIG=('image_topics: ["/camera/image_raw"]' "features: sift" "max_features: 4000")
for s in "${PHOTOS[@]}"; do
  replay_with "${s}_all" "$OUT/$s.bag" "${PHOTO_CONFIG[@]}" "keyframe_selection: all"
  for r in "${ROTATIONS[@]}"; do
    replay_with "${s}_rot$r" "$OUT/$s.bag" "${PHOTO_CONFIG[@]}" "keyframe_selection: motion" "keyframe_min_rotation_deg: $r"
  done
done

STREAMS=(600 1200)
for captures in "${STREAMS[@]}"; do
  bag="build/demo/demo_20hz_${captures}_2cam.bag"
  [ "$captures" = 1200 ] && bag=build/demo/demo_20hz_1200.bag  # benchmark_keyframe_selection.sh's
  if [ ! -f "$bag" ]; then
    "$BIN/rotation_averaging_make_demo_bag" --output "$bag.tmp" --captures "$captures" --period 0.05 --cameras 2 \
      > /dev/null 2>&1
    mv "$bag.tmp" "$bag"
  fi
  mapfile -t demo < <(grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:')
  for r in "${ROTATIONS[@]}"; do
    replay_with "stream${captures}_rot$r" "$bag" "${demo[@]}" "keyframe_selection: motion" "keyframe_min_rotation_deg: $r"
  done
done

# One camera (the rig's forward one) over one loop in 30 s, under three noise
# seeds: a single camera's median moves by a factor of two between seeds.
SEEDS=(1 2 3)
for seed in "${SEEDS[@]}"; do
  bag="$OUT/one_camera_seed$seed.bag"
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --captures 600 --period 0.05 --cameras 1 \
    --noise-seed "$seed" > /dev/null 2>&1
  mapfile -t demo < <(grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:\|^image_topics:')
  for r in 0 6; do
    replay_with "one_camera_seed${seed}_rot$r" "$bag" "${demo[@]}" 'image_topics: ["/cam_front/image_raw"]' \
      "keyframe_selection: motion" "keyframe_min_rotation_deg: $r"
  done
done

EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  [ -f "$OUT/euroc.bag" ] || "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
  for r in "${ROTATIONS[@]}"; do
    replay_with "euroc_rot$r" "$OUT/euroc.bag" 'image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' \
      "use_rig_extrinsics: false" "keyframe_selection: motion" "keyframe_max_interval_s: 0.5" \
      "keyframe_min_rotation_deg: $r"
  done
fi

python3 scripts/keyframe_rotation_report.py "$OUT" "$(IFS=,; echo "${PHOTOS[*]}")" \
  "$(IFS=,; echo "${STREAMS[*]}")" "$(IFS=,; echo "${ROTATIONS[*]}")" "$EUROC" "$(IFS=,; echo "${SEEDS[*]}")" \
  > results/keyframe_rotation.md
echo "wrote results/keyframe_rotation.md"
