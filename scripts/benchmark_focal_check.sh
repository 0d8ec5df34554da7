#!/usr/bin/env bash
# Regenerates results/focal_check.md: the node's check of each camera's focal
# length against its own verified pairs (focal_calibration: warn), replayed
# through rotation_averaging_replay.
#  * The demo renderer (two cameras, 60 captures) with camera_info's focal
#    lengths right, 3% short and 3% long (make_demo_bag --info-focal-scale):
#    every estimate as it came, the last one, and the averaging's error.
#  * The same bag with the check off: what it costs the replay, which waits
#    for each estimate (the node runs them beside its front end); and with
#    focal_calibration: apply.
#  * Lens distortion that camera_info does not describe: the demo through a
#    plumb_bob lens and EuRoC's stereo camera, read without their model.
#  * A raw camera with its model: the plumb_bob demo (the rig, and one
#    camera) with camera_info's focal lengths right and 3% short (warn, and
#    apply with and without the loops' refinement), and how the error
#    depends on a focal length a little off (`off`, from the first image).
#  * Strecha scenes, whose K is exact, played as one camera's keyframes at a
#    quarter of full width: the check must agree with them.
#   bash scripts/benchmark_focal_check.sh        (about twenty minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_focal_check
mkdir -p "$OUT"

# The focal lengths a replay with `apply` on a x0.97 bag ended at, of the
# true ones (0.97 times each correction), for the cameras given in order.
ended_at() {
  python3 - "$@" <<'PY'
import re, sys
text = open(sys.argv[1]).read()
found = dict(re.findall(r"focal length corrected \(focal_calibration: apply\): (\S+): camera_info's focal length x([\d.]+)", text))
print(",".join("%.6f" % (0.97 * float(found.get(c, 1.0))) for c in sys.argv[2:]))
PY
}

DEMO=$(grep -v '^#' config/demo.yaml | grep .)
for scale in 0.97 1 1.03; do
  "$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_$scale.bag" --info-focal-scale "$scale" > /dev/null 2>&1
  replay_with "demo_${scale}_warn" "$OUT/demo_$scale.bag" "$DEMO"
  replay_with "demo_${scale}_off" "$OUT/demo_$scale.bag" "$DEMO" "focal_calibration: off"
  replay_with "demo_${scale}_apply" "$OUT/demo_$scale.bag" "$DEMO" "focal_calibration: apply"
done

# A lens camera_info does not describe: the demo through a plumb_bob lens
# and EuRoC's real stereo camera (k1 = -0.28), both read as rectified
# images (image_type: rectified: no distortion model), as a driver whose
# camera_info lacks D would have them.
PLUMB_BOB=plumb_bob:-0.28,0.07,0.0002,0.00002
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob.bag" --distortion "$PLUMB_BOB" > /dev/null 2>&1
replay_with demo_plumb_bob_ignored "$OUT/demo_plumb_bob.bag" "$DEMO" "image_type: rectified"
replay_with demo_plumb_bob_model "$OUT/demo_plumb_bob.bag" "$DEMO"
# The same lens with its model, camera_info's focal lengths 3% short: the
# check of a raw camera, and its correction.
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob_0.97.bag" --distortion "$PLUMB_BOB" \
  --info-focal-scale 0.97 > /dev/null 2>&1
replay_with demo_plumb_bob_0.97_warn "$OUT/demo_plumb_bob_0.97.bag" "$DEMO"
replay_with demo_plumb_bob_0.97_apply "$OUT/demo_plumb_bob_0.97.bag" "$DEMO" "focal_calibration: apply"
replay_with demo_plumb_bob_0.97_check_only "$OUT/demo_plumb_bob_0.97.bag" "$DEMO" "focal_calibration: apply" \
  "focal_loop_refinement: false"
# The same with one camera (the rig's forward one): no second camera whose
# pairs relate the same captures.
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo1_plumb_bob.bag" --cameras 1 --distortion "$PLUMB_BOB" \
  > /dev/null 2>&1
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo1_plumb_bob_0.97.bag" --cameras 1 \
  --distortion "$PLUMB_BOB" --info-focal-scale 0.97 > /dev/null 2>&1
