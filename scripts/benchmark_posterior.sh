#!/usr/bin/env bash
# Regenerates results/posterior.md: the posterior covariances the node
# publishes on ~orientations, checked against ground truth on every input
# here that has it. Each replay scores its last solution's covariances
# (EvaluatePosteriorCovariances: each keyframe's error relative to its
# component's gauge keyframe, whitened by its covariance): the demo bag (the
# rendered two-camera rig at 1 Hz, every image a keyframe), the rig as a
# 20 Hz driver publishes it (600 captures, keyframe_selection: motion), its
# forward camera alone, the Strecha scenes and lund_door as bags (quarter
# resolution, every image a keyframe). Each input with the defaults (the
# refined keyframes' covariances from the bundle adjustment, with its
# jackknives over 3 x 3 cells and over clusters of the tracks that start in
# one), with the cells' alone, with the grid at 0 (the pixel model alone), 2
# and 4, with the averaging's covariances
# (refinement_covariances: false), and without the refinement, with and
# without the averaging's covariance floor; the rig's inputs (and its four
# cameras at 20 Hz) also with the rig's joint covariances. The Strecha scenes are scored
# twice: against their LIDAR-registered cameras, and against `rotavg images`
# on the full-resolution photographs (every pair, focal self-calibration,
# bundle adjustment), sixteen times the pixels the bags have. EuRoC's
# excerpt has no ground truth and is not scored.
#   bash scripts/benchmark_posterior.sh        (about half an hour)
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_posterior
mkdir -p "$OUT"

VARIANTS=(default cells_alone grid0 grid2 grid4 averaging no_refinement no_refinement_no_floor)
variant_lines() {  # variant: its config lines
  case $1 in
    default) ;;
    cells_alone) echo "refinement_jackknife_tracks: false" ;;
    grid*) echo "refinement_jackknife_grid: ${1#grid}" ;;
    averaging) echo "refinement_covariances: false" ;;
    no_refinement) echo "refinement: false" ;;
    no_refinement_no_floor) printf 'refinement: false\nposterior_covariance_floor: false\n' ;;
  esac
}
replay() {  # name bag gt config-lines...: every variant
  local name=$1 bag=$2 gt=$3
  shift 3
  for v in "${VARIANTS[@]}"; do
    { printf '%s\n' "$@"; variant_lines "$v"; } > "$OUT/${name}_$v.yaml"
    "$BIN/rotation_averaging_replay" --bag "$bag" --config "$OUT/${name}_$v.yaml" --gt "$gt" \
      --output-dir "$OUT/${name}_$v" --no-progress > "$OUT/${name}_$v.txt" 2>&1
  done
}

demo_bags
INPUTS=(demo stream one_camera)
replay demo "$DEMO" "$DEMO" "${demo[@]}"
replay stream "$STREAM" "$STREAM" "${stream[@]}" "keyframe_selection: motion"
replay one_camera "$ONE" "$ONE" "${one[@]}" 'image_topics: ["/cam_front/image_raw"]' "keyframe_selection: motion"

# A rig's keyframes with the covariances of the joint problem the rig makes
# (refinement_rig_joint_covariance: true) against each camera's own (the
# default): the two-camera bags, and the rig's four cameras at 20 Hz.
FOUR=build/demo/demo_20hz_600_4cam.bag  # benchmark_budget.sh plays it too
[ -f "$FOUR" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$FOUR" --captures 600 --period 0.05 \
  --cameras 4 > /dev/null 2>&1
rig_replay() {  # name bag config-lines...
  local name=$1 bag=$2
  shift 2
  printf '%s\n' "$@" > "$OUT/$name.yaml"
  "$BIN/rotation_averaging_replay" --bag "$bag" --config "$OUT/$name.yaml" --gt "$bag" \
    --output-dir "$OUT/$name" --no-progress > "$OUT/$name.txt" 2>&1
}
JOINT="refinement_rig_joint_covariance: true"
rig_replay demo_rig_joint "$DEMO" "${demo[@]}" "$JOINT"
rig_replay stream_rig_joint "$STREAM" "${stream[@]}" "keyframe_selection: motion" "$JOINT"
FOUR_CONFIG=("${one[@]}" 'image_topics: ["/cam_front/image_raw", "/cam_left/image_raw", "/cam_back/image_raw", "/cam_right/image_raw"]'
             "keyframe_selection: motion")
rig_replay four_cameras_default "$FOUR" "${FOUR_CONFIG[@]}"
rig_replay four_cameras_rig_joint "$FOUR" "${FOUR_CONFIG[@]}" "$JOINT"

PHOTO_CONFIG=('image_topics: ["/camera/image_raw"]' "keyframe_selection: all" "features: sift" "max_features: 4000")
for s in castle-P19 entry-P10 fountain-P11; do
  [ -d "$DATA/strecha/$s" ] || continue
  [ -f "$OUT/$s.bag" ] || strecha_bag "$DATA/strecha/$s" "$OUT/$s.bag"
  replay "$s" "$OUT/$s.bag" "$OUT/$s.bag" "${PHOTO_CONFIG[@]}"
  INPUTS+=("$s")
  # The full-resolution reference, keyed as the bag's keyframes: the
  # photographs in name order, one a second from 1000 s.
  if [ ! -f "$OUT/${s}_full_resolution.csv" ]; then
    "$BIN/rotavg" images --images "$DATA/strecha/$s/images" --intrinsics "$DATA/strecha/$s/images/K.txt" \
      --pairs exhaustive --output "$OUT/${s}_full_resolution_by_image.csv" --gt "$DATA/strecha/$s" \
      > "$OUT/${s}_full_resolution.txt" 2>&1
    python3 - "$OUT/${s}_full_resolution_by_image.csv" > "$OUT/${s}_full_resolution.csv" <<'EOF'
import sys
rows = sorted(line.strip().split(",") for line in open(sys.argv[1]) if line.strip() and not line.startswith("name"))
print("name,qw,qx,qy,qz")
for i, row in enumerate(rows):
    print("camera@%d,%s" % ((1000 + i) * 1000000000, ",".join(row[1:])))
EOF
  fi
  replay "${s}_full_resolution" "$OUT/$s.bag" "$OUT/${s}_full_resolution.csv" "${PHOTO_CONFIG[@]}"
  INPUTS+=("${s}_full_resolution")
done
LUND=$DATA/lund_door
if [ -d "$LUND" ]; then
  [ -f "$OUT/lund_door.bag" ] || lund_door_bag "$OUT/lund_door.bag"
  replay lund_door "$OUT/lund_door.bag" "$OUT/lund_door.bag" "${PHOTO_CONFIG[@]}"
  INPUTS+=(lund_door)
fi

python3 scripts/posterior_report.py "$OUT" "$(IFS=,; echo "${INPUTS[*]}")" > results/posterior.md
echo "wrote results/posterior.md"
