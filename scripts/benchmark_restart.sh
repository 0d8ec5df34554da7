#!/usr/bin/env bash
# Regenerates results/restart.md: a node restarted mid-run, reproduced with
# the replay. The demo bag (config/demo.yaml; 60 captures of a two-camera
# rig going once round the room) is cut after 15, 30 and 45 captures; the
# first part is replayed with `save_on_shutdown`, the rest with `load_graph`
# on the map it saved (graph, rig captures, keyframe database), against the
# uninterrupted replay: components, keyframes, accuracy over all of them,
# how far the keyframes of the saved map moved (at the first solve after
# loading, and when the new keyframes joined them), the database's size per
# keyframe, the time to save and to load the map.
#   bash scripts/benchmark_restart.sh        (about five minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_restart
rm -rf "$OUT" && mkdir -p "$OUT" build/demo
DEMO=build/demo/demo_60.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null
CONFIG=$(grep -v '^#' config/demo.yaml)
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config config/demo.yaml --gt "$DEMO" --output-dir "$OUT/full" \
  --no-progress > "$OUT/full.txt"

CUTS=(15 30 45)
for n in "${CUTS[@]}"; do
  # Halfway between the n-th capture and the next, by the bag's clock.
  cut=$(/usr/bin/python3 - "$DEMO" "$n" <<'PY'
import sys, rosbag
n = int(sys.argv[2])
with rosbag.Bag(sys.argv[1]) as bag:
    stamps = sorted({t.to_sec() for _, _, t in bag.read_messages(topics=["/cam_front/image_raw"])})
print((stamps[n - 1] + stamps[n]) / 2)
PY
)
  rosbag filter "$DEMO" "$OUT/before_$n.bag" \
    "topic == '/tf_static' or (topic != '/ground_truth/orientations' and t.to_sec() < $cut)" > /dev/null
  rosbag filter "$DEMO" "$OUT/after_$n.bag" \
    "topic == '/tf_static' or (topic != '/ground_truth/orientations' and t.to_sec() >= $cut)" > /dev/null
  mkdir -p "$OUT/map_$n"
  { echo "$CONFIG"; echo "save_on_shutdown: $OUT/map_$n/graph.txt"; } > "$OUT/before_$n.yaml"
  { echo "$CONFIG"; echo "load_graph: $OUT/map_$n/graph.txt"; } > "$OUT/after_$n.yaml"
  "$BIN/rotation_averaging_replay" --bag "$OUT/before_$n.bag" --config "$OUT/before_$n.yaml" \
    --output-dir "$OUT/before_$n" --no-progress > "$OUT/before_$n.txt"
  "$BIN/rotation_averaging_replay" --bag "$OUT/after_$n.bag" --config "$OUT/after_$n.yaml" --gt "$DEMO" \
    --output-dir "$OUT/after_$n" --no-progress > "$OUT/after_$n.txt"
done

python3 scripts/restart_report.py "$OUT" "${CUTS[@]}" > results/restart.md
cat results/restart.md
