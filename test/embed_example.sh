#!/usr/bin/env bash
# Builds examples/embed_cpp as a package of its own catkin workspace on top of
# this package's devel space, as a user's package would be, runs it (it checks
# its own result), and checks that it loads neither OpenCV nor ROS.
#   test/embed_example.sh DEVEL_SPACE WORKSPACE_DIR
set -euo pipefail
devel=$1
work=$2
here=$(cd "$(dirname "$0")/.." && pwd)
export PATH=/usr/bin:$PATH  # catkin runs on Debian's python3

rm -rf "$work"
mkdir -p "$work/src"
ln -s "$here/examples/embed_cpp" "$work/src/rotation_averaging_embed_example"
set +u
# shellcheck disable=SC1091
source "$devel/setup.bash"
set -u
if ! (cd "$work" && catkin_make -DPYTHON_EXECUTABLE=/usr/bin/python3 -DCMAKE_BUILD_TYPE=Release >build.log 2>&1); then
  cat "$work/build.log"
  echo "embed_example: the example package does not build against $devel"
  exit 1
fi
bin="$work/devel/lib/rotation_averaging_embed_example/solve_small_graph"
"$bin"
libraries=$(ldd "$bin")
if grep -Ei "opencv|libroscpp|librosbag|librotation_averaging_(frontend|ros)" <<<"$libraries"; then
  echo "embed_example: a program that links rotation_averaging::core loads the libraries above"
  exit 1
fi
echo "embed_example: $(wc -l <<<"$libraries") shared libraries loaded, none of OpenCV or ROS"
