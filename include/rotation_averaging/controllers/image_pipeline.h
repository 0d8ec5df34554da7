// Stable interface of rotation_averaging::frontend (README.md, "Embedding the averager").
// From images to a view graph with rotation covariances: features, pair
// selection, matching, relative pose with covariance per pair.
#ifndef ROTATION_AVERAGING_CONTROLLERS_IMAGE_PIPELINE_H_
#define ROTATION_AVERAGING_CONTROLLERS_IMAGE_PIPELINE_H_

#include <map>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/estimators/correspondence_refinement.h"
#include "rotation_averaging/estimators/relative_pose.h"
#include "rotation_averaging/features/features.h"
#include "rotation_averaging/scene/view_graph.h"

namespace rotation_averaging {

struct PairSelection {
  enum class Mode { kExhaustive, kSequential, kList } mode = Mode::kExhaustive;
  int window = 5;                                // kSequential: each image with the next `window`
  std::vector<std::pair<int, int>> pairs;        // kList: image indices
  std::vector<std::pair<std::string, std::string>> named_pairs;  // kList: image file names
  // "exhaustive", "sequential:N" or "list:FILE" (FILE: one "name1 name2" per
  // line, image file names without folder). False (with `error`) if invalid.
  static bool Parse(const std::string& text, PairSelection* selection, std::string* error = nullptr);
};

// Pinhole intrinsics of the full-resolution images plus radial distortion
// (COLMAP SIMPLE_RADIAL / RADIAL): in normalised coordinates
// x_distorted = x (1 + k1 r^2 + k2 r^4). Keypoints are undistorted before the
// relative pose.
struct CameraIntrinsics {
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();
  double k1 = 0.0, k2 = 0.0;
  // Undistorts a pixel of an image whose intrinsics are `scaled_k`.
  Eigen::Vector2d Undistort(const Eigen::Vector2d& pixel, const Eigen::Matrix3d& scaled_k) const;
};

// Reads intrinsics from a K.txt (3x3, row-major) or a COLMAP cameras.txt
// (first camera; SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL or RADIAL).
bool ReadCameraIntrinsics(const std::string& path, CameraIntrinsics* intrinsics, std::string* error);

struct ImagePipelineOptions {
  FeatureOptions features;
  MatchOptions matching;
  RelativePoseOptions relative_pose;
  PairSelection pairs;
};

struct PairReport {
  int image1 = 0, image2 = 0;
  int matches = 0;
  RelativePoseResult pose;  // R_21 with covariance, inliers, failure reason
  // The inlier correspondences of a successful pair in normalised image
  // coordinates (K^-1 x), for RefineRotationsWithCorrespondences.
  std::vector<Eigen::Vector2d> inlier_points1, inlier_points2;
  double milliseconds = 0.0;  // matching + relative pose + covariance
};

struct ImagePipelineResult {
  ViewGraph graph;                 // view id = image index, name = file name
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();  // pinhole matrix of the keypoints
  std::vector<PairReport> pairs;   // every pair tried
  std::vector<int> features_per_image;
  double features_s = 0.0, matching_s = 0.0, relative_pose_s = 0.0;
  std::map<std::string, int> failures;  // reason -> count
  int near_planar_pairs = 0;            // kept pairs a homography explains (see RelativePoseOptions)
  int rotation_model_pairs = 0;         // kept pairs whose rotation comes from the rotation-only model
  std::vector<std::string> errors;      // images that could not be read
  std::string Report() const;
};

// Lists the images (jpg, jpeg, png, ppm, pgm, tif, tiff, bmp) of a folder,
// sorted by name.
std::vector<std::string> ListImages(const std::string& directory);

// Reads a 3x3 intrinsics matrix (nine numbers, row-major, whitespace separated).
bool ReadIntrinsics(const std::string& path, Eigen::Matrix3d* k, std::string* error);

// The pinhole matrix of the images features are detected in (intrinsics.k
// scaled by options.downsample).
Eigen::Matrix3d FeatureIntrinsics(const CameraIntrinsics& intrinsics, const FeatureOptions& options);

// Features of images that share `intrinsics` (of the full-resolution images),
// keypoints undistorted, in the coordinates of FeatureIntrinsics. `names`
// gets the file names; an image that cannot be read gets no features and a
// line in `errors`.
std::vector<ImageFeatures> ExtractImageFeatures(const std::vector<std::string>& image_paths,
                                                const CameraIntrinsics& intrinsics, const FeatureOptions& options,
                                                std::vector<std::string>* names, std::vector<std::string>* errors);

// Runs the front end over images that share the intrinsics `k` (of the
// full-resolution images). Edge (i, j) stores R_ij = R_i R_j^T and the
// covariance of its right perturbation (estimators/relative_pose.h).
ImagePipelineResult BuildViewGraphFromImages(const std::vector<std::string>& image_paths,
                                             const CameraIntrinsics& intrinsics, const ImagePipelineOptions& options);

// Same, from features already extracted (e.g. by the node); `k` is the
// pinhole matrix at the resolution the features were detected in, the
// keypoints are already undistorted.
ImagePipelineResult BuildViewGraphFromFeatures(const std::vector<ImageFeatures>& features,
                                               const std::vector<std::string>& names, const Eigen::Matrix3d& k,
                                               const ImagePipelineOptions& options);

// Relative pose of images (image1, image2) from matched keypoints (pixels of
// the images with pinhole matrix k), with the inlier points kept in
// normalised coordinates.
PairReport EstimatePair(int image1, int image2, const std::vector<Eigen::Vector2d>& points1,
                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k,
                        const RelativePoseOptions& options);

// The edge of one successful pair (i, j).
RelativeRotation EdgeFromPair(const PairReport& pair);

// The correspondences of the pairs that gave an edge of result.graph, for
// RefineRotationsWithCorrespondences. Every edge, including those the
// averaging down-weighted as outliers: the averaging judges an edge by its
// covariance, and a covariance that is too confident (the pair's cost is a
// long curved valley) makes a correct pair look like an outlier there; the
// refinement judges each edge by its own matches.
std::vector<EdgeCorrespondences> CorrespondencesOfEdges(const ImagePipelineResult& result);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CONTROLLERS_IMAGE_PIPELINE_H_
