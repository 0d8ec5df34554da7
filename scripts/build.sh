#!/usr/bin/env bash
# Configures and builds the package into build/, with its devel space in
# devel/ (where `source devel/setup.bash` then `rosrun rotation_averaging ...`
# find every program), and trains the default vocabulary once. Needs the
# dependencies of scripts/install_deps.sh; no root.
source "$(dirname "$0")/common.sh"

# Some container images keep dpkg from unpacking /usr/share/doc: then the
# photographs come from opencv-doc's package file instead.
IMAGES=/usr/share/doc/opencv-doc/examples/data
if [ ! -d "$IMAGES" ]; then
  mkdir -p "$BUILD/opencv-doc"
  if [ ! -d "$BUILD/opencv-doc/usr/share/doc/opencv-doc/examples/data" ]; then
    (cd "$BUILD/opencv-doc" && apt-get download opencv-doc >/dev/null && dpkg-deb -x opencv-doc_*.deb . && rm -f opencv-doc_*.deb)
  fi
  IMAGES=$(pwd)/$BUILD/opencv-doc/usr/share/doc/opencv-doc/examples/data
fi

cmake -S . -B "$BUILD" -G Ninja -DCMAKE_BUILD_TYPE=Release -DPYTHON_EXECUTABLE=/usr/bin/python3 \
  -DCATKIN_DEVEL_PREFIX="$(pwd)/$DEVEL" -DROTAVG_VOCABULARY_IMAGES="$IMAGES" >/dev/null
cmake --build "$BUILD"
cmake --build "$BUILD" --target vocabulary  # once: the default vocabulary of loop-closure retrieval
echo "build: built into $(pwd)/$BUILD, programs in $BIN (source devel/setup.bash, then rosrun rotation_averaging ...)"
