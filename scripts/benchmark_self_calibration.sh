#!/usr/bin/env bash
# Regenerates results/self_calibration.md: each camera's focal length
# estimated in the node's background refinement (refinement_focal), with
# camera_info's focal length right and 3% off, replayed through
# rotation_averaging_replay. Three configurations per input:
#  * fixed: refinement_focal: false, focal_calibration: warn (the focal
#    length is camera_info's throughout; the focal check warns);
#  * warn:  refinement_focal: true, focal_calibration: warn (the refinement's
#    orientations are those of the adjustment with the focal length free;
#    it warns);
#  * apply: refinement_focal: true, focal_calibration: apply (the defaults:
#    it corrects).
# Inputs with ground truth: the rendered rig (1 capture a second, 60
# captures: the README's demo), its forward camera alone, the rig through a
# plumb_bob lens with its model, the Strecha scenes and lund_door as one
# camera's keyframes at a quarter of full width (camera_info's focal length
# x1 and x0.97); and EuRoC's stereo pair (its own calibration; no ground
# truth for orientations), where no correction should be made.
#   bash scripts/benchmark_self_calibration.sh        (about twenty minutes)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_self_calibration
mkdir -p "$OUT"

mapfile -t DEMO < <(grep -v '^#' config/demo.yaml | grep .)
mapfile -t DEMO1 < <(grep -v '^#' config/demo.yaml | grep . | grep -v '^image_topics:'; echo 'image_topics: ["/cam_front/image_raw"]')
STILLS=('image_topics: ["/camera/image_raw"]' "keyframe_selection: all" "max_features: 4000")
EUROC_LINES=('image_topics: ["/cam0/image_raw", "/cam1/image_raw"]' "use_rig_extrinsics: false"
  "keyframe_selection: motion" "keyframe_max_interval_s: 0.5")

# The three configurations of one input, two at a time: name, bag, lines...
three() {
  local name=$1 bag=$2
  shift 2
  replay_with "${name}_fixed" "$bag" "$@" "refinement_focal: false" "focal_calibration: warn" &
  replay_with "${name}_warn" "$bag" "$@" "refinement_focal: true" "focal_calibration: warn" &
  wait
  replay_with "${name}_apply" "$bag" "$@" "refinement_focal: true" "focal_calibration: apply"
}

# A camera file with its focal length times a scale: K.txt (3 x 3) or
# COLMAP's cameras.txt (SIMPLE_RADIAL / PINHOLE ...: the focal parameters).
scaled_intrinsics() {
  python3 - "$1" "$2" "$3" <<'PY'
import sys
source, scale, out = sys.argv[1], float(sys.argv[2]), sys.argv[3]
lines = open(source).read().splitlines()
if source.endswith("K.txt"):
    rows = [[float(v) for v in l.split()] for l in lines if l.strip()]
    rows[0][0] *= scale
    rows[1][1] *= scale
    text = "\n".join(" ".join(repr(v) for v in r) for r in rows)
else:
    focal_count = {"SIMPLE_PINHOLE": 1, "SIMPLE_RADIAL": 1, "RADIAL": 1, "PINHOLE": 2, "OPENCV": 2}
    kept = []
    for l in lines:
        f = l.split()
        if f and not l.startswith("#"):
            for k in range(focal_count[f[1]]):
                f[4 + k] = repr(float(f[4 + k]) * scale)
            l = " ".join(f)
        kept.append(l)
    text = "\n".join(kept)
open(out, "w").write(text + "\n")
PY
}

INPUTS=()
for scale in 1 0.97 1.03; do
  bag="$OUT/demo_$scale.bag"
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --info-focal-scale "$scale" > /dev/null 2>&1
  three "demo_$scale" "$bag" "${DEMO[@]}"
  INPUTS+=("demo_$scale")
done
for scale in 1 0.97; do
  bag="$OUT/one_$scale.bag"
  [ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --cameras 1 --info-focal-scale "$scale" \
    > /dev/null 2>&1
  three "one_$scale" "$bag" "${DEMO1[@]}"
  INPUTS+=("one_$scale")
done
PLUMB_BOB=plumb_bob:-0.28,0.07,0.0002,0.00002
bag="$OUT/plumb_bob_0.97.bag"
[ -f "$bag" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$bag" --distortion "$PLUMB_BOB" \
  --info-focal-scale 0.97 > /dev/null 2>&1
three plumb_bob_0.97 "$bag" "${DEMO[@]}"
INPUTS+=(plumb_bob_0.97)

for s in fountain-P11 entry-P10 castle-P19; do
  C="$DATA/strecha/$s"
  [ -d "$C" ] || continue
  for scale in 1 0.97; do
    bag="$OUT/${s}_$scale.bag"
    scaled_intrinsics "$C/images/K.txt" "$scale" "$OUT/${s}_${scale}_K.txt"
    [ -f "$bag" ] || "$BIN/rotation_averaging_images_to_bag" --images "$C/images" --intrinsics "$OUT/${s}_${scale}_K.txt" \
      --gt "$C" --downsample 0.25 --output "$bag" > /dev/null 2>&1
    three "${s}_$scale" "$bag" "${STILLS[@]}"
    INPUTS+=("${s}_$scale")
  done
done
if [ -d "$DATA/lund_door" ]; then
  for scale in 1 0.97; do
    bag="$OUT/lund_door_$scale.bag"
    scaled_intrinsics "$DATA/lund_door/colmap_ground_truth/cameras.txt" "$scale" "$OUT/lund_door_${scale}_cameras.txt"
    [ -f "$bag" ] || "$BIN/rotation_averaging_images_to_bag" --images "$DATA/lund_door/images" \
      --intrinsics "$OUT/lund_door_${scale}_cameras.txt" --gt "$DATA/lund_door/colmap_ground_truth/images.txt" \
      --downsample 0.25 --output "$bag" > /dev/null 2>&1
    three "lund_door_$scale" "$bag" "${STILLS[@]}"
    INPUTS+=("lund_door_$scale")
  done
fi
EUROC="$DATA/euroc_v1_01_micro/mav0"
if [ -d "$EUROC" ]; then
  [ -f "$OUT/euroc.bag" ] || "$BIN/rotation_averaging_images_to_bag" --euroc "$EUROC" --output "$OUT/euroc.bag" > /dev/null
  three euroc_1 "$OUT/euroc.bag" "${EUROC_LINES[@]}"
  INPUTS+=(euroc_1)
fi

python3 scripts/self_calibration_report.py "$OUT" "${INPUTS[@]}" > results/self_calibration.md
echo "wrote results/self_calibration.md"