DEMO1=$(printf '%s\n' "$DEMO" | grep -v '^image_topics:'; echo 'image_topics: ["/cam_front/image_raw"]')
replay_with demo1_plumb_bob_model "$OUT/demo1_plumb_bob.bag" "$DEMO1"
replay_with demo1_plumb_bob_0.97_warn "$OUT/demo1_plumb_bob_0.97.bag" "$DEMO1"
replay_with demo1_plumb_bob_0.97_apply "$OUT/demo1_plumb_bob_0.97.bag" "$DEMO1" "focal_calibration: apply"
replay_with demo1_plumb_bob_0.97_check_only "$OUT/demo1_plumb_bob_0.97.bag" "$DEMO1" "focal_calibration: apply" \
  "focal_loop_refinement: false"
# The focal lengths apply arrived at, in camera_info from the first image
# (the true ones times 0.97 times each correction): the best apply can do
# with its estimates, their residual errors included.
CORRECTED=$(ended_at "$OUT/demo_plumb_bob_0.97_apply.txt" cam_front cam_left)
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob_corrected.bag" --distortion "$PLUMB_BOB" \
  --info-focal-scale "$CORRECTED" > /dev/null 2>&1
replay_with demo_plumb_bob_corrected_off "$OUT/demo_plumb_bob_corrected.bag" "$DEMO" "focal_calibration: off"
echo "$CORRECTED" > "$OUT/demo_plumb_bob_corrected.scales"
# How little a focal length may be off: both cameras 0.02% and 0.13% short.
for scale in 0.9998 0.9987; do
  "$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo_plumb_bob_$scale.bag" --distortion "$PLUMB_BOB" \
    --info-focal-scale "$scale" > /dev/null 2>&1
  replay_with "demo_plumb_bob_${scale}_off" "$OUT/demo_plumb_bob_$scale.bag" "$DEMO" "focal_calibration: off"
done
# The same for one camera: where `apply` ended on it, and a few thousandths
# of a percent short of the true focal length (its loops' own deviation).
CORRECTED1=$(ended_at "$OUT/demo1_plumb_bob_0.97_apply.txt" cam_front)
"$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo1_plumb_bob_corrected.bag" --cameras 1 \
  --distortion "$PLUMB_BOB" --info-focal-scale "$CORRECTED1" > /dev/null 2>&1
replay_with demo1_plumb_bob_corrected_off "$OUT/demo1_plumb_bob_corrected.bag" "$DEMO1" "focal_calibration: off"
echo "$CORRECTED1" > "$OUT/demo1_plumb_bob_corrected.scales"
for scale in 0.99998 0.9999; do
  "$BIN/rotation_averaging_make_demo_bag" --output "$OUT/demo1_plumb_bob_$scale.bag" --cameras 1 \
    --distortion "$PLUMB_BOB" --info-focal-scale "$scale" > /dev/null 2>&1
  replay_with "demo1_plumb_bob_${scale}_off" "$OUT/demo1_plumb_bob_$scale.bag" "$DEMO1" "focal_calibration: off"
done
EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
  replay_with euroc_ignored "$OUT/euroc.bag" 'image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' \
    "keyframe_selection: all" "image_type: rectified"
fi

SCENES=()
for s in fountain-P11 herzjesu-P8 entry-P10 castle-P19 herzjesu-P25 castle-P30; do
  [ -d "$DATA/strecha/$s" ] && SCENES+=("$s")
done
for s in "${SCENES[@]}"; do
  C="$DATA/strecha/$s"
  strecha_bag "$C" "$OUT/$s.bag"
  replay_with "$s" "$OUT/$s.bag" 'image_topics: ["/camera/image_raw"]' "keyframe_selection: all" "max_features: 4000"
done

python3 scripts/focal_check_report.py "$OUT" "${SCENES[@]}" > results/focal_check.md
echo "wrote results/focal_check.md"
