// Public header of rotation_averaging::frontend (docs/embedding.md).
// Local features and matching for the two-view front end (OpenCV).
#ifndef ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURES_H_
#define ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURES_H_

#include <Eigen/Core>
#include <memory>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

namespace rotation_averaging {

enum class FeatureType { kSift, kOrb };
const char* FeatureTypeName(FeatureType type);
bool ParseFeatureType(const std::string& text, FeatureType* type);
std::string FeatureTypeChoices();  // "sift, orb", for messages

struct FeatureOptions {
  FeatureType type = FeatureType::kSift;
  int max_features = 8000;      // strongest kept
  // Images are resized by this factor before detection (1 = full resolution,
  // 0.25 = a quarter of the width); keypoints are returned in the coordinates
  // of the resized image, whose intrinsics are scaled to match.
  double downsample = 1.0;
};

struct ImageFeatures {
  std::vector<Eigen::Vector2d> keypoints_px;  // in the (possibly resized) image
  std::vector<float> strength;                // detector response per keypoint (stronger first to keep)
  // One row per keypoint: SIFT as CV_32F (or, compacted, CV_8U with 64
  // columns: two 4-bit values per byte, see CompactFeatures), ORB as CV_8U.
  cv::Mat descriptors;
  FeatureType type = FeatureType::kSift;
  int width = 0, height = 0;                  // of the image features were detected in
  // Vocabulary word of each keypoint (Vocabulary::Assign); empty without one.
  std::vector<int> words;
};

// Detects and describes features in an 8-bit image (grey or colour).
// Keypoints are in pixel-centre coordinates (pixel (0, 0) spans
// [-0.5, 0.5]^2), as OpenCV's K and undistortion take them; SIFT's own
// quarter-pixel offset is removed (kSiftUpscaleOffsetPx).
ImageFeatures ExtractFeatures(const cv::Mat& image, const FeatureOptions& options);

// Where OpenCV's SIFT puts a keypoint, minus where it is, in both axes
// (pixels): its doubled image is a linear resize (pixel X at X/2 - 1/4),
// reported at X/2.
constexpr double kSiftUpscaleOffsetPx = 0.25;

struct MatchOptions {
  double ratio = 0.8;          // Lowe's ratio test: best < ratio * second best
  bool mutual = true;          // keep only mutual nearest neighbours
};

// What matching needs of one image's descriptors, prepared once and reused
// for every pair the image is in: SIFT as float rows, compared exhaustively
// (exact nearest neighbours by L2, a blocked matrix product), and for an
// image of more than 5,000 features FLANN's kd-trees as well (two such
// images are matched by the trees, whose cost grows with the feature counts'
// sum where the exhaustive comparison's grows with their product; the trees
// are seeded: the same matches run after run); ORB by brute-force Hamming.
class FeatureIndex {
 public:
  explicit FeatureIndex(const ImageFeatures& features);
  ~FeatureIndex();
  // For each query row, the nearest neighbour in this index if it passes the
  // ratio test, else -1.
  std::vector<int> RatioMatches(const cv::Mat& query, double ratio) const;
  // The descriptors as prepared (SIFT: continuous CV_32F rows).
  const cv::Mat& Descriptors() const;
  bool HasTrees() const;  // SIFT beyond 5,000 features: kd-trees built

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

// Index pairs (into a.keypoints_px, b.keypoints_px).
std::vector<std::pair<int, int>> MatchFeatures(const ImageFeatures& a, const ImageFeatures& b,
                                               const MatchOptions& options = MatchOptions());
std::vector<std::pair<int, int>> MatchFeatures(const ImageFeatures& a, const FeatureIndex& index_a,
                                               const ImageFeatures& b, const FeatureIndex& index_b,
                                               const MatchOptions& options = MatchOptions());

// Matching confined to groups: feature i of `a` (in group group_a[i]) is
// only compared with the features j of `b` that list that group among theirs
// (groups_b holds k groups per feature, row-major, k = groups_b.size() /
// b's features; negative: none), by exact L2 (SIFT) or Hamming (ORB)
// distance, with the ratio test against the second best of those compared
// and, if asked, the mutual check. With the branches of a vocabulary tree as
// groups this is DBoW2's / ORB-SLAM's matching by vocabulary: no index to
// build, a small fraction of the distances of a full search; giving b its
// two nearest branches recovers most matches that fall across a boundary.
std::vector<std::pair<int, int>> MatchFeaturesByGroup(const ImageFeatures& a, const std::vector<int>& group_a,
                                                      const ImageFeatures& b, const std::vector<int>& groups_b,
                                                      const MatchOptions& options = MatchOptions());

// What a keyframe keeps for verification once it leaves the recent window:
// `max_features` features spread over a 4 x 4 grid of the image (the best of
// every cell before the second best of any), the best being those of highest
// priority (one value per feature; none: all equal), then the strongest;
// kept in their original order, with SIFT descriptors packed at 4 bits per
// value (the square root of each value quantised to 16 levels: 64 bytes per
// descriptor, matched as the values of those levels). Returns all the
// features, packed, when there are no more than `max_features`.
ImageFeatures CompactFeatures(const ImageFeatures& features, int max_features,
                              const std::vector<std::uint16_t>& priority = {});
// Float descriptors for matching (a copy only when they are bytes of SIFT).
ImageFeatures MatchableFeatures(const ImageFeatures& features);
// The SIFT descriptors as CV_32F rows of 128 values, whether they are
// floats, bytes or packed (compact).
cv::Mat SiftDescriptorsAsFloat(const ImageFeatures& features);
// Bytes held by the keypoints, strengths and descriptors.
std::size_t FeatureMemoryBytes(const ImageFeatures& features);

// Intrinsics of an image resized by `downsample` (pixel centres preserved).
Eigen::Matrix3d ScaleIntrinsics(const Eigen::Matrix3d& k, double downsample);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURES_H_
