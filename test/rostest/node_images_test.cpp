// rostest: castle-P19 images (downsampled to 768x512) are published as
// keyframes of one camera; the node must close the loop between the last and
// the first images and its orientations on tf must match the ground truth.
#include <cv_bridge/cv_bridge.h>
#include <gtest/gtest.h>
#include "common/test_data.h"
#include <ros/ros.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_ros/buffer.h>
#include <tf2_ros/transform_listener.h>

#include <filesystem>
#include <fstream>
#include <mutex>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

TEST(NodeImages, CastleKeyframesCloseTheLoopAndMatchGroundTruth) {
  const std::string dir = SharedDataPath("strecha/castle-P19");
  ROTAVG_REQUIRE_SHARED_DATA(dir);
  const std::vector<std::string> images = ListImages(dir + "/images");
  ASSERT_EQ(images.size(), 19u);
  CameraIntrinsics intrinsics;
  std::string error;
  ASSERT_TRUE(ReadCameraIntrinsics(dir + "/images/K.txt", &intrinsics, &error)) << error;
  const double scale = 0.25;
  const Eigen::Matrix3d k = ScaleIntrinsics(intrinsics.k, scale);

  ros::NodeHandle nh;
  ros::Publisher image_pub = nh.advertise<sensor_msgs::Image>("/test_cam/image_raw", 32);
  ros::Publisher info_pub = nh.advertise<sensor_msgs::CameraInfo>("/test_cam/camera_info", 32);
  ros::Publisher jpeg_pub = nh.advertise<sensor_msgs::CompressedImage>("/test_cam/image_raw/compressed", 32);
  ASSERT_TRUE(ros::service::waitForService("/averaging_images/save_graph", ros::Duration(30.0)));
  const ros::Time deadline = ros::Time::now() + ros::Duration(20.0);
  while ((image_pub.getNumSubscribers() == 0 || info_pub.getNumSubscribers() < 2 || jpeg_pub.getNumSubscribers() == 0) &&
         ros::Time::now() < deadline) {
    ros::Duration(0.05).sleep();
  }
  ASSERT_GT(image_pub.getNumSubscribers(), 0u);

  std::mutex mutex;
  Orientations::ConstPtr latest, latest_compressed;
  ros::Subscriber sub = nh.subscribe<Orientations>("/averaging_images/orientations", 1,
                                                   [&](const Orientations::ConstPtr& m) {
                                                     std::lock_guard<std::mutex> lock(mutex);
                                                     latest = m;
                                                   });
  ros::Subscriber sub_compressed = nh.subscribe<Orientations>("/averaging_compressed/orientations", 1,
                                                              [&](const Orientations::ConstPtr& m) {
                                                                std::lock_guard<std::mutex> lock(mutex);
                                                                latest_compressed = m;
                                                              });
  std::map<std::int64_t, std::string> stamp_to_image;
  for (int i = 0; i < 19; ++i) {
    cv::Mat full = cv::imread(images[i], cv::IMREAD_GRAYSCALE), small;
    cv::resize(full, small, cv::Size(), scale, scale, cv::INTER_AREA);
    std_msgs::Header header;
    header.frame_id = "castle_cam";
    header.stamp = ros::Time(100.0 + i);
    stamp_to_image[static_cast<std::int64_t>(header.stamp.toNSec())] = fs::path(images[i]).filename().string();
    sensor_msgs::CameraInfo info;
    info.header = header;
    info.width = small.cols;
    info.height = small.rows;
    for (int e = 0; e < 9; ++e) info.K[e] = k(e / 3, e % 3);
    info_pub.publish(info);
    image_pub.publish(cv_bridge::CvImage(header, "mono8", small).toImageMsg());
    sensor_msgs::CompressedImage jpeg;
    jpeg.header = header;
    jpeg.format = "jpeg";
    cv::imencode(".jpg", small, jpeg.data, {cv::IMWRITE_JPEG_QUALITY, 95});
    if (i == 5) {  // a corrupt image first: must be dropped, nothing else disturbed
      sensor_msgs::CompressedImage corrupt = jpeg;
      corrupt.header.stamp = ros::Time(99.0 + i + 0.5);
      corrupt.data.assign(100, 0x42);
      jpeg_pub.publish(corrupt);
    }
    jpeg_pub.publish(jpeg);
    ros::Duration(0.4).sleep();
  }
  // Wait until every keyframe is in a solution.
  auto count = [&](bool compressed) {
    std::lock_guard<std::mutex> lock(mutex);
    const Orientations::ConstPtr& m = compressed ? latest_compressed : latest;
    return m ? m->keyframes.size() : 0u;
  };
  const ros::Time solved_by = ros::Time::now() + ros::Duration(120.0);
  while ((count(false) < 19 || count(true) < 19) && ros::Time::now() < solved_by) ros::Duration(0.1).sleep();
  ASSERT_EQ(count(false), 19u);
  ASSERT_EQ(count(true), 19u) << "the compressed-image node did not solve every keyframe";

  // The saved graph holds a loop closure between the last and the first images.
  const std::string path = (fs::temp_directory_path() / ("rotavg_images_" + std::to_string(::getpid()) + ".txt")).string();
  SaveGraph save;
  save.request.path = path;
  ASSERT_TRUE(ros::service::call("/averaging_images/save_graph", save));
  ASSERT_TRUE(save.response.success) << save.response.message;
  std::map<std::string, std::string> view_image;  // graph view id -> image
  bool closes = false;
  LineReader reader(path);
  std::string line;
  while (reader.Next(&line)) {
    const std::vector<std::string> t = SplitTokens(line);
    if (t.size() >= 3 && t[0] == "VIEW") {
      const std::int64_t stamp = std::stoll(t[2].substr(t[2].rfind('@') + 1));
      view_image[t[1]] = stamp_to_image.at(stamp);
    } else if (t.size() >= 4 && t[0] == "EDGE" && t[3] == "loop_closure") {
      const int a = std::stoi(view_image.at(t[1]).substr(0, 4)), b = std::stoi(view_image.at(t[2]).substr(0, 4));
      closes = closes || (std::min(a, b) <= 2 && std::max(a, b) >= 16);
    }
  }
  fs::remove(path);
  EXPECT_TRUE(closes) << "no loop closure between the last and the first images";

  // Orientations on tf against ground truth.
  NamedOrientations gt_all, gt;
  ASSERT_TRUE(ReadGroundTruth(dir, GroundTruthFormat::kStrecha, &gt_all).ok());
  tf2_ros::Buffer buffer;
  tf2_ros::TransformListener listener(buffer);
  for (const std::string prefix : {"images", "compressed"}) {
    NamedOrientations est;
    for (const auto& [stamp, image] : stamp_to_image) {
      const std::string child = prefix + "/castle_cam_kf_" + std::to_string(stamp);
      const auto t = buffer.lookupTransform("map", child, ros::Time(0), ros::Duration(10.0));
      const auto& q = t.transform.rotation;
      est[image] = QuaternionToRotation(q.w, q.x, q.y, q.z).transpose();
      gt[image] = gt_all.at(image);
    }
    const EvaluationResult e = EvaluateOrientations(est, gt);
    EXPECT_EQ(e.views_common, 19u) << prefix;
    EXPECT_LT(e.median_error_deg, 1.0) << prefix;
  }
}

}  // namespace
}  // namespace rotation_averaging
