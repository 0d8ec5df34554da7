#include "rotation_averaging/frontend/controllers/focal_monitor.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <set>

#include "rotation_averaging/frontend/controllers/focal_corrector.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/sim/focal_scene.h"
#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

Eigen::Matrix3d FocalTimes(const Eigen::Matrix3d& k, double scale) {
  Eigen::Matrix3d out = k;
  out(0, 0) *= scale;
  out(1, 1) *= scale;
  return out;
}

Eigen::Matrix3d SceneK() {
  Eigen::Matrix3d k;
  k << 500, 0, 320, 0, 500, 240, 0, 0, 1;
  return k;
}

// A pair's sample keeps at most the asked number of matches, and the pose's
// inliers still point at the same correspondences.
TEST(FocalMonitor, ASampleKeepsItsInliersWhenItDropsMatches) {
  std::vector<Eigen::Vector2d> p1, p2;
  RelativePoseResult pose;
  for (int i = 0; i < 1000; ++i) {
    p1.emplace_back(i, 0.5 * i);
    p2.emplace_back(-i, 2.0 * i);
    if (i % 3 != 0) pose.inliers.push_back(i);
  }
  const auto sample = MakeFocalSample(p1, p2, pose, 200);
  ASSERT_EQ(sample->points1.size(), 200u);
  ASSERT_EQ(sample->points2.size(), 200u);
  // Every fifth match is kept, and of those the inliers (2 of 3) stay inliers.
  EXPECT_NEAR(static_cast<double>(sample->pose.inliers.size()), 200.0 * 2 / 3, 2.0);
  for (int m : sample->pose.inliers) {
    ASSERT_GE(m, 0);
    ASSERT_LT(m, 200);
    const int original = static_cast<int>(sample->points1[m].x());
    EXPECT_NE(original % 3, 0) << "an outlier became an inlier";
    EXPECT_EQ(sample->points2[m].x(), -original);
  }
  // Fewer matches than asked for: all kept, inliers as they were.
  const auto all = MakeFocalSample(p1, p2, pose, 5000);
  EXPECT_EQ(all->points1.size(), 1000u);
  EXPECT_EQ(all->pose.inliers, pose.inliers);
}

// Estimates fall due at first_estimate_pairs, then each time the count has
// grown by `growth`; a camera whose intrinsics change starts again; the
// pairs held stay within max_pairs.
TEST(FocalMonitor, EstimatesFallDueAsACameraGrowsAndStartAgainWithNewIntrinsics) {
  FocalMonitorOptions options;
  options.enabled = true;
  options.first_estimate_pairs = 3;
  options.growth = 2.0;
  options.max_pairs = 5;
  FocalMonitor monitor(options);
  const auto sample = std::make_shared<FocalSample>();
  const Eigen::Matrix3d k = SceneK();
  std::vector<std::uint64_t> due_at;
  for (int n = 1; n <= 13; ++n) {
    monitor.Add("cam0", k, 500.0, CameraIntrinsics(), sample);
    EXPECT_LE(monitor.HeldPairs("cam0"), 5u);
    for (const FocalJob& job : monitor.TakeDue()) {
      EXPECT_EQ(job.camera, "cam0");
      EXPECT_EQ(job.samples.size(), monitor.HeldPairs("cam0"));
      due_at.push_back(job.pairs_seen);
    }
  }
  EXPECT_EQ(due_at, (std::vector<std::uint64_t>{3, 6, 12}));
  // Another camera counts on its own; new intrinsics for cam0 restart it.
  monitor.Add("cam1", k, 500.0, CameraIntrinsics(), sample);
  monitor.Add("cam0", FocalTimes(k, 1.1), 550.0, CameraIntrinsics(), sample);
  EXPECT_EQ(monitor.HeldPairs("cam0"), 1u);
  EXPECT_EQ(monitor.HeldPairs("cam1"), 1u);
  monitor.Add("cam0", FocalTimes(k, 1.1), 550.0, CameraIntrinsics(), sample);
  monitor.Add("cam0", FocalTimes(k, 1.1), 550.0, CameraIntrinsics(), sample);
  const std::vector<FocalJob> due = monitor.TakeDue();
  ASSERT_EQ(due.size(), 1u);
  EXPECT_EQ(due[0].pairs_seen, 3u);
  EXPECT_DOUBLE_EQ(due[0].given_focal_px, 550.0);
  // Off: nothing is held.
  FocalMonitor off{FocalMonitorOptions()};
  for (int n = 0; n < 5; ++n) off.Add("cam0", k, 500.0, CameraIntrinsics(), sample);
  EXPECT_EQ(off.HeldPairs("cam0"), 0u);
  EXPECT_TRUE(off.TakeDue().empty());
}

// The scene's pairs as a job, with the pairs' matches thinned as the front
// end thins them.
FocalJob SceneJob(const FocalScene& scene, const Eigen::Matrix3d& k_given) {
  FocalJob job;
  job.camera = "cam0";
  job.k = k_given;
  job.given_focal_px = k_given(0, 0);
  for (std::size_t p = 0; p < scene.poses.size(); ++p) {
    if (!scene.poses[p].success) continue;
    job.samples.push_back(MakeFocalSample(scene.points1[p], scene.points2[p], scene.poses[p],
                                          FocalMonitorOptions().max_matches_per_pair));
  }
  job.pairs_seen = job.samples.size();
  return job;
}

