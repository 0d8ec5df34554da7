#!/usr/bin/env bash
# Builds the libFuzzer target for every file reader (test/fuzz/fuzz_readers.cpp:
# 1DSfM, g2o, TORO, iRotAvg, the package's graph file, orientations CSV,
# COLMAP and chained ground truth, format detection) with clang and
# ASan + UBSan, and runs it for a fixed budget from the seed corpus in
# test/fuzz/corpus. A crash, leak, timeout or out-of-memory fails the run and
# leaves the input in build-fuzz/ (turn it into a regression test).
#   bash scripts/fuzz.sh [seconds]      (default 60; after scripts/setup.sh)
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_BUDGET=${1:-60}
OUT=build-fuzz
mkdir -p "$OUT/corpus"
SRC="src/io/graph_io.cpp src/io/orientation_io.cpp src/io/text_lines.cpp src/scene/view_graph.cpp
     src/geometry/so3.cpp src/eval/rotation_evaluation.cpp src/estimators/rotation_averaging.cpp
     src/estimators/component_problem.cpp src/estimators/irls_solver.cpp src/estimators/block_sparse_system.cpp
     src/estimators/robust_loss.cpp src/estimators/l1_irls_solver.cpp src/estimators/ceres_solver.cpp"
if [ ! -x "$OUT/fuzz_readers" ] || [ -n "$(find src include test/fuzz -newer "$OUT/fuzz_readers" -name '*.[ch]*' | head -1)" ]; then
  echo "fuzz: building $OUT/fuzz_readers (clang, -fsanitize=fuzzer,address,undefined)"
  # shellcheck disable=SC2086
  clang++ -std=c++17 -O1 -g -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined \
    -I include -I /usr/include/eigen3 test/fuzz/fuzz_readers.cpp $SRC -o "$OUT/fuzz_readers" \
    /usr/lib/x86_64-linux-gnu/libceres.a -lglog -lgflags -lcholmod -lcxsparse -lspqr -llapack -lblas -lpthread -fopenmp
fi
cd "$OUT"
./fuzz_readers -max_total_time="$SECONDS_BUDGET" -max_len=4096 -timeout=10 -rss_limit_mb=2048 \
  -print_final_stats=1 corpus ../test/fuzz/corpus 2>&1 | tee fuzz.log | grep -E "^(#[0-9]+ *DONE|stat::number_of_executed_units|stat::peak_rss_mb|SUMMARY|==[0-9]+==ERROR)" || true
if grep -q "SUMMARY\|ERROR: libFuzzer" fuzz.log; then
  echo "fuzz: FAILED, input saved in $(pwd) (see fuzz.log)" >&2
  exit 1
fi
echo "fuzz: no crash in ${SECONDS_BUDGET} s"
