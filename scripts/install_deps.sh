#!/usr/bin/env bash
# Installs every build and test dependency from Debian bookworm's packages
# (as root, or through sudo). Safe to run again: installed packages are
# skipped. package.xml declares the same dependencies as rosdep keys
# (test/package_dependencies.py checks that the two agree with CMakeLists.txt).
source "$(dirname "$0")/common.sh"

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
  pybind11-dev python3-dev python3-numpy python3-pytest  # Python bindings and their tests
  libopenblas0-pthread  # BLAS for CHOLMOD's supernodal solves, thread-safe (see src/backends/CMakeLists.txt)
  libfaiss-dev  # k-means and nearest-word search of the loop-closure vocabulary
  libxxhash-dev  # the keyframe database's checksum
  opencv-doc    # OpenCV's example photographs: what the default vocabulary is trained on
)
missing=()
for p in "${PACKAGES[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ "${#missing[@]}" -gt 0 ]; then
  echo "install_deps: installing ${missing[*]}"
  SUDO=""
  [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${missing[@]}" >/dev/null
fi
