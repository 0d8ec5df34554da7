#!/usr/bin/env bash
# Sets up, builds every test and runs them all with ctest (which, unlike
# `make run_tests`, fails when a test fails).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
export PATH=/usr/bin:$PATH
cmake --build build --target tests
cd build
ctest --output-on-failure
