# Sourced by every script in scripts/ (`source "$(dirname "$0")/common.sh"`):
# strict mode, the repository root as working directory, Debian's python3 ahead
# of any other on PATH (ROS tools run on it), and where the build puts things.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
export PATH=/usr/bin:$PATH
# The CMake build tree, and the devel space beside it: outside build/, because
# rosrun skips every file under <package>/build/.
BUILD=build
DEVEL=devel
BIN=$DEVEL/lib/rotation_averaging
DATA=${ROTAVG_DATA_DIR:-../shared/data}
# The first value a tool's summary gives: file, sed pattern whose first
# group is the value.
value() {
  sed -n "s/$2/\1/p" "$1" | head -1
}
# A Strecha scene (its folder: images/, images/K.txt and the ground-truth
# cameras) as a bag of one camera's keyframes at a quarter of full width, as
# the benchmarks play it through the node: scene folder, output bag, more
# images_to_bag flags (a lens: --distortion SPEC, --rectify).
strecha_bag() {
  local scene=$1 bag=$2
  shift 2
  "$BIN/rotation_averaging_images_to_bag" --images "$scene/images" --intrinsics "$scene/images/K.txt" --gt "$scene" \
    --downsample 0.25 "$@" --output "$bag" > /dev/null 2>&1
}
# One replay of a bag with a configuration of the given lines (written to
# $OUT/NAME.yaml), scored against the bag's ground truth if it has one: its
# summary in $OUT/NAME.txt, its outputs in $OUT/NAME/. name, bag, lines...
replay_with() {
  local name=$1 bag=$2 gt=()
  shift 2
  printf '%s\n' "$@" > "$OUT/$name.yaml"
  [[ "$(/usr/bin/rosbag info "$bag")" == */ground_truth/orientations* ]] && gt=(--gt "$bag")
  "$BIN/rotation_averaging_replay" --bag "$bag" --config "$OUT/$name.yaml" "${gt[@]}" --output-dir "$OUT/$name" \
    --no-progress > "$OUT/$name.txt" 2>&1
}
# lund_door (12 photographs, COLMAP's model as the reference) the same way:
# output bag.
lund_door_bag() {
  "$BIN/rotation_averaging_images_to_bag" --images "$DATA/lund_door/images" \
    --intrinsics "$DATA/lund_door/colmap_ground_truth/cameras.txt" \
    --gt "$DATA/lund_door/colmap_ground_truth/images.txt" --downsample 0.25 --output "$1" > /dev/null 2>&1
}
# The rendered rig's bags the benchmarks share, made once under build/demo:
# DEMO (two cameras, one capture a second, 60 captures), STREAM (two cameras
# at 20 Hz, 600 captures) and ONE (its forward camera alone); and the demo
# configuration's lines for each: demo, stream (without its
# keyframe_selection) and one (without keyframe_selection and image_topics).
demo_bags() {
  mkdir -p build/demo
  DEMO=build/demo/demo_60.bag
  STREAM=build/demo/demo_20hz_600_2cam.bag
  ONE=build/demo/demo_20hz_600_1cam.bag
  local bag args
  for bag in "$DEMO" "$STREAM" "$ONE"; do
    [ -f "$bag" ] && continue
    case $bag in
      "$DEMO") args=(--captures 60 --cameras 2) ;;
      "$STREAM") args=(--captures 600 --period 0.05 --cameras 2) ;;
      *) args=(--captures 600 --period 0.05 --cameras 1) ;;
    esac
    "$BIN/rotation_averaging_make_demo_bag" --output "$bag.tmp" "${args[@]}" > /dev/null && mv "$bag.tmp" "$bag"
  done
  mapfile -t demo < <(grep -v '^#' config/demo.yaml)
  mapfile -t stream < <(grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:')
  mapfile -t one < <(grep -v '^#' config/demo.yaml | grep -v '^keyframe_selection:\|^image_topics:')
}
