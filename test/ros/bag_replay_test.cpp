// The replay tool's library: a rendered rig bag end to end, determinism, and
// every kind of bad bag (no ROS master needed).
#include "rotation_averaging/CameraInfoCheckArray.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/ros/bag_replay.h"

#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <std_msgs/String.h>
#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <iterator>
#include <random>
#include <set>
#include <sstream>
#include <vector>

#include "rotation_averaging/RelativePose.h"
#include <opencv2/imgcodecs.hpp>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "common/test_vocabulary.h"
#include "rotation_averaging/sim/demo_bag.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

std::string TempDir() {
  static const std::string dir = [] {
    char pattern[] = "/tmp/rotavg_replay_test_XXXXXX";
    return std::string(mkdtemp(pattern));
  }();
  return dir;
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void WriteText(const std::string& path, const std::string& text) { std::ofstream(path) << text; }

class BagReplay : public ::testing::Test {
 protected:
  static void SetUpTestSuite() { ros::Time::init(); }

  ReplayOptions Options(const std::string& bag, const std::string& out) {
    ReplayOptions o;
    o.bags = {bag};
    o.output_dir = TempDir() + "/" + out;
    o.progress = false;
    return o;
  }

  // The rendered two-camera rig, 16 captures at 320x240, as a bag (its
  // ground truth inside), and a config of the node's parameters for it with
  // `extra` (YAML lines) added; the bag's and the config's paths.
  std::pair<std::string, std::string> WriteRigBagAndConfig(const std::string& extra = "") {
    RigSceneOptions scene_options;
    scene_options.num_captures = 16;
    scene_options.WithWidth(320);
    const RigScene scene(scene_options);
    const std::string bag = TempDir() + "/rig.bag";
    NamedOrientations truth;
    std::string error;
    EXPECT_TRUE(WriteRigSceneBag(scene, bag, /*compressed=*/false, &truth, &error)) << error;
    const std::string config = TempDir() + "/rig.yaml";
    WriteText(config,
              "image_topics: [\"/cam_front/image_raw\", \"/cam_left/image_raw\"]\n"
              "max_features: 1000\nretrieval_sample: 150\nmax_loop_candidates: 2\n" +
                  extra);
    return {bag, config};
  }

  // A bag of relative poses of a ring of views with known orientations,
  // one outlier and loop closures; returns the ground truth.
  NamedOrientations WriteRelativePoseBag(const std::string& path, int views) {
    rosbag::Bag bag(path, rosbag::bagmode::Write);
    std::mt19937 rng(3);
    std::normal_distribution<double> noise(0.0, DegToRad(0.5));
    std::vector<Eigen::Matrix3d> truth;
    NamedOrientations named;
    for (int v = 0; v < views; ++v) {
      truth.push_back(ExpSO3(Eigen::Vector3d(0.3 * std::sin(0.2 * v), 0.1 * v, 0.2 * std::cos(0.3 * v))));
      named[OnlineAverager::KeyframeName({"cam", 1000000000LL * (v + 1)})] = truth.back();
    }
    auto edge = [&](int a, int b, std::uint8_t source, bool outlier) {
      KeyframeRelativeRotation m;
      m.keyframe1 = {"cam", 1000000000LL * (a + 1)};
      m.keyframe2 = {"cam", 1000000000LL * (b + 1)};
      m.rotation = truth[a] * truth[b].transpose() * ExpSO3(DrawVector3(rng, noise));
      if (outlier) m.rotation = m.rotation * ExpSO3(Eigen::Vector3d(0.0, 0.0, 1.0));
      m.has_covariance = true;
      m.covariance = std::pow(DegToRad(0.5), 2) * Eigen::Matrix3d::Identity();
      m.num_inliers = 100;
      m.source = static_cast<EdgeSource>(source);
      RelativePose msg = ToMsg(m);
      bag.write("/relative_pose", ros::Time(1000.0 + b + 0.5), msg);
    };
    for (int v = 1; v < views; ++v) {
      edge(v - 1, v, RelativePose::SOURCE_SEQUENTIAL, false);
      if (v >= 2) edge(v - 2, v, RelativePose::SOURCE_SEQUENTIAL, v == views / 2);  // one outlier
      if (v % 5 == 0) edge(0, v, RelativePose::SOURCE_LOOP_CLOSURE, false);
    }
    bag.close();
    return named;
  }
};

TEST_F(BagReplay, RenderedRigEndToEndIsAccurateAndDeterministic) {
  const auto [bag, config] = WriteRigBagAndConfig("solve_period: 2.0\n");
  ASSERT_FALSE(HasFailure());

  ReplayOptions o = Options(bag, "rig1");
  o.config_path = config;
  o.ground_truth_path = bag;  // the bag's /ground_truth/orientations
  o.num_threads = 3;          // the front end's pool (--threads)
  const ReplayResult first = ReplayBags(o);
  ASSERT_TRUE(first.ok) << first.error;
  EXPECT_FALSE(first.truncated);
  EXPECT_EQ(first.keyframes, 32u);
  EXPECT_EQ(first.variables, 16u);  // one orientation per capture: the extrinsics were used
  EXPECT_EQ(first.rig_cameras.size(), 2u);
  EXPECT_EQ(first.components, 1u);
  EXPECT_GE(first.solves, 2u);
  ASSERT_TRUE(first.have_scores);
  EXPECT_EQ(first.scores.views_common, 32u);
  EXPECT_LT(first.scores.median_error_deg, 0.5);
  EXPECT_GT(first.scores.auc[0].second, 0.8);  // AUC@2
  for (const std::string& f : {first.orientations_csv, first.graph_file, first.output_bag, first.plot_png}) {
    EXPECT_FALSE(ReadAll(f).empty()) << f;
  }
  // The ground truth written beside them scores the orientations as the
  // replay did: it is the keyframes' own, under their names.
  {
    NamedOrientations estimate, written_truth;
    ASSERT_TRUE(ReadOrientationsCsv(first.orientations_csv, &estimate).ok());
    ASSERT_TRUE(ReadOrientationsCsv(first.ground_truth_csv, &written_truth).ok());
    EXPECT_EQ(written_truth.size(), 32u);
    const EvaluationResult rescored = EvaluateOrientations(estimate, written_truth);
    EXPECT_EQ(rescored.views_common, 32u);
    EXPECT_NEAR(rescored.median_error_deg, first.scores.median_error_deg, 1e-9);
  }
  // Each scored keyframe's posterior, one row each: its NEES is its error
  // whitened by a covariance whose trace is 3 sigma^2, so at least
  // (error / sigma)^2 / 3 (d^T C^-1 d >= |d|^2 / trace C).
  {
    const std::string csv = ReadAll(first.posterior_csv);
    EXPECT_EQ(csv.rfind("name,gauge,error_deg,sigma_deg,nees\n", 0), 0u) << csv.substr(0, 80);
    std::istringstream rows(csv);
    std::string row;
    std::getline(rows, row);
    std::size_t count = 0;
    while (std::getline(rows, row)) {
      std::vector<std::string> f;
      std::istringstream fields(row);
      for (std::string x; std::getline(fields, x, ',');) f.push_back(x);
      ASSERT_EQ(f.size(), 5u) << row;
      EXPECT_EQ(first.posterior.views.count(f[0]), 1u) << row;
      const double error = std::stod(f[2]), sigma = std::stod(f[3]), nees = std::stod(f[4]);
      EXPECT_GT(sigma, 0.0) << row;
      EXPECT_NEAR(nees, first.posterior.views.at(f[0]).nees, 1e-5 * (1.0 + nees)) << row;
      EXPECT_GE(nees * (1.0 + 1e-3), (error / sigma) * (error / sigma) / 3.0) << row;
      ++count;
    }
    EXPECT_EQ(count, first.posterior.views_scored);
    EXPECT_GT(count, 0u);
  }
  // The background refinement (on by default): the bag is shorter than
  // refinement_period_s, so only the final solution is refined, the cameras
  // of each capture with one correction.
  EXPECT_TRUE(first.refinement);
  EXPECT_EQ(first.refinement_stats.runs, 1u);
  EXPECT_TRUE(first.refinement_stats.last_ok) << first.refinement_stats.last_report;
  EXPECT_EQ(first.refinement_stats.corrected_keyframes, 32u);
  // Each with the adjustment's covariance, which the published solution
  // carries (relative to the gauge keyframe: the gauge's capture zero).
  EXPECT_EQ(first.refinement_stats.covariance_keyframes, 32u);
  EXPECT_NE(first.Summary().find("refinement (bundle adjustment of the newest keyframes): 1 runs, 1 applied"),
            std::string::npos)
      << first.Summary();
  // The output bag holds an Orientations message per solve, and the final
  // solution's again once refined.
  {
    rosbag::Bag out(first.output_bag, rosbag::bagmode::Read);
    rosbag::View orientations(out, rosbag::TopicQuery("/rotation_averaging/orientations"));
    EXPECT_EQ(orientations.size(), first.solves + 1);
  }
  // Same input, same output, bit for bit, on one thread as on three.
  ReplayOptions again = Options(bag, "rig2");
  again.config_path = config;
  again.num_threads = 1;
  const ReplayResult second = ReplayBags(again);
  ASSERT_TRUE(second.ok) << second.error;
  EXPECT_EQ(ReadAll(first.orientations_csv), ReadAll(second.orientations_csv));
  EXPECT_EQ(ReadAll(first.graph_file), ReadAll(second.graph_file));
}

// Refinements during the bag run on a thread of their own and land when the
// next is due by bag time: every Orientations message of the output bag,
// those between refinements too, is the same bit for bit on one thread as
// on three, whenever each refinement's thread ends.
TEST_F(BagReplay, RefinementsDuringTheBagLandAtTheSameBagTimesOnEveryRun) {
  const auto [bag, config] = WriteRigBagAndConfig("solve_period: 1.0\nrefinement_period_s: 3.0\n");
  ASSERT_FALSE(HasFailure());
  auto messages = [](const std::string& path) {
    std::vector<std::string> out;
    rosbag::Bag b(path, rosbag::bagmode::Read);
    for (const rosbag::MessageInstance& m : rosbag::View(b, rosbag::TopicQuery("/rotation_averaging/orientations"))) {
      const Orientations::ConstPtr o = m.instantiate<Orientations>();
      std::ostringstream text;
      text.precision(17);
      text << m.getTime() << " " << o->solve_sequence;
      for (const KeyframeOrientation& k : o->keyframes) {
        text << " " << k.frame_id << "@" << k.stamp << " " << k.orientation.w << " " << k.orientation.x << " "
             << k.orientation.y << " " << k.orientation.z;
      }
      out.push_back(text.str());
    }
    return out;
  };
  std::vector<std::string> runs[2];
  for (int r = 0; r < 2; ++r) {
    ReplayOptions o = Options(bag, r == 0 ? "staged3" : "staged1");
    o.config_path = config;
    o.ground_truth_path = bag;
    o.num_threads = r == 0 ? 3 : 1;
    const ReplayResult result = ReplayBags(o);
    ASSERT_TRUE(result.ok) << result.error;
    // Several refinements during the 16 s bag, and the final one (the first,
    // of the first few captures, may find too little to adjust).
    EXPECT_GE(result.refinement_stats.runs, 4u) << result.Summary();
    EXPECT_GE(result.refinement_stats.applied, 3u) << result.Summary();
    EXPECT_TRUE(result.refinement_stats.last_ok) << result.refinement_stats.last_report;
    ASSERT_TRUE(result.have_scores);
    EXPECT_LT(result.scores.median_error_deg, 0.5);
    runs[r] = messages(result.output_bag);
  }
  ASSERT_GT(runs[0].size(), 4u);
  EXPECT_EQ(runs[0], runs[1]);
}

// A map larger than the refinement's window: the final solution is refined
// once (the newest keyframes), then swept back over the rest a window at a
// time (refinement_sweep_back), so that every keyframe ends adjusted in it;
// without the sweep back the older ones keep the averaging's orientations.
TEST_F(BagReplay, TheFinalSolutionIsSweptBackOverTheKeyframesTheWindowHadNoRoomFor) {
  for (const bool sweep : {true, false}) {
    const auto [bag, config] = WriteRigBagAndConfig(std::string("solve_period: 2.0\nrefinement_max_keyframes: 12\n") +
                                                    "refinement_sweep_back: " + (sweep ? "true" : "false") + "\n");
    ASSERT_FALSE(HasFailure());
    ReplayOptions o = Options(bag, sweep ? "sweep" : "newest");
    o.config_path = config;
    o.ground_truth_path = bag;
    const ReplayResult result = ReplayBags(o);
    ASSERT_TRUE(result.ok) << result.error;
    EXPECT_EQ(result.keyframes, 32u);
    // The bag is shorter than refinement_period_s: the final solution's
    // refinements only, 12 keyframes (six captures) at a time.
    EXPECT_EQ(result.refinement_stats.runs, sweep ? 3u : 1u) << result.Summary();
    EXPECT_EQ(result.refinement_stats.applied, result.refinement_stats.runs) << result.Summary();
    EXPECT_EQ(result.refinement_stats.corrected_keyframes, sweep ? 32u : 12u) << result.Summary();
    ASSERT_TRUE(result.have_scores);
    EXPECT_LT(result.scores.median_error_deg, 0.5);
  }
}

// The rendered rig as a 20 Hz driver publishes it, replayed with tracks:
// its keyframes' window pairs come from the tracks, the orientations are
// accurate, and the keyframes, the graph and the orientations are the same
// on one thread as on three.
TEST_F(BagReplay, TracksOnARawStreamGiveTheSameGraphOnAnyThreadCount) {
  RigSceneOptions scene_options;
  scene_options.num_captures = 240;  // one loop in 12 s: 1.5 deg per image
  scene_options.capture_period_s = 0.05;
  scene_options.WithWidth(320);
  const RigScene scene(scene_options);
  const std::string bag = TempDir() + "/stream.bag";
  NamedOrientations truth;
  std::string error;
  ASSERT_TRUE(WriteRigSceneBag(scene, bag, /*compressed=*/false, &truth, &error)) << error;
  const std::string config = TempDir() + "/stream.yaml";
  WriteText(config,
            "image_topics: [\"/cam_front/image_raw\", \"/cam_left/image_raw\"]\n"
            "keyframe_selection: motion\ntracks: true\nmax_features: 1000\nmax_loop_candidates: 2\n"
            "solve_period: 2.0\nfocal_calibration: off\n");
  ReplayResult runs[2];
  for (int r = 0; r < 2; ++r) {
    ReplayOptions o = Options(bag, r == 0 ? "tracks3" : "tracks1");
    o.config_path = config;
    o.ground_truth_path = bag;
    o.num_threads = r == 0 ? 3 : 1;
    runs[r] = ReplayBags(o);
    ASSERT_TRUE(runs[r].ok) << runs[r].error;
  }
  const ReplayResult& first = runs[0];
  std::cout << first.keyframes << " keyframes of " << first.images_seen << " images, " << first.track_pairs
            << " pairs from tracks, median " << first.scores.median_error_deg << " deg\n";
  EXPECT_EQ(first.images_seen, 480u);
  EXPECT_GE(first.keyframes, 20u);
  EXPECT_LE(first.keyframes, 120u);
  EXPECT_GT(first.selection.by_motion + first.selection.by_tracking, 0u);
  EXPECT_GE(first.track_pairs, first.keyframes / 2) << "the window pairs come from the tracks";
  ASSERT_TRUE(first.have_scores);
  EXPECT_LT(first.scores.median_error_deg, 0.1);
  EXPECT_EQ(first.components, 1u);
  EXPECT_EQ(runs[1].keyframes, first.keyframes);
  EXPECT_EQ(runs[1].track_pairs, first.track_pairs);
  EXPECT_EQ(ReadAll(first.graph_file), ReadAll(runs[1].graph_file));
  EXPECT_EQ(ReadAll(first.orientations_csv), ReadAll(runs[1].orientations_csv));
}

// The rendered rig for the camera_info checks: 24 captures, 480 px wide.
RigSceneOptions CheckScene() {
  RigSceneOptions options;
  options.num_captures = 24;
  options.WithWidth(480);
  return options;
}

// A barrel lens as strong as EuRoC's (k1 = -0.28), K left to the scene.
CameraIntrinsics PlumbBobLens() {
  CameraIntrinsics lens;
  lens.distortion = DistortionModel::kPlumbBob;
  lens.coefficients = {-0.28, 0.07, 0.0002, 0.00002};
  return lens;
}

// `scene` through `lens` as a bag whose camera_info has the focal lengths
// times info_focal_scale, replayed with every image a keyframe, no loop
// closures, and `extra` configuration lines.
ReplayResult ReplayCheckScene(const RigScene& scene, const std::string& name, const CameraIntrinsics& lens,
                              double info_focal_scale, const std::string& extra,
                              const SensorReadout& readout = SensorReadout()) {
  const std::string dir = TempDir();
  const std::string bag = dir + "/" + name + ".bag", config = dir + "/" + name + ".yaml";
  NamedOrientations truth;
  ReplayResult failed;
  RigSceneBagOptions bag_options;
  bag_options.lens = lens;
  bag_options.info_focal_scale = info_focal_scale;
  bag_options.readout = readout;
  if (!WriteRigSceneBag(scene, bag, /*compressed=*/false, &truth, &failed.error, bag_options)) {
    return failed;
  }
  std::ofstream(config) << "image_topics: [\"/cam_front/image_raw\", \"/cam_left/image_raw\"]\n"
                           "keyframe_selection: all\nmax_features: 1500\nmax_loop_candidates: 0\nsolve_period: 5.0\n"
                        << extra;
  ReplayOptions o;
  o.bags = {bag};
  o.config_path = config;
  o.output_dir = dir + "/" + name;
  o.progress = false;
  o.ground_truth_path = bag;
  return ReplayBags(o);
}

// A raw rig whose driver bins its sensor 2 x 2 and reads out a region of it
// (camera_info: the sensor's K and size, binning and roi), through a strong
// barrel lens: every image is taken, with the readout's camera, and the
// orientations are as accurate as the same lens's whole-sensor images'.
TEST_F(BagReplay, ABinnedRegionOfTheSensorIsReadWithItsCamera) {
  RigSceneOptions options;
  options.num_captures = 12;
  options.WithWidth(960);
  SensorReadout readout;
  readout.binning = 2;
  readout.roi = cv::Rect(32, 24, 896, 672);
  const ReplayResult binned =
      ReplayCheckScene(RigScene(options), "binned_region", PlumbBobLens(), 1.0, "focal_calibration: off\n", readout);
  ASSERT_TRUE(binned.ok) << binned.error;
  EXPECT_EQ(binned.rejected_images, 0u);
  EXPECT_EQ(binned.keyframes, 24u);
  ASSERT_TRUE(binned.have_scores);
  EXPECT_EQ(binned.scores.views_common, 24u);
  // The whole sensor's images at the readout's size, through the same lens.
  options.WithWidth(448);
  const ReplayResult whole =
      ReplayCheckScene(RigScene(options), "whole_448", PlumbBobLens(), 1.0, "focal_calibration: off\n");
  ASSERT_TRUE(whole.ok) << whole.error;
  ASSERT_TRUE(whole.have_scores);
  EXPECT_LT(binned.scores.median_error_deg, 2.0 * whole.scores.median_error_deg + 0.005)
      << "whole sensor: " << whole.scores.median_error_deg << " deg";
}

// A camera_info whose focal length is 3% short on both cameras: the replay's
// check of each camera's focal length finds it out (the sideways camera; the
// forward one, moving along its optical axis, cannot tell) and warns; with
// focal_calibration: apply it does not correct the sideways camera alone (a
// rig's cameras would disagree) and says why, once. The refinement, which
// turns the rig's cameras together, tells both, and both are corrected by its
// estimates to within 0.5%; the output bag's focal-check messages carry it.
TEST_F(BagReplay, ACameraInfoWithAWrongFocalLengthIsFoundOut) {
  const RigScene scene(CheckScene());
  const ReplayResult result =
      ReplayCheckScene(scene, "short_focal", CameraIntrinsics(), 0.97, "focal_calibration: apply\n");
  ASSERT_TRUE(result.ok) << result.error;
  std::string said;
  for (const std::string& w : result.warnings) said += w + "\n";
  for (const std::string& c : result.focal_corrections) said += c + "\n";
  bool warned = false;
  for (const std::string& w : result.warnings) {
    if (w.find("camera_info check: cam_left: focal length x") == std::string::npos) continue;
    warned |= w.find("disagrees") != std::string::npos;
    // Not a lens distortion: the ideal lens's pairs bent by the wrong focal
    // length are explained by the focal length alone (docs/node.md,
    // "Checking camera_info's focal length").
    EXPECT_EQ(w.find("distorted"), std::string::npos) << w;
  }
  EXPECT_TRUE(warned) << said;
  int held_back = 0, for_the_rig = 0;
  for (const std::string& n : result.focal_notices) {
    if (n.rfind("cam_left: focal length not corrected: ", 0) != 0) continue;
    ++held_back;
    for_the_rig += n.find("other cameras of its rig") != std::string::npos;
  }
  EXPECT_EQ(held_back, 1) << said;
  EXPECT_EQ(for_the_rig, 1) << said;
  std::map<std::string, double> corrected;
  for (const std::string& c : result.focal_corrections) {
    const std::size_t x = c.find("camera_info's focal length x");
    if (x != std::string::npos) corrected[c.substr(0, c.find(':'))] = std::stod(c.substr(x + 28));
  }
  for (const std::string camera : {"cam_front", "cam_left"}) {
    ASSERT_TRUE(corrected.count(camera)) << said;
    EXPECT_NEAR(corrected.at(camera) * 0.97, 1.0, 0.005) << camera;
  }
  EXPECT_NE(result.Summary().find("camera_info check"), std::string::npos);
  // Each camera's estimates are timed (the replay runs every one that came
  // due, a camera's first at 20 pairs), and the summary gives their time.
  EXPECT_GE(result.focal_check_times.Count(), result.focal_checks.size());
  EXPECT_GT(result.focal_check_times.Median(), 0.0);
  EXPECT_NE(result.Summary().find("time per camera_info check estimate"), std::string::npos);
  // The focal-check messages carry the sideways camera's estimate that
  // disagreed (a camera's check starts again at its corrected focal length).
  rosbag::Bag out(result.output_bag, rosbag::bagmode::Read);
  rosbag::View checks_topic(out, rosbag::TopicQuery("/rotation_averaging/camera_info_checks"));
  bool found = false;
  for (const rosbag::MessageInstance& m : checks_topic) {
    const CameraInfoCheckArray::ConstPtr checks = m.instantiate<CameraInfoCheckArray>();
    ASSERT_TRUE(checks);
    for (const CameraInfoCheck& c : checks->cameras) {
      if (c.frame_id != "cam_left" || !c.disagrees) continue;
      found = true;
      EXPECT_TRUE(c.estimated);
      EXPECT_NEAR(c.scale * 0.97, 1.0, 0.01);
      EXPECT_GT(c.scale_stddev, 0.0);
      EXPECT_GE(c.pairs_seen, 20u);
      EXPECT_NEAR(c.given_focal_px, 0.97 * scene.Intrinsics()(0, 0), 1e-6);
      EXPECT_EQ(c.applied_scale, 1.0);  // held back for the rig: reported, not corrected
    }
  }
  EXPECT_TRUE(found) << said;
}

// Raw images of a distorting lens whose camera_info is read as if they were
// rectified (image_type: rectified: no distortion model): the check sees
// the distortion and says so, naming what to give (in the forward camera's
// pairs; the sideways camera's may leave it undetermined). With
// focal_calibration: apply (the default) the cameras are given the lens the
// check sees, and the orientations are several times better than without.
TEST_F(BagReplay, DistortedImagesWithoutADistortionModelAreFoundOut) {
  const RigScene scene(CheckScene());
  const ReplayResult result =
      ReplayCheckScene(scene, "distorted", PlumbBobLens(), 1.0, "image_type: rectified\nfocal_calibration: warn\n");
  ASSERT_TRUE(result.ok) << result.error;
  bool warned = false;
  for (const std::string& w : result.warnings) warned |= w.find("has no distortion model") != std::string::npos;
  EXPECT_TRUE(warned);
  rosbag::Bag out(result.output_bag, rosbag::bagmode::Read);
  rosbag::View checks_topic(out, rosbag::TopicQuery("/rotation_averaging/camera_info_checks"));
  CameraInfoCheckArray::ConstPtr last;
  for (const rosbag::MessageInstance& m : checks_topic) last = m.instantiate<CameraInfoCheckArray>();
  ASSERT_TRUE(last);
  int unmodelled = 0;
  for (const CameraInfoCheck& c : last->cameras) {
    if (!c.distortion_unmodelled) continue;
    EXPECT_TRUE(c.distortion_checked) << c.frame_id;
    ++unmodelled;
    EXPECT_LT(c.distortion_lambda, -0.1) << c.frame_id;  // barrel, as the lens's k1 = -0.28
    EXPECT_GT(c.distortion_corner_px, 10.0) << c.frame_id;
  }
  EXPECT_GE(unmodelled, 1);  EXPECT_TRUE(result.lens_corrections.empty());

  const ReplayResult given = ReplayCheckScene(scene, "distorted_apply", PlumbBobLens(), 1.0, "image_type: rectified\n");
  ASSERT_TRUE(given.ok) << given.error;
  ASSERT_GE(given.lens_corrections.size(), 1u) << given.Summary();
  for (const std::string& line : given.lens_corrections) EXPECT_NE(line.find("division model -0."), std::string::npos) << line;
  EXPECT_NE(given.Summary().find("lens given where camera_info describes none"), std::string::npos);
  ASSERT_TRUE(result.have_scores && given.have_scores);
  EXPECT_LT(given.scores.median_error_deg, 0.5 * result.scores.median_error_deg)
      << "without the lens " << result.scores.median_error_deg << " deg, with the check's "
      << given.scores.median_error_deg << " deg";
}

// A raw rig through a plumb_bob lens whose camera_info has the model and
// focal lengths 3% short, with focal_calibration: apply. Through the lens
// the focal length of both cameras is determined (a wrong one bends the
// undistorted keypoints radially, which the forward camera's pairs show as
// well), so both are corrected: the rig waits for the second camera's
// estimate instead of deciding on the first one's alone.
TEST_F(BagReplay, BothCamerasOfARawRigAreCorrectedThroughTheirLens) {
  const RigScene scene(CheckScene());
  const ReplayResult result =
      ReplayCheckScene(scene, "lens_short_focal", PlumbBobLens(), 0.97, "focal_calibration: apply\n");
  ASSERT_TRUE(result.ok) << result.error;
  std::string notices;
  for (const std::string& n : result.focal_notices) notices += n + "\n";
  rosbag::Bag out(result.output_bag, rosbag::bagmode::Read);
  rosbag::View checks_topic(out, rosbag::TopicQuery("/rotation_averaging/camera_info_checks"));
  CameraInfoCheckArray::ConstPtr last;
  for (const rosbag::MessageInstance& m : checks_topic) last = m.instantiate<CameraInfoCheckArray>();
  ASSERT_TRUE(last);
  std::set<std::string> corrected;
  for (const CameraInfoCheck& c : last->cameras) {
    EXPECT_NEAR(c.applied_scale * 0.97, 1.0, 0.01) << c.frame_id << "\n" << notices;
    if (c.applied_scale != 1.0) corrected.insert(c.frame_id);
  }
  EXPECT_EQ(corrected, (std::set<std::string>{"cam_front", "cam_left"})) << notices;
}

// The node's configuration for sessions of the rendered rig: its two
// cameras' streams, every image a keyframe, and a vocabulary trained on
// another room's textures (saved in `dir`). The camera_info check, which
// these tests are not about and whose estimates the replay waits for, is
// off (its own tests above; the end-to-end test runs it).
std::string SessionConfig(const std::string& dir) {
  const std::string vocabulary = dir + "/test.vocab";
  std::string error;
  EXPECT_TRUE(TestVocabulary()->Save(vocabulary, &error)) << error;
  return "image_topics: [\"/cam_front/image_raw\", \"/cam_left/image_raw\"]\n"
         "keyframe_selection: all\nmax_features: 1000\nsolve_period: 2.0\nfocal_calibration: off\nvocabulary: " +
         vocabulary + "\n";
}

// A map saved at the end of one bag (save_on_shutdown) and loaded by the
// replay of the next (load_graph), as a node restarted mid-run would: the
// rig's second lap closes loops with the first lap's keyframes, so the two
// sessions make one map, scored as one against the ground truth. A damaged
// keyframe database stops the replay with the reason.
TEST_F(BagReplay, TheNextSessionContinuesTheSavedMap) {
  RigSceneOptions scene_options;
  scene_options.laps = 2;
  scene_options.num_captures = 32;
  scene_options.WithWidth(320);
  const RigScene scene(scene_options);
  const std::string dir = TempDir() + "/sessions";
  std::filesystem::create_directories(dir);
  const std::string full = dir + "/both_laps.bag";
  NamedOrientations truth;
  std::string error;
  ASSERT_TRUE(WriteRigSceneBag(scene, full, /*compressed=*/false, &truth, &error)) << error;
  const std::string truth_csv = dir + "/truth.csv";
  ASSERT_TRUE(WriteOrientationsCsv(truth_csv, truth, &error)) << error;

  // One bag per lap; both carry the rig's static transforms.
  std::set<ros::Time> captures;
  {
    rosbag::Bag in(full, rosbag::bagmode::Read);
    for (const rosbag::MessageInstance& m : rosbag::View(in, rosbag::TopicQuery("/cam_front/image_raw"))) {
      captures.insert(m.getTime());
    }
  }
  ASSERT_EQ(captures.size(), 32u);
  const ros::Time second_lap = *std::next(captures.begin(), 16);
  const std::string first_bag = dir + "/first.bag", second_bag = dir + "/second.bag";
  {
    rosbag::Bag in(full, rosbag::bagmode::Read);
    rosbag::Bag first(first_bag, rosbag::bagmode::Write), second(second_bag, rosbag::bagmode::Write);
    for (const rosbag::MessageInstance& m : rosbag::View(in)) {
      if (m.getTopic() == "/ground_truth/orientations") continue;
      const bool both = m.getTopic() == "/tf_static";
      if (both || m.getTime() < second_lap) first.write(m.getTopic(), m.getTime(), m, m.getConnectionHeader());
      if (both || m.getTime() >= second_lap) second.write(m.getTopic(), m.getTime(), m, m.getConnectionHeader());
    }
  }

  const std::string map = dir + "/map/graph.txt";
  std::filesystem::create_directories(dir + "/map");
  const std::string common = SessionConfig(dir);
  WriteText(dir + "/first.yaml", common + "save_on_shutdown: " + map + "\n");
  WriteText(dir + "/second.yaml", common + "load_graph: " + map + "\n");

  ReplayOptions o1 = Options(first_bag, "session1");
  o1.config_path = dir + "/first.yaml";
  const ReplayResult first = ReplayBags(o1);
  ASSERT_TRUE(first.ok) << first.error;
  EXPECT_EQ(first.keyframes, 32u);
  EXPECT_NE(first.map_saved.find("32 keyframes"), std::string::npos) << first.map_saved;
  // The time budget counts every image offered, every keyframe and every
  // two-view pair, and the summary reports it.
  EXPECT_EQ(first.image_times.Count(), first.images_seen);
  EXPECT_EQ(first.keyframe_times.Count(), first.keyframe_images);
  EXPECT_GE(first.pair_times.Count(), first.keyframe_images - 2);  // every keyframe but each camera's first has a pair
  EXPECT_GT(first.keyframe_times.Median(), 0.0);
  EXPECT_LE(first.keyframe_times.Median(), first.keyframe_times.P95());
  EXPECT_NE(first.Summary().find("time per keyframe (front end): median "), std::string::npos);
  ASSERT_TRUE(std::filesystem::exists(map + ".keyframes"));
  // The background refinement's corrections are saved with the map.
  std::map<KeyframeKey, Eigen::Matrix3d> saved_corrections;
  ASSERT_TRUE(KeyframeRefiner::ReadCorrections(map + ".refinement", &saved_corrections, &error)) << error;
  EXPECT_EQ(saved_corrections.size(), first.refinement_stats.corrected_keyframes);
  EXPECT_EQ(saved_corrections.size(), 32u);

  ReplayOptions o2 = Options(second_bag, "session2");
  o2.config_path = dir + "/second.yaml";
  o2.ground_truth_path = truth_csv;
  const ReplayResult second = ReplayBags(o2);
  ASSERT_TRUE(second.ok) << second.error;
  std::cout << second.Summary() << "\n";
  EXPECT_NE(second.map_loaded.find("32 keyframes"), std::string::npos) << second.map_loaded;
  EXPECT_NE(second.map_loaded.find("the refinement's corrections of 32 keyframes"), std::string::npos)
      << second.map_loaded;
  EXPECT_EQ(second.keyframes, 64u);   // both sessions' keyframes are oriented
  EXPECT_EQ(second.variables, 32u);   // as rig captures: the loaded graph's and the new ones
  EXPECT_EQ(second.components, 1u);   // joined by loop closures to the first session's keyframes
  EXPECT_GT(second.loop_closure_edges, 0u);
  ASSERT_TRUE(second.have_scores);
  EXPECT_EQ(second.scores.views_common, 64u);
  EXPECT_LT(second.scores.median_error_deg, 0.5);
  // The first session's keyframes keep the frames they were published in:
  // where the map had them at the first solve after loading; when the second
  // session joined them, their frame as a whole stays and single keyframes
  // move within a few of their posterior standard deviations.
  EXPECT_GE(second.map_load_shift_deg, 0.0);  // the map holds orientations
  EXPECT_LT(second.map_load_shift_deg, 0.01);
  EXPECT_TRUE(second.map_merged);
  EXPECT_LT(second.map_merge_frame_deg, 0.01);
  EXPECT_LT(second.map_merge_move_sigma, 3.0);

  // Both bags in one replay, the map saved after each: the map after the
  // first bag is the one the first session saved at its end (same graph,
  // same orientations), the one after the second holds both laps.
  ReplayOptions o_each = Options(first_bag, "each_bag");
  o_each.bags.push_back(second_bag);
  o_each.config_path = dir + "/each.yaml";
  o_each.save_after_each_bag = true;
  WriteText(o_each.config_path, common);
  const ReplayResult each = ReplayBags(o_each);
  ASSERT_TRUE(each.ok) << each.error;
  ASSERT_EQ(each.maps_saved_after_bags.size(), 2u);
  EXPECT_NE(each.maps_saved_after_bags[0].find("32 keyframes"), std::string::npos) << each.maps_saved_after_bags[0];
  EXPECT_NE(each.maps_saved_after_bags[1].find("64 keyframes"), std::string::npos) << each.maps_saved_after_bags[1];
  {
    ViewGraph at_end, after_bag;
    std::map<ViewId, Eigen::Matrix3d> at_end_r, after_bag_r;
    ASSERT_TRUE(ReadRotavgGraph(map, &at_end, &at_end_r).ok());
    const std::string after_first = o_each.output_dir + "/map_after_bag1_first.txt";
    ASSERT_TRUE(ReadRotavgGraph(after_first, &after_bag, &after_bag_r).ok()) << after_first;
    EXPECT_TRUE(std::filesystem::exists(after_first + ".keyframes"));
    EXPECT_TRUE(std::filesystem::exists(o_each.output_dir + "/map_after_bag2_second.txt.keyframes"));
    EXPECT_EQ(after_bag.NumViews(), at_end.NumViews());
    EXPECT_EQ(after_bag.NumEdges(), at_end.NumEdges());
    ASSERT_EQ(after_bag_r.size(), at_end_r.size());
    std::map<std::string, ViewId> by_name;
    for (const View& v : after_bag.Views()) by_name[v.name] = v.id;
    double worst_deg = 0.0;
    for (const View& v : at_end.Views()) {
      ASSERT_EQ(by_name.count(v.name), 1u) << v.name;
      worst_deg = std::max(worst_deg, RadToDeg(AngularDistanceRad(at_end_r.at(v.id), after_bag_r.at(by_name[v.name]))));
    }
    EXPECT_LT(worst_deg, 1e-6);
  }

  // Two maps made apart: the first lap's (above), and the second lap's by a
  // session that never saw the first. Added to the first (add_maps), the
  // second is matched against it: loop closures between the two join them
  // at once. A third session starting from both passes the start again.
  const std::string apart = dir + "/apart/graph.txt";
  std::filesystem::create_directories(dir + "/apart");
  WriteText(dir + "/apart.yaml", common + "save_on_shutdown: " + apart + "\n");
  ReplayOptions o_apart = Options(second_bag, "apart");
  o_apart.config_path = dir + "/apart.yaml";
  const ReplayResult second_apart = ReplayBags(o_apart);
  ASSERT_TRUE(second_apart.ok) << second_apart.error;
  EXPECT_EQ(second_apart.components, 1u);
  // The third session: the first four captures again, 1,000 s later.
  const std::string third_bag = dir + "/third.bag";
  {
    const ros::Duration later(1000.0);
    const ros::Time end = *std::next(captures.begin(), 4);
    rosbag::Bag in(full, rosbag::bagmode::Read);
    rosbag::Bag third(third_bag, rosbag::bagmode::Write);
    for (const rosbag::MessageInstance& m : rosbag::View(in)) {
      if (m.getTopic() == "/tf_static") {
        third.write(m.getTopic(), m.getTime(), m, m.getConnectionHeader());
      } else if (sensor_msgs::Image::ConstPtr image = m.instantiate<sensor_msgs::Image>()) {
        if (m.getTime() >= end) continue;
        sensor_msgs::Image shifted = *image;
        shifted.header.stamp += later;
        third.write(m.getTopic(), m.getTime() + later, shifted);
      } else if (sensor_msgs::CameraInfo::ConstPtr info = m.instantiate<sensor_msgs::CameraInfo>()) {
        if (m.getTime() >= end) continue;
        sensor_msgs::CameraInfo shifted = *info;
        shifted.header.stamp += later;
        third.write(m.getTopic(), m.getTime() + later, shifted);
      }
    }
  }
  WriteText(dir + "/third.yaml", common + "load_graph: " + map + "\nadd_maps: [\"" + apart + "\"]\n");
  ReplayOptions o3 = Options(third_bag, "session3");
  o3.config_path = dir + "/third.yaml";
  o3.ground_truth_path = truth_csv;
  const ReplayResult third = ReplayBags(o3);
  ASSERT_TRUE(third.ok) << third.error;
  std::cout << third.Summary() << "\n";
  ASSERT_EQ(third.maps_added.size(), 1u);
  EXPECT_NE(third.maps_added[0].find("32 keyframes to retrieve from (0 already held)"), std::string::npos)
      << third.maps_added[0];
  EXPECT_EQ(third.maps_added[0].find("; 0 loop closures"), std::string::npos) << third.maps_added[0];
  {
    // The two maps alone, no new keyframe: one component once added.
    PipelineConfig config;
    std::vector<std::string> warnings;
    ASSERT_TRUE(ReadReplayConfig(dir + "/third.yaml", &config, &warnings, &error)) << error;
    KeyframePipeline pipeline(config);
    ASSERT_TRUE(pipeline.LoadMap(map, &error)) << error;
    std::string note;
    ASSERT_TRUE(pipeline.AddMap(apart, &error, &note)) << error;
    std::cout << note << "\n";
    ASSERT_TRUE(pipeline.Averager().SolveNow());
    const OnlineSolution cameras = pipeline.CameraSolution(*pipeline.Averager().Solution());
    std::set<int> components;
    for (const auto& [key, c] : cameras.component) components.insert(c);
    EXPECT_EQ(cameras.orientations.size(), 64u);
    EXPECT_EQ(components.size(), 1u);
    EXPECT_GT(pipeline.FrontendStats().map_links, 0u);
  }
  EXPECT_EQ(third.keyframes, 72u);  // both maps' and the third session's
  EXPECT_EQ(third.components, 1u);
  ASSERT_TRUE(third.have_scores);
  EXPECT_EQ(third.scores.views_common, 64u);  // the third session's stamps have no ground truth
  EXPECT_LT(third.scores.median_error_deg, 0.5);
  EXPECT_GT(third.map_links, 0u);
  // The loaded map keeps its frame and the added one is placed in it (the
  // two sessions began at the same pose, so their frames differ by their
  // errors only; online_averager_test AddedGraphsKeepTheirFramesUntilJoined
  // joins frames that differ). The loop closures between the maps correct
  // single keyframes within a few posterior standard deviations, which
  // turns the best-fitting frame by a few hundredths of a degree. Two maps of
  // the same size correct each other more than a session does the map it
  // continues, and the posterior is as over-confident as the pairs'
  // covariances (camera_models.md, "NEES"): up to five.
  EXPECT_TRUE(third.map_merged);
  EXPECT_LT(third.map_merge_frame_deg, 0.1);
  EXPECT_LT(third.map_merge_move_sigma, 5.0);

  // A truncated database: the replay stops and says why.
  const std::string database = ReadAll(map + ".keyframes");
  std::ofstream(map + ".keyframes", std::ios::binary) << database.substr(0, database.size() / 3);
  const ReplayResult damaged = ReplayBags(o2);
  EXPECT_FALSE(damaged.ok);
  EXPECT_NE(damaged.error.find("truncated"), std::string::npos) << damaged.error;
}

// Two sessions in the same room on different days: the second starts a
// quarter of the loop further on, 100 s later, under other lighting (darker,
// and brighter on one side of the room than the other) and with other image
// noise. Started from the first session's map, it closes loops with it, and
// the two make one map scored as one against both ground truths.
TEST_F(BagReplay, ASessionUnderOtherLightingJoinsTheSavedMap) {
  const std::string dir = TempDir() + "/lighting";
  std::filesystem::create_directories(dir + "/map");
  RigSceneOptions first_options;
  first_options.num_captures = 16;
  first_options.WithWidth(320);
  RigSceneOptions second_options = first_options;
  second_options.start_angle_deg = 90.0;
  second_options.start_time_s = 100.0;
  second_options.light_gain = 0.75;
  second_options.light_gradient = 0.5;
  second_options.noise_seed = 7;
  const RigScene first_scene(first_options), second_scene(second_options);
  NamedOrientations truth, second_truth;
  std::string error;
  const std::string first_bag = dir + "/first.bag", second_bag = dir + "/second.bag";
  ASSERT_TRUE(WriteRigSceneBag(first_scene, first_bag, /*compressed=*/false, &truth, &error)) << error;
  ASSERT_TRUE(WriteRigSceneBag(second_scene, second_bag, /*compressed=*/false, &second_truth, &error)) << error;
  ASSERT_EQ(truth.size(), 32u);
  truth.insert(second_truth.begin(), second_truth.end());
  ASSERT_EQ(truth.size(), 64u);  // the stamps of the sessions differ
  const std::string truth_csv = dir + "/truth.csv";
  ASSERT_TRUE(WriteOrientationsCsv(truth_csv, truth, &error)) << error;
  // The lighting differs: the same place is darker in the second session.
  const cv::Scalar first_mean = cv::mean(first_scene.Render(4, 0));
  const cv::Scalar second_mean = cv::mean(second_scene.Render(0, 0));  // 90 deg on: the first's capture 4
  EXPECT_LT(second_mean[0], 0.9 * first_mean[0]);

  const std::string map = dir + "/map/graph.txt";
  const std::string common = SessionConfig(dir);
  WriteText(dir + "/first.yaml", common + "save_on_shutdown: " + map + "\n");
  WriteText(dir + "/second.yaml", common + "load_graph: " + map + "\n");
  ReplayOptions o1 = Options(first_bag, "lighting1");
  o1.config_path = dir + "/first.yaml";
  ASSERT_TRUE(ReplayBags(o1).ok);
  ReplayOptions o2 = Options(second_bag, "lighting2");
  o2.config_path = dir + "/second.yaml";
  o2.ground_truth_path = truth_csv;
  const ReplayResult second = ReplayBags(o2);
  ASSERT_TRUE(second.ok) << second.error;
  std::cout << second.Summary() << "\n";
  EXPECT_EQ(second.keyframes, 64u);
  EXPECT_EQ(second.components, 1u);
  EXPECT_GT(second.loop_closure_edges, 0u);
  // The first session's frame is kept: its gauge keyframe is held where it
  // was published, so there is no jump of its tf frames (a cold solve's new
  // gauge turns the frame by degrees: online_averager_test
  // ALoadedGraphKeepsThePublishedFrames); its keyframes move only by the
  // correction the new loop closures bring, within a few of their posterior
  // standard deviations (relative to that gauge keyframe).
  EXPECT_TRUE(second.map_merged);
  EXPECT_LT(second.map_merge_frame_deg, 0.1);
  EXPECT_LT(second.map_merge_move_sigma, 3.0);
  ASSERT_TRUE(second.have_scores);
  EXPECT_EQ(second.scores.views_common, 64u);
  EXPECT_LT(second.scores.median_error_deg, 0.5);
}

TEST_F(BagReplay, RelativePosesAreAveragedAndTheOutlierRejected) {
  const std::string bag = TempDir() + "/poses.bag";
  const NamedOrientations truth = WriteRelativePoseBag(bag, 30);
  const std::string csv = TempDir() + "/poses_truth.csv";
  std::string error;
  ASSERT_TRUE(WriteOrientationsCsv(csv, truth, &error)) << error;
  ReplayOptions o = Options(bag, "poses");
  o.ground_truth_path = csv;
  const ReplayResult r = ReplayBags(o);
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_EQ(r.keyframes, 30u);
  EXPECT_EQ(r.scores.views_common, 30u);
  EXPECT_LT(r.scores.median_error_deg, 0.5);
  EXPECT_GE(r.outlier_edges, 1u);
  EXPECT_EQ(r.edges_by_source.at("loop_closure"), 5u);
  // Early solves after loop closures, and periodic ones (1 s of bag time).
  EXPECT_GE(r.solves, 10u);
}

TEST_F(BagReplay, BadBagsAreRefusedWithTheReason) {
  const std::string missing = TempDir() + "/does_not_exist.bag";
  ReplayResult r = ReplayBags(Options(missing, "bad1"));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("cannot open " + missing), std::string::npos) << r.error;

  const std::string garbage = TempDir() + "/garbage.bag";
  WriteText(garbage, "this is not a bag\n");
  r = ReplayBags(Options(garbage, "bad2"));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("cannot open " + garbage), std::string::npos) << r.error;

  // Truncated while recording: no index at the end.
  const std::string good = TempDir() + "/good.bag";
  WriteRelativePoseBag(good, 30);
  const std::string bytes = ReadAll(good);
  const std::string truncated = TempDir() + "/truncated.bag";
  std::ofstream(truncated, std::ios::binary) << bytes.substr(0, bytes.size() * 6 / 10);
  r = ReplayBags(Options(truncated, "bad3"));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("rosbag reindex"), std::string::npos) << r.error;

  // An input topic with the wrong type.
  const std::string wrong = TempDir() + "/wrong_type.bag";
  {
    rosbag::Bag bag(wrong, rosbag::bagmode::Write);
    std_msgs::String text;
    text.data = "not a pose";
    bag.write("/relative_pose", ros::Time(1000.0), text);
  }
  r = ReplayBags(Options(wrong, "bad4"));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("/relative_pose has type std_msgs/String"), std::string::npos) << r.error;

  // None of the input topics.
  const std::string other = TempDir() + "/other_topics.bag";
  {
    rosbag::Bag bag(other, rosbag::bagmode::Write);
    std_msgs::String text;
    bag.write("/chatter", ros::Time(1000.0), text);
  }
  r = ReplayBags(Options(other, "bad5"));
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("none of the input topics"), std::string::npos) << r.error;
  EXPECT_NE(r.error.find("/chatter"), std::string::npos) << r.error;

  // A config that is not YAML.
  const std::string config = TempDir() + "/broken.yaml";
  WriteText(config, "image_topics: [unclosed\n");
  ReplayOptions o = Options(good, "bad6");
  o.config_path = config;
  r = ReplayBags(o);
  EXPECT_FALSE(r.ok);
  EXPECT_NE(r.error.find("config " + config), std::string::npos) << r.error;
}

