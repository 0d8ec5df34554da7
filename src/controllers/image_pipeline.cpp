#include "rotation_averaging/controllers/image_pipeline.h"

#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iomanip>
#include <opencv2/imgcodecs.hpp>
#include <sstream>

#include "rotation_averaging/io/text_lines.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

std::vector<std::pair<int, int>> SelectPairs(int n, const PairSelection& selection,
                                             const std::vector<std::string>& names, std::vector<std::string>* errors) {
  std::vector<std::pair<int, int>> pairs;
  switch (selection.mode) {
    case PairSelection::Mode::kExhaustive:
      for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n; ++j) pairs.emplace_back(i, j);
      break;
    case PairSelection::Mode::kSequential:
      for (int i = 0; i < n; ++i)
        for (int j = i + 1; j < n && j <= i + selection.window; ++j) pairs.emplace_back(i, j);
      break;
    case PairSelection::Mode::kList: {
      for (const auto& [i, j] : selection.pairs) {
        if (i >= 0 && j >= 0 && i < n && j < n && i != j) pairs.emplace_back(std::min(i, j), std::max(i, j));
      }
      for (const auto& [a, b] : selection.named_pairs) {
        const auto ia = std::find(names.begin(), names.end(), a), ib = std::find(names.begin(), names.end(), b);
        if (ia == names.end() || ib == names.end() || ia == ib) {
          errors->push_back("pair list: '" + a + " " + b + "' does not name two different images");
          continue;
        }
        const int i = static_cast<int>(ia - names.begin()), j = static_cast<int>(ib - names.begin());
        pairs.emplace_back(std::min(i, j), std::max(i, j));
      }
      std::sort(pairs.begin(), pairs.end());
      pairs.erase(std::unique(pairs.begin(), pairs.end()), pairs.end());
      break;
    }
  }
  return pairs;
}

}  // namespace

bool PairSelection::Parse(const std::string& text, PairSelection* selection, std::string* error) {
  if (text.rfind("list:", 0) == 0) {
    LineReader reader(text.substr(5));
    if (!reader.IsOpen()) {
      if (error) *error = "cannot open pair list " + text.substr(5);
      return false;
    }
    std::string line;
    selection->named_pairs.clear();
    while (reader.Next(&line)) {
      if (IsBlankOrComment(line)) continue;
      const std::vector<std::string> t = SplitTokens(line);
      if (t.size() != 2) {
        if (error) *error = reader.Where("expected 'image1 image2'");
        return false;
      }
      selection->named_pairs.emplace_back(t[0], t[1]);
    }
    selection->mode = Mode::kList;
    return true;
  }
  if (text == "exhaustive") {
    selection->mode = Mode::kExhaustive;
    return true;
  }
  if (text.rfind("sequential:", 0) == 0) {
    int window = 0;
    if (!ParseInt(text.substr(11), &window) || window < 1) return false;
    selection->mode = Mode::kSequential;
    selection->window = window;
    return true;
  }
  return false;
}

std::vector<std::string> ListImages(const std::string& directory) {
  std::vector<std::string> images;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(directory, ec)) {
    std::string ext = entry.path().extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
    if (ext == ".jpg" || ext == ".jpeg" || ext == ".png" || ext == ".ppm" || ext == ".pgm" || ext == ".tif" ||
        ext == ".tiff" || ext == ".bmp") {
      images.push_back(entry.path().string());
    }
  }
  std::sort(images.begin(), images.end());
  return images;
}

Eigen::Vector2d CameraIntrinsics::Undistort(const Eigen::Vector2d& pixel, const Eigen::Matrix3d& scaled_k) const {
  if (k1 == 0.0 && k2 == 0.0) return pixel;
  const Eigen::Vector3d d = scaled_k.inverse() * pixel.homogeneous();
  const Eigen::Vector2d distorted = d.hnormalized();
  Eigen::Vector2d x = distorted;
  for (int it = 0; it < 20; ++it) {  // fixed point: x = x_d / (1 + k1 r^2 + k2 r^4)
    const double r2 = x.squaredNorm();
    x = distorted / (1.0 + k1 * r2 + k2 * r2 * r2);
  }
  return (scaled_k * x.homogeneous()).hnormalized();
}

