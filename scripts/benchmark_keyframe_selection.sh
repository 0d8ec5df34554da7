#!/usr/bin/env bash
# Regenerates results/keyframe_selection.md: keyframe selection on a raw
# 20 Hz stream. The demo renderer's two-camera rig driven along its loop at
# 20 captures per second (1200 captures, 2400 images, 60 s) replayed with
# `keyframe_selection: motion` at several thresholds, against the 1 Hz demo
# bag whose every image is a keyframe (config/demo.yaml): keyframes made,
# speed against real time, the cost of the check per image, accuracy; both
# also without window pairs; and both bags rendered with other pixel noise, for
# the spread of the median.
#   bash scripts/benchmark_keyframe_selection.sh        (about fifteen minutes)
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
SETTINGS=(3/0.6 5/0.5 8/0.4 12/0.3)  # keyframe_min_motion_deg / keyframe_min_tracked_fraction
for setting in "${SETTINGS[@]}"; do
  motion=${setting%/*} tracked=${setting#*/}
  name="stream_${motion}_${tracked}"
  { grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:'
    echo "keyframe_selection: motion"
    echo "keyframe_min_motion_deg: $motion"
    echo "keyframe_min_tracked_fraction: $tracked"; } > "$OUT/$name.yaml"
  "$BIN/rotation_averaging_replay" --bag "$STREAM" --config "$OUT/$name.yaml" --gt "$STREAM" \
    --output-dir "$OUT/$name" --no-progress > "$OUT/$name.txt"
done

# Both without window pairs (each keyframe related to the previous one of its
# camera alone): what the default's older keyframes cost against real time
# and give in accuracy.
{ cat config/demo.yaml; echo "window_pairs: false"; } > "$OUT/demo_1hz_chain.yaml"
{ cat "$OUT/stream_8_0.4.yaml"; echo "window_pairs: false"; } > "$OUT/stream_chain.yaml"
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config "$OUT/demo_1hz_chain.yaml" --gt "$DEMO" \
  --output-dir "$OUT/demo_1hz_chain" --no-progress > "$OUT/demo_1hz_chain.txt"
"$BIN/rotation_averaging_replay" --bag "$STREAM" --config "$OUT/stream_chain.yaml" --gt "$STREAM" \
  --output-dir "$OUT/stream_chain" --no-progress > "$OUT/stream_chain.txt"

# Other noise realisations of both bags (seed 1 is the bags above), the
# stream at the default thresholds, each also without window pairs.
SEEDS=(1 2 3 4 5)
cp "$OUT/demo_1hz.txt" "$OUT/seed1_1hz.txt"
cp "$OUT/stream_8_0.4.txt" "$OUT/seed1_stream.txt"
cp "$OUT/demo_1hz_chain.txt" "$OUT/seed1_1hz_chain.txt"
cp "$OUT/stream_chain.txt" "$OUT/seed1_stream_chain.txt"
for seed in "${SEEDS[@]:1}"; do
  one_hz="$OUT/seed${seed}_1hz.bag" stream="$OUT/seed${seed}_stream.bag"
  "$BIN/rotation_averaging_make_demo_bag" --output "$one_hz" --captures 60 --cameras 2 --noise-seed "$seed" > /dev/null 2>&1
  "$BIN/rotation_averaging_make_demo_bag" --output "$stream" --captures 1200 --period 0.05 --cameras 2 \
    --noise-seed "$seed" > /dev/null 2>&1
  "$BIN/rotation_averaging_replay" --bag "$one_hz" --config config/demo.yaml --gt "$one_hz" \
    --output-dir "$OUT/seed${seed}_1hz" --no-progress > "$OUT/seed${seed}_1hz.txt"
  "$BIN/rotation_averaging_replay" --bag "$stream" --config "$OUT/stream_8_0.4.yaml" --gt "$stream" \
    --output-dir "$OUT/seed${seed}_stream" --no-progress > "$OUT/seed${seed}_stream.txt"
  "$BIN/rotation_averaging_replay" --bag "$one_hz" --config "$OUT/demo_1hz_chain.yaml" --gt "$one_hz" \
    --output-dir "$OUT/seed${seed}_1hz_chain" --no-progress > "$OUT/seed${seed}_1hz_chain.txt"
  "$BIN/rotation_averaging_replay" --bag "$stream" --config "$OUT/stream_chain.yaml" --gt "$stream" \
    --output-dir "$OUT/seed${seed}_stream_chain" --no-progress > "$OUT/seed${seed}_stream_chain.txt"
  rm -f "$one_hz" "$stream"
done


python3 scripts/keyframe_selection_report.py "$OUT" "$(IFS=,; echo "${SETTINGS[*]}")" "$(IFS=,; echo "${SEEDS[*]}")" \
  > results/keyframe_selection.md
echo "wrote results/keyframe_selection.md"
