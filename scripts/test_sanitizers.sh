#!/usr/bin/env bash
# Builds the package with AddressSanitizer and UndefinedBehaviorSanitizer into
# build/sanitize/ and runs the tests with ctest (unit tests and the node's
# rostests; a few that only repeat code to compare results are left out, see
# GTEST_FILTER below). Any sanitizer report fails the test that triggered it.
#   bash scripts/test_sanitizers.sh [ctest options]   (after scripts/setup.sh; ~25 minutes on 2 cores)
source "$(dirname "$0")/common.sh"
cmake -S . -B build/sanitize -G Ninja -DCMAKE_BUILD_TYPE=RelWithDebInfo -DROTAVG_SANITIZE=ON \
  -DPYTHON_EXECUTABLE=/usr/bin/python3 > /dev/null
# Only what ctest runs: the test programs and what they start (the node, the
# back ends, images_to_bag), not the benchmark and evaluation tools.
cmake --build build/sanitize --target tests
# halt_on_error: a report is a failure. Leak checking stays on; known leaks
# of third-party libraries, if any, are listed in test/sanitizer_suppressions.txt.
# Reports of every process (also the nodes that rostest launches, whose
# stderr ctest does not see) go to files, and any file fails the run.
REPORTS=$(pwd)/build/sanitize/sanitizer_reports
rm -rf "$REPORTS" && mkdir -p "$REPORTS"
export ASAN_OPTIONS="halt_on_error=1:detect_leaks=1:abort_on_error=0:exitcode=23:log_path=$REPORTS/asan"
export UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1:exitcode=23:log_path=$REPORTS/ubsan"
export LSAN_OPTIONS="suppressions=$(pwd)/test/sanitizer_suppressions.txt:print_suppressions=0"
# Left out here, and run in the plain build: tests that run code the suite
# runs anyway, again and again, to compare results (the same edges whatever
# the thread count or the cameras' arrival order, the focal profile on one
# thread and on several, the focal estimate on rings of cameras (the path's
# runs the same code), two covariance models or two thresholds side by
# side, a second session joining a saved map under other lighting after the
# test that joins sessions, the camera_info check on rendered images: the
# node's tests feed it pairs, its own tests run its estimates, and the
# replay of a wrong focal length runs the same code as that of an
# undescribed lens). They add no code to what the sanitizers see and
# took a large part of this pass (in keyframe_frontend_test, two thirds of
# its time).
export GTEST_FILTER="-KeyframeFrontend.EdgesDoNotDependOnTheThreadCount:KeyframeFrontend.EdgesDoNotDependOnTheOrderOfTheCamerasOfACapture:KeyframeFrontend.LoopClosuresCarryTheCellJackknifeCovariance:ImagePipeline.FocalLengthDoesNotDependOnTheThreadCount:ImagePipeline.ARingOfCameras*:ImagePipeline.NoiseScaledThresholdMakesCastlePairsMoreAccurate:BagReplay.ASessionUnderOtherLightingJoinsTheSavedMap:FocalMonitor.TheFrontEndFindsACameraWhoseFocalLengthIsOff:BagReplay.DistortedImagesWithoutADistortionModelAreFoundOut"
status=0
(cd build/sanitize && ctest --output-on-failure "$@") || status=$?
# LeakSanitizer's stop-the-world at exit now and then crashes in its own
# tracer thread ("Tracer caught signal 11", google/sanitizers#1353): no
# finding, but the process fails (seen at the exit of image_pipeline_test in
# runs of the whole suite, not when that test ran alone). Such a report is
# set aside and the failed tests run again, at most twice; any other report,
# or a third failure, fails the run.
TRACER="$REPORTS.tracer_crashes"
rm -rf "$TRACER"
set_aside_tracer_crashes() {  # true if it set any report aside
  local moved=1
  for f in "$REPORTS"/*; do
    [ -e "$f" ] || continue
    if grep -q "LeakSanitizer has encountered a fatal error" "$f" &&
       ! grep -q -E "ERROR: (AddressSanitizer|LeakSanitizer: detected)|runtime error" "$f"; then
      mkdir -p "$TRACER" && mv "$f" "$TRACER/" && moved=0
    fi
  done
  return $moved
}
for attempt in 1 2; do
  set_aside_tracer_crashes || break
  echo "LeakSanitizer's tracer crashed at exit (no finding) in:" >&2
  for f in "$TRACER"/*; do echo "== $f" >&2; head -3 "$f" >&2; done
  [ "$status" != 0 ] || break
  echo "running the failed tests again ($attempt of 2)" >&2
  status=0
  (cd build/sanitize && ctest --output-on-failure --rerun-failed) || status=$?
done
if [ -n "$(ls -A "$REPORTS")" ]; then
  echo "sanitizer reports:" >&2
  for f in "$REPORTS"/*; do echo "== $f" >&2; head -40 "$f" >&2; done
  exit 1
fi
echo "sanitizers: no report from any process"
exit $status
