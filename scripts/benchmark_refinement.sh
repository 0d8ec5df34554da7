#!/usr/bin/env bash
# Regenerates results/refinement.md: the node's background refinement (the
# bundle adjustment of its newest keyframes on their pairs' inliers,
# `refinement`) on and off, on every input with ground truth:
#  * the Strecha scenes and lund_door at a quarter of full width as bags,
#    every photograph a keyframe, against `rotavg images` (every pair, the
#    averaging, focal self-calibration and the bundle adjustment) on the same
#    images;
#  * the demo bag (two cameras, rig extrinsics known, one capture a second);
#  * the demo renderer's rig as a 20 Hz driver publishes it (one loop in
#    30 s), and its forward camera alone (a bag of that camera);
#  * EuRoC's raw stereo stream.
# Replays refine by bag time (refinement_period_s), each refinement on a
# thread of its own while the bag goes on, taken when the next is due, and
# the final solution in the replay's thread: the same refinements on every
# run, and their time is in the wall and CPU time.
#   bash scripts/benchmark_refinement.sh        (about fifteen minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_refinement
mkdir -p "$OUT" build/demo

PHOTOS=()
for s in castle-P19 entry-P10 fountain-P11; do
  [ -d "$DATA/strecha/$s" ] || continue
  [ -f "$OUT/$s.bag" ] || strecha_bag "$DATA/strecha/$s" "$OUT/$s.bag"
  "$BIN/rotavg" images --images "$DATA/strecha/$s/images" --intrinsics "$DATA/strecha/$s/images/K.txt" \
    --downsample 0.25 --pairs exhaustive --gt "$DATA/strecha/$s" > "$OUT/${s}_offline.txt"
  PHOTOS+=("$s")
done
if [ -d "$DATA/lund_door" ]; then
  [ -f "$OUT/lund_door.bag" ] || lund_door_bag "$OUT/lund_door.bag"
  "$BIN/rotavg" images --images "$DATA/lund_door/images" --intrinsics "$DATA/lund_door/colmap_ground_truth/cameras.txt" \
    --downsample 0.25 --pairs exhaustive --gt "$DATA/lund_door/colmap_ground_truth/images.txt" \
    > "$OUT/lund_door_offline.txt"
  PHOTOS+=(lund_door)
fi
PHOTO_CONFIG=('image_topics: ["/camera/image_raw"]' "features: sift" "max_features: 4000" "keyframe_selection: all")
for s in "${PHOTOS[@]}"; do
  for r in false true; do replay_with "${s}_$r" "$OUT/$s.bag" "${PHOTO_CONFIG[@]}" "refinement: $r"; done
done

demo_bags
for r in false true; do
  replay_with "demo_$r" "$DEMO" "${demo[@]}" "refinement: $r"
  replay_with "stream_$r" "$STREAM" "${stream[@]}" "keyframe_selection: motion" "refinement: $r"
  replay_with "one_camera_$r" "$ONE" "${one[@]}" 'image_topics: ["/cam_front/image_raw"]' \
    "keyframe_selection: motion" "refinement: $r"
done

# A focal length that agrees: the refinement with the focal length held once
# a refinement finds it agreeing (the default) against free in every one, on
# the rendered rig, whose camera_info is exact; with the four-camera 20 Hz
# stream and a 600-keyframe bag (two cameras, every image a keyframe) whose
# keyframes outnumber the refinement's window (refinement_max_keyframes).
FOUR=build/demo/demo_20hz_600_4cam.bag
[ -f "$FOUR" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$FOUR" --captures 600 --period 0.05 \
  --cameras 4 > /dev/null 2>&1
LONG=build/demo/demo_300_2cam.bag
[ -f "$LONG" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$LONG" --captures 300 --cameras 2 > /dev/null 2>&1
four=("${one[@]}" 'image_topics: ["/cam_front/image_raw", "/cam_left/image_raw", "/cam_back/image_raw", "/cam_right/image_raw"]'
  "keyframe_selection: motion")
replay_with "demo_free_focal" "$DEMO" "${demo[@]}" "refinement_hold_agreed_focal: false"
replay_with "stream_free_focal" "$STREAM" "${stream[@]}" "keyframe_selection: motion" \
  "refinement_hold_agreed_focal: false"
for r in false true; do
  replay_with "four_cameras_$r" "$FOUR" "${four[@]}" "refinement: $r"
  replay_with "long_$r" "$LONG" "${demo[@]}" "refinement: $r"
done
replay_with "four_cameras_free_focal" "$FOUR" "${four[@]}" "refinement_hold_agreed_focal: false"
replay_with "long_free_focal" "$LONG" "${demo[@]}" "refinement_hold_agreed_focal: false"
# The keyframes before the window: the window adjusted alone, turned to the
# averaging's frame, against with the older keyframes its edges reach held
# (the default); each keyframe's error, for the errors along the bag.
replay_with "four_cameras_window_alone" "$FOUR" "${four[@]}" "refinement_hold_outside: false"
replay_with "long_window_alone" "$LONG" "${demo[@]}" "refinement_hold_outside: false"
# The sweep back: the final solution refined again over the keyframes the
# windows had no room for (the default) against the newest window alone.
replay_with "four_cameras_no_sweep" "$FOUR" "${four[@]}" "refinement_sweep_back: false"
replay_with "long_no_sweep" "$LONG" "${demo[@]}" "refinement_sweep_back: false"
for run in four_cameras_false four_cameras_true four_cameras_window_alone four_cameras_no_sweep \
  long_false long_true long_window_alone long_no_sweep; do
  "$BIN/rotavg" eval --estimate "$OUT/$run/orientations.csv" --gt "$OUT/$run/ground_truth.csv" --per-view \
    > "$OUT/$run/per_view.txt"
done

EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  [ -f "$OUT/euroc.bag" ] || "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
  for r in false true; do
    replay_with "euroc_$r" "$OUT/euroc.bag" 'image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' \
      "use_rig_extrinsics: false" "keyframe_selection: motion" "keyframe_max_interval_s: 0.5" "refinement: $r"
  done
fi

# OpenBLAS's pool against OpenBLAS held to one thread (the package's
# default; a thread count the user sets is left alone, so
# OPENBLAS_NUM_THREADS=2 gives the pool back): the demo bag with the
# refinement and the front end on one thread, so that the second core is the
# pool's, alternated twice in the same run.
for k in 1 2; do
  OPENBLAS_NUM_THREADS=2 replay_with "openblas_pool_$k" "$DEMO" "${demo[@]}" "num_threads: 1"
  replay_with "openblas_held_$k" "$DEMO" "${demo[@]}" "num_threads: 1"
done

python3 scripts/refinement_report.py "$OUT" "$(IFS=,; echo "${PHOTOS[*]}")" "$EUROC" > results/refinement.md
echo "wrote results/refinement.md"
