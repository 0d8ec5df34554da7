#!/usr/bin/env bash
# The README's main command: set up, then solve a built-in synthetic view graph
# with ground truth and print the scores of each method; if the shared real
# data is present, also solve sphere2500 and score it against ground truth.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
ROTAVG=build/devel/lib/rotation_averaging/rotavg
echo
echo "== Built-in synthetic graph =="
"$ROTAVG" demo
DATA=../shared/data/pose_graphs
if [ -f "$DATA/sphere2500.txt" ]; then
  echo
  echo "== sphere2500 (real benchmark graph, scored against its noise-free version) =="
  mkdir -p demo_output
  "$ROTAVG" solve "$DATA/sphere2500.txt" --gt "$DATA/sphere2500_groundtruth.txt" \
    --output demo_output/sphere2500_orientations.csv
fi
