#!/usr/bin/env bash
# Regenerates results/core_benchmark.md: solver speed and memory on the real
# graphs in ../shared/data, sphere2500 accuracy and synthetic accuracy.
# Pass --quick for a fast smoke run (1 repeat, no memory figures).
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
build/devel/lib/rotation_averaging/rotavg_benchmark --data ../shared/data --output results/core_benchmark.md "$@"
