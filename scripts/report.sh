#!/usr/bin/env bash
# One command for the whole results report: regenerates every
# results/*.md file and the plots in results/plots/, each file naming the
# command that produced it:
#   core_benchmark.md  solvers on the real graphs (time, iterations, cost,
#                      memory, GLOMAP reference), sphere2500 accuracy,
#                      synthetic robustness and the synthetic loss x weighting table
#   scale.md           1,000 to 1,000,000 synthetic views (time, memory, growth exponent)
#   online.md          the online re-solve of a 10,000-keyframe graph growing one keyframe at a time
#   colmap.md          COLMAP's bundle adjustment against rotavg images, one evaluator
#   frontend.md        the two-view front end on the Strecha scenes and lund_door
#   loss_table.md      (full resolution and downsampled by 4): covariance
#   plots/cdf_*.png    calibration, the loss x weighting table, CDF plots, speed
#   node_benchmark.md  the running node: latency and message rate
#   replay.md          bag replay of the demo and the Strecha scenes, loop-closure recall
#   long_run.md        the keyframe front end over 800 keyframes and three laps
#   camera_models.md   lens distortion: EuRoC's real stereo camera, scenes warped through known lenses
#   keyframe_selection.md  keyframe selection on a rendered 20 Hz stream
#   keyframe_rotation.md   keyframes by the camera's rotation: photographs as a stream, the 20 Hz streams
#   focal_check.md     the node's check of camera_info's focal length against the images
#   refinement.md      the node's background bundle adjustment on and off, on every input with ground truth
#   restart.md         the demo replayed as a node restarted mid-run: the map saved and loaded
#   map.md             the saved map at 800 and 10,000 keyframes: size on disk, load and save times
#   sessions.md        two 400-capture sessions (other start, other lighting) merged, against one 800-capture run
# results/README.md is the written summary of these files.
#
#   bash scripts/report.sh            everything
#   bash scripts/report.sh --quick    small sizes, written to build/report_quick/
#                                     (CI runs it so the report code never rots)
#   bash scripts/report.sh --node     only the files that run the node's pipeline (node_benchmark.md
#                                     to sessions.md below: what a default of the node or its front
#                                     end changes)
# How long each takes: results/README.md (its first paragraph).
# Real data comes from ../shared/data (ROTAVG_DATA_DIR to override); parts that
# need it say so and are skipped when it is absent.
source "$(dirname "$0")/common.sh"
QUICK=0
NODE_ONLY=0
[ "${1:-}" = "--quick" ] && QUICK=1
[ "${1:-}" = "--node" ] && NODE_ONLY=1
bash scripts/setup.sh > /dev/null
start=$(date +%s)
step() { echo "== $1 ($(( $(date +%s) - start )) s so far)"; }
if [ "$QUICK" = 1 ]; then
  OUT=build/report_quick
  mkdir -p "$OUT"
  step "core solvers (quick)"
  "$BIN/rotavg_benchmark" --data "$DATA" --quick --output "$OUT/core_benchmark.md" > /dev/null
  step "scale and online re-solve (quick)"
  "$BIN/rotavg_scale_benchmark" --quick --output "$OUT/scale.md" > /dev/null  # both sections in one file
  step "front end and loss x weighting table (quick)"
  "$BIN/rotavg_frontend_eval" --data "$DATA" --quick --output "$OUT/frontend.md" --plots "$OUT/plots" > /dev/null
  # The report must have its sections and plots, or the code has rotted.
  for section in "## Real graphs" "## Loss x weighting (synthetic)" "## Scale" "## Online re-solve"; do
    grep -qF "$section" "$OUT"/core_benchmark.md "$OUT"/scale.md || { echo "report: '$section' missing" >&2; exit 1; }
  done
  if [ -d "$DATA/strecha" ]; then
    grep -q "median error (deg) per loss and weighting" "$OUT/frontend.md" || { echo "report: loss table missing" >&2; exit 1; }
    grep -q "then bundle adjusted (rotavg images defaults) | [0-9]" "$OUT/frontend.md" ||
      { echo "report: bundle adjustment row missing" >&2; exit 1; }
    ls "$OUT"/plots/cdf_*.png > /dev/null || { echo "report: no CDF plot" >&2; exit 1; }
  fi
  step "done: quick report in $OUT"
  exit 0
fi
# Timing-sensitive parts run alone; then the 1,000,000-view scale run (about 18
# minutes, single-threaded) shares the two cores with the front-end
# evaluation (single-threaded too), which keeps those two together under 30 minutes.
if [ "$NODE_ONLY" = 0 ]; then
  step "core solvers"
  "$BIN/rotavg_benchmark" --data "$DATA" --output results/core_benchmark.md > /dev/null
  step "online re-solve"
  "$BIN/rotavg_scale_benchmark" --only online --output results/online.md > /dev/null
  step "COLMAP on the Strecha scenes (its models are scored in frontend.md too)"
  bash scripts/benchmark_colmap.sh > /dev/null
  step "scale (in the background) and the front end with the loss x weighting table"
  "$BIN/rotavg_scale_benchmark" --only scale --output results/scale.md > build/report_scale.log 2>&1 &
  SCALE=$!
  "$BIN/rotavg_frontend_eval" --data "$DATA" --scales 1,0.25 --output results/frontend.md --plots results/plots > /dev/null
  step "front end done; waiting for the scale run"
  wait $SCALE || { cat build/report_scale.log >&2; exit 1; }
fi
step "node"
bash scripts/benchmark_node.sh > /dev/null
step "bag replay"
bash scripts/benchmark_replay.sh > /dev/null
step "long image runs"
bash scripts/benchmark_long_run.sh > /dev/null
step "camera models (lens distortion), keyframe selection, tracks, the time budget, posterior covariances, the focal-length check, the background refinement, self-calibration and lenses camera_info leaves out"
bash scripts/benchmark_camera_models.sh > /dev/null
bash scripts/benchmark_keyframe_selection.sh > /dev/null
bash scripts/benchmark_keyframe_rotation.sh > /dev/null
bash scripts/benchmark_tracks.sh > /dev/null
bash scripts/benchmark_budget.sh > /dev/null
bash scripts/benchmark_posterior.sh > /dev/null
bash scripts/benchmark_focal_check.sh > /dev/null
bash scripts/benchmark_refinement.sh > /dev/null
bash scripts/benchmark_self_calibration.sh > /dev/null
bash scripts/benchmark_lens.sh > /dev/null
step "restarts: the map saved and loaded"
bash scripts/benchmark_restart.sh > /dev/null
bash scripts/benchmark_map.sh > /dev/null
bash scripts/benchmark_sessions.sh > /dev/null
step "done: results/*.md and results/plots/ regenerated; summary in results/README.md"
