#include "rotation_averaging/frontend/geometry/camera_model.h"

#include <gtest/gtest.h>

#include <iostream>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <opencv2/core.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/test_data.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

// EuRoC's cam0 (VI-sensor, 752x480): a strong barrel distortion.
CameraIntrinsics EurocCam0() {
  CameraIntrinsics c;
  c.k << 458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1;
  c.distortion = DistortionModel::kPlumbBob;
  c.coefficients = {-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05};
  return c;
}

// The pixel at which `camera` sees the ray through normalised point x, by
// the model's forward equations written out here (not the library's).
Eigen::Vector2d Project(const CameraIntrinsics& camera, const Eigen::Vector2d& x) {
  std::vector<double> d = camera.coefficients;
  d.resize(8, 0.0);
  Eigen::Vector2d xd;
  if (camera.distortion == DistortionModel::kEquidistant) {
    const double r = x.norm(), theta = std::atan(r);
    const double t2 = theta * theta;
    const double theta_d = theta * (1 + d[0] * t2 + d[1] * t2 * t2 + d[2] * t2 * t2 * t2 + d[3] * t2 * t2 * t2 * t2);
    xd = r > 0 ? Eigen::Vector2d(x * theta_d / r) : x;
  } else {
    const double r2 = x.squaredNorm();
    const double radial = (1 + d[0] * r2 + d[1] * r2 * r2 + d[4] * r2 * r2 * r2) /
                          (1 + d[5] * r2 + d[6] * r2 * r2 + d[7] * r2 * r2 * r2);
    xd.x() = x.x() * radial + 2 * d[2] * x.x() * x.y() + d[3] * (r2 + 2 * x.x() * x.x());
    xd.y() = x.y() * radial + d[2] * (r2 + 2 * x.y() * x.y()) + 2 * d[3] * x.x() * x.y();
  }
  return (camera.k * xd.homogeneous()).hnormalized();
}

TEST(CameraModel, UndistortInvertsEachModelAcrossTheImage) {
  CameraIntrinsics rational = EurocCam0();
  rational.distortion = DistortionModel::kRationalPolynomial;
  rational.coefficients = {0.4, -0.1, 0.0005, -0.0003, 0.01, 0.7, -0.05, 0.02};
  CameraIntrinsics fisheye = EurocCam0();
  fisheye.k << 190.98, 0, 254.93, 0, 190.98, 256.89, 0, 0, 1;  // a TUM-VI-like 512x512 fisheye
  fisheye.distortion = DistortionModel::kEquidistant;
  fisheye.coefficients = {0.0034823894022493434, 0.0007150348452162257, -0.0020532361418706202,
                          0.00020293673591811182};
  CameraIntrinsics radial = EurocCam0();  // COLMAP's RADIAL: plumb_bob with k1, k2 only
  radial.coefficients = {-0.2, 0.05, 0.0, 0.0};
  for (const CameraIntrinsics& camera : {EurocCam0(), rational, fisheye, radial}) {
    SCOPED_TRACE(DistortionModelName(camera.distortion));
    ASSERT_TRUE(camera.HasDistortion());
    std::string error;
    ASSERT_TRUE(camera.Validate(&error)) << error;
    // Rays out to the image corners (and the fisheye's to 70 degrees).
    const double extent = camera.distortion == DistortionModel::kEquidistant ? 2.7 : 0.95;
    std::vector<Eigen::Vector2d> ideal, pixels;
    for (double u = -extent; u <= extent + 1e-9; u += extent / 8) {
      for (double v = -0.7 * extent; v <= 0.7 * extent + 1e-9; v += extent / 8) {
        ideal.push_back((camera.k * Eigen::Vector3d(u, v, 1)).hnormalized());
        pixels.push_back(Project(camera, Eigen::Vector2d(u, v)));
      }
    }
    EXPECT_EQ(UndistortPixels(camera, camera.k, &pixels), 0);
    double worst = 0.0;
    for (std::size_t i = 0; i < pixels.size(); ++i) worst = std::max(worst, (pixels[i] - ideal[i]).norm());
    EXPECT_LT(worst, 1e-4) << "px";
    // A resized image: the same rays at the scaled K.
    const Eigen::Matrix3d half = ScaleIntrinsics(camera.k, 0.5);
    const Eigen::Vector2d x(0.6, -0.4);
    CameraIntrinsics at_half = camera;
    at_half.k = half;
    const Eigen::Vector2d undistorted = camera.Undistort(Project(at_half, x), half);
    EXPECT_LT((undistorted - (half * x.homogeneous()).hnormalized()).norm(), 1e-4);
  }
}

