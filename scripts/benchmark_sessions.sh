#!/usr/bin/env bash
# Regenerates results/sessions.md: two sessions in the same room merged into
# one map, against one run as long as both. The rendered room (seed 1) and
# its two-camera rig, config/demo.yaml:
#   session A: 400 captures, two laps, starting at 0 deg;
#   session B: 400 captures, two laps, a quarter loop on, 1,000 s later,
#              under other lighting (gain 0.8, 40% brighter on one side of the
#              room than the other) and other image noise; replayed with
#              load_graph on the map A saved, and alone (a map that never saw
#              A's);
#   A and B added together: load_graph on A's map, add_maps with B's alone
#              (matched against A's as it is added), then a few captures
#              passing A's start;
#   one run:   800 captures, four laps, the same spacing of captures.
#   bash scripts/benchmark_sessions.sh        (about twenty minutes on 2 cores)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_sessions
rm -rf "$OUT" && mkdir -p "$OUT/map" "$OUT/b_map"
MAKE="$BIN/rotation_averaging_make_demo_bag --cameras 2 --seed 1"
$MAKE --output "$OUT/a.bag" --captures 400 --laps 2 --gt-csv "$OUT/a.csv" > /dev/null 2>&1
$MAKE --output "$OUT/b.bag" --captures 400 --laps 2 --start-angle 90 --start-time 1000 --light-gain 0.8 \
  --light-gradient 0.4 --noise-seed 7 --gt-csv "$OUT/b.csv" > /dev/null 2>&1
$MAKE --output "$OUT/one.bag" --captures 800 --laps 4 --gt-csv "$OUT/one.csv" > /dev/null 2>&1
$MAKE --output "$OUT/later.bag" --captures 4 --start-time 5000 > /dev/null 2>&1
{ cat "$OUT/a.csv"; tail -n +2 "$OUT/b.csv"; } > "$OUT/both.csv"
CONFIG=$(grep -v '^#' config/demo.yaml)
{ echo "$CONFIG"; echo "save_on_shutdown: $OUT/map/graph.txt"; } > "$OUT/a.yaml"
{ echo "$CONFIG"; echo "load_graph: $OUT/map/graph.txt"; } > "$OUT/b.yaml"
{ echo "$CONFIG"; echo "save_on_shutdown: $OUT/b_map/graph.txt"; } > "$OUT/b_alone.yaml"
{ echo "$CONFIG"; echo "load_graph: $OUT/map/graph.txt"; echo "add_maps: [\"$OUT/b_map/graph.txt\"]"; } > "$OUT/added.yaml"
"$BIN/rotation_averaging_replay" --bag "$OUT/a.bag" --config "$OUT/a.yaml" --gt "$OUT/a.csv" \
  --output-dir "$OUT/a" --no-progress > "$OUT/a.txt"
"$BIN/rotation_averaging_replay" --bag "$OUT/b.bag" --config "$OUT/b.yaml" --gt "$OUT/both.csv" \
  --output-dir "$OUT/b" --no-progress > "$OUT/b.txt"
"$BIN/rotation_averaging_replay" --bag "$OUT/b.bag" --config "$OUT/b_alone.yaml" --gt "$OUT/b.csv" \
  --output-dir "$OUT/b_alone" --no-progress > "$OUT/b_alone.txt"
"$BIN/rotation_averaging_replay" --bag "$OUT/later.bag" --config "$OUT/added.yaml" --gt "$OUT/both.csv" \
  --output-dir "$OUT/added" --no-progress > "$OUT/added.txt"
"$BIN/rotation_averaging_replay" --bag "$OUT/one.bag" --config config/demo.yaml --gt "$OUT/one.csv" \
  --output-dir "$OUT/one" --no-progress > "$OUT/one.txt"

python3 scripts/sessions_report.py "$OUT" > results/sessions.md
cat results/sessions.md