// On a path (general motion) a focal length given 3% short disagrees with
// the pairs, which put it within 1% of the truth; the true one agrees.
TEST(FocalMonitor, AFocalLengthThreePercentOffDisagreesAndTheTrueOneAgrees) {
  const Eigen::Matrix3d k = SceneK();
  const FocalCalibrationOptions options = FocalMonitorOptions().focal;
  for (const double given : {0.97, 1.0}) {
    const Eigen::Matrix3d k_given = FocalTimes(k, given);
    const FocalScene scene = MakeFocalScene(k, k_given);
    const CameraFocalCheck check = RunFocalJob(SceneJob(scene, k_given), options);
    ASSERT_TRUE(check.calibration.estimated) << check.Report();
    EXPECT_NEAR(check.calibration.scale * given, 1.0, 0.01) << check.Report();
    EXPECT_EQ(check.disagrees, given != 1.0) << check.Report();
    EXPECT_NE(check.Report().find(given != 1.0 ? "disagrees" : "agrees"), std::string::npos) << check.Report();
  }
}

// Raw pixels of a lens with radial distortion, taken for an undistorted
// camera's: the pairs show the distortion, about the lens's k1, beyond the
// noise; the same scene through an ideal lens shows none. The focal job of
// a camera without a distortion model carries that check.
TEST(FocalMonitor, ADistortionTheIntrinsicsDoNotDescribeIsSeen) {
  const Eigen::Matrix3d k = SceneK();
  const RadialDistortionOptions options;
  for (const double k1 : {-0.15, 0.0}) {
    FocalSceneOptions lens;
    lens.lens_k1 = k1;
    const FocalScene scene = MakeFocalScene(k, k, lens);
    const RadialDistortion seen = EstimateRadialDistortion(scene.Pairs(), k, options);
    ASSERT_TRUE(seen.estimated) << k1;
    EXPECT_NEAR(seen.lambda, k1, 0.05) << seen.lambda << " +- " << seen.standard_deviation;
    EXPECT_EQ(DistortionIsUnmodelled(seen, options), k1 != 0.0)
        << seen.lambda << " +- " << seen.standard_deviation << ", " << seen.corner_shift_px << " px";
    FocalJob job = SceneJob(scene, k);
    job.check_distortion = true;
    const CameraFocalCheck check = RunFocalJob(job, FocalMonitorOptions().focal);
    EXPECT_TRUE(check.distortion_checked);
    EXPECT_EQ(check.distortion_unmodelled, k1 != 0.0) << check.Report();
    EXPECT_EQ(check.Flagged(), check.disagrees || k1 != 0.0);
    EXPECT_EQ(check.Report().find("has no distortion model") != std::string::npos, k1 != 0.0) << check.Report();
  }
}

// A focal length a few percent off bends the pairs as a distortion would:
// at the given focal length the pairs of an ideal lens show a "distortion"
// beyond their noise. The focal scale alone explains them as well, so the
// distortion is not flagged; a real distortion (10 px at the corners) under
// the same wrong focal length is, because no focal length explains it.
TEST(FocalMonitor, AWrongFocalLengthIsNotTakenForADistortion) {
  const Eigen::Matrix3d k = SceneK();
  const RadialDistortionOptions options;
  for (const double k1 : {0.0, -0.05}) {
    for (const double given : {0.97, 1.03}) {
      FocalSceneOptions lens;
      lens.lens_k1 = k1;
      const Eigen::Matrix3d k_given = FocalTimes(k, given);
      const FocalScene scene = MakeFocalScene(k, k_given, lens);
      FocalJob job = SceneJob(scene, k_given);
      job.check_distortion = true;
      const CameraFocalCheck check = RunFocalJob(job, FocalMonitorOptions().focal);
      const RadialDistortion& seen = check.distortion;
      ASSERT_TRUE(seen.estimated) << check.Report();
      const std::string costs = "; cost " + std::to_string(seen.cost) + ", focal only " +
                                std::to_string(seen.focal_only_cost) + " +- " + std::to_string(seen.advantage_deviation);
      RecordProperty("lens_k1_" + testing::PrintToString(k1) + "_focal_x" + testing::PrintToString(given),
                     check.Report() + costs);
      EXPECT_EQ(check.distortion_unmodelled, k1 != 0.0) << check.Report() << costs;
      if (k1 == 0.0) {
        // Without the focal scale to compare with, the old verdict: the
        // ideal lens looks distorted at the wrong focal length.
        ASSERT_TRUE(check.calibration.estimated) << check.Report();
        EXPECT_GT(std::abs(seen.lambda), 3.0 * seen.standard_deviation) << check.Report();
        EXPECT_TRUE(seen.FocalExplainsAsWell()) << check.Report() << costs;
      } else if (check.calibration.estimated) {
        EXPECT_FALSE(seen.FocalExplainsAsWell()) << check.Report() << costs;
      }
    }
  }
}

