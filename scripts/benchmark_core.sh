#!/usr/bin/env bash
# Regenerates results/core_benchmark.md: solver speed and memory on the real
# graphs in ../shared/data, sphere2500 accuracy and synthetic accuracy.
# Pass --quick for a fast smoke run (1 repeat, no memory figures).
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh
$BIN/rotavg_benchmark --data "$DATA" --output results/core_benchmark.md "$@"
