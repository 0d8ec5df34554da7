#!/usr/bin/env bash
# libFuzzer targets built with clang, ASan and UBSan into build/fuzz/
# (cmake -DROTAVG_FUZZ=ON, only the fuzz targets), each run for a fixed budget
# from its seed corpus:
#   fuzz_readers   every file reader (1DSfM, g2o, TORO, iRotAvg, the package's
#                  graph file, orientations CSV, COLMAP and chained ground
#                  truth, format detection, the rig file, the keyframe
#                  database, the refinement's corrections); seeds in
#                  test/fuzz/corpus
#   fuzz_messages  the message-to-graph path: serialised RelativePose(Array),
#                  CameraInfo, Image, CompressedImage and /tf_static messages
#                  through the KeyframePipeline, the averager and the output
#                  messages; seeds in test/fuzz/corpus_messages
# A crash, leak, broken invariant, timeout or out-of-memory fails the run and
# leaves the input in build/fuzz/runs/<target>/ (turn it into a regression test).
# Executions and time per target go to build/fuzz/fuzz_stats.txt.
#   bash scripts/fuzz.sh [seconds per target]   (default 60; after scripts/setup.sh)
source "$(dirname "$0")/common.sh"
SECONDS_BUDGET=${1:-60}
OUT=$(pwd)/build/fuzz
mkdir -p "$OUT"
CC=clang CXX=clang++ cmake -S . -B "$OUT" -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DROTAVG_FUZZ=ON \
  -DCATKIN_ENABLE_TESTING=OFF -DPYTHON_EXECUTABLE=/usr/bin/python3 > "$OUT/configure.log" 2>&1 \
  || { cat "$OUT/configure.log" >&2; exit 1; }
echo "fuzz: building the fuzz targets (clang, -fsanitize=fuzzer,address,undefined)"
cmake --build "$OUT" --target fuzz_readers fuzz_messages | grep -vE "^\[[0-9]+/[0-9]+\]" || true
BIN=$OUT/devel/lib/rotation_averaging
[ -x "$BIN/fuzz_readers" ] && [ -x "$BIN/fuzz_messages" ] || { echo "fuzz: build failed" >&2; exit 1; }
: > "$OUT/fuzz_stats.txt"
status=0
run() {  # target seed-dir extra-options...
  local target=$1 seeds=$2
  shift 2
  mkdir -p "$OUT/runs/$target/corpus"
  (cd "$OUT/runs/$target" && "$BIN/$target" -max_total_time="$SECONDS_BUDGET" -timeout=10 -print_final_stats=1 \
     "$@" corpus "$seeds" > fuzz.log 2>&1) || true
  local execs rss
  execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$OUT/runs/$target/fuzz.log")
  rss=$(sed -n 's/^stat::peak_rss_mb: *//p' "$OUT/runs/$target/fuzz.log")
  if grep -q "SUMMARY\|ERROR: libFuzzer\|invariant broken" "$OUT/runs/$target/fuzz.log"; then
    echo "fuzz: $target FAILED, input saved in $OUT/runs/$target (see fuzz.log):" >&2
    # The report, then the first frames past libFuzzer's and the sanitizers' own.
    grep -E "ERROR|SUMMARY|invariant" "$OUT/runs/$target/fuzz.log" | head -6 >&2
    grep -E "^    #[0-9]+ " "$OUT/runs/$target/fuzz.log" | grep -vE " in (fuzzer::|__sanitizer|__asan|__ubsan|__lsan|malloc|calloc|realloc|operator new)" \
      | head -14 >&2
    status=1
  else
    echo "fuzz: $target: ${execs:-0} inputs in ${SECONDS_BUDGET} s, peak RSS ${rss:-?} MB, no finding" \
      | tee -a "$OUT/fuzz_stats.txt"
  fi
}
run fuzz_readers "$(pwd)/test/fuzz/corpus" -max_len=4096 -rss_limit_mb=2048
run fuzz_messages "$(pwd)/test/fuzz/corpus_messages" -max_len=65536 -rss_limit_mb=3072
exit $status
