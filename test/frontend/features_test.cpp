#include "rotation_averaging/frontend/features/features.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include <opencv2/core.hpp>
#include <opencv2/features2d.hpp>

#include "rotation_averaging/sim/rig_scene.h"

namespace rotation_averaging {
namespace {

// A rendered view (textured walls), as the detectors see a camera image.
cv::Mat TexturedImage() {
  RigSceneOptions o;
  o.noise_grey = 0.0;
  const RigScene scene(o);
  return scene.Render(7, 0);
}

// Where a detector puts a keypoint minus where it is, along x: a keypoint at
// x in the image and at W - 1 - x' in its mirror image gives
// (x + x' - (W - 1)) / 2, whatever the scene.
double MirrorBiasPx(const std::vector<Eigen::Vector2d>& points, const std::vector<Eigen::Vector2d>& mirrored,
                    int width) {
  double sum = 0.0;
  int n = 0;
  for (const Eigen::Vector2d& p : points) {
    const Eigen::Vector2d* nearest = nullptr;
    double best = 1.0;  // pixels: a keypoint and its mirror are far closer
    for (const Eigen::Vector2d& q : mirrored) {
      const double d = std::hypot(width - 1 - q.x() - p.x(), q.y() - p.y());
      if (d < best) {
        best = d;
        nearest = &q;
      }
    }
    if (nearest == nullptr) continue;
    sum += 0.5 * (p.x() + nearest->x() - (width - 1));
    ++n;
  }
  EXPECT_GT(n, 100);
  return n > 0 ? sum / n : std::nan("");
}

// The mirror bias of ExtractFeatures' SIFT keypoints on the rendered view,
// detected at `downsample` of its resolution.
double ExtractedMirrorBiasPx(double downsample) {
  const cv::Mat image = TexturedImage();
  cv::Mat mirror;
  cv::flip(image, mirror, 1);
  FeatureOptions options;
  options.type = FeatureType::kSift;
  options.max_features = 2000;
  options.downsample = downsample;
  const ImageFeatures a = ExtractFeatures(image, options), b = ExtractFeatures(mirror, options);
  EXPECT_EQ(a.width, static_cast<int>(std::lround(image.cols * downsample)));
  return MirrorBiasPx(a.keypoints_px, b.keypoints_px, a.width);
}

TEST(Features, SiftKeypointsAreAtTheirPixelCentres) {
  EXPECT_NEAR(ExtractedMirrorBiasPx(1.0), 0.0, 0.02);

  // What OpenCV's SIFT itself reports, and ExtractFeatures takes back. If a
  // later OpenCV stops doubling the image this way, this fails and the
  // correction must go.
  const cv::Mat image = TexturedImage();
  cv::Mat mirror;
  cv::flip(image, mirror, 1);
  const cv::Ptr<cv::SIFT> sift = cv::SIFT::create(2000);
  std::vector<cv::KeyPoint> ka, kb;
  sift->detect(image, ka);
  sift->detect(mirror, kb);
  const auto points = [](const std::vector<cv::KeyPoint>& k) {
    std::vector<Eigen::Vector2d> p;
    for (const cv::KeyPoint& x : k) p.emplace_back(x.pt.x, x.pt.y);
    return p;
  };
  EXPECT_NEAR(MirrorBiasPx(points(ka), points(kb), image.cols), kSiftUpscaleOffsetPx, 0.02);
}

TEST(Features, DownsampledSiftKeypointsAreAtTheirPixelCentresToo) {
  EXPECT_NEAR(ExtractedMirrorBiasPx(0.5), 0.0, 0.02);
}

}  // namespace
}  // namespace rotation_averaging