// The checker runs jobs on its own thread: after Wait the check is there,
// its first estimate and a change of verdict are notices, once.
TEST(FocalMonitor, TheCheckerReportsEachCameraAndItsChangesOfVerdictOnce) {
  const Eigen::Matrix3d k = SceneK();
  const Eigen::Matrix3d short_k = FocalTimes(k, 0.97);
  const FocalJob wrong = SceneJob(MakeFocalScene(k, short_k), short_k);
  FocalChecker checker(FocalMonitorOptions().focal);
  checker.Submit({wrong});
  checker.Wait();
  std::map<std::string, CameraFocalCheck> checks = checker.Checks();
  ASSERT_EQ(checks.count("cam0"), 1u);
  EXPECT_TRUE(checks["cam0"].disagrees);
  std::vector<std::pair<std::string, bool>> notices = checker.TakeNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_TRUE(notices[0].second);
  // The same verdict again: no notice.
  checker.Submit({wrong});
  checker.Wait();
  EXPECT_TRUE(checker.TakeNotices().empty());
  // Corrected intrinsics: it agrees now, and says so.
  checker.Submit({SceneJob(MakeFocalScene(k, k), k)});
  checker.Wait();
  notices = checker.TakeNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_FALSE(notices[0].second) << notices[0].first;
  EXPECT_FALSE(checker.Checks()["cam0"].disagrees);
}

// The rendered rig (two cameras, 24 captures) through a front end whose
// sideways camera is given a focal length `focal_factor` times its own (3%
// short by default). With a `lens`, that camera's images are seen through it
// and given with its model (keypoints undistorted with the given K).
struct ShortFocalRun {
  RigSceneOptions scene_options;
  std::unique_ptr<RigScene> scene;
  KeyframeFrontendOptions options;
  std::unique_ptr<KeyframeFrontend> frontend;
  Eigen::Matrix3d short_k;
  std::vector<KeyframeRelativeRotation> edges;
  std::vector<FocalJob> jobs;
};