TEST_F(BagReplay, DamageInsideABagKeepsWhatCameBefore) {
  const std::string good = TempDir() + "/to_damage.bag";
  WriteRelativePoseBag(good, 30);
  std::string bytes = ReadAll(good);
  // Overwrite a stretch in the middle of the message data (the index at the
  // end stays intact, so the bag opens).
  const std::size_t at = bytes.size() / 2;
  for (std::size_t k = at; k < at + 400 && k < bytes.size(); ++k) bytes[k] = static_cast<char>(0xA5);
  const std::string damaged = TempDir() + "/damaged.bag";
  std::ofstream(damaged, std::ios::binary) << bytes;
  const ReplayResult r = ReplayBags(Options(damaged, "damaged"));
  // Either the damage stops the replay part-way (with a warning), or the
  // damaged messages are rejected one by one; never a crash, and the graph
  // keeps what was readable.
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_GT(r.keyframes, 5u);
  if (r.truncated) {
    EXPECT_LT(r.messages_read, r.messages_total);
    bool warned = false;
    for (const std::string& w : r.warnings) warned = warned || w.find("damaged") != std::string::npos;
    EXPECT_TRUE(warned);
  } else {
    EXPECT_GT(r.damaged_messages + r.rejected_messages, 0u);
  }
}

