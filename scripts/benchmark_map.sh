#!/usr/bin/env bash
# Regenerates results/map.md: the saved map at the sizes a robot reaches.
# The demo bag (config/demo.yaml) is replayed with `save_on_shutdown`; the
# keyframes of that map (real ones, 640x480 SIFT through the node's front
# end) are repeated under new stamps to 800 and 10,000 keyframes, and
# rotavg_map_benchmark loads and saves each map through the node's pipeline.
#   bash scripts/benchmark_map.sh        (about two minutes; 1 GB on disk under build/)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_map
rm -rf "$OUT" && mkdir -p "$OUT/demo" build/demo
DEMO=build/demo/demo_60.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null
{ grep -v '^#' config/demo.yaml; echo "save_on_shutdown: $OUT/demo/graph.txt"; } > "$OUT/demo.yaml"
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config "$OUT/demo.yaml" --output-dir "$OUT/replay" \
  --no-progress > "$OUT/replay.txt"
"$BIN/rotavg_map_benchmark" --map "$OUT/demo/graph.txt" --config config/demo.yaml --output-dir "$OUT/maps" \
  --sizes 800,10000 --saves 5 --loads 2 > "$OUT/table.md"
python3 scripts/map_report.py "$OUT" > results/map.md
rm -rf "$OUT/maps"
cat results/map.md
