// Public header of rotation_averaging::frontend (docs/embedding.md).
// From images to a view graph with rotation covariances: features, pair
// selection, matching, relative pose with covariance per pair.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_IMAGE_PIPELINE_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_IMAGE_PIPELINE_H_

#include <limits>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"
#include "rotation_averaging/core/scene/view_graph.h"

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


// Self-calibration of the focal length for images whose intrinsics are not
// trusted. A focal length 1% off moves two-view rotations by about 1% of
// their angle (results/frontend.md, "What moves the two-view rotations"),
// while an essential matrix in the wrong focal length fits the matches less
// well: the scale a of the focal length (f -> a f, principal point kept)
// that minimises the Sampson errors of every pair's inliers, each pair's
// pose re-refined at each a (a profile likelihood), estimates it.
struct FocalCalibrationOptions {
  bool enabled = false;  // the library and the node trust K; `rotavg images` turns it on
  // Applied only when the estimate is further from 1 than this and than 3
  // of its standard deviations. On scenes whose intrinsics are exact it
  // lands a few tenths of a percent from 1 (results/frontend.md, "Focal
  // self-calibration"), so a smaller correction would as likely add an
  // error as remove one.
  double min_correction = 0.005;
  // Standard deviation of the error of K's principal point, as a fraction of
  // the image width (taken as 2 cx). The focal length two views give
  // depends on where the principal point is; near the critical
  // configuration of focal self-calibration (optical axes meeting at a point
  // equally far from the cameras: a ring or an arc around an object) it
  // depends on little else: a principal point 1% of the width off moves the
  // estimate by percents while the matches alone still look certain of it
  // (results/frontend.md, "Focal self-calibration"). The
  // estimate is repeated with the principal point moved by this much along
  // x and y, and the change is part of its standard deviation: at 3
  // standard deviations a correction is applied only when it holds against
  // principal point errors up to 2.1% of the width, the largest distance of
  // a given camera's calibrated principal point from its image centre (the
  // same table).
  double principal_point_sigma = 0.007;
  double search_range = 0.15;  // scales in [1 - range, 1 + range]
  int min_inliers = 50;        // pairs (essential-matrix model) with fewer are not used
  int min_pairs = 3;
  int num_threads = 0;         // 0: the machine's cores; the result does not depend on it
};

struct ImagePipelineOptions {
  FeatureOptions features;
  MatchOptions matching;
  RelativePoseOptions relative_pose;
  PairSelection pairs;
  FocalCalibrationOptions focal;
};

struct FocalCalibration {
  bool estimated = false;          // enough pairs to estimate it
  double scale = 1.0;              // estimated true / given focal length
  // Of scale. From the matches: the larger of the profile's curvature (pixel
  // noise alone) and a jackknife over four groups of pairs (how much the
  // pairs disagree). From the principal point: how far the estimate moves
  // when it is moved by FocalCalibrationOptions::principal_point_sigma.
  // standard_deviation combines both.
  double standard_deviation = 0.0;
  double matches_deviation = 0.0, principal_point_deviation = 0.0;
  int pairs = 0;                   // pairs used
  // Enough pairs, but the estimate or its deviation left the search range:
  // the pairs do not determine the focal length.
  bool unobservable = false;
  bool applied = false;            // the pairs were estimated again with the corrected focal length
  // Points of the profiles evaluated (each refines every pair's pose): what
  // the estimate cost.
  int evaluations = 0;
  std::string Report() const;
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
  FocalCalibration focal;               // ImagePipelineOptions::focal
  double focal_s = 0.0;                 // its estimation and the pairs estimated again
  std::vector<std::string> errors;      // images that could not be read
  std::string Report() const;
};

// Lists the images (jpg, jpeg, png, ppm, pgm, tif, tiff, bmp) of a folder,
// sorted by name.
std::vector<std::string> ListImages(const std::string& directory);


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
// covariance of its right perturbation (frontend/estimators/relative_pose.h).
ImagePipelineResult BuildViewGraphFromImages(const std::vector<std::string>& image_paths,
                                             const CameraIntrinsics& intrinsics, const ImagePipelineOptions& options);

// Same, from features already extracted (e.g. by the node); `k` is the
// pinhole matrix at the resolution the features were detected in, the
// keypoints are already undistorted, by `lens`'s distortion model if one is
// given (the focal calibration then undistorts them again for every focal
// length it tries, and with the one it applies).
ImagePipelineResult BuildViewGraphFromFeatures(const std::vector<ImageFeatures>& features,
                                               const std::vector<std::string>& names, const Eigen::Matrix3d& k,
                                               const ImagePipelineOptions& options,
                                               const CameraIntrinsics* lens = nullptr);

// Relative pose of images (image1, image2) from matched keypoints (pixels of
// the images with pinhole matrix k), with the inlier points kept in
// normalised coordinates.
PairReport EstimatePair(int image1, int image2, const std::vector<Eigen::Vector2d>& points1,
                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k,
                        const RelativePoseOptions& options);