TEST(CameraModel, RectifiedCameraLeavesFeaturesBitIdentical) {
  ImageFeatures features;
  features.keypoints_px = {{10.25, 20.5}, {700.125, 470.0}};
  features.strength = {1.0f, 2.0f};
  features.descriptors = cv::Mat::ones(2, 128, CV_32F);
  const ImageFeatures before = features;
  CameraIntrinsics camera = EurocCam0();
  camera.coefficients.assign(5, 0.0);  // plumb_bob, D all zero: what a rectified camera_info carries
  EXPECT_FALSE(camera.HasDistortion());
  EXPECT_EQ(UndistortFeatures(camera, camera.k, &features), 0);
  EXPECT_EQ(features.keypoints_px, before.keypoints_px);
  camera.distortion = DistortionModel::kNone;
  camera.coefficients.clear();
  EXPECT_EQ(UndistortFeatures(camera, camera.k, &features), 0);
  EXPECT_EQ(features.keypoints_px, before.keypoints_px);
}

TEST(CameraModel, KeypointsTheModelCannotInvertAreDroppedWithTheirDescriptors) {
  // A strong pincushion polynomial folds back beyond its calibrated radius:
  // no ideal ray maps to the far corners, so their undistortion cannot
  // reproject onto them.
  CameraIntrinsics camera = EurocCam0();
  camera.coefficients = {-0.9, 0.0, 0.0, 0.0};
  ImageFeatures features;
  features.keypoints_px = {{367.0, 248.0}, {5000.0, 4000.0}, {400.0, 260.0}};
  features.strength = {1.0f, 2.0f, 3.0f};
  features.descriptors = (cv::Mat_<float>(3, 2) << 0, 0, 1, 1, 2, 2);
  EXPECT_EQ(UndistortFeatures(camera, camera.k, &features), 1);
  ASSERT_EQ(features.keypoints_px.size(), 2u);
  EXPECT_EQ(features.strength, (std::vector<float>{1.0f, 3.0f}));
  ASSERT_EQ(features.descriptors.rows, 2);
  EXPECT_EQ(features.descriptors.at<float>(1, 0), 2.0f);
  for (const Eigen::Vector2d& p : features.keypoints_px) EXPECT_TRUE(p.allFinite());
}

// A focal length corrected after the keypoints were undistorted: moving
// them gives what undistorting the raw pixels with the new K gives, which is
// not the old undistorted pixels scaled; for every model.
TEST(CameraModel, UndistortionRedoneWithANewFocalLengthMatchesUndistortingAgain) {
  for (const auto& [model, coefficients] :
       {std::make_pair(DistortionModel::kPlumbBob, std::vector<double>{-0.28, 0.07, 2e-4, 2e-5}),
        std::make_pair(DistortionModel::kEquidistant, std::vector<double>{0.02, -0.01, 0.005, -0.001}),
        std::make_pair(DistortionModel::kRationalPolynomial,
                       std::vector<double>{-0.3, 0.1, 1e-4, -1e-4, 0.0, 0.05, 0.01, 0.0})}) {
    CameraIntrinsics camera = EurocCam0();
    camera.distortion = model;
    camera.coefficients = coefficients;
    Eigen::Matrix3d to_k = camera.k;
    to_k(0, 0) *= 1.03;
    to_k(1, 1) *= 1.03;
    const std::vector<Eigen::Vector2d> raw = {{367.0, 248.0}, {40.0, 30.0}, {700.0, 450.0}, {600.0, 100.0}};
    std::vector<Eigen::Vector2d> moved = raw, direct = raw;
    UndistortPixels(camera, camera.k, &moved);
    UndistortPixels(camera, to_k, &direct);
    const std::vector<Eigen::Vector2d> old_pixels = moved;
    EXPECT_EQ(RedoUndistortion(camera, camera.k, to_k, &moved), 0) << DistortionModelName(model);
    double largest_move = 0.0;
    for (std::size_t i = 0; i < raw.size(); ++i) {
      EXPECT_LT((moved[i] - direct[i]).norm(), 1e-6) << DistortionModelName(model) << " pixel " << i;
      largest_move = std::max(largest_move, (moved[i] - old_pixels[i]).norm());
    }
    EXPECT_GT(largest_move, 1.0) << DistortionModelName(model) << ": the new K moved nothing";
  }
  // A rectified camera's keypoints are the raw ones: nothing to redo.
  CameraIntrinsics rectified = EurocCam0();
  rectified.distortion = DistortionModel::kNone;
  rectified.coefficients.clear();
  Eigen::Matrix3d longer = rectified.k;
  longer(0, 0) *= 1.1;
  longer(1, 1) *= 1.1;
  std::vector<Eigen::Vector2d> pixels = {{10.0, 20.0}};
  EXPECT_EQ(RedoUndistortion(rectified, rectified.k, longer, &pixels), 0);
  EXPECT_EQ(pixels[0], Eigen::Vector2d(10.0, 20.0));
}

