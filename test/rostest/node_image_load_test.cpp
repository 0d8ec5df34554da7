// rostest: the node under image load. Rendered keyframe images arrive far
// faster than the front end can process them while relative poses of another
// camera keep coming. Asserted: the image queue never exceeds its capacity,
// the excess images are dropped and counted in diagnostics, the front end's
// latency stays bounded by the queue (it does not fall ever further behind),
// and every relative pose still gets into the solution: images never delay
// or crowd out relative poses.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_msgs/DiagnosticArray.h>
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>

#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/sim/rig_scene.h"

namespace rotation_averaging {
namespace {

constexpr int kQueueCapacity = 4;          // max_image_queue in node_image_load.test
constexpr double kImageRate = 40.0;        // images per second, several times the front end's rate
constexpr double kFloodSeconds = 6.0;
constexpr double kPoseRate = 20.0;         // relative poses per second on another camera

TEST(NodeImageLoad, ImagesFasterThanTheFrontEndAreDroppedAndCountedWithoutDelayingPoses) {
  ros::NodeHandle nh;
  ros::Publisher image_pub = nh.advertise<sensor_msgs::Image>("/load_cam/image_raw", 100);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("/load_cam/camera_info", 100);
  ros::Publisher pose_pub = nh.advertise<RelativePose>("/load/relative_pose", 100);
  std::mutex mutex;
  std::map<std::string, double> diagnostics;
  double max_queue_seen = 0.0, max_latency_ms = 0.0;
  Orientations::ConstPtr latest;
  ros::Subscriber diag_sub = nh.subscribe<diagnostic_msgs::DiagnosticArray>(
      "/diagnostics", 10, [&](const diagnostic_msgs::DiagnosticArray::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        for (const auto& status : m->status) {
          if (status.name.find("image_load") == std::string::npos) continue;
          for (const auto& kv : status.values) diagnostics[kv.key] = std::atof(kv.value.c_str());
        }
        max_queue_seen = std::max(max_queue_seen, diagnostics["image queue (keyframes waiting)"]);
        max_latency_ms = std::max(max_latency_ms, diagnostics["front-end latency per keyframe, last (ms)"]);
      });
  ros::Subscriber orientations_sub = nh.subscribe<Orientations>(
      "/image_load/orientations", 1, [&](const Orientations::ConstPtr& m) {
        std::lock_guard<std::mutex> lock(mutex);
        latest = m;
      });
  const ros::WallTime wait_until = ros::WallTime::now() + ros::WallDuration(30.0);
  while ((image_pub.getNumSubscribers() == 0 || info_pub.getNumSubscribers() == 0 || pose_pub.getNumSubscribers() == 0) &&
         ros::WallTime::now() < wait_until) {
    ros::WallDuration(0.05).sleep();
  }
  ASSERT_GT(image_pub.getNumSubscribers(), 0u);
  ASSERT_GT(pose_pub.getNumSubscribers(), 0u);

  RigSceneOptions scene_options;
  scene_options.num_cameras = 1;
  scene_options.num_captures = 40;
  const RigScene scene(scene_options);
  std::vector<cv::Mat> images;
  for (int c = 0; c < 8; ++c) images.push_back(scene.Render(c, 0));
  const Eigen::Matrix3d k = scene.Intrinsics();

  // Relative poses of a chain of "pose_cam" keyframes, 5 deg apart.
  int poses_sent = 0;
  auto send_pose = [&]() {
    KeyframeRelativeRotation m;
    m.keyframe1 = {"pose_cam", 1'000'000'000LL * (poses_sent + 1)};
    m.keyframe2 = {"pose_cam", 1'000'000'000LL * (poses_sent + 2)};
    m.rotation = ExpSO3(Eigen::Vector3d(0.0, 0.0, DegToRad(5.0)));
    m.has_covariance = true;
    m.covariance = Eigen::Matrix3d::Identity() * 1e-6;
    m.num_inliers = 100;
    m.source = EdgeSource::kSequential;
    pose_pub.publish(ToMsg(m));
    ++poses_sent;
  };

  const ros::WallTime start = ros::WallTime::now();
  int images_sent = 0;
  double next_pose = 0.0;
  while ((ros::WallTime::now() - start).toSec() < kFloodSeconds) {
    const double t = (ros::WallTime::now() - start).toSec();
    std_msgs::Header header;
    header.frame_id = "load_cam";
    header.stamp = ros::Time(100.0 + 0.025 * images_sent);
    sensor_msgs::CameraInfo info;
    info.header = header;
    info.width = images[0].cols;
    info.height = images[0].rows;
    for (int e = 0; e < 9; ++e) info.K[e] = k(e / 3, e % 3);
    info_pub.publish(info);
    image_pub.publish(cv_bridge::CvImage(header, "mono8", images[images_sent % images.size()]).toImageMsg());
    ++images_sent;
    if (t >= next_pose) {
      send_pose();
      next_pose += 1.0 / kPoseRate;
    }
    ros::WallDuration(1.0 / kImageRate).sleep();
  }
  // Every relative pose reaches the solution.
  const int pose_keyframes = poses_sent + 1;
  auto solved_pose_keyframes = [&]() {
    std::lock_guard<std::mutex> lock(mutex);
    int n = 0;
    if (latest) {
      for (const auto& kf : latest->keyframes) n += kf.frame_id == "pose_cam";
    }
    return n;
  };
  const ros::WallTime solved_by = ros::WallTime::now() + ros::WallDuration(30.0);
  while (solved_pose_keyframes() < pose_keyframes && ros::WallTime::now() < solved_by) ros::WallDuration(0.1).sleep();
  EXPECT_EQ(solved_pose_keyframes(), pose_keyframes);
  // Diagnostics after the flood (published once a second).
  ros::WallDuration(2.5).sleep();
  std::lock_guard<std::mutex> lock(mutex);
  const double processed = diagnostics["keyframe images processed"];
  const double dropped = diagnostics["dropped images (queue full)"];
  const double frontend_ms = diagnostics["front-end time per keyframe, mean of the last 50 (ms)"];
  std::printf("image load: %d images sent in %.1f s, %.0f processed, %.0f dropped (queue full); front end %.0f ms per "
              "keyframe; largest queue seen %.0f of %d; largest latency seen %.0f ms; %d relative poses sent\n",
              images_sent, kFloodSeconds, processed, dropped, frontend_ms, max_queue_seen, kQueueCapacity, max_latency_ms,
              poses_sent);
  EXPECT_GT(dropped, 0.0) << "the front end kept up: the test does not load it";
  EXPECT_GT(processed, 0.0);
  EXPECT_LE(processed + dropped, images_sent);
  EXPECT_LE(max_queue_seen, kQueueCapacity);
  EXPECT_EQ(diagnostics["image queue capacity"], kQueueCapacity);
  // Latency: at most a full queue ahead of a keyframe, plus itself (with
  // margin for a loaded machine), never growing with the flood.
  EXPECT_GT(frontend_ms, 0.0);
  EXPECT_LT(max_latency_ms, 3.0 * (kQueueCapacity + 1) * frontend_ms + 1000.0);
}

}  // namespace
}  // namespace rotation_averaging