// The rig's sideways camera given `focal_factor` times its focal length,
// its images through `lens` (if any), which camera_info carries unless
// `lens_in_info` is false (a lens nobody calibrated); the check's first
// estimate after `first_estimate_pairs` pairs (0: the default).
std::unique_ptr<ShortFocalRun> RunShortFocal(bool hold_for_correction, const CameraIntrinsics* lens = nullptr,
                                             double focal_factor = 0.97, bool lens_in_info = true,
                                             int first_estimate_pairs = 0) {
  auto run = std::make_unique<ShortFocalRun>();
  run->scene_options.num_cameras = 2;
  run->scene_options.num_captures = 24;
  run->scene_options.WithWidth(480);
  run->scene = std::make_unique<RigScene>(run->scene_options);
  run->options.features.max_features = 1500;
  run->options.max_loop_candidates = 0;
  run->options.focal_monitor.enabled = true;
  run->options.focal_monitor.hold_for_correction = hold_for_correction;
  if (first_estimate_pairs > 0) run->options.focal_monitor.first_estimate_pairs = first_estimate_pairs;
  run->frontend = std::make_unique<KeyframeFrontend>(run->options);
  const RigScene& scene = *run->scene;
  run->short_k = FocalTimes(scene.Intrinsics(), focal_factor);
  CameraIntrinsics true_lens, given;
  if (lens) true_lens = *lens;
  true_lens.k = scene.Intrinsics();
  given = true_lens;
  given.k = run->short_k;
  if (!lens_in_info) {
    given.distortion = DistortionModel::kNone;
    given.coefficients.clear();
  }
  CameraIntrinsics front;
  front.k = scene.Intrinsics();
  // The lens's image is warped from the wider field it sees: no black border.
  const int margin =
      LensMarginPx(true_lens, cv::Size(run->scene_options.width, run->scene_options.height));
  for (int c = 0; c < run->scene_options.num_captures; ++c) {
    for (int cam = 0; cam < 2; ++cam) {
      const KeyframeKey key{scene.Cameras()[cam].frame_id, (c + 1) * 1'000'000'000LL};
      const cv::Mat image =
          cam == 1 ? DistortImage(scene.Render(c, cam, margin), true_lens, margin) : scene.Render(c, cam);
      for (const KeyframeRelativeRotation& e : run->frontend->AddKeyframe(key, image, cam == 1 ? given : front)) {
        run->edges.push_back(e);
      }
      for (FocalJob& job : run->frontend->TakeFocalJobs()) run->jobs.push_back(std::move(job));
    }
  }
  return run;
}

// The front end gives the check each camera's own verified pairs: a camera
// of the rendered rig looking sideways, whose focal length is given 3%
// short, is found out within 1% by its 20th pair, and its pairs alone are
// used (none with the other camera, whose intrinsics are right).
TEST(FocalMonitor, TheFrontEndFindsACameraWhoseFocalLengthIsOff) {
  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(false);
  const RigScene& scene = *run->scene;
  const KeyframeFrontend& frontend = *run->frontend;
  const KeyframeFrontendOptions& options = run->options;
  const Eigen::Matrix3d& short_k = run->short_k;
  const std::vector<FocalJob>& jobs = run->jobs;
  EXPECT_GT(frontend.Stats().focal_bytes, 0u);
  std::set<std::string> cameras;
  for (const FocalJob& job : jobs) cameras.insert(job.camera);
  ASSERT_EQ(cameras.count(scene.Cameras()[1].frame_id), 1u) << "no estimate of the camera given a wrong focal length";
  for (const FocalJob& job : jobs) {
    const bool off = job.camera == scene.Cameras()[1].frame_id;
    EXPECT_TRUE(job.k.isApprox(off ? short_k : scene.Intrinsics())) << job.camera;
    if (!off) continue;
    const CameraFocalCheck check = RunFocalJob(job, options.focal_monitor.focal);
    ASSERT_TRUE(check.calibration.estimated) << check.Report();
    EXPECT_NEAR(check.calibration.scale * 0.97, 1.0, 0.01) << check.Report();
    EXPECT_TRUE(check.disagrees) << check.Report();
  }
}

// A barrel lens as strong as EuRoC's (k1 = -0.28), which the raw-camera
// tests render through.
CameraIntrinsics PlumbBobLens() {
  CameraIntrinsics lens;
  lens.distortion = DistortionModel::kPlumbBob;
  lens.coefficients = {-0.28, 0.07, 2e-4, 2e-5};
  return lens;
}

// The errors of the edges between two keyframes of the rig's sideways
// camera (its second) against the scene's true R_12 = R_1 R_2^T, sorted, deg.
std::vector<double> SidewaysErrors(const RigScene& scene, const std::vector<KeyframeRelativeRotation>& edges) {
  const std::string& left = scene.Cameras()[1].frame_id;
  auto world_to_camera = [&](const KeyframeKey& key) {
    const int capture = static_cast<int>(key.stamp_ns / 1'000'000'000LL) - 1;
    return scene.WorldToCamera(capture, key.frame_id == left ? 1 : 0);
  };
  std::vector<double> errors;
  for (const KeyframeRelativeRotation& e : edges) {
    if (e.keyframe1.frame_id != left || e.keyframe2.frame_id != left) continue;
    const Eigen::Matrix3d r = world_to_camera(e.keyframe1) * world_to_camera(e.keyframe2).transpose();
    errors.push_back(RadToDeg(AngularDistanceRad(r, e.rotation)));
  }
  std::sort(errors.begin(), errors.end());
  return errors;
}

// focal_calibration: apply. The camera's pairs estimated again with the
// corrected focal length measure its rotations several times better, and
// its check then agrees with the corrected focal length.
TEST(FocalMonitor, ACorrectedFocalLengthMakesTheCamerasPairsRight) {
  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true);
  const RigScene& scene = *run->scene;
  KeyframeFrontend& frontend = *run->frontend;
  const KeyframeFrontendOptions& options = run->options;
  const Eigen::Matrix3d& short_k = run->short_k;
  const std::string left = scene.Cameras()[1].frame_id;
  const std::vector<KeyframeRelativeRotation>& before = run->edges;
  const std::vector<FocalJob>& jobs = run->jobs;
  auto left_errors = [&](const std::vector<KeyframeRelativeRotation>& edges) {
    return SidewaysErrors(scene, edges);
  };
  const FocalJob* last = nullptr;
  for (const FocalJob& job : jobs) {
    if (job.camera == left) last = &job;
  }
  ASSERT_NE(last, nullptr);
  const CameraFocalCheck check = RunFocalJob(*last, options.focal_monitor.focal);
  ASSERT_TRUE(check.disagrees) << check.Report();
  std::vector<KeyframeRelativeRotation> after;
  std::string why;
  ASSERT_TRUE(frontend.ApplyFocalCorrection(left, check.calibration.scale, &after, &why)) << why;
  EXPECT_DOUBLE_EQ(frontend.FocalCorrection(left), check.calibration.scale);
  const std::vector<double> old_errors = left_errors(before), new_errors = left_errors(after);
  ASSERT_GE(new_errors.size(), 20u);
  EXPECT_GE(new_errors.size() + 2, old_errors.size());  // nearly every pair again
  const double old_median = old_errors[old_errors.size() / 2], new_median = new_errors[new_errors.size() / 2];
  RecordProperty("median_error_given_deg", std::to_string(old_median));
  RecordProperty("median_error_corrected_deg", std::to_string(new_median));
  EXPECT_LT(new_median, 0.5 * old_median) << "median error of the left camera's pairs: " << old_median << " deg with "
                                          << "the given focal length, " << new_median << " deg corrected";
  // The check starts again on the corrected focal length, with those pairs.
  std::vector<FocalJob> again = frontend.TakeFocalJobs();
  ASSERT_FALSE(again.empty());
  const CameraFocalCheck rechecked = RunFocalJob(again.back(), options.focal_monitor.focal);
  EXPECT_EQ(again.back().camera, left);
  EXPECT_FALSE(rechecked.disagrees) << rechecked.Report();
  EXPECT_NEAR(again.back().given_focal_px, short_k(0, 0) * check.calibration.scale, 1e-9);
}

// A FocalCorrector over a run's front end, with a checker, a rig model and
// an averager of its own; the edges it puts into the graph are collected.
struct Correcting {
  explicit Correcting(ShortFocalRun* run, const FocalCorrectorOptions& options = FocalCorrectorOptions())
      : checker(run->options.focal_monitor.focal),
        corrector(options, run->frontend.get(), &frontend_mutex, &checker, &rig, &averager,
                  [this](const KeyframeRelativeRotation& e, std::string*) {
                    added.push_back(e);
                    return true;
                  }) {}
  FocalChecker checker;
  std::mutex frontend_mutex;
  RigModel rig{RigModelOptions()};
  OnlineAverager averager{OnlineAveragerOptions()};
  std::vector<KeyframeRelativeRotation> added;
  FocalCorrector corrector;
};

// FocalCorrector, what focal_calibration: apply runs: a camera whose check
// disagrees is corrected once per estimate. Its pairs estimated again go
// into the graph through the given edge sink, the correction and its notice
// are reported, and the checker then looks at the corrected focal length:
// the same estimate is never applied twice, and the camera that agrees is
// left as it is.
TEST(FocalMonitor, TheCorrectorAppliesADisagreeingCheckOnce) {
  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true);
  const std::string front = run->scene->Cameras()[0].frame_id, left = run->scene->Cameras()[1].frame_id;
  Correcting harness(run.get());
  FocalChecker& checker = harness.checker;
  FocalCorrector& corrector = harness.corrector;
  std::vector<KeyframeRelativeRotation>& added = harness.added;
  checker.Submit(run->jobs);
  checker.Wait();
  const CameraFocalCheck check = checker.Checks().at(left);
  ASSERT_TRUE(check.disagrees) << check.Report();
  std::vector<std::string> warnings;
  corrector.ApplyCorrections(&warnings);
  EXPECT_TRUE(warnings.empty());
  const std::map<std::string, double> corrections = corrector.Corrections();
  ASSERT_EQ(corrections.size(), 1u);
  EXPECT_DOUBLE_EQ(corrections.at(left), check.calibration.scale);
  EXPECT_DOUBLE_EQ(run->frontend->FocalCorrection(left), check.calibration.scale);
  EXPECT_DOUBLE_EQ(run->frontend->FocalCorrection(front), 1.0);
  ASSERT_GE(added.size(), 20u);
  for (const KeyframeRelativeRotation& e : added) {
    EXPECT_TRUE(e.keyframe1.frame_id == left || e.keyframe2.frame_id == left);
  }
  const std::vector<std::pair<std::string, bool>> notices = corrector.TakeNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].first.find(left + ": focal length corrected by x"), std::string::npos) << notices[0].first;
  EXPECT_NE(notices[0].first.find(std::to_string(added.size()) + " of its pairs estimated again"), std::string::npos)
      << notices[0].first;
  EXPECT_TRUE(corrector.TakeNotices().empty());
  // The check runs again at the corrected focal length; nothing more to do.
  checker.Wait();
  const std::size_t edges_after_first = added.size();
  corrector.ApplyCorrections(&warnings);
  EXPECT_EQ(added.size(), edges_after_first);
  EXPECT_EQ(corrector.Corrections(), corrections);
  EXPECT_TRUE(corrector.TakeNotices().empty());
  // No loop closures: nothing for the loops to refine.
  corrector.RefineByLoops(0);
  EXPECT_TRUE(corrector.LoopRefinements().empty());
}

