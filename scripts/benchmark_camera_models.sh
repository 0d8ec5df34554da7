#!/usr/bin/env bash
# Regenerates results/camera_models.md: what the lens distortion model does
# for the node on raw camera streams.
#  * EuRoC's real stereo camera (../shared/data/euroc_v1_01_micro, both
#    cameras at 20 Hz, radial-tangential k1 = -0.28): its bag replayed with
#    the model (image_raw), with the model ignored (image_type: rectified on
#    the raw images), and rectified by image_proc's method (--rectify); the
#    cam0 -> cam1 rotation of each capture's solved orientations against the
#    calibration's.
#  * Real image content with a known distortion: Strecha scenes (one camera,
#    a quarter of full width) warped through a plumb_bob and an equidistant
#    (fisheye) lens, and the demo renderer through a plumb_bob lens: median
#    error against ground truth on the original input, with the model,
#    without it, and on the warped images rectified (image_proc's
#    image_rect of the same stream); and the scenes' sequential pairs, the
#    same image pairs in every input, scored one by one; each view's error;
#    and the plumb_bob inputs with loop closures admitted at 36 and 44
#    inliers instead of 40.
#  * A sensor read out binned or by a region of interest (camera_info's
#    binning_x/binning_y and roi, REP 104): the demo rendered on a larger
#    sensor, with and without the lens.
#   bash scripts/benchmark_camera_models.sh        (about fifteen minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_camera_models
mkdir -p "$OUT"
EUROC="$DATA/euroc_v1_01_micro/mav0"
[ -d "$EUROC" ] || { echo "benchmark_camera_models: $EUROC is missing (see ../shared/data/README.md)" >&2; exit 1; }

# EuRoC: the rig's extrinsics are not used, so that each capture's cam0 and
# cam1 keyframes are solved on their own and their relative rotation is
# measured, not imposed.
"$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
"$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --rectify --output "$OUT/euroc_rectified.bag" > /dev/null
# Every image is a keyframe (keyframe_selection: all): the vehicle stands
# still, and each stereo capture is a measurement of the rig.
STEREO=('image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' "use_rig_extrinsics: false" "keyframe_selection: all")
replay_with euroc_model "$OUT/euroc.bag" "${STEREO[@]}"
replay_with euroc_ignored "$OUT/euroc.bag" "${STEREO[@]}" "image_type: rectified"
replay_with euroc_rectified "$OUT/euroc_rectified.bag" "${STEREO[@]}"

# Strecha scenes through a lens; the lens keeps the scene's K.
PLUMB_BOB=plumb_bob:-0.28,0.07,0.0002,0.00002
FISHEYE=equidistant:0.02,-0.01,0.005,-0.001
SCENES=()
for s in fountain-P11 castle-P19; do
  [ -d "$DATA/strecha/$s" ] && SCENES+=("$s")
done
STRECHA='image_topics: ["/camera/image_raw"]'
# The scenes' images are keyframes (a photo collection played as a sequence).
for s in "${SCENES[@]}"; do
  C="$DATA/strecha/$s"
  for lens in none plumb_bob equidistant; do
    flags=()
    [ "$lens" = plumb_bob ] && flags=(--distortion "$PLUMB_BOB")
    [ "$lens" = equidistant ] && flags=(--distortion "$FISHEYE")
    strecha_bag "$C" "$OUT/${s}_$lens.bag" "${flags[@]}"
    replay_with "${s}_${lens}_model" "$OUT/${s}_$lens.bag" "$STRECHA" "keyframe_selection: all" "max_features: 4000"
    if [ "$lens" != none ]; then
      replay_with "${s}_${lens}_ignored" "$OUT/${s}_$lens.bag" "$STRECHA" "keyframe_selection: all" \
        "max_features: 4000" "image_type: rectified"
      # Through the lens and back (warped, then rectified): what the
      # resampling and the lens's compression of the periphery lose.
      strecha_bag "$C" "$OUT/${s}_${lens}_rectified.bag" "${flags[@]}" --rectify
      replay_with "${s}_${lens}_rectified" "$OUT/${s}_${lens}_rectified.bag" "$STRECHA" "keyframe_selection: all" \
        "max_features: 4000"
    fi
  done
  # Every pair of the final graphs scored against ground truth with its
  # covariance: the sequential pairs are the same image pairs in each input.
  for run in none_model plumb_bob_model plumb_bob_rectified equidistant_model equidistant_rectified; do
    "$BIN/rotavg" eval --graph "$OUT/${s}_$run/graph.txt" --gt "$OUT/${s}_$run/ground_truth.csv" --per-edge \
      > "$OUT/${s}_${run}_eval.txt"
    # And each view's error: where along the sequence the inputs differ.
    "$BIN/rotavg" eval --estimate "$OUT/${s}_$run/orientations.csv" --gt "$OUT/${s}_$run/ground_truth.csv" \
      --per-view > "$OUT/${s}_${run}_views.txt"
  done
  # The plumb_bob inputs again with loop closures admitted at fewer and at
  # more inliers (min_loop_inliers, default 40): whether a median above is
  # the input's, or that of which marginal loop closures got in.
  for inliers in 36 44; do
    replay_with "${s}_none_model_loops$inliers" "$OUT/${s}_none.bag" "$STRECHA" "keyframe_selection: all" \
      "max_features: 4000" "min_loop_inliers: $inliers"
    replay_with "${s}_plumb_bob_model_loops$inliers" "$OUT/${s}_plumb_bob.bag" "$STRECHA" "keyframe_selection: all" \
      "max_features: 4000" "min_loop_inliers: $inliers"
    replay_with "${s}_plumb_bob_rectified_loops$inliers" "$OUT/${s}_plumb_bob_rectified.bag" "$STRECHA" \
      "keyframe_selection: all" "max_features: 4000" "min_loop_inliers: $inliers"
  done
