// The node's shared pipeline without a master: bad input of every kind,
// rig extrinsics through /tf_static messages, and the rviz markers.
#include "rotation_averaging/ros/keyframe_pipeline.h"

#include <gtest/gtest.h>
#include <ros/time.h>

#include <filesystem>
#include <fstream>
#include <limits>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

class NoParameters : public ParameterSource {
 public:
  bool Get(const std::string&, std::string*) const override { return false; }
  bool Get(const std::string&, double*) const override { return false; }
  bool Get(const std::string&, int*) const override { return false; }
  bool Get(const std::string&, bool*) const override { return false; }
  bool Get(const std::string&, std::vector<std::string>*) const override { return false; }
};

// What the node runs with when no parameter is set.
PipelineConfig DefaultConfig() {
  PipelineConfig config;
  std::string error;
  EXPECT_TRUE(ReadPipelineConfig(NoParameters(), &config, nullptr, &error)) << error;
  return config;
}

RelativePose Pose(const std::string& f1, double t1, const std::string& f2, double t2, const Eigen::Matrix3d& r,
                  std::uint8_t source = RelativePose::SOURCE_SEQUENTIAL) {
  KeyframeRelativeRotation m;
  m.keyframe1 = {f1, std::llround(t1 * 1e9)};
  m.keyframe2 = {f2, std::llround(t2 * 1e9)};
  m.rotation = r;
  m.has_covariance = true;
  m.covariance = std::pow(DegToRad(0.5), 2) * Eigen::Matrix3d::Identity();
  m.num_inliers = 100;
  m.source = static_cast<EdgeSource>(source);
  return ToMsg(m);
}

sensor_msgs::CameraInfo Info(int width, int height) {
  sensor_msgs::CameraInfo info;
  info.width = width;
  info.height = height;
  info.K = {100, 0, width / 2.0, 0, 100, height / 2.0, 0, 0, 1};
  return info;
}

sensor_msgs::Image Image(const std::string& frame, double t, int width, int height, const std::string& encoding) {
  sensor_msgs::Image m;
  m.header.frame_id = frame;
  m.header.stamp = ros::Time(t);
  m.width = width;
  m.height = height;
  m.encoding = encoding;
  m.step = width * (encoding == "rgb8" ? 3 : 1);
  m.data.assign(m.step * height, 128);
  return m;
}

TEST(KeyframePipeline, BadRelativePosesAreRejectedAndCounted) {
  KeyframePipeline pipeline(DefaultConfig());
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.1, 0.0, 0.0));
  std::vector<RelativePose> bad(6, Pose("cam", 1.0, "cam", 2.0, r));
  bad[0].rotation.x = std::numeric_limits<double>::quiet_NaN();
  bad[1].rotation.w = 2.0;
  bad[2].stamp_2 = bad[2].stamp_1;
  bad[3].rotation_covariance = {-1, 0, 0, 0, -1, 0, 0, 0, -1};
  bad[4].stamp_1 = ros::Time(0);
  bad[5].frame_id_2 = "";
  std::string error;
  for (const RelativePose& m : bad) {
    EXPECT_FALSE(pipeline.AcceptRelativePose(m, &error));
    EXPECT_FALSE(error.empty());
  }
  EXPECT_EQ(pipeline.Stats().rejected_messages, 6u);
  EXPECT_TRUE(pipeline.AcceptRelativePose(Pose("cam", 1.0, "cam", 2.0, r), &error)) << error;
  EXPECT_TRUE(pipeline.Averager().SolveNow());
  EXPECT_EQ(pipeline.Averager().Solution()->orientations.size(), 2u);
}

