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
#      0, min_loop_inliers 60), and with every loop kept
#      (one_loop_per_place: false): what the defaults cost or gain there.
#   bash scripts/benchmark_long_run.sh        (about 25 minutes on 2 cores)
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
{ cat config/demo.yaml; echo "one_loop_per_place: false"; } > "$OUT/all_loops.yaml"
replay "$LONG" "$OUT/all_loops.yaml" long_all_loops
replay "$MID" "$OUT/all_loops.yaml" mid_all_loops
cp "$OUT/long/frontend_cost.png" results/plots/long_run_frontend_cost.png

python3 scripts/long_run_report.py "$OUT" > results/long_run.md
echo "wrote results/long_run.md"
