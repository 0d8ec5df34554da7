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
  --sizes 800,10000 --saves 5 > "$OUT/table.md"
{
  echo "# The saved map at the size of a robot's"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_map.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "The keyframes of the demo's saved map ($(sed -n 's/^keyframes: \([0-9]*\) .*/\1/p' "$OUT/replay.txt" | head -1)"
  echo "keyframes: 640×480 images, SIFT, config/demo.yaml) repeated under new stamps to each size, with a view graph"
  echo "that chains them (\`rotavg_map_benchmark\`). Through the node's pipeline: the keyframe database on disk;"
  echo "loading the database alone (read, checksum, every keyframe checked, inverted index built) and the whole map"
  echo "(\`load_graph\`: graph, first solve, database); saving the map as autosave does (median of 5), and how long"
  echo "the save held the graph (a solve waits that long) and the front end (a new keyframe waits that long); the"
  echo "files are written after those copies, outside both. Files are read from the page cache (just written): a"
  echo "cold start reads them from the disk first. Peak memory is the process's, cumulative over the rows."
  echo
  cat "$OUT/table.md"
} > results/map.md
rm -rf "$OUT/maps"
cat results/map.md