TEST(KeyframePipeline, BadImagesAreRejectedAndCounted) {
  PipelineConfig config = DefaultConfig();
  KeyframePipeline pipeline(config);
  PendingKeyframe k;
  std::string error;
  EXPECT_TRUE(pipeline.DecodeImage(Image("cam", 1.0, 64, 48, "mono8"), Info(64, 48), &k, &error)) << error;
  EXPECT_EQ(k.image.cols, 64);
  EXPECT_TRUE(pipeline.DecodeImage(Image("cam", 2.0, 64, 48, "rgb8"), Info(64, 48), &k, &error)) << error;
  // Stamps going backwards or repeating, per camera.
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 2.0, 64, 48, "mono8"), Info(64, 48), &k, &error));
  EXPECT_NE(error.find("did not advance"), std::string::npos) << error;
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 1.5, 64, 48, "mono8"), Info(64, 48), &k, &error));
  // Another camera has its own clock.
  EXPECT_TRUE(pipeline.DecodeImage(Image("cam2", 1.5, 64, 48, "mono8"), Info(64, 48), &k, &error)) << error;
  // No valid K, wrong size, unknown encoding, truncated data, empty frame id.
  sensor_msgs::CameraInfo no_k = Info(64, 48);
  no_k.K = {0, 0, 0, 0, 0, 0, 0, 0, 0};
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 3.0, 64, 48, "mono8"), no_k, &k, &error));
  EXPECT_NE(error.find("no valid K"), std::string::npos) << error;
  sensor_msgs::CameraInfo skewed_last_row = Info(64, 48);
  skewed_last_row.K[6] = 0.01;  // a last row other than 0 0 1 is no pinhole camera
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 3.5, 64, 48, "mono8"), skewed_last_row, &k, &error));
  EXPECT_NE(error.find("no valid K"), std::string::npos) << error;
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 4.0, 64, 48, "mono8"), Info(80, 60), &k, &error));
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 5.0, 64, 48, "no_such_encoding"), Info(64, 48), &k, &error));
  sensor_msgs::Image short_data = Image("cam", 6.0, 64, 48, "mono8");
  short_data.data.resize(10);
  EXPECT_FALSE(pipeline.DecodeImage(short_data, Info(64, 48), &k, &error));
  // height * step wraps around to the data's size in 32 bits (4 rows of a
  // gigabyte over 3072 bytes): refused before cv_bridge, which checks in 32
  // bits and would copy 4 GiB from past the data.
  sensor_msgs::Image wrapped = Image("cam", 6.5, 64, 48, "mono8");
  wrapped.height = 4;
  wrapped.width = wrapped.step = (1u << 30) + 768;
  wrapped.data.assign(3072, 0);
  ASSERT_EQ(static_cast<std::uint32_t>(wrapped.height * wrapped.step), wrapped.data.size());
  EXPECT_FALSE(pipeline.DecodeImage(wrapped, Info(64, 48), &k, &error));
  EXPECT_NE(error.find("malformed"), std::string::npos) << error;
  // So is a width whose bytes per row (6 per pixel) wrap around to below step.
  wrapped = Image("cam", 6.7, 64, 48, "rgb16");
  wrapped.width = 715827883;
  wrapped.height = 1;
  wrapped.step = 16;
  wrapped.data.assign(16, 0);
  EXPECT_FALSE(pipeline.DecodeImage(wrapped, Info(64, 48), &k, &error));
  EXPECT_NE(error.find("malformed"), std::string::npos) << error;
  EXPECT_FALSE(pipeline.DecodeImage(Image("", 7.0, 64, 48, "mono8"), Info(64, 48), &k, &error));
  sensor_msgs::CompressedImage jpeg;
  jpeg.header.frame_id = "cam";
  jpeg.header.stamp = ros::Time(8.0);
  jpeg.format = "jpeg";
  jpeg.data = {0xFF, 0xD8, 0x00, 0x01};  // a JPEG that stops after its marker
  EXPECT_FALSE(pipeline.DecodeCompressedImage(jpeg, Info(64, 48), &k, &error));
  EXPECT_EQ(pipeline.Stats().rejected_images, 11u);
}

// A 20 Hz stream that lost frames before the pipeline saw them (a
// subscriber queue that overflowed, a driver that dropped them): the gaps in
// each camera's stamps count them, with every keyframe selection mode.
TEST(KeyframePipeline, ImagesMissingFromAStreamAreCounted) {
  for (const char* mode : {"motion", "all"}) {
    PipelineConfig config = DefaultConfig();
    ASSERT_TRUE(ParseOption(mode, &config.keyframe_selection)) << mode;
    KeyframePipeline pipeline(config);
    for (int i = 0; i < 60; ++i) {
      if (i == 30 || i == 31 || i == 45) continue;
      for (const char* camera : {"cam_a", "cam_b"}) {
        if (std::string(camera) == "cam_b" && i == 50) continue;
        PendingKeyframe k;
        std::string error;
        ASSERT_TRUE(pipeline.DecodeImage(Image(camera, 10.0 + 0.05 * i, 64, 48, "mono8"), Info(64, 48), &k, &error))
            << error;
        pipeline.SelectKeyframes(k);
      }
    }
    EXPECT_EQ(pipeline.Stats().frames_missing, 7u) << mode;
    EXPECT_EQ(pipeline.FramesMissing(), 7u) << mode;
  }
}

