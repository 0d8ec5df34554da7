// The rendered rig's writers: the image folder for `rotavg images` holds the
// bag's keyframes under their names, a lens's images rectified again are
// written as a rectified camera's, a readout of part of the sensor is what
// camera_info says, and each camera's camera_info carries its own focal
// scale.
#include "rotation_averaging/sim/demo_bag.h"

#include <gtest/gtest.h>
#include <rosbag/bag.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/Image.h>
#include <unistd.h>

#include <filesystem>
#include <map>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <set>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

std::string TempDir() {
  static const std::string dir = [] {
    char pattern[] = "/tmp/rotavg_demo_bag_test_XXXXXX";
    return std::string(mkdtemp(pattern));
  }();
  return dir;
}

RigSceneOptions SmallScene() {
  RigSceneOptions options;
  options.num_captures = 4;
  options.WithWidth(320);
  return options;
}

// Every image of the bag by keyframe name (<frame>@<stamp_ns>), and each
// camera's camera_info.
void ReadBag(const std::string& path, std::map<std::string, cv::Mat>* images,
             std::map<std::string, sensor_msgs::CameraInfo>* infos) {
  rosbag::Bag bag(path, rosbag::bagmode::Read);
  for (const rosbag::MessageInstance& m : rosbag::View(bag)) {
    if (const auto image = m.instantiate<sensor_msgs::Image>()) {
      const KeyframeKey key{image->header.frame_id, ToNanoseconds(image->header.stamp)};
      cv::Mat grey(static_cast<int>(image->height), static_cast<int>(image->width), CV_8UC1,
                   const_cast<std::uint8_t*>(image->data.data()), image->step);
      (*images)[OnlineAverager::KeyframeName(key)] = grey.clone();
    } else if (const auto info = m.instantiate<sensor_msgs::CameraInfo>()) {
      (*infos)[info->header.frame_id] = *info;
    }
  }
}

double MeanAbsoluteDifference(const cv::Mat& a, const cv::Mat& b, const cv::Rect& region) {
  cv::Mat diff;
  cv::absdiff(a(region), b(region), diff);
  return cv::mean(diff)[0];
}

TEST(DemoBag, TheImageFolderHoldsTheBagsKeyframesUnderTheirNames) {
  ros::Time::init();
  const RigScene scene(SmallScene());
  const std::string bag = TempDir() + "/scene.bag", dir = TempDir() + "/images";
  NamedOrientations bag_truth;
  std::string error;
  RigSceneBagOptions bag_options;
  bag_options.images_dir = dir;
  ASSERT_TRUE(WriteRigSceneBag(scene, bag, /*compressed=*/false, &bag_truth, &error, bag_options)) << error;

  std::map<std::string, cv::Mat> images;
  std::map<std::string, sensor_msgs::CameraInfo> infos;
  ReadBag(bag, &images, &infos);
  ASSERT_EQ(images.size(), 8u);
  NamedOrientations folder_truth;
  ASSERT_TRUE(ReadOrientationsCsv(dir + "/ground_truth.csv", &folder_truth).ok());
  ASSERT_EQ(folder_truth.size(), images.size());
  std::set<std::string> pngs;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    if (entry.path().extension() == ".png") pngs.insert(entry.path().filename().string());
  }
  ASSERT_EQ(pngs.size(), images.size());
  for (const auto& [name, image] : images) {
    const std::string file = name + ".png";
    ASSERT_TRUE(pngs.count(file)) << file;
    const cv::Mat written = cv::imread(dir + "/" + file, cv::IMREAD_GRAYSCALE);
    ASSERT_EQ(written.size(), image.size()) << file;
    EXPECT_EQ(cv::norm(written, image, cv::NORM_INF), 0.0) << file << ": not the bag's image";
    ASSERT_TRUE(folder_truth.count(file)) << file;
    EXPECT_LT(AngularDistanceRad(folder_truth.at(file), bag_truth.at(name)), 1e-9) << file;
  }
  Eigen::Matrix3d k;
  ASSERT_TRUE(ReadIntrinsics(dir + "/K.txt", &k, &error)) << error;
  EXPECT_LT((k - scene.Intrinsics()).norm(), 1e-12);

  // The folder holds ideal pinhole images: not a lens's.
  ASSERT_TRUE(ParseDistortionSpec("plumb_bob:-0.28,0.07,0,0", &bag_options.lens, &error)) << error;
  EXPECT_FALSE(WriteRigSceneBag(scene, TempDir() + "/refused.bag", false, nullptr, &error, bag_options));
  EXPECT_NE(error.find("ideal pinhole"), std::string::npos) << error;
}