TEST(CameraModel, DistortImageAndUndistortImageAreInverses) {
  cv::Mat ideal(240, 320, CV_8U);
  cv::randu(ideal, 0, 255);
  cv::Mat smooth;
  cv::resize(ideal(cv::Rect(0, 0, 40, 30)), smooth, ideal.size(), 0, 0, cv::INTER_CUBIC);
  CameraIntrinsics camera;
  camera.k << 230, 0, 159.5, 0, 230, 119.5, 0, 0, 1;
  camera.distortion = DistortionModel::kPlumbBob;
  camera.coefficients = {-0.25, 0.06, 0.0, 0.0};
  const cv::Mat raw = DistortImage(smooth, camera);
  ASSERT_EQ(raw.size(), smooth.size());
  EXPECT_GT(cv::norm(raw, smooth, cv::NORM_L1) / raw.total(), 3.0);  // it did move the pixels
  const cv::Mat back = UndistortImage(raw, camera);
  // The centre, away from the border the barrel pulls in: resampled twice.
  const cv::Rect centre(80, 60, 160, 120);
  EXPECT_LT(cv::norm(back(centre), smooth(centre), cv::NORM_L1) / centre.area(), 2.0);
  camera.coefficients.assign(4, 0.0);
  EXPECT_EQ(cv::norm(DistortImage(smooth, camera), smooth, cv::NORM_INF), 0.0);
}

// A barrel lens sees beyond the pinhole image of its size: its corners are
// black unless the ideal image is rendered wider, by LensMarginPx. Inside,
// the wider image gives the same lens image.
TEST(CameraModel, ALensImageFromAWiderIdealImageHasNoBlackBorder) {
  CameraIntrinsics camera;
  camera.k << 230, 0, 159.5, 0, 230, 119.5, 0, 0, 1;
  camera.distortion = DistortionModel::kPlumbBob;
  camera.coefficients = {-0.28, 0.07, 0.0, 0.0};
  const cv::Size size(320, 240);
  const int margin = LensMarginPx(camera, size);
  ASSERT_GT(margin, 10);
  cv::Mat noise(size.height + 2 * margin, size.width + 2 * margin, CV_8U), wide;
  cv::randu(noise, 0, 255);
  cv::resize(noise(cv::Rect(0, 0, 40, 30)), wide, noise.size(), 0, 0, cv::INTER_CUBIC);
  cv::max(wide, 1, wide);  // no black in the scene itself
  const cv::Mat ideal = wide(cv::Rect(margin, margin, size.width, size.height)).clone();
  double lowest = 0.0;
  const cv::Mat narrow_lens = DistortImage(ideal, camera);
  cv::minMaxLoc(narrow_lens, &lowest);
  EXPECT_EQ(lowest, 0.0) << "the corners of the lens image see beyond the ideal image";
  const cv::Mat wide_lens = DistortImage(wide, camera, margin);
  ASSERT_EQ(wide_lens.size(), size);
  cv::minMaxLoc(wide_lens, &lowest);
  EXPECT_GT(lowest, 0.0) << "a margin of " << margin << " px leaves black pixels";
  const cv::Rect centre(80, 60, 160, 120);
  EXPECT_LE(cv::norm(wide_lens(centre), narrow_lens(centre), cv::NORM_INF), 2.0);
  camera.coefficients.assign(4, 0.0);
  EXPECT_EQ(LensMarginPx(camera, size), 0);
}