// camera_info as image_proc reads it: a raw image's camera is K with its
// distortion model and D; a rectified image's is P, without distortion.
TEST(KeyframePipeline, CameraInfoGivesTheCameraModelOfRawAndRectifiedImages) {
  sensor_msgs::CameraInfo info = Info(752, 480);
  info.K = {458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1};
  info.P = {435.2, 0, 367.4, 0, 0, 435.2, 252.2, 0, 0, 0, 1, 0};
  info.distortion_model = "plumb_bob";
  info.D = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0};
  CameraIntrinsics camera;
  std::string error;
  ASSERT_TRUE(CameraFromInfo(info, /*rectified=*/false, &camera, &error)) << error;
  EXPECT_EQ(camera.distortion, DistortionModel::kPlumbBob);
  EXPECT_TRUE(camera.HasDistortion());
  EXPECT_DOUBLE_EQ(camera.k(0, 0), 458.654);
  ASSERT_TRUE(CameraFromInfo(info, /*rectified=*/true, &camera, &error)) << error;
  EXPECT_FALSE(camera.HasDistortion());
  EXPECT_DOUBLE_EQ(camera.k(0, 0), 435.2);
  EXPECT_DOUBLE_EQ(camera.k(1, 2), 252.2);
  info.distortion_model = "equidistant";
  info.D = {0.01, 0.002, 0.0, 0.0};
  ASSERT_TRUE(CameraFromInfo(info, false, &camera, &error)) << error;
  EXPECT_EQ(camera.distortion, DistortionModel::kEquidistant);

  // Refused with the reason, never read as no distortion.
  info.distortion_model = "double_sphere";
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  EXPECT_NE(error.find("'double_sphere'"), std::string::npos) << error;
  info.distortion_model = "";
  info.D = {-0.28, 0.07, 0.0, 0.0, 0.0};
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  info.distortion_model = "plumb_bob";
  info.D = {-0.28, 0.07};
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  // An uncalibrated camera_info: a model named, no coefficients.
  info.D.clear();
  ASSERT_TRUE(CameraFromInfo(info, false, &camera, &error)) << error;
  EXPECT_FALSE(camera.HasDistortion());
  info.D = {-0.28, 0.07, 0.0, std::nan(""), 0.0};
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));

  EXPECT_FALSE(IsRectifiedTopic("/cam0/image_raw", ImageType::kAuto));
  EXPECT_TRUE(IsRectifiedTopic("/cam0/image_rect", ImageType::kAuto));
  EXPECT_TRUE(IsRectifiedTopic("/stereo/left/image_rect_color", ImageType::kAuto));
  EXPECT_FALSE(IsRectifiedTopic("/image_rect/image_raw", ImageType::kAuto));
  EXPECT_FALSE(IsRectifiedTopic("/cam0/image_rect", ImageType::kRaw));
  EXPECT_TRUE(IsRectifiedTopic("/cam0/image_raw", ImageType::kRectified));

  // Through the pipeline: the keyframe carries the camera; an unknown model
  // rejects the image with its camera and model named.
  KeyframePipeline pipeline(DefaultConfig());
  PendingKeyframe k;
  sensor_msgs::CameraInfo raw = Info(64, 48);
  raw.distortion_model = "plumb_bob";
  raw.D = {-0.2, 0.05, 0.0, 0.0, 0.0};
  ASSERT_TRUE(pipeline.DecodeImage(Image("cam", 1.0, 64, 48, "mono8"), raw, &k, &error)) << error;
  EXPECT_EQ(k.camera.coefficients, raw.D);
  const std::vector<std::string> notices = pipeline.TakeCameraModelNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].find("cam: f 100, 100 px, keypoints undistorted by plumb_bob"), std::string::npos);
  EXPECT_TRUE(pipeline.TakeCameraModelNotices().empty());  // once per camera
  raw.distortion_model = "fov";
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 2.0, 64, 48, "mono8"), raw, &k, &error));
  EXPECT_NE(error.find("camera_info of cam: unknown distortion_model 'fov'"), std::string::npos) << error;
  EXPECT_EQ(pipeline.Stats().rejected_images, 1u);
}

