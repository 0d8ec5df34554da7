#!/usr/bin/env bash
# Regenerates results/lens.md: a lens camera_info does not describe (raw
# images, camera_info without distortion_model and D), which the camera_info
# check measures (a division model) and, with `focal_calibration: apply`
# (the default), gives the camera. Each input runs three ways:
#  * lens: camera_info carries the lens (the reference);
#  * warn: camera_info without it, focal_calibration: warn (the check warns);
#  * apply: camera_info without it, focal_calibration: apply (the default).
# Inputs: the rendered rig through a barrel lens of k1 -0.1 and -0.05, and
# through a pincushion one of +0.05; fountain-P11 and entry-P10 (real
# photographs, a quarter of full width) through k1 -0.1; EuRoC's stereo
# pair, raw (its own lens, k1 -0.28: no ground truth for orientations, the
# cam0 -> cam1 rotation against the calibration's); and the rig's images
# rectified, camera_info without a lens (nothing to give: no lens should be).
#   bash scripts/benchmark_lens.sh        (about ten minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_lens
mkdir -p "$OUT"

mapfile -t DEMO < <(grep -v '^#' config/demo.yaml | grep .)
STILLS=('image_topics: ["/camera/image_raw"]' "keyframe_selection: all" "max_features: 4000")
EUROC_LINES=('image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' "use_rig_extrinsics: false"
  "keyframe_selection: motion" "keyframe_max_interval_s: 0.5")

# One input's three runs: name, bag with the lens in camera_info, bag without, lines...
three() {
  local name=$1 with=$2 without=$3
  shift 3
  replay_with "${name}_lens" "$with" "$@" "focal_calibration: apply" &
  replay_with "${name}_warn" "$without" "$@" "focal_calibration: warn" &
  wait
  replay_with "${name}_apply" "$without" "$@" "focal_calibration: apply"
}

INPUTS=()
for k1 in -0.1 -0.05 0.05; do
  for info in lens nolens; do
    bag="$OUT/demo_${k1}_$info.bag"
    flags=(--distortion "plumb_bob:$k1,0,0,0")
    [ "$info" = nolens ] && flags+=(--info-no-lens)
    [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" "${flags[@]}" > /dev/null 2>&1
  done
  three "demo_$k1" "$OUT/demo_${k1}_lens.bag" "$OUT/demo_${k1}_nolens.bag" "${DEMO[@]}"
  INPUTS+=("demo_$k1")
done
for s in fountain-P11 entry-P10; do
  C="$DATA/strecha/$s"
  [ -d "$C" ] || continue
  [ -f "$OUT/${s}_lens.bag" ] || strecha_bag "$C" "$OUT/${s}_lens.bag" --distortion plumb_bob:-0.1,0,0,0
  [ -f "$OUT/${s}_nolens.bag" ] || strecha_bag "$C" "$OUT/${s}_nolens.bag" --distortion plumb_bob:-0.1,0,0,0 \
    --info-no-lens
  three "$s" "$OUT/${s}_lens.bag" "$OUT/${s}_nolens.bag" "${STILLS[@]}"
  INPUTS+=("$s")
done
EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  [ -f "$OUT/euroc_lens.bag" ] || "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" \
    --output "$OUT/euroc_lens.bag" > /dev/null
  [ -f "$OUT/euroc_nolens.bag" ] || "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --info-no-lens \
    --output "$OUT/euroc_nolens.bag" > /dev/null
  three euroc "$OUT/euroc_lens.bag" "$OUT/euroc_nolens.bag" "${EUROC_LINES[@]}"
  INPUTS+=(euroc)
fi
bag="$OUT/demo_rectified.bag"
[ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --distortion plumb_bob:-0.1,0,0,0 --rectify \
  > /dev/null 2>&1
replay_with demo_rectified_apply "$bag" "${DEMO[@]}" "focal_calibration: apply"

python3 scripts/lens_report.py "$OUT" "$EUROC" "${INPUTS[@]}" > results/lens.md
echo "wrote results/lens.md"
