#!/usr/bin/env bash
# Regenerates results/frontend.md: covariance calibration, rotation-averaging
# accuracy and speed of the two-view front end on the Strecha scenes and
# lund_door (../shared/data), at full resolution and downsampled by 4.
# Takes about ten minutes at full resolution; --quick runs two scenes at 1/4.
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
build/devel/lib/rotation_averaging/rotavg_frontend_eval --data ../shared/data --output results/frontend.md "$@"