// A driver that reads out a region of the sensor or bins its pixels
// (REP 104) keeps camera_info's K, width and height those of the full
// sensor. The image's camera must put each of its pixels where the sensor
// pixels it combines are: a spot rendered on the full sensor and read out
// binned 2 x 2 (block means, as the sensor sums its charges) and from a
// region must be seen, through the camera CameraFromInfo gives the image,
// along the ray the full sensor's K gives the spot. image_geometry's
// formula, which leaves out half a block, misses by a quarter of a binned
// pixel.
TEST(KeyframePipeline, BinningAndRegionOfInterestGiveTheReadoutsCamera) {
  const int width = 200, height = 160;
  const Eigen::Vector2d spot(83.3, 61.7);  // full-sensor pixels, K's convention
  cv::Mat full(height, width, CV_64F);
  for (int v = 0; v < height; ++v)
    for (int u = 0; u < width; ++u)
      full.at<double>(v, u) = std::exp(-((u - spot.x()) * (u - spot.x()) + (v - spot.y()) * (v - spot.y())) / 18.0);
  const auto centroid = [](const cv::Mat& image) {
    Eigen::Vector2d sum = Eigen::Vector2d::Zero();
    double mass = 0.0;
    for (int v = 0; v < image.rows; ++v)
      for (int u = 0; u < image.cols; ++u) {
        sum += image.at<double>(v, u) * Eigen::Vector2d(u, v);
        mass += image.at<double>(v, u);
      }
    return Eigen::Vector2d(sum / mass);
  };
  sensor_msgs::CameraInfo info = Info(width, height);
  info.K = {150.0, 0, 97.3, 0, 152.0, 83.1, 0, 0, 1};
  info.P = {140.0, 0, 95.0, 0, 0, 141.0, 80.0, 0, 0, 0, 1, 0};
  const Eigen::Matrix3d k_full = Eigen::Map<const Eigen::Matrix<double, 3, 3, Eigen::RowMajor>>(info.K.data());
  const Eigen::Vector3d ray = (k_full.inverse() * spot.homogeneous()).normalized();

  struct Readout {
    unsigned binning, x, y, w, h;
  };
  for (const Readout& r : {Readout{2, 0, 0, 0, 0}, Readout{1, 40, 30, 120, 90}, Readout{2, 40, 30, 120, 90},
                           Readout{4, 20, 10, 160, 120}}) {
    SCOPED_TRACE("binning " + std::to_string(r.binning) + ", roi at (" + std::to_string(r.x) + ", " +
                 std::to_string(r.y) + ")");
    info.binning_x = info.binning_y = r.binning;
    info.roi.x_offset = r.x;
    info.roi.y_offset = r.y;
    info.roi.width = r.w;
    info.roi.height = r.h;
    cv::Mat readout = r.w > 0 ? full(cv::Rect(r.x, r.y, r.w, r.h)) : full;
    cv::resize(readout, readout, cv::Size(readout.cols / r.binning, readout.rows / r.binning), 0, 0, cv::INTER_AREA);
    CameraIntrinsics camera;
    std::string error;
    cv::Size size;
    ASSERT_TRUE(CameraFromInfo(info, /*rectified=*/false, &camera, &error, &size)) << error;
    EXPECT_EQ(size, readout.size());
    const Eigen::Vector3d seen = (camera.k.inverse() * centroid(readout).homogeneous()).normalized();
    // 0.002 px of the full sensor, in radians at its focal length.
    EXPECT_LT(std::acos(std::min(1.0, seen.dot(ray))), 0.002 / 150.0);
    // A rectified image's P goes through the same readout.
    ASSERT_TRUE(CameraFromInfo(info, /*rectified=*/true, &camera, &error)) << error;
    EXPECT_DOUBLE_EQ(camera.k(0, 0), 140.0 / r.binning);
    EXPECT_DOUBLE_EQ(camera.k(1, 2), (80.0 - r.y - 0.5 * (r.binning - 1.0)) / r.binning);
  }

  // Binning 0 is 1, and a sensor read out whole leaves K as it is.
  info = Info(width, height);
  info.K = {150.0, 0, 97.3, 0, 152.0, 83.1, 0, 0, 1};
  CameraIntrinsics camera;
  std::string error;
  cv::Size size;
  ASSERT_TRUE(CameraFromInfo(info, false, &camera, &error, &size)) << error;
  EXPECT_EQ(camera.k, k_full);
  EXPECT_EQ(size, cv::Size(width, height));
  // The lens acts on normalised coordinates: its model carries over.
  info.distortion_model = "plumb_bob";
  info.D = {-0.28, 0.07, 0.0002, 0.00002, 0.0};
  info.binning_x = info.binning_y = 2;
  ASSERT_TRUE(CameraFromInfo(info, false, &camera, &error, &size)) << error;
  EXPECT_EQ(camera.coefficients, info.D);
  EXPECT_EQ(size, cv::Size(width / 2, height / 2));

  // Readouts that do not fit the sensor are refused with the reason.
  info.roi.x_offset = 150;
  info.roi.width = 100;
  info.roi.height = 50;
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  EXPECT_NE(error.find("does not lie on the 200 x 160 sensor"), std::string::npos) << error;
  info.roi.x_offset = 4294967295u;  // offset + width wraps around in 32 bits
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  info.roi.x_offset = 10;
  info.roi.width = 0;
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  EXPECT_NE(error.find("has no size"), std::string::npos) << error;
  info.roi = sensor_msgs::RegionOfInterest();
  info.binning_x = 1000;
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  info.binning_x = 2;
  info.roi.width = info.roi.height = 1;
  EXPECT_FALSE(CameraFromInfo(info, false, &camera, &error));
  EXPECT_NE(error.find("leaves no pixel"), std::string::npos) << error;

  // Through the pipeline: the binned image is taken with the readout's
  // camera; the full sensor's size is not the image's, raw or compressed.
  KeyframePipeline pipeline(DefaultConfig());
  PendingKeyframe k;
  info.roi = sensor_msgs::RegionOfInterest();
  ASSERT_TRUE(pipeline.DecodeImage(Image("cam", 1.0, width / 2, height / 2, "mono8"), info, &k, &error)) << error;
  EXPECT_DOUBLE_EQ(k.camera.k(0, 0), 75.0);
  EXPECT_DOUBLE_EQ(k.camera.k(0, 2), (97.3 - 0.5) / 2.0);
  const std::vector<std::string> notices = pipeline.TakeCameraModelNotices();
  ASSERT_EQ(notices.size(), 1u);
  EXPECT_NE(notices[0].find("binned 2 x 2"), std::string::npos) << notices[0];
  EXPECT_FALSE(pipeline.DecodeImage(Image("cam", 2.0, width, height, "mono8"), info, &k, &error));
  EXPECT_NE(error.find("is 200 x 160, its camera_info says 100 x 80"), std::string::npos) << error;
  // The driver's readout changes at run time (REP 104: without a new
  // calibration): the next image is taken with the new readout's camera,
  // and the camera is described again.
  sensor_msgs::CameraInfo region = info;
  region.binning_x = region.binning_y = 1;
  region.roi.x_offset = 40;
  region.roi.y_offset = 30;
  region.roi.width = 120;
  region.roi.height = 90;
  ASSERT_TRUE(pipeline.DecodeImage(Image("cam", 2.5, 120, 90, "mono8"), region, &k, &error)) << error;
  EXPECT_DOUBLE_EQ(k.camera.k(0, 2), 97.3 - 40.0);
  EXPECT_DOUBLE_EQ(k.camera.k(0, 0), 150.0);
  const std::vector<std::string> again = pipeline.TakeCameraModelNotices();
  ASSERT_EQ(again.size(), 1u);
  EXPECT_NE(again[0].find("region 120 x 90 at (40, 30) of the sensor"), std::string::npos) << again[0];
  sensor_msgs::CompressedImage png;
  png.header.frame_id = "cam";
  png.header.stamp = ros::Time(3.0);
  png.format = "mono8; png compressed";
  cv::Mat grey(height / 2, width / 2, CV_8UC1, cv::Scalar(7));
  cv::imencode(".png", grey, png.data);
  EXPECT_TRUE(pipeline.DecodeCompressedImage(png, info, &k, &error)) << error;
  info.binning_x = info.binning_y = 1;
  png.header.stamp = ros::Time(4.0);
  EXPECT_FALSE(pipeline.DecodeCompressedImage(png, info, &k, &error));
  EXPECT_EQ(pipeline.Stats().rejected_images, 2u);
}