done

# The demo renderer (two cameras, 60 captures) through the plumb_bob lens,
# and through it and back.
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_none.bag" > /dev/null
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob.bag" --distortion "$PLUMB_BOB" > /dev/null
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob_rectified.bag" --distortion "$PLUMB_BOB" \
  --rectify > /dev/null
DEMO=$(grep -v '^#' config/demo.yaml | grep .)
replay_with demo_none_model "$OUT/demo_none.bag" "$DEMO"
replay_with demo_plumb_bob_model "$OUT/demo_plumb_bob.bag" "$DEMO"
replay_with demo_plumb_bob_ignored "$OUT/demo_plumb_bob.bag" "$DEMO" "image_type: rectified"
replay_with demo_plumb_bob_rectified "$OUT/demo_plumb_bob_rectified.bag" "$DEMO"
# The demo's pairs on their own: the same three inputs without the rig's
# extrinsics (each keyframe a view), every pair scored against ground truth
# with its covariance.
NO_RIG=$(echo "$DEMO" | grep -v '^use_rig_extrinsics:')
for input in none_model plumb_bob_model plumb_bob_rectified; do
  bag="$OUT/demo_${input%_model}.bag"
  replay_with "demo_${input}_pairs" "$bag" "$NO_RIG" "use_rig_extrinsics: false"
  "$BIN/rotavg" eval --graph "$OUT/demo_${input}_pairs/graph.txt" --gt "$OUT/demo_${input}_pairs/ground_truth.csv" \
    --per-edge > "$OUT/demo_${input}_pairs_eval.txt"
done

# A driver that reads its sensor out in part or binned (REP 104): the demo
# rendered on a larger sensor and read out binned 2 x 2, or by a region of
# interest, with no lens and through the plumb_bob lens; camera_info keeps
# the sensor's K and size. And binned with camera_info's principal point
# half a sensor pixel off: where image_geometry's binning formula, which
# leaves out half a block, puts the binned image's camera.
readout() {  # name, make_demo_bag flags...
  local name=$1
  shift
  "$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_$name.bag" "$@" > /dev/null
  replay_with "demo_$name" "$OUT/demo_$name.bag" "$DEMO"
}
BIN2=(--width 1280 --height 960 --binning 2)
ROI=(--width 800 --height 600 --roi 80,60,640,480)
readout readout_binned "${BIN2[@]}"
readout readout_binned_offset "${BIN2[@]}" --info-principal-offset 0.5,0.5
readout readout_binned_plumb_bob "${BIN2[@]}" --distortion "$PLUMB_BOB"
readout readout_binned_plumb_bob_offset "${BIN2[@]}" --distortion "$PLUMB_BOB" --info-principal-offset 0.5,0.5
readout readout_roi "${ROI[@]}"
readout readout_roi_plumb_bob "${ROI[@]}" --distortion "$PLUMB_BOB"

python3 scripts/camera_models_report.py "$OUT" "$EUROC" "$PLUMB_BOB" "$FISHEYE" "${SCENES[@]}" \
  > results/camera_models.md
echo "wrote results/camera_models.md"
