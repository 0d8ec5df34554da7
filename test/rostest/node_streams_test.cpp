// Raw camera streams, played by rosbag play --clock in real time, make the
// same keyframes in the live node as in rotation_averaging_replay on the same
// bag: keyframe selection decides from the images alone, and the node keeps
// up. A rendered two-camera rig at 20 Hz, and EuRoC's real stereo camera with
// its lens distortion in camera_info, whose cameras' solved relative
// rotation must match the calibration.
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>

#include "common/test_data.h"
#include "rotation_averaging/frontend/io/euroc_dataset.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/bag_replay.h"
#include "rotation_averaging/sim/demo_bag.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rostest/play_bag.h"

namespace rotation_averaging {
namespace {

std::string TempDir() {
  char pattern[] = "/tmp/rotavg_node_streams_XXXXXX";
  return mkdtemp(pattern);
}

// The replay of `bag` with the node's parameters (`config`, YAML).
ReplayResult Replay(const std::string& dir, const std::string& bag, const std::string& config) {
  std::ofstream(dir + "/config.yaml") << config;
  ReplayOptions options;
  options.bags = {bag};
  options.config_path = dir + "/config.yaml";
  options.output_dir = dir + "/replay";
  options.progress = false;
  return ReplayBags(options);
}

std::vector<std::string> Names(const NamedOrientations& orientations) {
  std::vector<std::string> names;
  for (const auto& [name, r] : orientations) names.push_back(name);
  return names;
}

// The node made the replay's keyframes and, from them, its graph edge for
// edge. Its orientations come from solves at other moments, each warm-started
// from the one before: where a keyframe's edges disagree (a weak loop
// closure), the robust loss can settle one keyframe elsewhere on a loaded
// machine, so the orientations are compared by their median.
void ExpectTheReplaysKeyframesAndGraph(const std::string& node, const std::string& dir, const ReplayResult& replay,
                                       const NamedOrientations& live, const NamedOrientations& replayed) {
  EXPECT_EQ(Names(live), Names(replayed)) << "the live node made other keyframes than the replay";
  ExpectNodeGraphIsTheReplays(node, dir + "/live_graph.txt", replay.graph_file);
  const EvaluationResult between = EvaluateOrientations(live, replayed);
  EXPECT_LT(between.median_error_deg, 0.01);
  std::printf("live node vs replay over %zu keyframes: median %.6f deg apart\n", between.views_common,
              between.median_error_deg);
}

TEST(NodeStreams, RenderedRigAt20HzMakesTheReplaysKeyframesInRealTime) {
  const std::string dir = TempDir();
  // The demo rig's two cameras at 20 Hz and 320x240 over 12 s (a quarter
  // of its loop): 480 images, written as a driver records them.
  RigSceneOptions scene_options;
  scene_options.WithWidth(320);
  scene_options.num_captures = 960;
  scene_options.capture_period_s = 0.05;
  const RigScene scene(scene_options);
  const std::string bag = dir + "/stream.bag";
  {
    rosbag::Bag out(bag, rosbag::bagmode::Write);
    CameraIntrinsics camera;
    camera.k = scene.Intrinsics();
    for (int c = 0; c < 240; ++c) {
      for (int i = 0; i < 2; ++i) {
        WriteKeyframeImage(&out, scene.Cameras()[i].frame_id, ros::Time(1000.0 + scene.CaptureTime(c)),
                           scene.Render(c, i), camera, false);
      }
    }
  }
  const ReplayResult replay =
      Replay(dir, bag, "image_topics: [\"/cam_front/image_raw\", \"/cam_left/image_raw\"]\nmax_features: 1500\n");
  ASSERT_TRUE(replay.ok) << replay.error;
  EXPECT_EQ(replay.images_seen, 480u);
  EXPECT_GE(replay.keyframes, 20u);
  EXPECT_LE(replay.keyframes, 160u);
  EXPECT_EQ(replay.components, 1u);
  NamedOrientations replayed;
  ASSERT_TRUE(ReadOrientationsCsv(replay.orientations_csv, &replayed).ok());

  // The node's own count of the frames that never reached keyframe
  // selection: one lost on the way (a subscriber queue that overflowed on a
  // loaded machine) changes the keyframes, and this says so when the
  // comparison fails. The diagnostics run on the bag's clock, so the last
  // ones came while it played.
  ros::NodeHandle nh;
  std::mutex mutex;
  std::map<std::string, std::string> diagnostics;
  ros::Subscriber diagnostics_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        for (const auto& status : m->status) {
          if (status.name.find("stream") == std::string::npos) continue;
          for (const auto& kv : status.values) diagnostics[kv.key] = kv.value;
        }
      });
  const NamedOrientations live = PlayIntoNode("stream", bag, replayed.size());
  {
    std::lock_guard<std::mutex> lock(mutex);
    EXPECT_GT(std::atoi(diagnostics["images seen"].c_str()), 240);
    EXPECT_EQ(diagnostics["images missing by their cameras' stamps (lost before the node)"], "0");
  }
  ExpectTheReplaysKeyframesAndGraph("stream", dir, replay, live, replayed);
  std::printf("%zu keyframes of %zu images\n", replay.keyframes, replay.images_seen);
}

