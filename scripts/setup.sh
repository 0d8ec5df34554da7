#!/usr/bin/env bash
# Installs every build and test dependency from Debian bookworm's packages
# (run as root on a fresh machine), then configures and builds the package
# into ./build. Safe to run again: installed packages are skipped.
set -euo pipefail
cd "$(dirname "$0")/.."
export PATH=/usr/bin:$PATH  # ROS tools run on Debian's python3, not a pyenv one

PACKAGES=(
  build-essential cmake ninja-build pkg-config
  catkin ros-message-generation ros-base-dev
  libtf2-ros-dev libtf2-eigen-dev librosbag-dev librostest-dev python3-rostest
  libcv-bridge-dev libimage-transport-dev
  libstd-srvs-dev libdiagnostic-updater-dev libtf2-geometry-msgs-dev
  libdynamic-reconfigure-config-init-mutex-dev python3-dynamic-reconfigure
  libceres-dev libeigen3-dev libsuitesparse-dev libopencv-dev libgtest-dev
  libyaml-cpp-dev python3-rosbag libvisualization-msgs-dev
  clang libclang-rt-14-dev  # libFuzzer targets (scripts/fuzz.sh); the fuzzer runtime is only a Recommends of clang
  pybind11-dev python3-numpy python3-pytest  # Python bindings and their tests
  libopenblas0-pthread  # BLAS for CHOLMOD's supernodal solves, thread-safe (see CMakeLists.txt)
  libfaiss-dev  # k-means and nearest-word search of the loop-closure vocabulary
  opencv-doc    # OpenCV's example photographs: what the default vocabulary is trained on
)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "setup: installing ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi

# Some container images keep dpkg from unpacking /usr/share/doc: then the
# photographs come from opencv-doc's package file instead.
IMAGES=/usr/share/doc/opencv-doc/examples/data
if [ ! -d "$IMAGES" ]; then
  mkdir -p build/opencv-doc
  if [ ! -d build/opencv-doc/usr/share/doc/opencv-doc/examples/data ]; then
    (cd build/opencv-doc && apt-get download opencv-doc >/dev/null && dpkg-deb -x opencv-doc_*.deb . && rm -f opencv-doc_*.deb)
  fi
  IMAGES=$(pwd)/build/opencv-doc/usr/share/doc/opencv-doc/examples/data
fi

cmake -S . -B build -G Ninja -DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DROTAVG_VOCABULARY_IMAGES="$IMAGES" >/dev/null
cmake --build build
cmake --build build --target vocabulary  # once: the default vocabulary of loop-closure retrieval
echo "setup: built into $(pwd)/build (tools in build/devel/lib/rotation_averaging)"
