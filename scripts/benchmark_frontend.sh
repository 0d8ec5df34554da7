#!/usr/bin/env bash
# Regenerates results/frontend.md: covariance calibration, rotation-averaging
# accuracy and speed of the two-view front end on the Strecha scenes and
# lund_door (../shared/data), at full resolution and downsampled by 4.
# Takes about ten minutes at full resolution; --quick runs two scenes at 1/4.
source "$(dirname "$0")/common.sh"
bash scripts/setup.sh
$BIN/rotavg_frontend_eval --data "$DATA" --output results/frontend.md "$@"