TEST(NodeStreams, EurocRawStereoUndistortedMatchesItsCalibration) {
  const std::string mav0 = SharedDataPath("euroc_v1_01_micro/mav0");
  ROTAVG_REQUIRE_SHARED_DATA(mav0);
  const std::string dir = TempDir();
  std::vector<EurocCamera> cameras;
  std::size_t missing = 0;
  std::string error;
  ASSERT_TRUE(ReadEurocCameras(mav0, &cameras, &missing, &error)) << error;
  ASSERT_EQ(cameras.size(), 2u);
  const std::string bag = dir + "/euroc.bag";
  ASSERT_EQ(WriteEurocBag(cameras, bag, false, false, &error), 190u) << error;
  // The vehicle stands still: a keyframe capture every half second.
  const ReplayResult replay = Replay(dir, bag,
                                     "image_topics: [\"/cam0/image_raw\", \"/cam1/image_raw\"]\n"
                                     "use_rig_extrinsics: false\nkeyframe_max_interval_s: 0.5\n");
  ASSERT_TRUE(replay.ok) << replay.error;
  EXPECT_EQ(replay.images_seen, 190u);
  NamedOrientations replayed;
  ASSERT_TRUE(ReadOrientationsCsv(replay.orientations_csv, &replayed).ok());
  ASSERT_GE(replayed.size(), 16u);

  const NamedOrientations live = PlayIntoNode("euroc", bag, replayed.size());
  ExpectTheReplaysKeyframesAndGraph("euroc", dir, replay, live, replayed);

  // Each capture's cam0 -> cam1 rotation against the calibration's (x_cam1 = R x_cam0).
  const Eigen::Matrix3d r10 = cameras[1].body_from_camera.transpose() * cameras[0].body_from_camera;
  std::vector<double> errors;
  for (const auto& [name, r0] : live) {
    KeyframeKey key;
    ASSERT_TRUE(OnlineAverager::ParseKeyframeName(name, &key));
    if (key.frame_id != "cam0") continue;
    auto r1 = live.find(OnlineAverager::KeyframeName({"cam1", key.stamp_ns}));
    if (r1 != live.end()) errors.push_back(RadToDeg(AngularDistanceRad(r1->second * r0.transpose(), r10)));
  }
  ASSERT_GE(errors.size(), 8u);
  std::sort(errors.begin(), errors.end());
  std::printf("EuRoC: %zu stereo captures, cam0 -> cam1 against the calibration: median %.3f deg, max %.3f deg\n",
              errors.size(), errors[errors.size() / 2], errors.back());
  EXPECT_LT(errors[errors.size() / 2], 0.3);
}

}  // namespace
}  // namespace rotation_averaging
