#!/usr/bin/env bash
# The README's main command. Sets everything up, renders the built-in demo bag
# if it is not there yet (a two-camera rig driving a loop through a textured
# room, with its extrinsics on /tf_static and ground truth), replays it through
# the node's pipeline with rotation_averaging_replay, and prints the scores
# against ground truth and where the plot is.
#
#   bash scripts/demo.sh [--captures N] [--fresh]
#
# Outputs go to build/demo/ (the bag) and build/demo/replay/ (results).
source "$(dirname "$0")/common.sh"
CAPTURES=60
FRESH=0
while [ $# -gt 0 ]; do
  case "$1" in
    --captures) CAPTURES="$2"; shift 2 ;;
    --fresh) FRESH=1; shift ;;
    *) echo "usage: bash scripts/demo.sh [--captures N] [--fresh]" >&2; exit 2 ;;
  esac
done

bash scripts/setup.sh
DEMO=build/demo
mkdir -p "$DEMO"
BAG="$DEMO/demo_${CAPTURES}.bag"
if [ "$FRESH" = 1 ] || [ ! -f "$BAG" ]; then
  echo
  echo "== Rendering the demo bag ($CAPTURES captures x 2 cameras, 640x480) =="
  "$BIN/rotation_averaging_make_demo_bag" --output "$BAG.tmp" --captures "$CAPTURES" --cameras 2
  mv "$BAG.tmp" "$BAG"
else
  echo
  echo "== Using the demo bag rendered earlier: $BAG (--fresh renders it again) =="
fi

echo
echo "== Replaying it through the node's pipeline (config/demo.yaml) =="
"$BIN/rotation_averaging_replay" --bag "$BAG" --config config/demo.yaml --gt "$BAG" --output-dir "$DEMO/replay"
echo
echo "The plot of the errors per keyframe and their distribution: $DEMO/replay/errors.png"
echo "Replay your own bags the same way (README.md, "Replaying bags")."