TEST(DemoBag, ALensImagesRectifiedAgainAreARectifiedCamerasImages) {
  ros::Time::init();
  const RigScene scene(SmallScene());
  RigSceneBagOptions lens_options;
  std::string error;
  ASSERT_TRUE(ParseDistortionSpec("plumb_bob:-0.28,0.07,0.0002,0.00002", &lens_options.lens, &error)) << error;
  RigSceneBagOptions rectified_options = lens_options;
  rectified_options.rectify = true;
  const std::string raw_bag = TempDir() + "/lens.bag", rectified_bag = TempDir() + "/lens_rectified.bag";
  ASSERT_TRUE(WriteRigSceneBag(scene, raw_bag, false, nullptr, &error, lens_options)) << error;
  ASSERT_TRUE(WriteRigSceneBag(scene, rectified_bag, false, nullptr, &error, rectified_options)) << error;

  std::map<std::string, cv::Mat> raw, rectified;
  std::map<std::string, sensor_msgs::CameraInfo> raw_infos, rectified_infos;
  ReadBag(raw_bag, &raw, &raw_infos);
  ReadBag(rectified_bag, &rectified, &rectified_infos);
  ASSERT_EQ(rectified.size(), 8u);
  ASSERT_EQ(rectified_infos.size(), 2u);
  for (const auto& [frame, info] : rectified_infos) {
    EXPECT_EQ(raw_infos.at(frame).D[0], -0.28) << frame << ": the raw stream carries the lens";
    for (double d : info.D) EXPECT_EQ(d, 0.0) << frame << ": a rectified camera_info has no distortion";
    EXPECT_EQ(info.K, raw_infos.at(frame).K) << frame;
  }
  // Away from the centre, the lens moves the content by pixels; rectified
  // again, it is back where the ideal camera sees it, up to the two
  // resamplings' blur.
  const cv::Rect ring(40, 30, 80, 60);  // between the centre and the top-left corner of 320x240
  for (int c = 0; c < 2; ++c) {
    const std::string name = OnlineAverager::KeyframeName({scene.Cameras()[c].frame_id, ToNanoseconds(ros::Time(1000.0))});
    const cv::Mat ideal = scene.Render(0, c);
    ASSERT_TRUE(rectified.count(name)) << name;
    const double rectified_error = MeanAbsoluteDifference(rectified.at(name), ideal, ring);
    const double raw_error = MeanAbsoluteDifference(raw.at(name), ideal, ring);
    EXPECT_LT(rectified_error, 0.5 * raw_error) << name << ": rectified " << rectified_error << ", raw " << raw_error;
  }
}