sensor_msgs::CompressedImage Compressed(double t, const std::string& extension) {
  sensor_msgs::CompressedImage m;
  m.header.frame_id = "cam";
  m.header.stamp = ros::Time(t);
  m.format = "mono8; " + extension.substr(1) + " compressed";
  cv::Mat grey(48, 64, CV_8UC1);
  cv::randu(grey, 0, 255);
  cv::imencode(extension, grey, m.data);
  return m;
}

void PutBigEndian16(std::uint32_t value, std::uint8_t* at) {
  at[0] = static_cast<std::uint8_t>(value >> 8);
  at[1] = static_cast<std::uint8_t>(value);
}

// The decoder allocates the size a header declares before it reads any
// pixel: a header that disagrees with camera_info, or declares an
// implausible size (whatever camera_info says), is refused before decoding,
// and formats other than image_transport's PNG and JPEG are refused.
TEST(KeyframePipeline, CompressedImagesAreCheckedBeforeDecoding) {
  KeyframePipeline pipeline(DefaultConfig());
  PendingKeyframe k;
  std::string error;
  EXPECT_TRUE(pipeline.DecodeCompressedImage(Compressed(1.0, ".png"), Info(64, 48), &k, &error)) << error;
  EXPECT_EQ(k.image.cols, 64);
  EXPECT_TRUE(pipeline.DecodeCompressedImage(Compressed(2.0, ".jpg"), Info(64, 48), &k, &error)) << error;
  EXPECT_EQ(k.image.rows, 48);
  EXPECT_TRUE(pipeline.DecodeCompressedImage(Compressed(3.0, ".png"), Info(0, 0), &k, &error)) << error;

  sensor_msgs::CompressedImage png = Compressed(4.0, ".png");
  PutBigEndian16(6000, &png.data[18]);  // IHDR width 6000, height 4000
  PutBigEndian16(4000, &png.data[22]);
  EXPECT_FALSE(pipeline.DecodeCompressedImage(png, Info(64, 48), &k, &error));
  EXPECT_NE(error.find("declares 6000x4000 pixels, not camera_info's 64x48"), std::string::npos) << error;
  PutBigEndian16(0x4000, &png.data[16]);  // about 2^30 x 4000, no camera_info size
  EXPECT_FALSE(pipeline.DecodeCompressedImage(png, Info(0, 0), &k, &error));
  EXPECT_NE(error.find("implausibly large"), std::string::npos) << error;
  EXPECT_FALSE(pipeline.DecodeCompressedImage(png, Info(0x40001770, 4000), &k, &error));  // also when camera_info says so
  EXPECT_NE(error.find("implausibly large"), std::string::npos) << error;

  sensor_msgs::CompressedImage jpeg = Compressed(5.0, ".jpg");
  std::size_t sof = 2;
  while (sof + 1 < jpeg.data.size() && !(jpeg.data[sof] == 0xFF && jpeg.data[sof + 1] == 0xC0)) ++sof;
  ASSERT_LT(sof + 9, jpeg.data.size());
  PutBigEndian16(48, &jpeg.data[sof + 7]);  // width 48, height 48
  EXPECT_FALSE(pipeline.DecodeCompressedImage(jpeg, Info(64, 48), &k, &error));
  EXPECT_NE(error.find("JPEG header declares 48x48"), std::string::npos) << error;

  EXPECT_FALSE(pipeline.DecodeCompressedImage(Compressed(6.0, ".bmp"), Info(64, 48), &k, &error));
  EXPECT_NE(error.find("neither PNG nor JPEG"), std::string::npos) << error;
  sensor_msgs::CompressedImage cut = Compressed(7.0, ".png");
  cut.data.resize(20);
  EXPECT_FALSE(pipeline.DecodeCompressedImage(cut, Info(64, 48), &k, &error));
  EXPECT_EQ(pipeline.Stats().rejected_images, 6u);
  // A header that agrees, over pixels cut short, is left to the decoder.
  sensor_msgs::CompressedImage truncated = Compressed(8.0, ".png");
  truncated.data.resize(truncated.data.size() / 2);
  EXPECT_FALSE(pipeline.DecodeCompressedImage(truncated, Info(64, 48), &k, &error));
  EXPECT_NE(error.find("does not decode"), std::string::npos) << error;
}

