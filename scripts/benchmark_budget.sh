#!/usr/bin/env bash
# Regenerates results/budget.md: where the node's time goes, per image, per
# keyframe and per two-view pair (median and 95th percentile), against the
# camera count and the keyframe count. The demo renderer's rig as a 20 Hz
# driver publishes it (600 captures, 30 s) with one, two and four cameras,
# replayed with `keyframe_selection: motion` (config/demo.yaml otherwise);
# and a 1 Hz two-camera bag whose every image is a keyframe (300 captures,
# 600 keyframes), whose per-keyframe cost is read in bins of its keyframe
# count (rotation_averaging_replay's frontend_cost.csv). Each bag is replayed
# with the defaults (the background refinement on) and with `refinement:
# false`.
#   bash scripts/benchmark_budget.sh
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_budget
mkdir -p "$OUT" build/demo

CAMERAS=(1 2 4)
NAMES=(cam_front cam_left cam_back cam_right)  # the renderer's cameras, in the order --cameras adds them
for cameras in "${CAMERAS[@]}"; do
  bag="build/demo/demo_20hz_600_${cameras}cam.bag"  # benchmark_posterior.sh plays the two-camera one too
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --captures 600 --period 0.05 \
    --cameras "$cameras" > /dev/null 2>&1
  topics=$(printf '"/%s/image_raw", ' "${NAMES[@]:0:$cameras}")
  { grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:\|^image_topics:'
    echo "image_topics: [${topics%, }]"
    echo "keyframe_selection: motion"; } > "$OUT/stream_${cameras}cam.yaml"
  { cat "$OUT/stream_${cameras}cam.yaml"; echo "refinement: false"; } > "$OUT/stream_${cameras}cam_unrefined.yaml"
  for run in stream_${cameras}cam stream_${cameras}cam_unrefined; do
    "$BIN/rotation_averaging_replay" --bag "$bag" --config "$OUT/$run.yaml" --gt "$bag" \
      --output-dir "$OUT/$run" --no-progress > "$OUT/$run.txt"
  done
done
LONG="$OUT/every_image_300.bag"
[ -f "$LONG" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$LONG" --captures 300 --cameras 2 > /dev/null 2>&1
{ grep -v '^#' config/demo.yaml; echo "refinement: false"; } > "$OUT/every_image_300_unrefined.yaml"
"$BIN/rotation_averaging_replay" --bag "$LONG" --config config/demo.yaml --gt "$LONG" \
  --output-dir "$OUT/every_image_300" --no-progress > "$OUT/every_image_300.txt"
"$BIN/rotation_averaging_replay" --bag "$LONG" --config "$OUT/every_image_300_unrefined.yaml" --gt "$LONG" \
  --output-dir "$OUT/every_image_300_unrefined" --no-progress > "$OUT/every_image_300_unrefined.txt"

python3 scripts/budget_report.py "$OUT" "$(IFS=,; echo "${CAMERAS[*]}")" > results/budget.md
echo "wrote results/budget.md"
