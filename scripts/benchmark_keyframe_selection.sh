#!/usr/bin/env bash
# Regenerates results/keyframe_selection.md: keyframe selection on a raw
# 20 Hz stream. The demo renderer's two-camera rig driven along its loop at
# 20 captures per second (1200 captures, 2400 images, 60 s) replayed with
# `keyframe_selection: motion` at several thresholds, against the 1 Hz demo
# bag whose every image is a keyframe (config/demo.yaml): keyframes made,
# speed against real time, the cost of the check per image, accuracy.
#   bash scripts/benchmark_keyframe_selection.sh        (about ten minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_keyframe_selection
mkdir -p "$OUT" build/demo

DEMO=build/demo/demo_60.bag
STREAM=build/demo/demo_20hz_1200.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null
if [ ! -f "$STREAM" ]; then
  "$BIN/rotation_averaging_make_demo_bag" --output "$STREAM.tmp" --captures 1200 --period 0.05 --cameras 2 > /dev/null
  mv "$STREAM.tmp" "$STREAM"
fi
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config config/demo.yaml --gt "$DEMO" --output-dir "$OUT/demo_1hz" \
  --no-progress > "$OUT/demo_1hz.txt"
SETTINGS=("3 0.6" "5 0.5" "8 0.4" "12 0.3")
for setting in "${SETTINGS[@]}"; do
  read -r motion tracked <<< "$setting"
  name="stream_${motion}_${tracked}"
  { grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:'
    echo "keyframe_selection: motion"
    echo "keyframe_min_motion_deg: $motion"
    echo "keyframe_min_tracked_fraction: $tracked"; } > "$OUT/$name.yaml"
  "$BIN/rotation_averaging_replay" --bag "$STREAM" --config "$OUT/$name.yaml" --gt "$STREAM" \
    --output-dir "$OUT/$name" --no-progress > "$OUT/$name.txt"
done

row() {  # label, summary file
  local f=$2
  echo "| $1 | $(value "$f" '^keyframe selection ([a-z]*): \([0-9]*\) images.*' | grep . || value "$f" '^keyframes: .* (\([0-9]*\) images through.*') |" \
    "$(value "$f" '^keyframes: \([0-9]*\) .*') | $(value "$f" '^solved variables: \([0-9]*\) .*') |" \
    "$(value "$f" '.* not keyframes; \([0-9.]*\) ms per image$' | grep . || echo -) |" \
    "$(value "$f" '.*wall time: \([0-9.]*\) s.*') | $(value "$f" '.*(\([0-9.]*\)x real time).*')x |" \
    "$(value "$f" '^median error: \([0-9.]*\) deg') | $(value "$f" '^AUC@2: \([0-9.]*\) %') |"
}

{
  echo "# Keyframe selection on a raw stream"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_keyframe_selection.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "The demo renderer's rig (two cameras 90 deg apart, 640x480, one loop of the room in 60 s) as a"
  echo "camera driver publishes it, 20 captures per second (\`rotation_averaging_make_demo_bag --captures 1200"
  echo "--period 0.05\`), replayed with \`keyframe_selection: motion\` at the thresholds of each row"
  echo "(\`keyframe_min_motion_deg\` / \`keyframe_min_tracked_fraction\`; config/demo.yaml otherwise); the first"
  echo "row is the 1 Hz demo bag, whose every image is a keyframe (\`keyframe_selection: all\`). Accuracy over"
  echo "the keyframes (the ground truth of images that were not keyframes is not scored); speed-up = bag"
  echo "duration / wall time of the replay, which runs the node's pipeline as fast as the CPU allows."
  echo
  echo "| input | images | keyframes | rig captures solved | selection ms per image | wall (s) | speed-up | median (deg) | AUC@2 |"
  echo "|---|---|---|---|---|---|---|---|---|"
  row "1 Hz demo bag, every image a keyframe" "$OUT/demo_1hz.txt"
  for setting in "${SETTINGS[@]}"; do
    read -r motion tracked <<< "$setting"
    label="20 Hz stream, $motion deg / $tracked"
    [ "$motion $tracked" = "8 0.4" ] && label="$label (defaults)"
    row "$label" "$OUT/stream_${motion}_${tracked}.txt"
  done
  echo
  echo "## The 20 Hz stream with the defaults"
  echo
  echo '```'
  cat "$OUT/stream_8_0.4.txt"
  echo '```'
} > results/keyframe_selection.md
echo "wrote results/keyframe_selection.md"