// A driver's readout of part of the sensor: each image is the region of the
// whole sensor's image, binned, and camera_info keeps the sensor's K and
// size and says how it was read out, so that the node's camera of the image
// (CameraFromInfo) has the image's size.
TEST(DemoBag, AReadoutOfPartOfTheSensorIsWhatCameraInfoSays) {
  ros::Time::init();
  const RigScene scene(SmallScene());
  const std::string whole_bag = TempDir() + "/whole.bag", readout_bag = TempDir() + "/readout.bag";
  std::string error;
  ASSERT_TRUE(WriteRigSceneBag(scene, whole_bag, false, nullptr, &error)) << error;
  RigSceneBagOptions options;
  options.readout.roi = cv::Rect(40, 30, 161, 120);  // an odd width: the last column is left out
  options.readout.binning = 2;
  ASSERT_TRUE(WriteRigSceneBag(scene, readout_bag, false, nullptr, &error, options)) << error;
  std::map<std::string, cv::Mat> whole, read_out;
  std::map<std::string, sensor_msgs::CameraInfo> whole_infos, infos;
  ReadBag(whole_bag, &whole, &whole_infos);
  ReadBag(readout_bag, &read_out, &infos);
  ASSERT_EQ(read_out.size(), whole.size());
  for (const auto& [name, image] : read_out) {
    ASSERT_EQ(image.size(), cv::Size(80, 60)) << name;
    EXPECT_EQ(cv::norm(image, ReadOut(whole.at(name), options.readout), cv::NORM_INF), 0.0) << name;
  }
  // One pixel is the mean of its block.
  const cv::Mat& sensor = whole.begin()->second;
  const cv::Mat& binned = read_out.begin()->second;
  const double block = (sensor.at<std::uint8_t>(30 + 2 * 5, 40 + 2 * 7) + sensor.at<std::uint8_t>(30 + 2 * 5, 41 + 2 * 7) +
                        sensor.at<std::uint8_t>(31 + 2 * 5, 40 + 2 * 7) + sensor.at<std::uint8_t>(31 + 2 * 5, 41 + 2 * 7)) /
                       4.0;
  EXPECT_LE(std::abs(binned.at<std::uint8_t>(5, 7) - block), 0.5);
  for (const auto& [frame, info] : infos) {
    const sensor_msgs::CameraInfo& full = whole_infos.at(frame);
    EXPECT_EQ(info.width, full.width) << frame;
    EXPECT_EQ(info.height, full.height) << frame;
    EXPECT_EQ(info.K, full.K) << frame << ": the sensor's K";
    EXPECT_EQ(info.binning_x, 2u);
    EXPECT_EQ(info.binning_y, 2u);
    EXPECT_EQ(info.roi.x_offset, 40u);
    EXPECT_EQ(info.roi.y_offset, 30u);
    EXPECT_EQ(info.roi.width, 161u);
    EXPECT_EQ(info.roi.height, 120u);
    CameraIntrinsics camera;
    cv::Size size;
    ASSERT_TRUE(CameraFromInfo(info, /*rectified=*/false, &camera, &error, &size)) << error;
    EXPECT_EQ(size, cv::Size(80, 60)) << frame;
  }
  // A region beyond the sensor is refused.
  options.readout.roi = cv::Rect(200, 0, 200, 100);
  EXPECT_FALSE(WriteRigSceneBag(scene, TempDir() + "/beyond.bag", false, nullptr, &error, options));
  EXPECT_NE(error.find("does not fit the 320 x 240 sensor"), std::string::npos) << error;
}

TEST(DemoBag, EachCamerasCameraInfoCarriesItsOwnFocalScale) {
  ros::Time::init();
  const RigScene scene(SmallScene());
  const Eigen::Matrix3d k = scene.Intrinsics();
  RigSceneBagOptions options;
  options.info_focal_scales = {0.97, 1.02};
  const std::string path = TempDir() + "/focal.bag";
  std::string error;
  ASSERT_TRUE(WriteRigSceneBag(scene, path, false, nullptr, &error, options)) << error;
  std::map<std::string, cv::Mat> images;
  std::map<std::string, sensor_msgs::CameraInfo> infos;
  ReadBag(path, &images, &infos);
  ASSERT_EQ(infos.size(), 2u);
  for (int c = 0; c < 2; ++c) {
    const sensor_msgs::CameraInfo& info = infos.at(scene.Cameras()[c].frame_id);
    EXPECT_NEAR(info.K[0], k(0, 0) * options.info_focal_scales[c], 1e-9) << c;
    EXPECT_NEAR(info.K[4], k(1, 1) * options.info_focal_scales[c], 1e-9) << c;
    EXPECT_EQ(info.K[2], k(0, 2)) << c << ": the principal point is the scene's";
    EXPECT_NEAR(info.P[0], info.K[0], 1e-12) << c;
  }
  // One factor per camera or none: three for two cameras is refused.
  options.info_focal_scales = {0.97, 1.02, 1.0};
  EXPECT_FALSE(WriteRigSceneBag(scene, TempDir() + "/refused.bag", false, nullptr, &error, options));
  EXPECT_NE(error.find("3 focal scales for 2 cameras"), std::string::npos) << error;
}

}  // namespace
}  // namespace rotation_averaging