TEST(KeyframePipeline, RigExtrinsicsFromStaticTransformsAndMarkers) {
  KeyframePipeline pipeline(DefaultConfig());
  // cam_b looks 90 degrees left of cam_a on base_link.
  const Eigen::Matrix3d b_in_rig = ExpSO3(Eigen::Vector3d(0.0, 0.0, kPi / 2));
  tf2_msgs::TFMessage statics;
  geometry_msgs::TransformStamped t;
  t.header.frame_id = "base_link";
  t.child_frame_id = "cam_a";
  t.transform.rotation.w = 1.0;
  statics.transforms.push_back(t);
  t.child_frame_id = "cam_b";
  const Eigen::Vector4d q = RotationToQuaternion(b_in_rig);
  t.transform.rotation.w = q[0];
  t.transform.rotation.x = q[1];
  t.transform.rotation.y = q[2];
  t.transform.rotation.z = q[3];
  statics.transforms.push_back(t);
  pipeline.AcceptStaticTransforms(statics);

  // Rig orientations along a ring; cam_a and cam_b measure them separately
  // (one outlier among cam_b's), and never each other.
  std::vector<Eigen::Matrix3d> rig;
  for (int k = 0; k < 8; ++k) rig.push_back(ExpSO3(Eigen::Vector3d(0.0, 0.0, 0.2 * k)));
  const Eigen::Matrix3d eb = b_in_rig.transpose();  // cam_b from rig
  std::string error;
  for (int k = 1; k < 8; ++k) {
    ASSERT_TRUE(pipeline.AcceptRelativePose(
        Pose("cam_a", k, "cam_a", k + 1, rig[k - 1] * rig[k].transpose()), &error)) << error;
    Eigen::Matrix3d rb = eb * rig[k - 1] * rig[k].transpose() * eb.transpose();
    if (k == 4) rb = rb * ExpSO3(Eigen::Vector3d(0.5, 0.0, 0.0));  // outlier
    ASSERT_TRUE(pipeline.AcceptRelativePose(Pose("cam_b", k + 0.001, "cam_b", k + 1.001, rb), &error)) << error;
  }
  EXPECT_EQ(pipeline.Rig().NumRigCameras(), 2u);
  ASSERT_TRUE(pipeline.Averager().SolveNow());
  const std::shared_ptr<const OnlineSolution> variables = pipeline.Averager().Solution();
  EXPECT_EQ(variables->orientations.size(), 8u);  // one per capture
  EXPECT_EQ(variables->edges.size(), 14u);        // both cameras' edges kept (channels)
  const OnlineSolution cameras = pipeline.CameraSolution(*variables);
  ASSERT_EQ(cameras.orientations.size(), 16u);
  // The cameras of a capture keep their extrinsic rotation.
  const Eigen::Matrix3d a3 = cameras.orientations.at({"cam_a", 3000000000});
  const Eigen::Matrix3d b3 = cameras.orientations.at({"cam_b", 3001000000});
  EXPECT_LT(RadToDeg(AngularDistanceRad(b3, eb * a3)), 1e-9);

  // Markers: a frustum (8 segments) per camera keyframe, an edge per solved
  // edge coloured by weight: the outlier red, the others green.
  const visualization_msgs::MarkerArray markers = pipeline.Markers(*variables, cameras, ros::Time(10.0));
  ASSERT_EQ(markers.markers.size(), 2u);
  EXPECT_EQ(markers.markers[0].ns, "keyframes");
  EXPECT_EQ(markers.markers[0].points.size(), 16u * 16u);
  const visualization_msgs::Marker& edges = markers.markers[1];
  ASSERT_EQ(edges.points.size(), 28u);
  ASSERT_EQ(edges.colors.size(), 28u);
  int red = 0, green = 0;
  for (std::size_t k = 0; k < edges.colors.size(); k += 2) {
    if (edges.colors[k].r > 0.9) ++red;
    if (edges.colors[k].g > 0.9) ++green;
  }
  EXPECT_EQ(red, 1);
  EXPECT_EQ(green, 13);
  // Orientations message and tf carry camera keyframes.
  const Orientations msg = pipeline.OrientationsMsg(cameras, ros::Time(10.0));
  EXPECT_EQ(msg.keyframes.size(), 16u);
  // Posterior covariances for every keyframe; the gauge capture's are zero,
  // the others positive, growing away from it.
  int zero = 0, positive = 0;
  for (const KeyframeOrientation& k : msg.keyframes) {
    EXPECT_TRUE(k.has_covariance);
    const double trace = k.covariance[0] + k.covariance[4] + k.covariance[8];
    if (trace == 0.0) ++zero;
    if (trace > 0.0) ++positive;
  }
  EXPECT_EQ(zero, 2);  // both cameras of the gauge capture
  EXPECT_EQ(positive, 14);
  EXPECT_EQ(pipeline.KeyframeTransforms(cameras).transforms.size(), 16u);
}