TEST(CameraModel, ParsesNamesAndRefusesUnknownModels) {
  DistortionModel m;
  EXPECT_TRUE(ParseDistortionModel("plumb_bob", &m));
  EXPECT_EQ(m, DistortionModel::kPlumbBob);
  EXPECT_TRUE(ParseDistortionModel("radtan", &m));
  EXPECT_EQ(m, DistortionModel::kPlumbBob);
  EXPECT_TRUE(ParseDistortionModel("radial-tangential", &m));
  EXPECT_TRUE(ParseDistortionModel("equidistant", &m));
  EXPECT_EQ(m, DistortionModel::kEquidistant);
  EXPECT_TRUE(ParseDistortionModel("rational_polynomial", &m));
  EXPECT_EQ(m, DistortionModel::kRationalPolynomial);
  EXPECT_TRUE(ParseDistortionModel("", &m));
  EXPECT_EQ(m, DistortionModel::kNone);
  EXPECT_FALSE(ParseDistortionModel("fov", &m));
  EXPECT_FALSE(ParseDistortionModel("double_sphere", &m));

  CameraIntrinsics c = EurocCam0();
  std::string error;
  c.coefficients = {0.1, 0.2, 0.3};  // plumb_bob needs 4 or 5
  EXPECT_FALSE(c.Validate(&error));
  EXPECT_NE(error.find("plumb_bob"), std::string::npos) << error;
  c.distortion = DistortionModel::kNone;
  c.coefficients = {0.1, 0, 0, 0, 0};  // a non-zero D with no model: refused, not ignored
  EXPECT_FALSE(c.Validate(&error));
  c.distortion = DistortionModel::kEquidistant;
  c.coefficients = {0.1, 0, 0, std::nan("")};
  EXPECT_FALSE(c.Validate(&error));
  c.coefficients = {0.1, 0, 0, 0, 0, 0, 0, 0};  // padded with zeros, as some drivers send D
  EXPECT_TRUE(c.Validate(&error)) << error;

  CameraIntrinsics spec = EurocCam0();
  EXPECT_TRUE(ParseDistortionSpec("equidistant:0.1,0.01,0,0", &spec, &error)) << error;
  EXPECT_EQ(spec.distortion, DistortionModel::kEquidistant);
  EXPECT_EQ(spec.coefficients.size(), 4u);
  EXPECT_FALSE(ParseDistortionSpec("kannala:0.1", &spec, &error));
  EXPECT_NE(error.find("kannala"), std::string::npos) << error;
  EXPECT_FALSE(ParseDistortionSpec("plumb_bob:0.1,x", &spec, &error));
}

