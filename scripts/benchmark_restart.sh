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

full_median=$(value "$OUT/full.txt" '^median error: \([0-9.]*\) deg')
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

{
  echo "# Restarts: the map saved and loaded"
  echo
  echo "Reproduce with: \`bash scripts/benchmark_restart.sh\`. Generated $(date -u '+%Y-%m-%d %H:%M') UTC on a $(nproc)-core machine."
  echo "The demo bag (60 captures of the rendered two-camera rig, once round the room; config/demo.yaml) cut"
  echo "after the capture of each row: the part before it replayed with \`save_on_shutdown\` (the map: graph,"
  echo "\`.rig\`, \`.keyframes\`), the part after it with \`load_graph\` on that map, as a node killed there and"
  echo "restarted would (\`rotation_averaging_replay\` runs the node's pipeline; docs/node.md, \"The map across"
  echo "restarts and sessions\"). Components, keyframes and accuracy are those of the second replay, over every"
  echo "keyframe of both parts; the uninterrupted replay of the whole bag is the reference. \"Moved at load\": the"
  echo "largest angle between a saved keyframe's orientation in the map file and at the first solve after loading"
  echo "(the frames published before the restart). \"Moved at the merge\": the largest move of a saved keyframe"
  echo "from there to the first solve that joined a new keyframe to them, in degrees and in that keyframe's"
  echo "posterior standard deviation along the move (relative to the gauge keyframe, which the solve holds where"
  echo "it was published), and the rotation of their frame as a whole (the one rotation that best maps them from"
  echo "before to after: a new gauge would turn it by degrees)."
  echo
  echo "| restart after capture | keyframes before / after the restart | keyframes in the final map | components | loop closures after the restart | median (deg) | median / uninterrupted | moved at load (deg) | moved at the merge (deg / std) | frame rotated at the merge (deg) | database per keyframe (KB) | save (ms) | load (ms) |"
  echo "|---|---|---|---|---|---|---|---|---|---|---|---|---|"
  echo "| none (uninterrupted) | - | $(value "$OUT/full.txt" '^keyframes: \([0-9]*\) .*') |" \
    "$(value "$OUT/full.txt" '^components: \([0-9]*\);.*') | $(value "$OUT/full.txt" '^loop closures: \([0-9]*\) edges.*') |" \
    "$full_median | 1.00 | - | - | - | - | - | - |"
  for n in "${CUTS[@]}"; do
    a=$OUT/before_$n.txt b=$OUT/after_$n.txt
    kf_before=$(value "$a" '^keyframes: \([0-9]*\) .*')
    median=$(value "$b" '^median error: \([0-9.]*\) deg')
    db_bytes=$(stat -c %s "$OUT/map_$n/graph.txt.keyframes")
    echo "| $n | $kf_before / $(value "$b" '^keyframes: .* (\([0-9]*\) images through.*') |" \
      "$(value "$b" '^keyframes: \([0-9]*\) .*') | $(value "$b" '^components: \([0-9]*\);.*') |" \
      "$(value "$b" '^loop closures: \([0-9]*\) edges.*') | $median |" \
      "$(awk -v a="$median" -v b="$full_median" 'BEGIN { printf "%.2f", a / b }') |" \
      "$(value "$b" '^loaded keyframes at the first solve: moved at most \([0-9.]*\) deg.*') |" \
      "$(value "$b" '^loaded keyframes when .*moved at most \([0-9.]*\) deg, .*') /" \
      "$(value "$b" '^loaded keyframes when .* deg, \([0-9.]*\) posterior.*') |" \
      "$(value "$b" '^loaded keyframes when .*rotated by \([0-9.]*\) deg$') |" \
      "$(awk -v s="$db_bytes" -v k="$kf_before" 'BEGIN { printf "%.1f", s / 1024 / k }') |" \
      "$(value "$a" '^map saved in \([0-9.]*\) ms.*') | $(value "$b" '^map loaded in \([0-9.]*\) ms.*') |"
  done
} > results/restart.md
cat results/restart.md
