#!/usr/bin/env bash
# Regenerates results/posterior.md: the posterior covariances the node
# publishes on ~orientations, checked against ground truth on every input
# here that has it. Each replay scores its last solution's covariances
# (EvaluatePosteriorCovariances: each keyframe's error relative to its
# component's gauge keyframe, whitened by its covariance): the demo bag (the
# rendered two-camera rig at 1 Hz, every image a keyframe), the rig as a
# 20 Hz driver publishes it (600 captures, keyframe_selection: motion), the
# Strecha scenes and lund_door as bags (quarter resolution, every image a
# keyframe), each with the defaults and again without the covariance floor
# (posterior_covariance_floor: false). EuRoC's excerpt has no ground truth and
# is not scored.
#   bash scripts/benchmark_posterior.sh
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh > /dev/null
OUT=build/benchmark_posterior
mkdir -p "$OUT" build/demo

DEMO=build/demo/demo_60.bag
[ -f "$DEMO" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$DEMO" --captures 60 --cameras 2 > /dev/null 2>&1
replay() {  # name bag config: the defaults, then the posterior scaled by the residual variance factor alone
  "$BIN/rotation_averaging_replay" --bag "$2" --config "$3" --gt "$2" --output-dir "$OUT/$1" --no-progress \
    > "$OUT/$1.txt"
  { cat "$3"; echo "posterior_covariance_floor: false"; } > "$OUT/$1_no_floor.yaml"
  "$BIN/rotation_averaging_replay" --bag "$2" --config "$OUT/$1_no_floor.yaml" --gt "$2" \
    --output-dir "$OUT/$1_no_floor" --no-progress > "$OUT/$1_no_floor.txt"
}
INPUTS=(demo)
replay demo "$DEMO" config/demo.yaml
STREAM=build/demo/demo_20hz_600_2cam.bag  # benchmark_budget.sh's two-camera stream
[ -f "$STREAM" ] || "$BIN/rotation_averaging_make_demo_bag" --output "$STREAM" --captures 600 --period 0.05 \
  --cameras 2 > /dev/null 2>&1
{ grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:'; echo "keyframe_selection: motion"; } > "$OUT/stream.yaml"
INPUTS+=(stream)
replay stream "$STREAM" "$OUT/stream.yaml"

scene() {  # name: $OUT/name.bag (made beforehand) replayed with every image a keyframe
  printf 'image_topics: ["/camera/image_raw"]\nkeyframe_selection: all\nfeatures: sift\nmax_features: 4000\n' \
    > "$OUT/$1.yaml"
  replay "$1" "$OUT/$1.bag" "$OUT/$1.yaml"
  INPUTS+=("$1")
}
for s in castle-P19 entry-P10 fountain-P11; do
  [ -d "$DATA/strecha/$s" ] || continue
  [ -f "$OUT/$s.bag" ] || strecha_bag "$DATA/strecha/$s" "$OUT/$s.bag"
  scene "$s"
done
LUND=$DATA/lund_door
if [ -d "$LUND" ]; then
  [ -f "$OUT/lund_door.bag" ] || lund_door_bag "$OUT/lund_door.bag"
  scene lund_door
fi

python3 scripts/posterior_report.py "$OUT" "$(IFS=,; echo "${INPUTS[*]}")" > results/posterior.md
echo "wrote results/posterior.md"
