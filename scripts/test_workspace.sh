#!/usr/bin/env bash
# Builds the package as a user's catkin workspace would: a fresh workspace in
# build/workspace with the repository in its src/, `catkin_make` and
# `catkin_make install` (tests and benchmark programs left out), then runs the
# installed programs from the install space: `rosrun rotation_averaging rotavg
# demo`, and the node against a master of its own on a private port, which
# must answer its ~solve service. Also checks that the devel space of
# scripts/build.sh lets rosrun find every installed program.
#   bash scripts/test_workspace.sh      (after scripts/setup.sh)
source "$(dirname "$0")/common.sh"
ROOT=$(pwd)
WS=$ROOT/$BUILD/workspace
PROGRAMS=(rotavg rotavg_images rotavg_vocabulary rotation_averaging_node rotation_averaging_replay
          rotation_averaging_make_demo_bag rotation_averaging_images_to_bag)
fail() { echo "test_workspace: $*" >&2; exit 1; }

# rosrun finds every program in the devel space of scripts/build.sh.
(
  set +u; source "$DEVEL/setup.bash"; set -u
  for p in "${PROGRAMS[@]}"; do
    found=$(rosrun --prefix echo rotation_averaging "$p" 2>&1 </dev/null) || fail "rosrun does not find $p in $DEVEL: $found"
    [ "$found" = "$ROOT/$BIN/$p" ] || fail "rosrun rotation_averaging $p runs '$found', not $ROOT/$BIN/$p"
  done
  echo "test_workspace: rosrun finds all ${#PROGRAMS[@]} programs in $DEVEL"
)

rm -rf "$WS"
mkdir -p "$WS/src"
ln -s "$ROOT" "$WS/src/rotation_averaging"
echo "test_workspace: catkin_make and catkin_make install in $WS"
# Release's -O3 is already built and tested in $BUILD; this build checks the
# catkin machinery (build, install, run from the install space), which the
# optimisation level does not touch, at -O1, which compiles the Eigen-heavy
# files in well under half the time of -O3.
if ! (cd "$WS" && catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=Release \
        -DCMAKE_CXX_FLAGS_RELEASE="-O1 -DNDEBUG" \
        -DCATKIN_ENABLE_TESTING=OFF -DROTAVG_BUILD_BENCHMARKS=OFF > build.log 2>&1 &&
      catkin_make vocabulary install >> build.log 2>&1); then
  tail -40 "$WS/build.log"
  fail "the package does not build and install in a catkin workspace"
fi
INSTALLED=$WS/install
for f in lib/rotation_averaging/rotavg include/rotation_averaging/core/geometry/so3.h \
         share/rotation_averaging/vocabulary/sift.vocab share/rotation_averaging/config/rotation_averaging.yaml; do
  [ -e "$INSTALLED/$f" ] || fail "the install space has no $f"
done
for f in lib/rotation_averaging/rotavg_benchmark include/rotation_averaging/core/linalg; do
  [ ! -e "$INSTALLED/$f" ] || fail "the install space has $f, which is not for users"
done

set +u; source "$INSTALLED/setup.bash"; set -u
out=$(rosrun rotation_averaging rotavg demo 2>&1) || { echo "$out"; fail "the installed rotavg demo failed"; }
grep -q "median" <<<"$out" || { echo "$out"; fail "the installed rotavg demo printed no scores"; }
echo "test_workspace: installed rotavg demo ran"

# The installed node, against a master of its own.
export ROS_MASTER_URI=http://127.0.0.1:11391 ROS_HOME=$WS/ros_home ROS_LOG_DIR=$WS/ros_log
rosmaster --core -p 11391 > "$WS/master.log" 2>&1 &
MASTER=$!
NODE=""
cleanup() { [ -n "$NODE" ] && kill "$NODE" 2>/dev/null; kill "$MASTER" 2>/dev/null; wait 2>/dev/null || true; }
trap cleanup EXIT
rosrun rotation_averaging rotation_averaging_node __name:=averaging > "$WS/node.log" 2>&1 &
NODE=$!
for _ in $(seq 1 60); do
  rosservice call /averaging/solve > "$WS/solve.log" 2>&1 && break
  kill -0 "$NODE" 2>/dev/null || { cat "$WS/node.log"; fail "the installed node exited"; }
  sleep 0.5
done
grep -q "success" "$WS/solve.log" || { cat "$WS/node.log" "$WS/solve.log"; fail "the installed node did not answer ~solve"; }
echo "test_workspace: installed node answered /averaging/solve"
