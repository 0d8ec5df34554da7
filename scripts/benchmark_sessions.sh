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

row() {  # label, summary file
  local f=$2
  echo "| $1 | $(value "$f" '^keyframes: \([0-9]*\) .*') | $(value "$f" '^components: \([0-9]*\);.*') |" \
    "$(value "$f" '^loop closures: \([0-9]*\) edges.*') | $(value "$f" '^median error: \([0-9.]*\) deg') |" \
    "$(value "$f" '^AUC@2: \([0-9.]*\) %') | $(value "$f" '^bag time: .*wall time: \([0-9.]*\) s.*') |"
}
merged=$(value "$OUT/b.txt" '^median error: \([0-9.]*\) deg')
one=$(value "$OUT/one.txt" '^median error: \([0-9.]*\) deg')
kf_a=$(value "$OUT/a.txt" '^keyframes: \([0-9]*\) .*')
{
  echo "# Two sessions merged into one map"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_sessions.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "The rendered room and two-camera rig of the demo (config/demo.yaml; 640×480, keyframes as the bags hold"
  echo "them, one capture per second). Session A: 400 captures, two laps. Session B, the same room another day:"
  echo "400 captures, two laps, starting a quarter of the loop further on, under other lighting (gain 0.8, 40%"
  echo "brighter on one side of the room than on the other) and other image noise, replayed with \`load_graph\` on"
  echo "the map A saved, and scored over both sessions' keyframes. The reference is one run of 800 captures, four"
  echo "laps, at the same spacing."
  echo
  echo "| run | keyframes | components | loop closures | median (deg) | AUC@2 (%) | wall (s) |"
  echo "|---|---|---|---|---|---|---|"
  row "session A" "$OUT/a.txt"
  row "session B, from A's map (A and B scored together)" "$OUT/b.txt"
  row "session B alone" "$OUT/b_alone.txt"
  row "A's map and B's alone added to it, then 4 captures (A and B scored together)" "$OUT/added.txt"
  row "one run of 800 captures" "$OUT/one.txt"
  echo
  echo "Merged against one run: median $merged° against $one° ($(awk -v a="$merged" -v b="$one" 'BEGIN { printf "%.2f", a / b }')×)."
  echo "A's saved map: $(awk -v s="$(stat -c %s "$OUT/map/graph.txt.keyframes")" -v k="$kf_a" 'BEGIN { printf "%.1f", s / 1024 / k }') KB of keyframe database per keyframe;"
  echo "$(value "$OUT/b.txt" '^\(map loaded in .* ms\):.*')."
  echo "When B's keyframes first joined A's, A's keyframes $(value "$OUT/b.txt" '^loaded keyframes when new keyframes joined them (solve [0-9]*): \(.*\)$')."
  echo
  echo "B's map alone added to A's (\`add_maps\`): $(value "$OUT/added.txt" '^ *of them between added maps and the map held: \(.*\)$')"
  echo "loop closures between the two maps, found as it was added (each of B's keyframes retrieved and verified"
  echo "against A's, on $(nproc) threads). At the first solve, A's keyframes $(value "$OUT/added.txt" '^loaded keyframes when new keyframes joined them (solve [0-9]*): \(.*\)$');"
  echo "B's map, saved in a frame a quarter turn from A's, was placed in A's frame."
} > results/sessions.md
cat results/sessions.md
