#!/usr/bin/env bash
# Regenerates results/replay.md: rotation_averaging_replay on the demo bag
# (rendered two-camera rig, 60 captures) and on the Strecha scenes turned into
# bags (one camera, images at a quarter of full width), with scores against
# ground truth, the speed against real time (bags at one capture per second)
# and the loop-closure recall of the retrieval, with one_loop_per_place (the
# default) and with every loop kept, with window pairs (the default) and without; and the node against
# `rotavg images --no-bundle-adjustment` on the Strecha scenes, lund_door and
# the demo's images.
#   bash scripts/benchmark_replay.sh        (about twenty minutes: the demo's exhaustive offline run takes 14)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_replay
mkdir -p "$OUT" build/demo

DEMO=build/demo/demo_60.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config config/demo.yaml --gt "$DEMO" --output-dir "$OUT/demo" \
  --no-progress > "$OUT/demo.txt"
{ cat config/demo.yaml; echo "one_loop_per_place: false"; } > "$OUT/demo_all.yaml"
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config "$OUT/demo_all.yaml" --gt "$DEMO" --output-dir "$OUT/demo_all" \
  --no-progress > "$OUT/demo_all.txt"
{ cat config/demo.yaml; echo "window_pairs: false"; } > "$OUT/demo_chain.yaml"
"$BIN/rotation_averaging_replay" --bag "$DEMO" --config "$OUT/demo_chain.yaml" --gt "$DEMO" \
  --output-dir "$OUT/demo_chain" --no-progress > "$OUT/demo_chain.txt"

# Strecha scenes as bags (one camera, images at a quarter of full width):
# castle-P19 replayed for the table, and every scene for loop-closure recall
# of the retrieval against an exhaustive two-view search of the same images
# (same resolution and two-view settings), with the vocabulary (defaults)
# and with voting over every keyframe's full features (vocabulary: none).
scene_bag() {  # name images intrinsics ground-truth: $OUT/name.bag and its configuration
  "$BIN/rotation_averaging_images_to_bag" --images "$2" --intrinsics "$3" --gt "$4" \
    --downsample 0.25 --output "$OUT/$1.bag" > /dev/null 2>&1
  printf 'image_topics: ["/camera/image_raw"]\nkeyframe_selection: all\nfeatures: sift\nmax_features: 4000\n' > "$OUT/$1.yaml"
}
replay_scene() {  # name mode config: $OUT/name_mode.txt and $OUT/name_mode/
  "$BIN/rotation_averaging_replay" --bag "$OUT/$1.bag" --config "$3" --gt "$OUT/$1.bag" \
    --output-dir "$OUT/$1_$2" --no-progress > "$OUT/$1_$2.txt"
}
solve_afresh() {  # name: the node's final graph solved from its spanning tree, as the
  # offline solve starts; the replay's own solves start from the last one.
  "$BIN/rotavg" solve "$OUT/$1_vocabulary/graph.txt" --format rotavg --output "$OUT/$1_afresh.csv" \
    --gt "$OUT/$1_vocabulary/ground_truth.csv" > "$OUT/$1_afresh.txt"
}
SCENES=()
for s in castle-P19 entry-P10 fountain-P11; do
  [ -d "$DATA/strecha/$s" ] && SCENES+=("$s")
done
for s in "${SCENES[@]}"; do
  C="$DATA/strecha/$s"
  scene_bag "$s" "$C/images" "$C/images/K.txt" "$C"
  { cat "$OUT/$s.yaml"; echo "vocabulary: none"; } > "$OUT/${s}_voting.yaml"
  { cat "$OUT/$s.yaml"; echo "compact_features: 2000"; } > "$OUT/${s}_compact2000.yaml"
  { cat "$OUT/$s.yaml"; echo "loop_jackknife_grid: 0"; } > "$OUT/${s}_pixel.yaml"
  { cat "$OUT/$s.yaml"; echo "loop_jackknife_grid: 0"; echo "min_loop_inliers: 60"; } > "$OUT/${s}_pixel60.yaml"
  { cat "$OUT/$s.yaml"; echo "one_loop_per_place: false"; } > "$OUT/${s}_all.yaml"
  { cat "$OUT/$s.yaml"; echo "window_pairs: false"; } > "$OUT/${s}_chain.yaml"
  # Also the offline reference for the node: every pair, the averaging alone.
  "$BIN/rotavg" images --images "$C/images" --intrinsics "$C/images/K.txt" --downsample 0.25 --pairs exhaustive \
    --no-bundle-adjustment --gt "$C" --graph-out "$OUT/${s}_exhaustive_graph.txt" \
    --output "$OUT/${s}_exhaustive.csv" > "$OUT/${s}_exhaustive.txt"
  for mode in vocabulary voting compact2000 pixel pixel60 all chain; do
    config="$OUT/$s.yaml"
    [ "$mode" != vocabulary ] && config="$OUT/${s}_$mode.yaml"
    replay_scene "$s" "$mode" "$config"
    "$BIN/rotavg_loop_recall" --exhaustive "$OUT/${s}_exhaustive_graph.txt" --keyframes "$OUT/${s}_$mode/graph.txt" \
      --gt "$C" > "$OUT/${s}_${mode}_recall.txt"
  done
  solve_afresh "$s"
done

# lund_door (12 photographs, COLMAP's model as ground truth) as a bag too,
# for the node against rotavg images only: the same steps as above.
LUND=$DATA/lund_door
OFFLINE=("${SCENES[@]}")
if [ -d "$LUND" ]; then
  OFFLINE+=(lund_door)
  scene_bag lund_door "$LUND/images" "$LUND/colmap_ground_truth/cameras.txt" "$LUND/colmap_ground_truth/images.txt"
  replay_scene lund_door vocabulary "$OUT/lund_door.yaml"
  { cat "$OUT/lund_door.yaml"; echo "one_loop_per_place: false"; } > "$OUT/lund_door_all.yaml"
  replay_scene lund_door all "$OUT/lund_door_all.yaml"
  { cat "$OUT/lund_door.yaml"; echo "window_pairs: false"; } > "$OUT/lund_door_chain.yaml"
  replay_scene lund_door chain "$OUT/lund_door_chain.yaml"
  "$BIN/rotavg" images --images "$LUND/images" --intrinsics "$LUND/colmap_ground_truth/cameras.txt" --downsample 0.25 \
    --pairs exhaustive --no-bundle-adjustment --gt "$LUND/colmap_ground_truth/images.txt" > "$OUT/lund_door_exhaustive.txt"
  solve_afresh lund_door
fi

# The demo's images as a folder (the bag's renders, under the bag's keyframe
# names) for the node against rotavg images on the demo as well. The offline
# run solves each image on its own: it has no rig.
DEMO_IMAGES=$OUT/demo_images
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_images.bag" --captures 60 --cameras 2 \
  --images-dir "$DEMO_IMAGES" > /dev/null 2>&1
rm -f "$OUT/demo_images.bag"
"$BIN/rotavg" images --images "$DEMO_IMAGES" --intrinsics "$DEMO_IMAGES/K.txt" --pairs exhaustive \
  --no-bundle-adjustment --gt "$DEMO_IMAGES/ground_truth.csv" > "$OUT/demo_exhaustive.txt"

python3 scripts/replay_report.py "$OUT" "$DATA" "$(IFS=,; echo "${SCENES[*]}")" "$(IFS=,; echo "${OFFLINE[*]}")" \
  > results/replay.md
echo "wrote results/replay.md"
