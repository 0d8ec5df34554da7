#!/usr/bin/env bash
# Regenerates results/replay.md: rotation_averaging_replay on the demo bag
# (rendered two-camera rig, 60 captures) and on castle-P19 turned into a bag
# (one camera, images at a quarter of full width), with scores against ground
# truth and the speed against real time (bags at one capture per second).
#   bash scripts/benchmark_replay.sh        (about three minutes)
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh > /dev/null
export PATH=/usr/bin:$PATH
BIN=build/devel/lib/rotation_averaging
OUT=build/benchmark_replay
mkdir -p "$OUT" build/demo
DATA=${ROTAVG_DATA_DIR:-../shared/data}

DEMO=build/demo/demo_60.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config config/demo.yaml --gt "$DEMO" --output-dir "$OUT/demo" \
  --no-progress > "$OUT/demo.txt"

CASTLE_ROW=""
if [ -d "$DATA/strecha/castle-P19" ]; then
  C="$DATA/strecha/castle-P19"
  "$BIN/rotation_averaging_images_to_bag" --images "$C/images" --intrinsics "$C/images/K.txt" --gt "$C" \
    --downsample 0.25 --output "$OUT/castle.bag" > /dev/null 2>&1
  printf 'image_topics: ["/camera/image_raw"]\nfeatures: sift\nmax_features: 4000\n' > "$OUT/castle.yaml"
  "$BIN/rotation_averaging_replay" --bag "$OUT/castle.bag" --config "$OUT/castle.yaml" --gt "$OUT/castle.bag" \
    --output-dir "$OUT/castle" --no-progress > "$OUT/castle.txt"
  # Loop-closure recall of the retrieval against an exhaustive two-view search
  # of the same images (same resolution and two-view settings).
  "$BIN/rotavg" images --images "$C/images" --intrinsics "$C/images/K.txt" --downsample 0.25 --pairs exhaustive \
    --graph-out "$OUT/castle_exhaustive_graph.txt" --output "$OUT/castle_exhaustive.csv" > /dev/null
  "$BIN/rotavg_loop_recall" --exhaustive "$OUT/castle_exhaustive_graph.txt" --keyframes "$OUT/castle/graph.txt" \
    --gt "$C" > "$OUT/castle_recall.txt"
fi

row() {  # name, summary file
  local f="$2"
  local speed wall cpu mem kf median auc2 auc5 auc10
  speed=$(sed -n 's/.*(\([0-9.]*\)x real time).*/\1/p' "$f")
  wall=$(sed -n 's/.*wall time: \([0-9.]*\) s.*/\1/p' "$f")
  bag=$(sed -n 's/^bag time: \([0-9.]*\) s.*/\1/p' "$f")
  cpu=$(sed -n 's/.*CPU time: \([0-9.]*\) s.*/\1/p' "$f")
  mem=$(sed -n 's/.*peak memory: \([0-9.]*\) MiB.*/\1/p' "$f")
  kf=$(sed -n 's/^keyframes: \([0-9]*\) .*/\1/p' "$f")
  median=$(sed -n 's/^median error: \([0-9.]*\) deg/\1/p' "$f")
  auc2=$(sed -n 's/^AUC@2: \([0-9.]*\) %/\1/p' "$f")
  auc5=$(sed -n 's/^AUC@5: \([0-9.]*\) %/\1/p' "$f")
  auc10=$(sed -n 's/^AUC@10: \([0-9.]*\) %/\1/p' "$f")
  echo "| $1 | $kf | $bag | $wall | ${speed}x | $cpu | $mem | $median | $auc2 | $auc5 | $auc10 |"
}

{
  echo "# Bag replay"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_replay.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "Each bag goes through \`rotation_averaging_replay\` (the node's pipeline: SIFT front end with"
  echo "loop-closure retrieval, MAGSAC + covariance averaging re-solved every second of bag time). Speed-up ="
  echo "bag duration / wall time; both bags hold one capture per second."
  echo
  echo "| bag | keyframes | bag time (s) | wall (s) | speed-up | CPU (s) | peak MiB | median (deg) | AUC@2 | AUC@5 | AUC@10 |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|"
  row "demo: rendered 2-camera rig, 640x480, 60 captures (config/demo.yaml)" "$OUT/demo.txt"
  if [ -f "$OUT/castle.txt" ]; then
    row "castle-P19 at 768x512 (one camera, 19 images)" "$OUT/castle.txt"
  fi
  echo
  echo "## Demo bag"
  echo
  echo '```'
  cat "$OUT/demo.txt"
  echo '```'
  if [ -f "$OUT/castle.txt" ]; then
    echo
    echo "## castle-P19"
    echo
    echo "Made with \`rotation_averaging_images_to_bag --images castle-P19/images --intrinsics castle-P19/images/K.txt --gt castle-P19 --downsample 0.25\`."
    echo
    echo '```'
    cat "$OUT/castle.txt"
    echo '```'
    echo
    echo "### Loop-closure retrieval recall"
    echo
    echo "The path returns to its start. Against an exhaustive two-view search of the same 19 images"
    echo '(`rotavg images --pairs exhaustive --downsample 0.25`, then `rotavg_loop_recall`): pairs more'
    echo "than 5 images apart that the search verifies with >= 60 inliers and whose rotation is within 2 deg"
    echo "of ground truth, and how many of them the retrieval (3 candidates per keyframe) found:"
    echo
    echo '```'
    cat "$OUT/castle_recall.txt"
    echo '```'
  else
    echo
    echo "castle-P19 skipped: $DATA/strecha/castle-P19 is absent."
  fi
} > results/replay.md
echo "wrote results/replay.md"
