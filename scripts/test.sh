#!/usr/bin/env bash
# The README's test command (CI runs it through .ci/run). Sets up, builds
# every test and runs them all with ctest (which, unlike `make run_tests`,
# fails when a test fails); the quick results report (scripts/report.sh
# --quick); the demo and every command of the README (scripts/demo.sh,
# scripts/test_readme.sh); the package built and installed in a fresh catkin workspace
# (scripts/test_workspace.sh); and a 60 s libFuzzer run of each target, built
# with AddressSanitizer and UndefinedBehaviorSanitizer: file readers and the
# message path through the front end and a solve (scripts/fuzz.sh). With
# --sanitizers, also the whole suite again in an ASan + UBSan build
# (scripts/test_sanitizers.sh). That pass is left out of CI: beside the rest
# of CI it leaves no margin under CI's 90 minutes (results/README.md,
# "Checks", has its durations).
#   bash scripts/test.sh [--sanitizers]
source "$(dirname "$0")/common.sh"
SANITIZERS=0
[ "${1:-}" = "--sanitizers" ] && SANITIZERS=1
# CI always has ../shared/data: there a test that needs it fails instead of
# skipping when it is missing.
if [ "${CI:-}" = true ]; then export ROTAVG_REQUIRE_DATA=1; fi
# Each stage says when it starts, so a slow stage shows in CI's log.
stage() { echo; echo "== $1 ($SECONDS s so far) =="; }
stage "Setup: dependencies and the build (scripts/setup.sh)"
bash scripts/setup.sh
stage "The tests (ctest)"
cmake --build "$BUILD" --target tests
# As many tests at a time as cores (the node's load tests alone, see
# test/CMakeLists.txt).
(cd "$BUILD" && ctest --output-on-failure -j "$(nproc)")
stage "The results report in its quick form (scripts/report.sh --quick), so the report code never rots"
bash scripts/report.sh --quick
stage "The README's commands as written (scripts/test_readme.sh), after the demo (scripts/demo.sh)"
bash scripts/demo.sh > "$BUILD/demo.log" 2>&1 || { tail -40 "$BUILD/demo.log"; exit 1; }
tail -4 "$BUILD/demo.log"
bash scripts/test_readme.sh
stage "The package in a fresh catkin workspace: catkin_make, catkin_make install, the installed programs"
bash scripts/test_workspace.sh
if [ "$SANITIZERS" = 1 ]; then
  stage "The test suite again with AddressSanitizer and UndefinedBehaviorSanitizer"
  # node_streams is left out: it asserts that the node keeps up with 20 Hz
  # streams in real time, which the sanitizers' slowdown does not allow; the
  # code it drives (decoding, undistortion, keyframe selection, the replay)
  # runs under them in keyframe_pipeline_test, camera_model_test,
  # keyframe_selector_test and bag_replay_test.
  bash scripts/test_sanitizers.sh -j "$(nproc)" -E node_streams
fi
stage "Fuzzing the file readers and the message path, 60 s each (libFuzzer, ASan + UBSan)"
bash scripts/fuzz.sh 60
stage "All passed"