// The refinement's focal estimates (FocalCorrector::ApplyRefinementEstimates):
// judged by JudgeFocalEstimate, a camera they put off is corrected by the
// estimate, once per refinement; one they cannot tell, or that agrees, is
// not; and a camera of a rig (extrinsics known) waits while another camera
// of the rig is not told.
TEST(FocalMonitor, TheCorrectorAppliesTheRefinementsEstimates) {
  BundleAdjustmentFocal::Estimate off, agrees, unsure;
  off.scale = 1.031, off.sigma = 0.001, off.determined = true;
  agrees.scale = 1.003, agrees.sigma = 0.001, agrees.determined = true;
  unsure.scale = 1.03, unsure.sigma = 0.04, unsure.determined = true;
  EXPECT_EQ(JudgeFocalEstimate(off, 0.005), FocalVerdict::kDisagrees);
  EXPECT_EQ(JudgeFocalEstimate(agrees, 0.005), FocalVerdict::kAgrees);  // within min_correction
  EXPECT_EQ(JudgeFocalEstimate(unsure, 0.005), FocalVerdict::kCannotTell);
  BundleAdjustmentFocal::Estimate undetermined = off;
  undetermined.determined = false;
  EXPECT_EQ(JudgeFocalEstimate(undetermined, 0.005), FocalVerdict::kCannotTell);
  // Described with two significant digits of its smallest deviation.
  BundleAdjustmentFocal::Estimate precise = off;
  precise.scale = 1.0309, precise.sigma = 0.000046, precise.sigma_matches = 0.000041;
  precise.sigma_principal_point = 0.000021, precise.views = 600;
  EXPECT_EQ(DescribeFocalEstimate(precise),
            "x1.030900 +- 0.000046 (matches 0.000041, principal point 0.000021), 600 keyframes");
  unsure.sigma_matches = 0.0101, unsure.sigma_principal_point = 0.0388, unsure.views = 12;
  EXPECT_EQ(DescribeFocalEstimate(unsure), "x1.0300 +- 0.0400 (matches 0.0101, principal point 0.0388), 12 keyframes");

  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true);
  const std::string front = run->scene->Cameras()[0].frame_id, left = run->scene->Cameras()[1].frame_id;
  Correcting harness(run.get());
  FocalCorrector& corrector = harness.corrector;
  std::vector<KeyframeRelativeRotation>& added = harness.added;
  const double given_px = run->frontend->FocalInUsePx(left);
  EXPECT_GT(given_px, 0.0);
  std::vector<std::string> warnings;
  corrector.ApplyRefinementEstimates({{left, off}, {front, unsure}}, 1, &warnings);
  EXPECT_EQ(corrector.Corrections(), (std::map<std::string, double>{{left, 1.031}}));
  EXPECT_DOUBLE_EQ(run->frontend->FocalInUsePx(left), given_px * 1.031);
  EXPECT_GE(added.size(), 20u);
  const std::vector<std::pair<std::string, bool>> notices = corrector.TakeNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].first.find(left + ": focal length corrected by x1.0310"), std::string::npos) << notices[0].first;
  EXPECT_NE(notices[0].first.find("the refinement's estimate"), std::string::npos) << notices[0].first;
  // The same refinement again: decided already.
  const std::size_t edges = added.size();
  corrector.ApplyRefinementEstimates({{left, off}}, 1, &warnings);
  EXPECT_EQ(added.size(), edges);
  // A later one that agrees with the corrected focal length: nothing to do.
  corrector.ApplyRefinementEstimates({{left, agrees}}, 2, &warnings);
  EXPECT_EQ(added.size(), edges);
  EXPECT_TRUE(corrector.TakeNotices().empty());
}