// One pair for EstimateFocalScale: its matched keypoints (pixels of images
// with the pinhole matrix k) and the pose estimated from them with k.
struct FocalPair {
  const std::vector<Eigen::Vector2d>* points1 = nullptr;
  const std::vector<Eigen::Vector2d>* points2 = nullptr;
  const RelativePoseResult* pose = nullptr;
};

// Estimates the scale of the focal length of `k` from the successful
// essential-matrix pairs (FocalCalibrationOptions). `applied` is left false:
// the caller decides, with ShouldApplyFocalScale. With a `lens` that has a
// distortion, the keypoints are a raw image's undistorted with `k`: every
// focal length tried undistorts them again (RedoUndistortion). Scaling them
// instead would miss a focal error: undistorted with the wrong K, a raw
// image's keypoints land near where the right K puts them, with a radial
// error that the scale's profile takes for the opposite error.
FocalCalibration EstimateFocalScale(const std::vector<FocalPair>& pairs, const Eigen::Matrix3d& k,
                                    const FocalCalibrationOptions& options, const CameraIntrinsics* lens = nullptr);
bool ShouldApplyFocalScale(const FocalCalibration& calibration, const FocalCalibrationOptions& options);

// A radial lens distortion that the intrinsics do not describe, seen in the
// pairs: the coefficient lambda of the one-parameter division model
// (x_undistorted = x / (1 + lambda |x|^2), x in normalised coordinates K^-1 p)
// that minimises the Sampson errors of every pair's matches, each pair's pose
// re-refined at each lambda (EstimateFocalScale's profile). lambda is about
// the k1 of a plumb_bob model (-0.28 for EuRoC's lenses).
struct RadialDistortionOptions {
  double search_range = 0.6;  // lambda in [-range, range]
  // Unmodelled when lambda moves a keypoint in an image corner by more than
  // this (a few times the keypoints' noise) and is 3 standard deviations
  // from 0.
  double min_corner_shift_px = 2.0;
  // Pairs whose median parallax is smaller are not used: with hardly any
  // translation the pose explains a distortion as well as the lack of one
  // (EuRoC's vehicle standing still, results/focal_check.md).
  double min_parallax_deg = 1.0;
  int min_inliers = 50;
  int min_pairs = 3;
  int num_threads = 0;  // 0: the machine's cores; the result does not depend on it
};

struct RadialDistortion {
  bool estimated = false;
  double lambda = 0.0, standard_deviation = 0.0;  // the matches' curvature and jackknife, as the focal scale's
  double corner_shift_px = 0.0;  // how far lambda moves a keypoint in a corner of the image (width 2 cx)
  int pairs = 0;
  bool unobservable = false;  // enough pairs, but lambda left the search range
  int evaluations = 0;        // points of the profiles evaluated, as FocalCalibration's
  // The other one-parameter explanation of pairs that bend: a wrong focal
  // length. A focal length a few percent off bends the pairs much as a
  // distortion does, and the distortion profile, which runs at the given
  // focal length, takes part of that for a distortion. With a focal scale
  // estimated from the same camera's pairs, both explanations are scored
  // on the pairs the distortion check uses (the profile cost: truncated
  // squared Sampson errors in units of each pair's noise): `cost` at lambda
  // and the given focal length, `focal_only_cost` at that scale and no
  // distortion. Both fit one parameter. `advantage_deviation` is the
  // standard deviation of the distortion's advantage, focal_only_cost -
  // cost, from how much it varies between the pairs. NaN when not compared
  // (no focal scale estimated).
  double cost = std::numeric_limits<double>::quiet_NaN();
  double focal_only_cost = std::numeric_limits<double>::quiet_NaN();
  double focal_only_scale = std::numeric_limits<double>::quiet_NaN();
  double advantage_deviation = std::numeric_limits<double>::quiet_NaN();
  // The distortion explains the pairs better than the focal scale alone by
  // less than 3 standard deviations of its advantage: either explanation
  // will do, and a focal length that disagrees is the simpler one (it is
  // reported on its own).
  bool FocalExplainsAsWell() const { return focal_only_cost - cost <= 3.0 * advantage_deviation; }
};

// `focal` (optional): the focal scale estimated from the same pairs
// (EstimateFocalScale); when estimated, the distortion is compared with it
// (RadialDistortion::focal_only_cost).
RadialDistortion EstimateRadialDistortion(const std::vector<FocalPair>& pairs, const Eigen::Matrix3d& k,
                                         const RadialDistortionOptions& options,
                                         const FocalCalibration* focal = nullptr);
// lambda beyond the noise: 3 standard deviations from 0, moving a corner by
// more than min_corner_shift_px.
bool DistortionBeyondNoise(const RadialDistortion& distortion, const RadialDistortionOptions& options);
// Beyond the noise and not explained as well by the focal scale alone
// (RadialDistortion::FocalExplainsAsWell).
bool DistortionIsUnmodelled(const RadialDistortion& distortion, const RadialDistortionOptions& options);

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

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_IMAGE_PIPELINE_H_
