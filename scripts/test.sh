#!/usr/bin/env bash
# Sets up, builds every test and runs them all with ctest (which, unlike
# `make run_tests`, fails when a test fails); the quick results report
# (scripts/report.sh --quick); then the same suite again in an
# AddressSanitizer + UndefinedBehaviorSanitizer build (scripts/test_sanitizers.sh)
# and a 60 s libFuzzer run of each target: file readers and the message path (scripts/fuzz.sh).
#   bash scripts/test.sh [--no-sanitizers]
set -euo pipefail
cd "$(dirname "$0")/.."
SANITIZERS=1
[ "${1:-}" = "--no-sanitizers" ] && SANITIZERS=0
bash scripts/setup.sh
export PATH=/usr/bin:$PATH
cmake --build build --target tests
# As many tests at a time as cores (the node's load tests alone, see
# CMakeLists.txt).
(cd build && ctest --output-on-failure -j "$(nproc)")
echo
echo "== The results report in its quick form (scripts/report.sh --quick), so the report code never rots =="
bash scripts/report.sh --quick
if [ "$SANITIZERS" = 1 ]; then
  echo
  echo "== The test suite again with AddressSanitizer and UndefinedBehaviorSanitizer =="
  bash scripts/test_sanitizers.sh -j "$(nproc)"
  echo
  echo "== Fuzzing the file readers and the message path, 60 s each (libFuzzer) =="
  bash scripts/fuzz.sh 60
fi