// The same with the rig's extrinsics known: the left camera waits while the
// refinement cannot tell the forward camera's focal length, and says why.
TEST(FocalMonitor, ARigCameraWaitsForTheRigsOtherCamerasToBeTold) {
  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true);
  const RigScene& scene = *run->scene;
  const std::string front = scene.Cameras()[0].frame_id, left = scene.Cameras()[1].frame_id;
  Correcting harness(run.get());
  for (const RigCamera& c : scene.Cameras()) {
    harness.rig.AddStaticTransform("base_link", c.frame_id, c.camera_from_rig.transpose());
    ASSERT_TRUE(harness.rig.IsRigCamera(c.frame_id));
  }
  FocalCorrector& corrector = harness.corrector;
  std::vector<KeyframeRelativeRotation>& added = harness.added;
  BundleAdjustmentFocal::Estimate off, unsure;
  off.scale = 1.031, off.sigma = 0.001, off.determined = true;
  unsure.scale = 1.03, unsure.sigma = 0.04, unsure.determined = true;
  std::vector<std::string> warnings;
  corrector.ApplyRefinementEstimates({{left, off}, {front, unsure}}, 1, &warnings);
  EXPECT_TRUE(corrector.Corrections().empty());
  EXPECT_TRUE(added.empty());
  const std::vector<std::pair<std::string, bool>> notices = corrector.TakeNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].first.find("cannot tell the focal lengths of the other cameras of its rig (" + front + ")"),
            std::string::npos)
      << notices[0].first;
  // Both told (the forward camera agrees): the left one is corrected.
  BundleAdjustmentFocal::Estimate agrees = off;
  agrees.scale = 1.001;
  corrector.ApplyRefinementEstimates({{left, off}, {front, agrees}}, 2, &warnings);
  EXPECT_EQ(corrector.Corrections(), (std::map<std::string, double>{{left, 1.031}}));
}

// focal_calibration: apply, refined by the loops (FocalCorrector::RefineByLoops
// in the node): once a camera is corrected, its held pairs' edges move by their
// derivatives with respect to its focal length for the loops' small
// corrections, instead of being estimated again. The left camera of the
// raw rig, its focal length given 3% short, corrected to 0.5% short of the
// true one, then by what remains both ways: moved, its pairs come most of
// the way that estimating them again takes them (which also re-selects
// their inliers at the new focal length: 0.5% is 1.5 px at the corners
// through this lens; the loops' corrections are a few hundredths of a
// percent). A camera that holds no pairs has no derivatives.
TEST(FocalMonitor, ALinearisedCorrectionIsAsGoodAsEstimatingThePairsAgain) {
  const CameraIntrinsics lens = PlumbBobLens();
  const std::unique_ptr<ShortFocalRun> again = RunShortFocal(true, &lens, 0.97);
  const std::unique_ptr<ShortFocalRun> moved = RunShortFocal(true, &lens, 0.97);
  const RigScene& scene = *again->scene;
  const std::string left = scene.Cameras()[1].frame_id;
  EXPECT_TRUE(moved->frontend->FocalSensitivities("no_such_camera").empty());
  const double short_of_truth = 0.995;
  std::vector<KeyframeRelativeRotation> first, estimated, linearised;
  std::string why;
  ASSERT_TRUE(again->frontend->ApplyFocalCorrection(left, short_of_truth / 0.97, &first, &why)) << why;
  ASSERT_TRUE(moved->frontend->ApplyFocalCorrection(left, short_of_truth / 0.97, &first, &why)) << why;
  const std::vector<FocalSensitivity> sensitivities = moved->frontend->FocalSensitivities(left);
  ASSERT_GE(sensitivities.size(), 20u);
  for (const FocalSensitivity& s : sensitivities) {
    EXPECT_TRUE(s.keyframe1.frame_id == left || s.keyframe2.frame_id == left);
    EXPECT_GT(s.derivative.norm(), 0.0);
  }
  const double remaining = 1.0 / short_of_truth;
  ASSERT_TRUE(again->frontend->ApplyFocalCorrection(left, remaining, &estimated, &why)) << why;
  ASSERT_TRUE(moved->frontend->ApplyFocalCorrection(left, remaining, &linearised, &why, true)) << why;
  EXPECT_NEAR(moved->frontend->FocalCorrection(left), 1.0 / 0.97, 1e-12);
  EXPECT_EQ(linearised.size(), sensitivities.size());
  auto median_error = [&](const std::vector<KeyframeRelativeRotation>& edges) {
    const std::vector<double> errors = SidewaysErrors(scene, edges);
    return errors.empty() ? 0.0 : errors[errors.size() / 2];
  };
  const double before = median_error(first), after_estimated = median_error(estimated),
               after_moved = median_error(linearised);
  RecordProperty("median_error_short_deg", std::to_string(before));
  RecordProperty("median_error_estimated_again_deg", std::to_string(after_estimated));
  RecordProperty("median_error_moved_deg", std::to_string(after_moved));
  EXPECT_LT(after_moved, 0.7 * before) << "median error of the left camera's pairs: " << before << " deg 0.5% "
                                        << "short, " << after_moved << " deg moved by their derivatives";
  EXPECT_LT(after_moved - after_estimated, 0.5 * (before - after_estimated))
      << "median error of the left camera's pairs: " << before << " deg 0.5% short, then "
      << after_estimated << " deg estimated again at the true one, " << after_moved
      << " deg moved there by their derivatives";
}