bool ReadCameraIntrinsics(const std::string& path, CameraIntrinsics* intrinsics, std::string* error) {
  LineReader reader(path);
  if (!reader.IsOpen()) {
    *error = "cannot open " + path;
    return false;
  }
  std::string line;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    const std::vector<std::string> t = SplitTokens(line);
    if (t.size() >= 5 && (t[1] == "SIMPLE_PINHOLE" || t[1] == "PINHOLE" || t[1] == "SIMPLE_RADIAL" || t[1] == "RADIAL")) {
      std::vector<double> p;
      for (std::size_t i = 4; i < t.size(); ++i) {
        double v;
        if (!ParseDouble(t[i], &v)) {
          *error = reader.Where("'" + t[i] + "' is not a number");
          return false;
        }
        p.push_back(v);
      }
      const std::size_t needed = t[1] == "SIMPLE_PINHOLE" ? 3 : t[1] == "PINHOLE" ? 4 : t[1] == "SIMPLE_RADIAL" ? 4 : 5;
      if (p.size() != needed) {
        *error = reader.Where(t[1] + " needs " + std::to_string(needed) + " parameters");
        return false;
      }
      Eigen::Matrix3d& k = intrinsics->k;
      k.setIdentity();
      if (t[1] == "PINHOLE") {
        k(0, 0) = p[0];
        k(1, 1) = p[1];
        k(0, 2) = p[2];
        k(1, 2) = p[3];
      } else {
        k(0, 0) = k(1, 1) = p[0];
        k(0, 2) = p[1];
        k(1, 2) = p[2];
        if (t[1] == "SIMPLE_RADIAL") intrinsics->k1 = p[3];
        if (t[1] == "RADIAL") {
          intrinsics->k1 = p[3];
          intrinsics->k2 = p[4];
        }
      }
      return true;
    }
    break;  // not a COLMAP camera line: try K.txt
  }
  intrinsics->k1 = intrinsics->k2 = 0.0;
  return ReadIntrinsics(path, &intrinsics->k, error);
}

bool ReadIntrinsics(const std::string& path, Eigen::Matrix3d* k, std::string* error) {
  LineReader reader(path);
  if (!reader.IsOpen()) {
    *error = "cannot open " + path;
    return false;
  }
  std::vector<double> values;
  std::string line;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    for (const std::string& t : SplitTokens(line)) {
      double v;
      if (!ParseDouble(t, &v) || !std::isfinite(v)) {
        *error = reader.Where("'" + t + "' is not a finite number");
        return false;
      }
      values.push_back(v);
    }
  }
  if (values.size() != 9) {
    *error = path + ": expected 9 numbers (3x3 K), found " + std::to_string(values.size());
    return false;
  }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) (*k)(r, c) = values[3 * r + c];
  if (!((*k)(0, 0) > 0.0 && (*k)(1, 1) > 0.0 && std::abs((*k)(2, 2) - 1.0) < 1e-9)) {
    *error = path + ": K must have positive focal lengths and K(2,2) = 1";
    return false;
  }
  return true;
}

RelativeRotation EdgeFromPair(const PairReport& pair) {
  RelativeRotation edge;
  edge.view1 = static_cast<ViewId>(pair.image1);
  edge.view2 = static_cast<ViewId>(pair.image2);
  edge.rotation = pair.pose.EdgeRotation();
  edge.has_covariance = true;
  edge.covariance = pair.pose.covariance;
  edge.num_inliers = static_cast<int>(pair.pose.inliers.size());
  edge.source = pair.image2 == pair.image1 + 1 ? EdgeSource::kSequential : EdgeSource::kOther;
  return edge;
}

PairReport EstimatePair(int image1, int image2, const std::vector<Eigen::Vector2d>& points1,
                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k,
                        const RelativePoseOptions& options) {
  PairReport report;
  report.image1 = image1;
  report.image2 = image2;
  report.matches = static_cast<int>(points1.size());
  report.pose = EstimateRelativePoseWithCovariance(points1, points2, k, k, options);
  if (report.pose.success) {
    const Eigen::Matrix3d k_inv = k.inverse();
    report.inlier_points1.reserve(report.pose.inliers.size());
    report.inlier_points2.reserve(report.pose.inliers.size());
    for (int m : report.pose.inliers) {
      report.inlier_points1.push_back((k_inv * points1[m].homogeneous()).hnormalized());
      report.inlier_points2.push_back((k_inv * points2[m].homogeneous()).hnormalized());
    }
  }
  return report;
}

std::vector<EdgeCorrespondences> CorrespondencesOfEdges(const ImagePipelineResult& result) {
  const double focal = 0.5 * (result.k(0, 0) + result.k(1, 1));
  std::vector<EdgeCorrespondences> out;
  for (const PairReport& p : result.pairs) {
    if (!p.pose.success || p.inlier_points1.empty()) continue;
    EdgeCorrespondences e;
    e.view1 = static_cast<ViewId>(p.image1);
    e.view2 = static_cast<ViewId>(p.image2);
    e.points1 = p.inlier_points1;
    e.points2 = p.inlier_points2;
    e.translation = p.pose.translation;
    // A floor keeps a noiseless (synthetic) pair finite.
    e.sigma = std::max(p.pose.sigma_px, 1e-3) / focal;
    out.push_back(std::move(e));
  }
  return out;
}

