#include "rotation_averaging/frontend/features/features.h"

#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <map>
#include <cstdlib>
#include <opencv2/features2d.hpp>
#include <opencv2/flann.hpp>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/util/blas_threads.h"

namespace rotation_averaging {

const char* FeatureTypeName(FeatureType type) { return type == FeatureType::kOrb ? "orb" : "sift"; }

bool ParseFeatureType(const std::string& text, FeatureType* type) {
  if (text == "sift") *type = FeatureType::kSift;
  else if (text == "orb") *type = FeatureType::kOrb;
  else return false;
  return true;
}

std::string FeatureTypeChoices() {
  return std::string(FeatureTypeName(FeatureType::kSift)) + ", " + FeatureTypeName(FeatureType::kOrb);
}

Eigen::Matrix3d ScaleIntrinsics(const Eigen::Matrix3d& k, double s) {
  // Pixel (u, v) at full resolution maps to ((u + 0.5) s - 0.5, (v + 0.5) s - 0.5).
  Eigen::Matrix3d scaled = k;
  scaled(0, 0) *= s;
  scaled(1, 1) *= s;
  scaled(0, 1) *= s;
  scaled(0, 2) = (k(0, 2) + 0.5) * s - 0.5;
  scaled(1, 2) = (k(1, 2) + 0.5) * s - 0.5;
  return scaled;
}

ImageFeatures ExtractFeatures(const cv::Mat& image, const FeatureOptions& options) {
  ImageFeatures out;
  out.type = options.type;
  if (image.empty()) return out;
  cv::Mat grey;
  if (image.channels() == 3) cv::cvtColor(image, grey, cv::COLOR_BGR2GRAY);
  else if (image.channels() == 4) cv::cvtColor(image, grey, cv::COLOR_BGRA2GRAY);
  else grey = image;
  if (options.downsample > 0.0 && options.downsample != 1.0) {
    cv::resize(grey, grey, cv::Size(), options.downsample, options.downsample, cv::INTER_AREA);
  }
  out.width = grey.cols;
  out.height = grey.rows;
  cv::Ptr<cv::Feature2D> detector;
  if (options.type == FeatureType::kOrb) {
    detector = cv::ORB::create(options.max_features);
  } else {
    detector = cv::SIFT::create(options.max_features);
  }
  std::vector<cv::KeyPoint> keypoints;
  detector->detectAndCompute(grey, cv::noArray(), keypoints, out.descriptors);
  // OpenCV's SIFT looks for keypoints in the image doubled by a linear
  // resize, whose pixel X lies at X / 2 - 1/4 of the input, and reports them at
  // X / 2: every keypoint a quarter pixel right of and below its place
  // (opencv/opencv#23123). Taken back, a keypoint has the pixel-centre
  // coordinates K is given in. ORB finds whole pixels per pyramid level and
  // is left as it is.
  const double offset = options.type == FeatureType::kSift ? kSiftUpscaleOffsetPx : 0.0;
  out.keypoints_px.reserve(keypoints.size());
  out.strength.reserve(keypoints.size());
  for (const cv::KeyPoint& k : keypoints) {
    out.keypoints_px.emplace_back(k.pt.x - offset, k.pt.y - offset);
    out.strength.push_back(k.response);
  }
  return out;
}

namespace {
// Cells per side of the grid compaction spreads the kept features over.
constexpr int kCompactGrid = 4;

// Compact SIFT descriptors keep 4 bits per value: the square root of the
// value (OpenCV's are whole numbers in [0, 255]) quantised uniformly to 16
// levels, fine where SIFT's values crowd (near zero) and coarse where they are
// rare. Two values per byte, 64 bytes per descriptor instead of 128: twice the
// features in the same memory.
constexpr int kSiftDims = 128;
constexpr int kPackedSiftCols = kSiftDims / 2;

std::uint8_t SiftCode(float value) {
  const double t = std::sqrt(std::clamp(static_cast<double>(value), 0.0, 255.0) / 255.0);
  return static_cast<std::uint8_t>(std::lround(15.0 * t));
}

float SiftLevel(int code) {
  const double t = code / 15.0;
  return static_cast<float>(255.0 * t * t);
}

// The two values of every packed byte.
const std::array<std::array<float, 2>, 256>& PackedSiftValues() {
  static const std::array<std::array<float, 2>, 256> table = [] {
    std::array<std::array<float, 2>, 256> t{};
    for (int b = 0; b < 256; ++b) t[b] = {SiftLevel(b & 15), SiftLevel(b >> 4)};
    return t;
  }();
  return table;
}

bool IsPackedSift(const ImageFeatures& features) {
  return features.type == FeatureType::kSift && features.descriptors.type() == CV_8U &&
         features.descriptors.cols == kPackedSiftCols;
}

cv::Mat PackSift(const cv::Mat& descriptors) {
  cv::Mat floats;
  descriptors.convertTo(floats, CV_32F);
  cv::Mat packed(floats.rows, kPackedSiftCols, CV_8U);
  for (int r = 0; r < floats.rows; ++r) {
    const float* in = floats.ptr<float>(r);
    std::uint8_t* out = packed.ptr<std::uint8_t>(r);
    for (int c = 0; c < kPackedSiftCols; ++c) out[c] = SiftCode(in[2 * c]) | (SiftCode(in[2 * c + 1]) << 4);
  }
  return packed;
}

}  // namespace

cv::Mat SiftDescriptorsAsFloat(const ImageFeatures& features) {
  cv::Mat floats;
  if (!IsPackedSift(features)) {
    features.descriptors.convertTo(floats, CV_32F);
    return floats;
  }
  const auto& values = PackedSiftValues();
  floats.create(features.descriptors.rows, kSiftDims, CV_32F);
  for (int r = 0; r < floats.rows; ++r) {
    const std::uint8_t* in = features.descriptors.ptr<std::uint8_t>(r);
    float* out = floats.ptr<float>(r);
    for (int c = 0; c < kPackedSiftCols; ++c) {
      out[2 * c] = values[in[c]][0];
      out[2 * c + 1] = values[in[c]][1];
    }
  }
  return floats;
}

ImageFeatures CompactFeatures(const ImageFeatures& features, int max_features,
                              const std::vector<std::uint16_t>& priority) {
  ImageFeatures out;
  out.type = features.type;
  out.width = features.width;
  out.height = features.height;
  const int n = static_cast<int>(features.keypoints_px.size());
  std::vector<int> keep(n);
  for (int i = 0; i < n; ++i) keep[i] = i;
  const bool strength = static_cast<int>(features.strength.size()) == n;
  const bool prioritised = static_cast<int>(priority.size()) == n;
  if (n > max_features) {
    // Better: higher priority, then stronger, then lower index.
    auto better = [&](int a, int b) {
      if (prioritised && priority[a] != priority[b]) return priority[a] > priority[b];
      if (strength && features.strength[a] != features.strength[b]) return features.strength[a] > features.strength[b];
      return a < b;
    };
    // Rank within cells of a grid over the image, then take the best of
    // every cell before the second best of any: features that the views
    // seen so far matched cover the part of the image those views overlap,
    // and a revisit from elsewhere needs the rest.
    std::vector<int> rank(n, 0);
    if (features.width > 0 && features.height > 0) {
      std::vector<std::vector<int>> cells(kCompactGrid * kCompactGrid);
      for (int i = 0; i < n; ++i) {
        const Eigen::Vector2d& p = features.keypoints_px[i];
        const int cx = std::clamp(static_cast<int>(p.x() * kCompactGrid / features.width), 0, kCompactGrid - 1);
        const int cy = std::clamp(static_cast<int>(p.y() * kCompactGrid / features.height), 0, kCompactGrid - 1);
        cells[cy * kCompactGrid + cx].push_back(i);
      }
      for (std::vector<int>& cell : cells) {
        std::sort(cell.begin(), cell.end(), better);
        for (std::size_t r = 0; r < cell.size(); ++r) rank[cell[r]] = static_cast<int>(r);
      }
    }
    std::sort(keep.begin(), keep.end(), [&](int a, int b) { return rank[a] != rank[b] ? rank[a] < rank[b] : better(a, b); });
    keep.resize(std::max(0, max_features));
    std::sort(keep.begin(), keep.end());  // back in the original order
  }
  cv::Mat kept_descriptors;
  if (!features.descriptors.empty()) {
    kept_descriptors.create(static_cast<int>(keep.size()), features.descriptors.cols, features.descriptors.type());
  }
  for (std::size_t r = 0; r < keep.size(); ++r) {
    out.keypoints_px.push_back(features.keypoints_px[keep[r]]);
    if (static_cast<int>(features.strength.size()) == n) out.strength.push_back(features.strength[keep[r]]);
    if (!features.descriptors.empty()) features.descriptors.row(keep[r]).copyTo(kept_descriptors.row(static_cast<int>(r)));
    if (static_cast<int>(features.words.size()) == n) out.words.push_back(features.words[keep[r]]);
  }
  const bool sift = features.type == FeatureType::kSift && features.descriptors.cols == kSiftDims;
  out.descriptors = sift ? PackSift(kept_descriptors) : kept_descriptors;
  return out;
}

ImageFeatures MatchableFeatures(const ImageFeatures& features) {
  if (features.type != FeatureType::kSift || features.descriptors.type() == CV_32F) return features;
  ImageFeatures out = features;
  out.descriptors = SiftDescriptorsAsFloat(features);
  return out;
}

std::size_t FeatureMemoryBytes(const ImageFeatures& features) {
  return features.keypoints_px.capacity() * sizeof(Eigen::Vector2d) + features.strength.capacity() * sizeof(float) +
         features.words.capacity() * sizeof(int) + features.descriptors.total() * features.descriptors.elemSize();
}

namespace {

// Rows of query compared with every row of the index at a time: a block of
// squared distances stays within a few MiB whatever the feature count, so a
// pool of threads matching pairs holds little.
constexpr int kMatchBlockRows = 256;
// SIFT images with more features than this also get FLANN's kd-trees, and
// two such images are matched by them rather than exhaustively: at this
// count the exhaustive comparison and two tree searches cost about the same
// on one core, and beyond it the searches are cheaper.
constexpr int kTreeMinFeatures = 5000;
// FLANN's randomised kd-trees draw from std::rand and cv::theRNG(): fixed
// seeds make the index, and so the matches, the same run after run.
constexpr unsigned kFlannSeed = 20230618;

using RowMajorFloats = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// The nearest and second-nearest squared distance, and the nearest's index.
struct NearestTwo {
  float d0 = std::numeric_limits<float>::infinity(), d1 = std::numeric_limits<float>::infinity();
  int index = -1;
  void Add(float d, int i) {
    if (d < d0) {
      d1 = d0;
      d0 = d;
      index = i;
    } else if (d < d1) {
      d1 = d;
    }
  }
  // Lowe's ratio test: `ratio` of the values compared (squared for squared
  // L2 distances).
  bool Passes(double ratio) const { return index >= 0 && d0 < ratio * d1; }
};

// Exact nearest neighbours by squared L2 distance, |x|^2 + |y|^2 - 2 x.y, the
// dot products a matrix product, block by block (OpenBLAS's sgemm where the
// process has it: its kernels are chosen for the CPU at hand, Eigen's for
// the SSE2 this package is compiled for, and it is 2.5x faster on this
// machine's AVX-512; Eigen's product otherwise). For the
// thousand or few thousand SIFT features of a keyframe this is faster than
// FLANN's randomised kd-trees with 64 checks (the trees' build and both
// directions' searches; results/budget.md), finds the true nearest
// neighbours rather than approximate ones, and one pass gives both
// directions of the mutual check. Its cost grows with the product of the
// two feature counts, a tree search's with their sum: images of more than
// kTreeMinFeatures features each are matched by the trees (FeatureIndex).
// Fills best_q (per query row) and, when not null, best_i (per index row).
void NearestByL2(const cv::Mat& query, const cv::Mat& index, std::vector<NearestTwo>* best_q,
                 std::vector<NearestTwo>* best_i) {
  const int nq = query.rows, ni = index.rows, dims = query.cols;
  best_q->assign(nq, NearestTwo());
  if (best_i) best_i->assign(ni, NearestTwo());
  if (nq == 0 || ni == 0 || dims != index.cols) return;
  CV_Assert(query.type() == CV_32F && index.type() == CV_32F && query.isContinuous() && index.isContinuous());
  const Eigen::Map<const RowMajorFloats> q(query.ptr<float>(), nq, dims), x(index.ptr<float>(), ni, dims);
  const Eigen::VectorXf x_norms = x.rowwise().squaredNorm();
  RowMajorFloats dots(std::min(kMatchBlockRows, nq), ni);
  const FloatProductByTransposed product = OpenBlasFloatProductByTransposed();
  // The index rows' nearest two, as arrays (best_i's NearestTwo, column by column).
  std::vector<float> index_d0, index_d1;
  std::vector<int> index_row;
  if (best_i) {
    index_d0.assign(ni, std::numeric_limits<float>::infinity());
    index_d1.assign(ni, std::numeric_limits<float>::infinity());
    index_row.assign(ni, -1);
  }
  for (int r0 = 0; r0 < nq; r0 += kMatchBlockRows) {
    const int rows = std::min(kMatchBlockRows, nq - r0);
    if (product) product(rows, ni, dims, q.row(r0).data(), x.data(), dots.data());
    else dots.topRows(rows).noalias() = q.middleRows(r0, rows) * x.transpose();
    for (int r = 0; r < rows; ++r) {
      const float q_norm = q.row(r0 + r).squaredNorm();
      float* row = dots.row(r).data();
      for (int j = 0; j < ni; ++j) row[j] = std::max(0.0f, q_norm + x_norms[j] - 2.0f * row[j]);
      NearestTwo& bq = (*best_q)[r0 + r];
      for (int j = 0; j < ni; ++j) bq.Add(row[j], j);
      if (!best_i) continue;
      // NearestTwo::Add for every index row at once, without branches (the
      // compiler vectorises it): the same values, ties to the first row.
      const int query_row = r0 + r;
      for (int j = 0; j < ni; ++j) {
        const float d = row[j];
        const bool nearer = d < index_d0[j];
        index_d1[j] = std::min(index_d1[j], std::max(index_d0[j], d));
        index_d0[j] = std::min(index_d0[j], d);
        index_row[j] = nearer ? query_row : index_row[j];
      }
    }
  }
  if (!best_i) return;
  for (int j = 0; j < ni; ++j) {
    (*best_i)[j].d0 = index_d0[j];
    (*best_i)[j].d1 = index_d1[j];
    (*best_i)[j].index = index_row[j];
  }
}

// SIFT descriptors as continuous CV_32F rows (unpacked when compact).
cv::Mat FloatRows(const ImageFeatures& features) {
  cv::Mat floats = features.descriptors.type() == CV_32F && !IsPackedSift(features) ? features.descriptors
                                                                                      : SiftDescriptorsAsFloat(features);
  return floats.isContinuous() ? floats : floats.clone();
}

}  // namespace

struct FeatureIndex::Impl {
  FeatureType type;
  cv::Mat descriptors;                        // SIFT: continuous CV_32F rows
  std::unique_ptr<cv::flann::Index> kdtree;  // SIFT beyond kTreeMinFeatures
  cv::Ptr<cv::BFMatcher> hamming;             // ORB
};

FeatureIndex::FeatureIndex(const ImageFeatures& features) : impl_(new Impl) {
  impl_->type = features.type;
  if (features.type == FeatureType::kOrb) {
    impl_->descriptors = features.descriptors;
    impl_->hamming = cv::BFMatcher::create(cv::NORM_HAMMING);
  } else if (features.descriptors.rows > 0) {
    impl_->descriptors = FloatRows(features);
    if (impl_->descriptors.rows > kTreeMinFeatures) {
      std::srand(kFlannSeed);
      cv::setRNGSeed(static_cast<int>(kFlannSeed));
      impl_->kdtree = std::make_unique<cv::flann::Index>(impl_->descriptors, cv::flann::KDTreeIndexParams(4));
    }
  }
}

namespace {

// For each query row, its nearest row of `index` if it passes the ratio test
// (of distances), else -1: a tree search of `kdtree`.
std::vector<int> TreeRatioMatches(cv::flann::Index& kdtree, const cv::Mat& query, double ratio) {
  std::vector<int> best(query.rows, -1);
  cv::Mat indices, distances;  // distances are squared L2
  kdtree.knnSearch(query, indices, distances, 2, cv::flann::SearchParams(64));
  for (int i = 0; i < query.rows; ++i) {
    const float d0 = distances.at<float>(i, 0), d1 = distances.at<float>(i, 1);
    if (d0 < ratio * ratio * d1) best[i] = indices.at<int>(i, 0);
  }
  return best;
}

}  // namespace

FeatureIndex::~FeatureIndex() = default;

const cv::Mat& FeatureIndex::Descriptors() const { return impl_->descriptors; }

bool FeatureIndex::HasTrees() const { return impl_->kdtree != nullptr; }

std::vector<int> FeatureIndex::RatioMatches(const cv::Mat& query, double ratio) const {
  std::vector<int> best(query.rows, -1);
  if (impl_->descriptors.rows < 2 || query.rows == 0) return best;
  if (impl_->type == FeatureType::kOrb) {
    std::vector<std::vector<cv::DMatch>> knn;
    impl_->hamming->knnMatch(query, impl_->descriptors, knn, 2);
    for (const auto& m : knn) {
      if (m.size() == 2 && m[0].distance < ratio * m[1].distance) best[m[0].queryIdx] = m[0].trainIdx;
    }
    return best;
  }
  cv::Mat floats = query.type() == CV_32F ? query : cv::Mat();
  if (floats.empty()) query.convertTo(floats, CV_32F);
  if (!floats.isContinuous()) floats = floats.clone();
  if (impl_->kdtree) return TreeRatioMatches(*impl_->kdtree, floats, ratio);
  std::vector<NearestTwo> nearest;
  NearestByL2(floats, impl_->descriptors, &nearest, nullptr);
  for (int i = 0; i < query.rows; ++i) {
    if (nearest[i].Passes(ratio * ratio)) best[i] = nearest[i].index;
  }
  return best;
}

std::vector<std::pair<int, int>> MatchFeatures(const ImageFeatures& a, const FeatureIndex& index_a,
                                               const ImageFeatures& b, const FeatureIndex& index_b,
                                               const MatchOptions& options) {
  std::vector<std::pair<int, int>> matches;
  if (a.descriptors.rows < 2 || b.descriptors.rows < 2 || a.type != b.type) return matches;
  if (a.type == FeatureType::kSift && !(index_a.HasTrees() && index_b.HasTrees())) {
    // One pass: each of a's nearest in b and each of b's nearest in a.
    std::vector<NearestTwo> ab, ba;
    NearestByL2(index_a.Descriptors(), index_b.Descriptors(), &ab, &ba);
    const double ratio = options.ratio * options.ratio;
    for (int i = 0; i < static_cast<int>(ab.size()); ++i) {
      if (!ab[i].Passes(ratio)) continue;
      const int j = ab[i].index;
      if (options.mutual && !(ba[j].Passes(ratio) && ba[j].index == i)) continue;
      matches.emplace_back(i, j);
    }
    return matches;
  }
  // ORB, or two SIFT images with trees.
  const std::vector<int> ab = index_b.RatioMatches(index_a.Descriptors(), options.ratio);
  std::vector<int> ba;
  if (options.mutual) ba = index_a.RatioMatches(index_b.Descriptors(), options.ratio);
  for (int i = 0; i < static_cast<int>(ab.size()); ++i) {
    const int j = ab[i];
    if (j < 0) continue;
    if (options.mutual && ba[j] != i) continue;
    matches.emplace_back(i, j);
  }
  return matches;
}

std::vector<std::pair<int, int>> MatchFeaturesByGroup(const ImageFeatures& a, const std::vector<int>& group_a,
                                                      const ImageFeatures& b, const std::vector<int>& groups_b,
                                                      const MatchOptions& options) {
  std::vector<std::pair<int, int>> matches;
  const int na = a.descriptors.rows, nb = b.descriptors.rows;
  const bool hamming = a.type == FeatureType::kOrb;
  cv::Mat fa, fb;  // float rows for L2 (SIFT may be stored as bytes, or packed)
  if (!hamming && a.type == b.type) {
    fa = SiftDescriptorsAsFloat(a);
    fb = SiftDescriptorsAsFloat(b);
  }
  if (na < 1 || nb < 2 || a.type != b.type || (hamming ? a.descriptors.cols != b.descriptors.cols : fa.cols != fb.cols) ||
      static_cast<int>(group_a.size()) != na || groups_b.empty() || groups_b.size() % nb != 0) {
    return matches;
  }
  const std::size_t k = groups_b.size() / nb;
  // Members of each group, in index order.
  std::map<int, std::pair<std::vector<int>, std::vector<int>>> groups;
  for (int i = 0; i < na; ++i) {
    if (group_a[i] >= 0) groups[group_a[i]].first.push_back(i);
  }
  for (int j = 0; j < nb; ++j) {
    for (std::size_t g = 0; g < k; ++g) {
      const int group = groups_b[j * k + g];
      if (group >= 0) groups[group].second.push_back(j);
    }
  }
  const int dims = hamming ? a.descriptors.cols : fa.cols;
  // Squared L2 distances through Eigen, whose sum the compiler vectorises
  // (a plain loop's additions must keep their order: a SIMD lane each was
  // not allowed, and the loop took a quarter of the matching's time on the
  // two-camera 20 Hz stream).
  auto distance = [&](int i, int j) -> float {
    if (hamming) return static_cast<float>(cv::norm(a.descriptors.row(i), b.descriptors.row(j), cv::NORM_HAMMING));
    if (dims == kSiftDims) {
      using Row = Eigen::Map<const Eigen::Matrix<float, kSiftDims, 1>>;
      return (Row(fa.ptr<float>(i)) - Row(fb.ptr<float>(j))).squaredNorm();
    }
    using Row = Eigen::Map<const Eigen::VectorXf>;
    return (Row(fa.ptr<float>(i), dims) - Row(fb.ptr<float>(j), dims)).squaredNorm();
  };
  // Best and second best distance seen by each feature, over every pair
  // compared (a feature of b may be compared in several groups).
  std::vector<NearestTwo> best_a(na), best_b(nb);
  for (const auto& [group, members] : groups) {
    for (int i : members.first) {
      for (int j : members.second) {
        const float d = distance(i, j);
        best_a[i].Add(d, j);
        best_b[j].Add(d, i);
      }
    }
  }
  // The ratio test on squared distances for L2.
  const double ratio = hamming ? options.ratio : options.ratio * options.ratio;
  for (int i = 0; i < na; ++i) {
    if (!best_a[i].Passes(ratio)) continue;
    const int j = best_a[i].index;
    // The mutual check: i is j's best (j may have had only i to compare with).
    if (options.mutual && best_b[j].index != i) continue;
    matches.emplace_back(i, j);
  }
  return matches;
}

std::vector<std::pair<int, int>> MatchFeatures(const ImageFeatures& a, const ImageFeatures& b,
                                               const MatchOptions& options) {
  const FeatureIndex index_a(a), index_b(b);
  return MatchFeatures(a, index_a, b, index_b, options);
}

}  // namespace rotation_averaging