// A raw camera through a plumb_bob lens whose focal length is given 3%
// short. Its keypoints were undistorted with that focal length, and the
// lens's distortion acts on the normalised coordinates it gave: they land
// near where the right focal length puts them, with a radial error.
//  * The check undistorts them again for every focal length it tries, and
//    finds the camera out as it does without a lens. Scaling them instead
//    takes the radial error for a focal error of the opposite sign and finds
//    nothing wrong.
//  * The correction undistorts them again with the corrected focal length:
//    the camera's pairs estimated again are those of a run given the right
//    focal length from the start, pair by pair. Scaling the old undistorted
//    keypoints instead leaves them many times the pairs' own error away.
TEST(FocalMonitor, ARawCamerasFocalLengthIsCheckedAndCorrectedThroughItsLens) {
  const CameraIntrinsics lens = PlumbBobLens();
  const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true, &lens, 0.97);
  const std::unique_ptr<ShortFocalRun> right = RunShortFocal(false, &lens, 1.0);
  const std::string left = run->scene->Cameras()[1].frame_id;
  const FocalJob* last = nullptr;
  for (const FocalJob& job : run->jobs) {
    if (job.camera == left) last = &job;
  }
  ASSERT_NE(last, nullptr);
  EXPECT_TRUE(last->lens.HasDistortion());
  const CameraFocalCheck check = RunFocalJob(*last, run->options.focal_monitor.focal);
  ASSERT_TRUE(check.calibration.estimated) << check.Report();
  RecordProperty("estimated_scale", std::to_string(check.calibration.scale));
  EXPECT_NEAR(check.calibration.scale * 0.97, 1.0, 0.01) << check.Report();
  EXPECT_TRUE(check.disagrees) << check.Report();
  std::vector<KeyframeRelativeRotation> after;
  std::string why;
  ASSERT_TRUE(run->frontend->ApplyFocalCorrection(left, 1.0 / 0.97, &after, &why)) << why;
  std::map<std::pair<std::int64_t, std::int64_t>, Eigen::Matrix3d> right_edges;
  for (const KeyframeRelativeRotation& e : right->edges) {
    if (e.keyframe1.frame_id == left && e.keyframe2.frame_id == left) {
      right_edges[{e.keyframe1.stamp_ns, e.keyframe2.stamp_ns}] = e.rotation;
    }
  }
  // Per pair, in degrees: the corrected edge against the right run's, and
  // the right run's against the truth.
  std::vector<double> to_right, right_errors;
  auto world_to_camera = [&](std::int64_t stamp_ns) {
    return run->scene->WorldToCamera(static_cast<int>(stamp_ns / 1'000'000'000LL) - 1, 1);
  };
  for (const KeyframeRelativeRotation& e : after) {
    if (e.keyframe1.frame_id != left || e.keyframe2.frame_id != left) continue;
    const auto other = right_edges.find({e.keyframe1.stamp_ns, e.keyframe2.stamp_ns});
    if (other == right_edges.end()) continue;
    to_right.push_back(RadToDeg(AngularDistanceRad(e.rotation, other->second)));
    const Eigen::Matrix3d truth =
        world_to_camera(e.keyframe1.stamp_ns) * world_to_camera(e.keyframe2.stamp_ns).transpose();
    right_errors.push_back(RadToDeg(AngularDistanceRad(truth, other->second)));
  }
  ASSERT_GE(to_right.size(), 20u);
  std::sort(to_right.begin(), to_right.end());
  std::sort(right_errors.begin(), right_errors.end());
  const double median_to_right = to_right[to_right.size() / 2], median_error = right_errors[right_errors.size() / 2];
  RecordProperty("median_to_right_run_deg", std::to_string(median_to_right));
  RecordProperty("median_error_right_run_deg", std::to_string(median_error));
  EXPECT_LT(median_to_right, 0.1 * median_error)
      << "the corrected pairs are " << median_to_right << " deg (median) from those given the right focal length, "
      << "whose own error is " << median_error << " deg";
  // The check starts again through the same lens, on the corrected focal
  // length, and agrees with it.
  const std::vector<FocalJob> again = run->frontend->TakeFocalJobs();
  ASSERT_FALSE(again.empty());
  EXPECT_EQ(again.back().camera, left);
  EXPECT_TRUE(again.back().lens.HasDistortion());
  EXPECT_FALSE(again.back().check_distortion);
  const CameraFocalCheck rechecked = RunFocalJob(again.back(), run->options.focal_monitor.focal);
  EXPECT_FALSE(rechecked.disagrees) << rechecked.Report();
}

// focal_calibration: apply on a camera whose camera_info describes no lens
// while its images come through one: the corrector gives it the lens its
// check sees, its pairs estimated again with it measure its rotations
// several times better, and its check starts again with the lens, which
// leaves no distortion for it to look for. A lens that moves the corners
// by min_single_estimate_lens_px is given on the check's first estimate;
// a slighter one when two estimates in a row see the same one.
TEST(FocalMonitor, TheCorrectorGivesALensCameraInfoLeavesOut) {
  CameraIntrinsics lens;
  lens.distortion = DistortionModel::kPlumbBob;
  lens.coefficients = {-0.1, 0.0, 0.0, 0.0};
  for (const bool slight : {false, true}) {
    SCOPED_TRACE(slight ? "taken for a slight lens" : "a strong lens");
    const std::unique_ptr<ShortFocalRun> run = RunShortFocal(true, &lens, 1.0, false, 8);
    const RigScene& scene = *run->scene;
    const std::string left = scene.Cameras()[1].frame_id;
    FocalCorrectorOptions options;
    if (slight) options.min_single_estimate_lens_px = 1e9;
    Correcting harness(run.get(), options);
    std::vector<FocalJob> left_jobs;
    for (const FocalJob& job : run->jobs) {
      if (job.camera == left) left_jobs.push_back(job);
    }
    ASSERT_GE(left_jobs.size(), 2u);
    std::vector<std::string> warnings;
    harness.checker.Submit({left_jobs[0]});
    harness.checker.Wait();
    const CameraFocalCheck first = harness.checker.Checks().at(left);
    ASSERT_TRUE(first.distortion_unmodelled) << first.Report();
    EXPECT_GE(first.distortion.corner_shift_px, FocalCorrectorOptions().min_single_estimate_lens_px) << first.Report();
    harness.corrector.ApplyCorrections(&warnings);
    CameraFocalCheck given_by = first;
    if (slight) {
      // The first estimate alone is not enough.
      EXPECT_TRUE(harness.corrector.LensCorrections().empty());
      EXPECT_EQ(run->frontend->LensCorrection(left), 0.0);
      EXPECT_TRUE(harness.added.empty());
      harness.checker.Submit({left_jobs[1]});
      harness.checker.Wait();
      given_by = harness.checker.Checks().at(left);
      ASSERT_TRUE(given_by.distortion_unmodelled) << given_by.Report();
      harness.corrector.ApplyCorrections(&warnings);
    }
    EXPECT_TRUE(warnings.empty());
    const std::map<std::string, RadialDistortion> lenses = harness.corrector.LensCorrections();
    ASSERT_EQ(lenses.size(), 1u);
    EXPECT_EQ(lenses.at(left).lambda, given_by.distortion.lambda);
    EXPECT_NEAR(run->frontend->LensCorrection(left), given_by.distortion.lambda, 1e-12);
    CameraIntrinsics given;
    given.k = scene.Intrinsics();
    EXPECT_TRUE(run->frontend->CameraInUse(left, given).HasDistortion());
    EXPECT_FALSE(run->frontend->CameraInUse(scene.Cameras()[0].frame_id, given).HasDistortion());
    const std::vector<double> old_errors = SidewaysErrors(scene, run->edges);
    const std::vector<double> new_errors = SidewaysErrors(scene, harness.added);
    ASSERT_GE(new_errors.size(), 20u);
    const double old_median = old_errors[old_errors.size() / 2], new_median = new_errors[new_errors.size() / 2];
    EXPECT_LT(new_median, 0.5 * old_median) << "median error of the left camera's pairs: " << old_median
                                            << " deg without a lens, " << new_median << " deg with the check's";
    const std::vector<std::pair<std::string, bool>> notices = harness.corrector.TakeNotices();
    ASSERT_EQ(notices.size(), 1u);
    EXPECT_NE(notices[0].first.find(left + ": camera_info describes no lens"), std::string::npos) << notices[0].first;
    EXPECT_TRUE(notices[0].second);
    // The check starts again with the lens: no distortion to look for.
    for (const FocalJob& job : run->frontend->TakeFocalJobs()) {
      if (job.camera == left) EXPECT_FALSE(job.check_distortion);
    }
    // Given once.
    const std::size_t edges = harness.added.size();
    harness.corrector.ApplyCorrections(&warnings);
    EXPECT_EQ(harness.added.size(), edges);
    std::string why;
    std::vector<KeyframeRelativeRotation> again;
    EXPECT_FALSE(run->frontend->ApplyLensCorrection(left, -0.1, &again, &why));
    EXPECT_NE(why.find("corrected already"), std::string::npos) << why;
  }
}

}  // namespace
}  // namespace rotation_averaging