// The map of a pipeline without images: SaveMap writes the graph and the rig
// beside it (and removes a keyframe database an earlier save left there,
// which belongs to another graph); LoadMap in a pipeline that has seen no
// static transform brings back the same camera keyframes. A corrupted rig
// file refuses the map and leaves the graph held as it was.
TEST(KeyframePipeline, AMapSavesAndLoadsTheGraphWithItsRig) {
  KeyframePipeline pipeline(DefaultConfig());
  tf2_msgs::TFMessage statics;
  geometry_msgs::TransformStamped t;
  t.header.frame_id = "base_link";
  t.transform.rotation.w = 1.0;
  for (const char* camera : {"cam_a", "cam_b"}) {
    t.child_frame_id = camera;
    statics.transforms.push_back(t);
  }
  pipeline.AcceptStaticTransforms(statics);
  std::string error;
  for (int k = 1; k < 6; ++k) {
    const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.0, 0.0, 0.2));
    ASSERT_TRUE(pipeline.AcceptRelativePose(Pose("cam_a", k, "cam_b", k + 1.001, r), &error)) << error;
  }
  ASSERT_TRUE(pipeline.Averager().SolveNow());
  const OnlineSolution before = pipeline.CameraSolution(*pipeline.Averager().Solution());
  ASSERT_EQ(before.orientations.size(), 10u);  // cam_a at 1..5 s, cam_b at 2..6 s

  const std::string graph = ::testing::TempDir() + "/keyframe_pipeline_test_map.txt";
  std::ofstream(KeyframeDatabasePath(graph)) << "left by an earlier save";
  std::string note;
  ASSERT_TRUE(pipeline.SaveMap(graph, &error, &note)) << error;
  EXPECT_TRUE(std::filesystem::exists(RigPath(graph)));
  EXPECT_FALSE(std::filesystem::exists(KeyframeDatabasePath(graph))) << note;

  KeyframePipeline restarted(DefaultConfig());  // no static transform
  ASSERT_TRUE(restarted.LoadMap(graph, &error, &note)) << error;
  EXPECT_NE(note.find("6 rig captures"), std::string::npos) << note;
  ASSERT_TRUE(restarted.Averager().SolveNow());
  const OnlineSolution after = restarted.CameraSolution(*restarted.Averager().Solution());
  ASSERT_EQ(after.orientations.size(), before.orientations.size());
  for (const auto& [key, r] : before.orientations) {
    ASSERT_TRUE(after.orientations.count(key)) << key.frame_id << "@" << key.stamp_ns;
    EXPECT_LT(RadToDeg(AngularDistanceRad(after.orientations.at(key), r)), 1e-6);
  }

  std::ofstream(RigPath(graph), std::ios::app) << "CAPTURE base_link 99\n";  // after END: not this file
  KeyframePipeline refused(DefaultConfig());
  EXPECT_FALSE(refused.LoadMap(graph, &error));
  EXPECT_NE(error.find("after the END record"), std::string::npos) << error;
  EXPECT_EQ(refused.Averager().Stats().views, 0u);
}

}  // namespace
}  // namespace rotation_averaging
