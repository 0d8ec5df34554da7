#include "rotation_averaging/frontend/features/features.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
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

// SIFT matching is exact: the mutual ratio-test matches of a naive double
// loop over every pair of descriptors, across more rows than one block of
// the matrix product (256), with planted correspondences among look-alikes.
TEST(Features, SiftMatchesAreTheExactMutualRatioMatches) {
  cv::RNG rng(7);
  ImageFeatures a, b;
  a.type = b.type = FeatureType::kSift;
  a.descriptors.create(700, 128, CV_32F);
  b.descriptors.create(600, 128, CV_32F);
  rng.fill(a.descriptors, cv::RNG::UNIFORM, 0.0, 60.0);
  rng.fill(b.descriptors, cv::RNG::UNIFORM, 0.0, 60.0);
  // Every third feature of b is one of a's, moved by noise of several sizes
  // (some fail the ratio test against the random others).
  for (int j = 0; j < b.descriptors.rows; j += 3) {
    cv::Mat noise(1, 128, CV_32F);
    rng.fill(noise, cv::RNG::NORMAL, 0.0, 1.0 + (j % 7) * 2.5);
    b.descriptors.row(j) = a.descriptors.row(j + 50) + noise;
  }
  a.keypoints_px.assign(a.descriptors.rows, Eigen::Vector2d::Zero());
  b.keypoints_px.assign(b.descriptors.rows, Eigen::Vector2d::Zero());
  const MatchOptions options;
  auto nearest_two = [](const cv::Mat& from, int row, const cv::Mat& to, int* index, double* d0, double* d1) {
    *d0 = *d1 = std::numeric_limits<double>::infinity();
    for (int k = 0; k < to.rows; ++k) {
      const double d = cv::norm(from.row(row), to.row(k), cv::NORM_L2SQR);
      if (d < *d0) {
        *d1 = *d0;
        *d0 = d;
        *index = k;
      } else if (d < *d1) {
        *d1 = d;
      }
    }
  };
  std::vector<std::pair<int, int>> expected;
  const double r2 = options.ratio * options.ratio;
  for (int i = 0; i < a.descriptors.rows; ++i) {
    int j = -1, back = -1;
    double d0, d1, e0, e1;
    nearest_two(a.descriptors, i, b.descriptors, &j, &d0, &d1);
    if (!(d0 < r2 * d1)) continue;
    nearest_two(b.descriptors, j, a.descriptors, &back, &e0, &e1);
    if (back == i && e0 < r2 * e1) expected.emplace_back(i, j);
  }
  ASSERT_GT(expected.size(), 100u);
  EXPECT_EQ(MatchFeatures(a, b, options), expected);
  // The ratio test alone, one direction (as retrieval by voting queries).
  const FeatureIndex index(b);
  const std::vector<int> one_way = index.RatioMatches(a.descriptors, options.ratio);
  int agreeing = 0;
  for (const auto& [i, j] : expected) agreeing += one_way[i] == j;
  EXPECT_EQ(agreeing, static_cast<int>(expected.size()));
}

}  // namespace
}  // namespace rotation_averaging