// A damaged length field in a message with an array makes ROS's deserialiser
// allocate before it checks the bytes (found by fuzz_messages): the replay
// drops the message as damaged and goes on.
TEST_F(BagReplay, ArrayLengthAskingForTerabytesIsDropped) {
#if defined(__SANITIZE_ADDRESS__)
  GTEST_SKIP() << "under AddressSanitizer operator new aborts instead of throwing bad_alloc; "
                  "the fuzz_messages target covers this path there";
#else
  const std::string good = TempDir() + "/array.bag";
  WriteRelativePoseBag(good, 20);
  {
    rosbag::Bag bag(good, rosbag::bagmode::Append);
    RelativePoseArray poses;
    KeyframeRelativeRotation m;
    m.keyframe1 = {"zzzz_marker_frame", 1000000000LL};
    m.keyframe2 = {"zzzz_marker_frame", 2000000000LL};
    poses.poses.push_back(ToMsg(m));
    bag.write("/relative_poses", ros::Time(1000.5), poses);
  }
  std::string bytes = ReadAll(good);
  // The array's length (uint32) comes just before the first pose's first
  // string (uint32 length + characters).
  const std::size_t marker = bytes.find("zzzz_marker_frame");
  ASSERT_NE(marker, std::string::npos);
  ASSERT_GE(marker, 8u);
  const std::size_t count_at = marker - 8;
  ASSERT_EQ(static_cast<unsigned char>(bytes[count_at]), 1u);
  bytes[count_at] = '\xF0';
  bytes[count_at + 1] = '\xFF';
  bytes[count_at + 2] = '\xFF';
  bytes[count_at + 3] = '\x7F';
  const std::string damaged = TempDir() + "/array_damaged.bag";
  std::ofstream(damaged, std::ios::binary) << bytes;
  const ReplayResult r = ReplayBags(Options(damaged, "array_damaged"));
  ASSERT_TRUE(r.ok) << r.error;
  EXPECT_EQ(r.damaged_messages, 1u);
  EXPECT_EQ(r.keyframes, 20u);
  bool warned = false;
  for (const std::string& w : r.warnings) warned = warned || w.find("does not deserialise") != std::string::npos;
  EXPECT_TRUE(warned);
#endif
}