TEST(CameraModel, ReadsRosEurocAndKalibrCameraFiles) {
  const fs::path dir = fs::temp_directory_path() / ("rotavg_camfile_" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::ofstream(dir / "ros.yaml") << "image_width: 752\nimage_height: 480\ncamera_name: cam0\n"
                                     "camera_matrix:\n  rows: 3\n  cols: 3\n"
                                     "  data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]\n"
                                     "distortion_model: plumb_bob\n"
                                     "distortion_coefficients:\n  rows: 1\n  cols: 5\n"
                                     "  data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0]\n";
  std::ofstream(dir / "sensor.yaml") << "%YAML:1.0\nsensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n"
                                        "  data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]\n"
                                        "rate_hz: 20\nresolution: [752, 480]\ncamera_model: pinhole\n"
                                        "intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv\n"
                                        "distortion_model: radial-tangential\n"
                                        "distortion_coefficients: [-0.28340811, 0.07395907, 0.00019359, "
                                        "1.76187114e-05]\n";
  std::ofstream(dir / "camchain.yaml") << "cam0:\n  camera_model: pinhole\n  distortion_coeffs: [0.01, 0.002, 0, 0]\n"
                                          "  distortion_model: equidistant\n  intrinsics: [190, 191, 254, 256]\n"
                                          "  resolution: [512, 512]\ncam1:\n  T_cn_cnm1:\n"
                                          "  - [1.0, 0.0, 0.0, -0.1]\n  - [0.0, 1.0, 0.0, 0.0]\n"
                                          "  - [0.0, 0.0, 1.0, 0.0]\n  - [0.0, 0.0, 0.0, 1.0]\n"
                                          "  camera_model: pinhole\n  distortion_coeffs: [0.02, 0.001, 0, 0]\n"
                                          "  distortion_model: equidistant\n  intrinsics: [192, 193, 255, 257]\n"
                                          "  resolution: [512, 512]\n";
  std::ofstream(dir / "unknown_model.yaml") << "intrinsics: [458, 457, 367, 248]\ndistortion_model: fov\n"
                                               "distortion_coefficients: [0.9]\n";
  std::ofstream(dir / "omni.yaml") << "cam0:\n  camera_model: omni\n  intrinsics: [0.8, 458, 457, 367, 248]\n";
  std::ofstream(dir / "wrong_count.yaml") << "intrinsics: [458, 457, 367, 248]\ndistortion_model: plumb_bob\n"
                                             "distortion_coefficients: [0.1, 0.2]\n";
  std::ofstream(dir / "cameras.txt") << "1 OPENCV_FISHEYE 512 512 190 191 254.5 256.5 0.01 0.002 0 0\n";
  std::ofstream(dir / "fov.txt") << "1 FOV 512 512 190 191 254.5 256.5 0.9\n";

  CameraIntrinsics c;
  std::string error;
  int width = 0, height = 0;
  ASSERT_TRUE(ReadCameraIntrinsics((dir / "ros.yaml").string(), &c, &error, &width, &height)) << error;
  EXPECT_EQ(c.distortion, DistortionModel::kPlumbBob);
  EXPECT_DOUBLE_EQ(c.k(1, 2), 248.375);
  EXPECT_DOUBLE_EQ(c.coefficients[0], -0.28340811);
  EXPECT_EQ(width, 752);
  EXPECT_EQ(height, 480);
  CameraIntrinsics euroc;
  ASSERT_TRUE(ReadCameraIntrinsics((dir / "sensor.yaml").string(), &euroc, &error, &width, &height)) << error;
  EXPECT_EQ(euroc.k, c.k);
  EXPECT_EQ(euroc.distortion, DistortionModel::kPlumbBob);
  EXPECT_EQ(euroc.coefficients.size(), 4u);
  EXPECT_EQ(width, 752);
  ASSERT_TRUE(ReadCameraIntrinsics((dir / "camchain.yaml").string(), &c, &error)) << error;
  EXPECT_EQ(c.distortion, DistortionModel::kEquidistant);
  EXPECT_DOUBLE_EQ(c.k(0, 0), 190.0);
  ASSERT_TRUE(ReadCameraIntrinsics((dir / "camchain.yaml").string(), &c, &error, nullptr, nullptr, "cam1")) << error;
  EXPECT_DOUBLE_EQ(c.k(0, 0), 192.0);
  EXPECT_DOUBLE_EQ(c.coefficients[0], 0.02);
  EXPECT_FALSE(ReadCameraIntrinsics((dir / "camchain.yaml").string(), &c, &error, nullptr, nullptr, "cam7"));
  EXPECT_NE(error.find("cam7"), std::string::npos) << error;
  ASSERT_TRUE(ReadCameraIntrinsics((dir / "cameras.txt").string(), &c, &error)) << error;
  EXPECT_EQ(c.distortion, DistortionModel::kEquidistant);
  EXPECT_DOUBLE_EQ(c.k(0, 2), 254.0);  // COLMAP's pixel convention moved into OpenCV's
  EXPECT_EQ(c.coefficients.size(), 4u);
  // Refused, naming the file and the model.
  EXPECT_FALSE(ReadCameraIntrinsics((dir / "unknown_model.yaml").string(), &c, &error));
  EXPECT_NE(error.find("'fov'"), std::string::npos) << error;
  EXPECT_NE(error.find("unknown_model.yaml"), std::string::npos) << error;
  EXPECT_FALSE(ReadCameraIntrinsics((dir / "omni.yaml").string(), &c, &error));
  EXPECT_NE(error.find("camera_model 'omni' is not supported"), std::string::npos) << error;
  EXPECT_FALSE(ReadCameraIntrinsics((dir / "wrong_count.yaml").string(), &c, &error));
  EXPECT_FALSE(ReadCameraIntrinsics((dir / "fov.txt").string(), &c, &error));
  EXPECT_NE(error.find("FOV"), std::string::npos) << error;
  fs::remove_all(dir);
}

// The calibrated rotation cam0 -> cam1 of EuRoC's stereo rig (x_cam1 =
// R x_cam0 + t) from the two sensor.yaml files' T_BS (camera-to-body).
Eigen::Matrix3d EurocStereoRotation(const std::string& mav0) {
  Eigen::Matrix3d r_bs[2];
  for (int c = 0; c < 2; ++c) {
    cv::FileStorage fs(mav0 + "/cam" + std::to_string(c) + "/sensor.yaml", cv::FileStorage::READ);
    std::vector<double> t;
    fs["T_BS"]["data"] >> t;
    EXPECT_EQ(t.size(), 16u);
    for (int i = 0; i < 9; ++i) r_bs[c](i / 3, i % 3) = t[4 * (i / 3) + i % 3];
  }
  return r_bs[1].transpose() * r_bs[0];
}

// The real stereo pair: its relative rotation from the raw images' SIFT
// matches agrees with the calibration only when the keypoints are
// undistorted.
TEST(CameraModel, EurocStereoPairMatchesItsCalibrationOnlyWhenUndistorted) {
  const std::string mav0 = SharedDataPath("euroc_v1_01_micro/mav0");
  ROTAVG_REQUIRE_SHARED_DATA(mav0);
  CameraIntrinsics cam[2];
  std::string error;
  for (int c = 0; c < 2; ++c) {
    ASSERT_TRUE(ReadCameraIntrinsics(mav0 + "/cam" + std::to_string(c) + "/sensor.yaml", &cam[c], &error)) << error;
    ASSERT_TRUE(cam[c].HasDistortion());
  }
  const Eigen::Matrix3d r10 = EurocStereoRotation(mav0);
  EXPECT_NEAR(RadToDeg(RotationAngleRad(r10)), 0.818, 0.01);
  std::vector<std::string> names;
  for (const auto& e : fs::directory_iterator(mav0 + "/cam0/data")) names.push_back(e.path().filename().string());
  std::sort(names.begin(), names.end());
  ASSERT_GE(names.size(), 20u);
  std::vector<double> raw_deg, undistorted_deg;
  for (std::size_t f = 0; f < names.size(); f += names.size() / 5) {
    ImageFeatures features[2];
    for (int c = 0; c < 2; ++c) {
      const cv::Mat image = cv::imread(mav0 + "/cam" + std::to_string(c) + "/data/" + names[f], cv::IMREAD_GRAYSCALE);
      ASSERT_FALSE(image.empty()) << names[f];
      features[c] = ExtractFeatures(image, FeatureOptions());
    }
    const auto matches = MatchFeatures(features[0], features[1]);
    for (bool undistort : {false, true}) {
      std::vector<Eigen::Vector2d> p[2];
      for (const auto& [i, j] : matches) {
        p[0].push_back(features[0].keypoints_px[i]);
        p[1].push_back(features[1].keypoints_px[j]);
      }
      if (undistort) {
        for (int c = 0; c < 2; ++c) EXPECT_EQ(UndistortPixels(cam[c], cam[c].k, &p[c]), 0);
      }
      const RelativePoseResult pose = EstimateRelativePoseWithCovariance(p[0], p[1], cam[0].k, cam[1].k);
      ASSERT_TRUE(pose.success) << names[f];
      (undistort ? undistorted_deg : raw_deg).push_back(RadToDeg(RotationAngleRad(pose.rotation * r10.transpose())));
    }
  }
  std::sort(raw_deg.begin(), raw_deg.end());
  std::sort(undistorted_deg.begin(), undistorted_deg.end());
  const double raw_median = raw_deg[raw_deg.size() / 2], undistorted_median = undistorted_deg[undistorted_deg.size() / 2];
  std::cout << "EuRoC cam0-cam1 rotation error, median over " << raw_deg.size() << " stereo frames: raw keypoints "
            << raw_median << " deg, undistorted " << undistorted_median << " deg\n";
  EXPECT_GT(raw_median, 1.0);
  EXPECT_LT(undistorted_median, 0.2);
}

// A lens keeps the undistorted keypoints from scaling with the focal
// length: a strong barrel lens (EuRoC's k1 = -0.28) at the corners of a
// 640 x 480 image by a large fraction of what the focal length does, a mild
// one (lund_door's k1 = -0.034 over a narrower field) by little, no lens
// not at all.
// The camera_info check measures a lens as a division model; the front end
// undistorts by plumb_bob. The fitted plumb_bob lens undistorts every pixel
// of the image as the division model does, within a twentieth of a pixel,
// for a barrel lens (47 px at the corners of 640 x 480 at f = 420) and a
// pincushion one; no lens for lambda 0 or one that folds over.
TEST(CameraIntrinsics, APlumbBobLensUndistortsAsTheDivisionModelItIsFittedTo) {
  Eigen::Matrix3d k;
  k << 420, 0, 320, 0, 420, 240, 0, 0, 1;
  for (const double lambda : {-0.12, 0.05}) {
    const CameraIntrinsics lens = PlumbBobFromDivision(k, lambda, CornerRadius(k));
    ASSERT_TRUE(lens.HasDistortion()) << lambda;
    EXPECT_EQ(lens.distortion, DistortionModel::kPlumbBob);
    std::string error;
    EXPECT_TRUE(lens.Validate(&error)) << error;
    double worst_px = 0.0, corner_shift_px = 0.0;
    for (int y = 0; y <= 480; y += 40) {
      for (int x = 0; x <= 640; x += 40) {
        const Eigen::Vector2d pixel(x, y);
        const Eigen::Vector2d d = (k.inverse() * pixel.homogeneous()).hnormalized();
        const Eigen::Vector2d division = (k * (d / (1.0 + lambda * d.squaredNorm())).homogeneous()).hnormalized();
        const Eigen::Vector2d fitted = lens.Undistort(pixel, k);
        worst_px = std::max(worst_px, (fitted - division).norm());
        corner_shift_px = std::max(corner_shift_px, (division - pixel).norm());
      }
    }
    EXPECT_LT(worst_px, 0.05) << lambda;
    EXPECT_GT(corner_shift_px, 15.0) << lambda;  // a lens that matters
  }
  EXPECT_FALSE(PlumbBobFromDivision(k, 0.0, CornerRadius(k)).HasDistortion());
  EXPECT_FALSE(PlumbBobFromDivision(k, -2.0, CornerRadius(k)).HasDistortion());  // 1 + lambda r^2 < 0: folds
  EXPECT_NEAR(CornerRadius(k), std::hypot(320.0, 240.0) / 420.0, 1e-12);
}

TEST(CameraIntrinsics, ALensKeepsKeypointsFromScalingWithTheFocalLength) {
  CameraIntrinsics none;
  none.k << 407.4, 0, 319.5, 0, 407.4, 239.5, 0, 0, 1;
  EXPECT_EQ(FocalScalingError(none, none.k, cv::Size(640, 480)), 0.0);
  CameraIntrinsics strong = none;
  strong.distortion = DistortionModel::kPlumbBob;
  strong.coefficients = {-0.28, 0.07, 0.0002, 0.00002};
  const double strong_error = FocalScalingError(strong, strong.k, cv::Size(640, 480));
  CameraIntrinsics mild;
  mild.k << 608.8, 0, 162, 0, 608.8, 242, 0, 0, 1;  // lund_door at a quarter of 1296 x 1936
  mild.distortion = DistortionModel::kPlumbBob;
  mild.coefficients = {-0.0336, 0, 0, 0};
  const double mild_error = FocalScalingError(mild, mild.k, cv::Size(324, 484));
  std::cout << "strong " << strong_error << ", mild " << mild_error << "\n";
  EXPECT_GT(strong_error, 0.1);  // 0.14
  EXPECT_LT(mild_error, 0.03);   // 0.016
  // The same lens at half the resolution (K scaled with the image): the same.
  Eigen::Matrix3d half = strong.k;
  half.topRows<2>() *= 0.5;
  EXPECT_NEAR(FocalScalingError(strong, half, cv::Size(320, 240)), strong_error, 0.02);
}

}  // namespace
}  // namespace rotation_averaging
