#!/usr/bin/env bash
# Regenerates results/long_run.md and results/plots/long_run_frontend_cost.png:
# the keyframe front end over long image runs, with the package's defaults
# (config/demo.yaml, the default vocabulary).
#   1. the demo renderer's two-camera rig, 400 captures (800 keyframes):
#      speed against real time, retrieval time, peak memory, memory per
#      keyframe, the front end's cost per keyframe against the keyframe count,
#      accuracy;
#   2. three laps of the room (180 captures): loop closures found on each lap;
#   3. the 60-capture demo bag with retrieval by vocabulary and by voting over
#      every keyframe (`vocabulary: none`), in the same run;
#   4. 200 captures, and the 400 and 200 captures with loop closures on the
#      pixel model's covariance at 60 inliers (loop_jackknife_grid
#      0, min_loop_inliers 60): what the defaults cost or gain there.
#   bash scripts/benchmark_long_run.sh        (about 18 minutes on 2 cores)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_long_run
mkdir -p "$OUT" build/demo results/plots

render() {  # bag, captures, laps
  [ -f "$1" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$1.tmp" --captures "$2" --cameras 2 --laps "$3" > /dev/null
  [ -f "$1" ] || mv "$1.tmp" "$1"
}
replay() {  # bag, config, output name
  "$BIN/rotation_averaging_replay" --bag "$1" --config "$2" --gt "$1" --output-dir "$OUT/$3" --no-progress > "$OUT/$3.txt"
}

LONG=build/demo/demo_400.bag
LAPS=build/demo/demo_3laps_180.bag
DEMO=build/demo/demo_60.bag
MID=build/demo/demo_200.bag
render "$LONG" 400 1
render "$MID" 200 1
render "$LAPS" 180 3
render "$DEMO" 60 1
replay "$LONG" config/demo.yaml long
replay "$LAPS" config/demo.yaml laps
replay "$DEMO" config/demo.yaml demo
{ cat config/demo.yaml; echo "vocabulary: none"; } > "$OUT/voting.yaml"
replay "$DEMO" "$OUT/voting.yaml" demo_voting
replay "$MID" config/demo.yaml mid
{ cat config/demo.yaml; echo "loop_jackknife_grid: 0"; echo "min_loop_inliers: 60"; } > "$OUT/pixel60.yaml"
replay "$LONG" "$OUT/pixel60.yaml" long_pixel60
replay "$MID" "$OUT/pixel60.yaml" mid_pixel60
cp "$OUT/long/frontend_cost.png" results/plots/long_run_frontend_cost.png

field() {  # summary file, sed expression
  sed -n "$2" "$1" | head -1
}
row() {  # name, summary file
  local f="$2"
  echo "| $1 | $(field "$f" 's/^keyframes: \([0-9]*\) .*/\1/p') | $(field "$f" 's/.*(\([0-9.]*\)x real time).*/\1/p')x |" \
       "$(field "$f" 's/.*retrieval \([0-9.]*\) ms.*/\1/p') | $(field "$f" 's/.*pair verification \([0-9.]*\) ms.*/\1/p') |" \
       "$(field "$f" 's/.*peak memory: \([0-9.]*\) MiB.*/\1/p') | $(field "$f" 's/.*compact, \([0-9.]*\) KB each.*/\1/p') |" \
       "$(field "$f" 's/^loop closures: \([0-9]*\) edges.*/\1/p') | $(field "$f" 's/^median error: \([0-9.]*\) deg/\1/p') |" \
       "$(field "$f" 's/^AUC@2: \([0-9.]*\) %/\1/p') |"
}

# Loop closures of the three-lap run by the lap of their newer keyframe
# (60 captures per lap, stamps from 1000 s), and how many reach an earlier lap.
lap_table() {
  awk '$1 == "VIEW" { split($3, a, "@"); lap[$2] = int((a[2] / 1e9 - 1000) / 60) }
       $1 == "EDGE" && $4 == "loop_closure" {
         newer = lap[$3] > lap[$2] ? lap[$3] : lap[$2]; older = lap[$3] > lap[$2] ? lap[$2] : lap[$3]
         n[newer]++; if (older < newer) across[newer]++ }
       END { for (l = 0; l < 3; ++l) printf "| %d | %d | %d |\n", l + 1, n[l], across[l] }' "$OUT/laps/graph.txt"
}

{
  echo "# Long image runs"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_long_run.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "Each bag goes through \`rotation_averaging_replay\` with \`config/demo.yaml\` (the node's pipeline and"
  echo "defaults: SIFT, 1500 features, retrieval with the default vocabulary, two loop candidates per keyframe,"
  echo "MAGSAC + covariance averaging re-solved every second of bag time). Bags hold one capture of two cameras"
  echo "per second; speed = bag time / wall time. Retrieval and pair verification are wall time per keyframe."
  echo
  echo "| run | keyframes | speed | retrieval (ms) | pair verification (ms) | peak memory (MiB) | compact keyframe (KB) | loop closures | median error (deg) | AUC@2 (%) |"
  echo "|---|---|---|---|---|---|---|---|---|---|"
  row "400 captures, one lap" "$OUT/long.txt"
  row "180 captures, three laps" "$OUT/laps.txt"
  row "60 captures (the demo)" "$OUT/demo.txt"
  row "60 captures, voting over every keyframe (\`vocabulary: none\`)" "$OUT/demo_voting.txt"
  row "200 captures, one lap" "$OUT/mid.txt"
  row "400 captures, loop closures with the pixel model at 60 inliers" "$OUT/long_pixel60.txt"
  row "200 captures, the same" "$OUT/mid_pixel60.txt"
  echo
  echo "The last two rows: loop closures on the pixel model's covariance (\`loop_jackknife_grid: 0\`)"
  echo "at \`min_loop_inliers: 60\`, against the defaults (the cell jackknife's covariance at 40; results/README.md,"
  echo "\"Loop closures and their covariances\")."
  echo
  echo "## Cost per keyframe against the keyframe count (400 captures)"
  echo
  echo "Front-end wall time of each keyframe, means of 20 (\`frontend_cost.csv\` of the replay has every"
  echo "keyframe): ![front-end cost](plots/long_run_frontend_cost.png)"
  echo
  echo '```'
  grep -E "^front-end cost per keyframe|^front end per keyframe|^front-end memory|^loop closures|^two-view pairs" "$OUT/long.txt"
  echo '```'
  echo
  echo "## Loop closures on every lap (three laps)"
  echo
  echo "Loop-closure edges by the lap of their newer keyframe, and of them those to a keyframe of an earlier lap:"
  echo
  echo "| lap | loop closures | to an earlier lap |"
  echo "|---|---|---|"
  lap_table
  echo
  echo "## Summaries"
  for name in long laps demo demo_voting mid long_pixel60 mid_pixel60; do
    echo
    echo "### $name"
    echo
    echo '```'
    sed -e '/^outputs:/,$d' "$OUT/$name.txt"
    echo '```'
  done
} > results/long_run.md
echo "wrote results/long_run.md"