ImagePipelineResult BuildViewGraphFromFeatures(const std::vector<ImageFeatures>& features,
                                               const std::vector<std::string>& names, const Eigen::Matrix3d& k,
                                               const ImagePipelineOptions& options) {
  ImagePipelineResult result;
  result.k = k;
  const int n = static_cast<int>(features.size());
  for (int i = 0; i < n; ++i) {
    result.graph.AddView(static_cast<ViewId>(i), i < static_cast<int>(names.size()) ? names[i] : "");
    result.features_per_image.push_back(static_cast<int>(features[i].keypoints_px.size()));
  }
  // One nearest-neighbour index per image, reused by every pair it is in.
  const auto index_start = Clock::now();
  std::vector<std::unique_ptr<FeatureIndex>> indices;
  for (const ImageFeatures& f : features) indices.push_back(std::make_unique<FeatureIndex>(f));
  result.matching_s += Seconds(index_start);
  for (const auto& [i, j] : SelectPairs(n, options.pairs, names, &result.errors)) {
    const auto start = Clock::now();
    const std::vector<std::pair<int, int>> matches =
        MatchFeatures(features[i], *indices[i], features[j], *indices[j], options.matching);
    result.matching_s += Seconds(start);
    std::vector<Eigen::Vector2d> p1, p2;
    p1.reserve(matches.size());
    p2.reserve(matches.size());
    for (const auto& [a, b] : matches) {
      p1.push_back(features[i].keypoints_px[a]);
      p2.push_back(features[j].keypoints_px[b]);
    }
    const auto pose_start = Clock::now();
    PairReport report = EstimatePair(i, j, p1, p2, k, options.relative_pose);
    result.relative_pose_s += Seconds(pose_start);
    report.milliseconds = 1e3 * Seconds(start);
    if (report.pose.success) {
      if (report.pose.homography_inlier_ratio >= options.relative_pose.near_planar_report_ratio) ++result.near_planar_pairs;
      if (report.pose.model == TwoViewModel::kRotation) ++result.rotation_model_pairs;
      std::string why;
      if (result.graph.AddEdge(EdgeFromPair(report), &why) == AddEdgeResult::kRejected) {
        report.pose.success = false;
        report.pose.message = "edge rejected: " + why;
        ++result.failures["edge_rejected"];
      }
    } else {
      ++result.failures[TwoViewFailureName(report.pose.failure)];
    }
    result.pairs.push_back(std::move(report));
  }
  return result;
}

Eigen::Matrix3d FeatureIntrinsics(const CameraIntrinsics& intrinsics, const FeatureOptions& options) {
  return ScaleIntrinsics(intrinsics.k, options.downsample > 0.0 ? options.downsample : 1.0);
}

std::vector<ImageFeatures> ExtractImageFeatures(const std::vector<std::string>& image_paths,
                                                const CameraIntrinsics& intrinsics, const FeatureOptions& options,
                                                std::vector<std::string>* names, std::vector<std::string>* errors) {
  std::vector<ImageFeatures> features(image_paths.size());
  const Eigen::Matrix3d scaled_k = FeatureIntrinsics(intrinsics, options);
  names->clear();
  for (std::size_t i = 0; i < image_paths.size(); ++i) {
    names->push_back(fs::path(image_paths[i]).filename().string());
    const cv::Mat image = cv::imread(image_paths[i], cv::IMREAD_GRAYSCALE);
    if (image.empty()) {
      errors->push_back("cannot read image " + image_paths[i]);
      continue;
    }
    features[i] = ExtractFeatures(image, options);
    for (Eigen::Vector2d& p : features[i].keypoints_px) p = intrinsics.Undistort(p, scaled_k);
  }
  return features;
}

ImagePipelineResult BuildViewGraphFromImages(const std::vector<std::string>& image_paths,
                                             const CameraIntrinsics& intrinsics, const ImagePipelineOptions& options) {
  std::vector<std::string> names, errors;
  const auto start = Clock::now();
  const std::vector<ImageFeatures> features =
      ExtractImageFeatures(image_paths, intrinsics, options.features, &names, &errors);
  const double features_s = Seconds(start);
  ImagePipelineResult result =
      BuildViewGraphFromFeatures(features, names, FeatureIntrinsics(intrinsics, options.features), options);
  result.features_s = features_s;
  result.errors = std::move(errors);
  return result;
}

std::string ImagePipelineResult::Report() const {
  std::ostringstream out;
  const int n = static_cast<int>(features_per_image.size());
  int ok = 0;
  for (const PairReport& p : pairs) ok += p.pose.success;
  double mean_features = 0.0;
  for (int f : features_per_image) mean_features += f;
  out << std::fixed << std::setprecision(1) << "images: " << n << ", features per image: "
      << (n ? mean_features / n : 0.0) << "\npairs: " << pairs.size() << " tried, " << ok << " with a relative pose";
  for (const auto& [reason, count] : failures) out << "\n  rejected (" << reason << "): " << count;
  if (near_planar_pairs) out << "\n  kept, near-planar (homography explains >= 95% of the inliers): " << near_planar_pairs;
  if (rotation_model_pairs) out << "\n  kept, rotation-only model (no measurable translation): " << rotation_model_pairs;
  out << "\ntime: features " << features_s << " s (" << (n ? 1e3 * features_s / n : 0.0) << " ms/image), matching "
      << matching_s << " s, relative pose + covariance " << relative_pose_s << " s ("
      << (pairs.empty() ? 0.0 : 1e3 * (matching_s + relative_pose_s) / pairs.size()) << " ms/pair)";
  for (const std::string& e : errors) out << "\nerror: " << e;
  return out.str();
}

}  // namespace rotation_averaging