// rotation_averaging_images_to_bag names its outputs as outputs and refuses
// to write over any of its inputs.
// Frames missing from a camera's stream in the bag (lost before it was
// recorded) are reported, and nothing is said when none are.
TEST(ReplaySummary, FramesMissingFromTheBagAreReported) {
  ReplayResult r;
  r.images_seen = 100;
  r.keyframe_images = 10;
  r.images_skipped = 90;
  const std::string line = "images missing from the bag by their cameras' stamps (lost before recording): 3";
  EXPECT_EQ(r.Summary().find("images missing"), std::string::npos) << r.Summary();
  r.images_missing = 3;
  EXPECT_NE(r.Summary().find(line), std::string::npos) << r.Summary();
}

TEST(ImagesToBag, NeverOverwritesAnInput) {
  const std::string dir = TempDir() + "/images_to_bag";
  std::filesystem::create_directories(dir + "/images");
  cv::Mat image(48, 64, CV_8UC1);
  cv::randu(image, 0, 255);
  ASSERT_TRUE(cv::imwrite(dir + "/images/a.png", image));
  ASSERT_TRUE(cv::imwrite(dir + "/images/b.png", image));
  WriteText(dir + "/K.txt", "50 0 32\n0 50 24\n0 0 1\n");
  NamedOrientations truth;
  truth["a.png"] = Eigen::Matrix3d::Identity();
  truth["b.png"] = ExpSO3(Eigen::Vector3d(0.0, 0.1, 0.0));
  std::string error;
  ASSERT_TRUE(WriteOrientationsCsv(dir + "/gt.csv", truth, &error)) << error;
  const std::string gt_before = ReadAll(dir + "/gt.csv");
  const auto run = [&](const std::string& extra) {
    const std::string command = std::string(ROTAVG_IMAGES_TO_BAG) + " --images " + dir + "/images --intrinsics " + dir +
                                "/K.txt --gt " + dir + "/gt.csv " + extra + " > " + dir + "/log.txt 2>&1";
    const int status = std::system(command.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  };
  // The CSV to write given as the ground truth read: refused, input intact.
  EXPECT_NE(run("--output " + dir + "/out.bag --write-gt-csv " + dir + "/gt.csv"), 0);
  EXPECT_NE(ReadAll(dir + "/log.txt").find("refusing to overwrite an input"), std::string::npos)
      << ReadAll(dir + "/log.txt");
  EXPECT_EQ(ReadAll(dir + "/gt.csv"), gt_before);
  // Through another spelling of the same path, and the bag over an image.
  EXPECT_NE(run("--output " + dir + "/out.bag --write-gt-csv " + dir + "/images/../gt.csv"), 0);
  EXPECT_EQ(ReadAll(dir + "/gt.csv"), gt_before);
  const std::string png_before = ReadAll(dir + "/images/a.png");
  EXPECT_NE(run("--output " + dir + "/images/a.png"), 0);
  EXPECT_EQ(ReadAll(dir + "/images/a.png"), png_before);
  // The old ambiguous flag is refused with the two names to use.
  EXPECT_NE(run("--output " + dir + "/out.bag --gt-csv " + dir + "/gt.csv"), 0);
  EXPECT_NE(ReadAll(dir + "/log.txt").find("--write-gt-csv"), std::string::npos);
  EXPECT_EQ(ReadAll(dir + "/gt.csv"), gt_before);
  // Distinct outputs: the bag and a CSV keyed by keyframe name.
  ASSERT_EQ(run("--output " + dir + "/out.bag --write-gt-csv " + dir + "/keyframes.csv"), 0) << ReadAll(dir + "/log.txt");
  NamedOrientations written;
  ASSERT_TRUE(ReadOrientationsCsv(dir + "/keyframes.csv", &written).ok());
  EXPECT_EQ(written.size(), 2u);
  EXPECT_EQ(ReadAll(dir + "/gt.csv"), gt_before);
}

}  // namespace
}  // namespace rotation_averaging
