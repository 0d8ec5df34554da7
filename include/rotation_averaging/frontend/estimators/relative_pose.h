// Public header of rotation_averaging::frontend (docs/embedding.md).
// Two-view relative pose with the covariance of its rotation.
//
// Convention (camera 1 = view i, camera 2 = view j of an edge): the estimate
// maps camera-1 coordinates to camera-2 coordinates, x2 = R x1 + t, so with
// world-to-camera R_i, R_j, R = R_j R_i^T = R_ji and |t| = 1. The rotation is
// refined as R = Exp(omega) R_hat (a LEFT perturbation of R_ji), and the
// covariance is that of omega. For the view-graph edge (i, j), which stores
// R_ij = R^T = R_hat^T Exp(-omega), this is exactly the covariance of the
// edge's right perturbation (core/geometry/so3.h): no frame change is needed.
//
// Pipeline: essential matrix by OpenCV's USAC MAGSAC++ on normalised
// coordinates, cheirality by recoverPose, then Levenberg-Marquardt refinement
// of R and t (t on the unit sphere, closed-form derivatives) minimising the
// Sampson error over the inliers, in pixels (the Sampson error is the same for
// t and -t, so t keeps the sign that puts more inliers in front of the
// cameras); then the same again at a threshold scaled to the pair's measured
// pixel noise (adaptive_threshold_sigmas). With J the Jacobian of the Sampson residuals w.r.t. (omega, t) at the
// optimum and sigma^2 the pixel noise variance estimated from the residuals:
//   conditional (the paper's code, t held fixed):  C = (J_w^T J_w)^-1
//   marginal over t (Schur complement):           C = [(J^T J)^-1]_ww
// each times sigma^2 to be in rad^2 (the paper leaves it unscaled).
//
// Model selection: a camera that turned without moving (or whose baseline is
// negligible against the depth) sees x2 ~ K2 R K1^-1 x1, a homography with
// three parameters. The translation is then unobservable and the essential
// matrix ill-conditioned, yet R is better determined than ever. When the
// essential matrix fails, or a homography explains at least half of its
// inliers (a rotation is a homography, so it can explain no more), R is also
// estimated from the rotation-only model (2-point RANSAC, Gauss-Newton on the
// transfer error in pixels, covariance sigma^2 (J^T J)^-1 in the same left
// perturbation of R_21), and Torr's GRIC picks the model: the sum of robust
// squared residuals (Sampson for E, half the squared transfer error for R,
// both in units of the pair's noise) plus a penalty for the model's
// dimension and parameters. `model` says which one the pose comes from.
#ifndef ROTATION_AVERAGING_FRONTEND_ESTIMATORS_RELATIVE_POSE_H_
#define ROTATION_AVERAGING_FRONTEND_ESTIMATORS_RELATIVE_POSE_H_

#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

namespace rotation_averaging {

enum class RotationCovarianceModel {
  kMarginal,     // marginal over the translation direction, scaled to rad^2 (default)
  kConditional,  // conditional on t (the paper's), scaled to rad^2
};
const char* RotationCovarianceModelName(RotationCovarianceModel model);
bool ParseRotationCovarianceModel(const std::string& text, RotationCovarianceModel* model);
std::string RotationCovarianceModelChoices();  // "marginal, conditional", for messages

enum class TwoViewFailure {
  kNone,
  kTooFewMatches,       // fewer than min_inliers correspondences to start with
  kEssentialFailed,     // the robust estimator found no model
  kTooFewInliers,       // model found, but fewer than min_inliers consistent (and in front of both cameras)
  kPureRotation,        // median parallax too small: translation unobservable, E ill-conditioned
  kNearPlanar,          // a homography explains the inliers (only if max_homography_inlier_ratio < 1)
  kRefinementFailed,    // the Sampson refinement diverged or produced non-finite numbers
  kSingularInformation,  // J^T J (nearly) singular: the rotation is not constrained
  kInvalidInput          // point lists of different lengths, a non-finite point, or intrinsics that are not a camera
};
const char* TwoViewFailureName(TwoViewFailure failure);

enum class TwoViewModel {
  kEssential,  // general motion: essential matrix, R and unit t
  kRotation,   // rotation only (pure or near-pure rotation): R, no t
};
const char* TwoViewModelName(TwoViewModel model);

struct RelativePoseOptions {
  // MAGSAC++ inlier threshold of the first robust estimation, pixels: an
  // upper bound on the pixel noise of any pair.
  double ransac_threshold_px = 3.0;
  // Then, with the pixel noise sigma of the pair measured from the first
  // model's inliers, the robust estimation is repeated at
  // max(min_adaptive_threshold_px, adaptive_threshold_sigmas * sigma) when
  // that is below ransac_threshold_px (0: off). The refinement re-selects
  // its inliers at 3 sigma of its own model either way.
  double adaptive_threshold_sigmas = 3.0;
  double min_adaptive_threshold_px = 0.5;
  double ransac_confidence = 0.9999;   // probability of finding the best model
  int ransac_max_iterations = 10000;
  int min_inliers = 20;                // fewer inliers: pair rejected
  // Without the rotation model (rotation_model = false), pairs below this
  // median parallax are rejected as near-pure rotation; with it, the model
  // selection decides.
  double min_median_parallax_deg = 0.3;
  // Pairs where a homography explains more than this fraction of the
  // essential-matrix inliers are rejected as near-planar. Default 1: keep them
  // (and report them): on a facade the near-planar pairs are among the most
  // accurate, and rejecting them loses the best pairs (docs/decisions.md,
  // "Near-planar pairs"). The two-fold planar ambiguity is resolved by
  // cheirality.
  double max_homography_inlier_ratio = 1.0;
  double near_planar_report_ratio = 0.95;  // counted as near-planar in reports (kept)
  int refine_max_iterations = 50;      // Levenberg-Marquardt iterations of the Sampson refinement
  double max_condition_number = 1e10;  // of J^T J; larger: rejected as singular
  RotationCovarianceModel covariance_model = RotationCovarianceModel::kMarginal;
  // The marginal covariance of an essential-matrix pose (the rotation-only
  // model's stays the pixel model's) is at least the delete-one-cell
  // jackknife's over a jackknife_grid x jackknife_grid partition of the
  // inliers in image 1 (in every direction: the larger of the two). The pixel model treats every
  // residual as independent; errors shared by a region of the image (a group
  // of wrong matches on a repeated structure, a local bias of the keypoints)
  // move the rotation together, and only leaving the region out shows it.
  // A 4 x 4 grid gives up to 16 cells, 15 degrees of freedom for a 3 x 3
  // covariance. 0 or 1: the pixel model alone, the default of the library
  // and, for sequential and rig pairs, of the node: where keypoint noise is
  // independent the jackknife only adds sampling noise to the weights and
  // costs accuracy (docs/decisions.md, "Cell jackknife"). The node's loop
  // closures get it (KeyframeFrontendOptions::loop_jackknife_grid), and
  // `rotavg images` uses 4 for every pair. The conditional covariance (the
  // paper's) is always the pixel model's.
  int jackknife_grid = 0;
  // Model selection with the rotation-only homography (see above). Off: pairs
  // without parallax fail with kPureRotation.
  bool rotation_model = true;

  // True if every field is within its range; otherwise false, with `error`
  // naming the first field that is not. An estimate with options that do
  // not validate fails with kInvalidInput.
  bool Validate(std::string* error) const;
};

struct RelativePoseResult {
  bool success = false;
  TwoViewFailure failure = TwoViewFailure::kNone;
  std::string message;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // R_21 (refined)
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();   // unit t_21; zero for the rotation model
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  // of omega, rad^2, per covariance_model
  Eigen::Matrix3d covariance_marginal = Eigen::Matrix3d::Identity();     // rad^2 (with the jackknife, if on)
  Eigen::Matrix3d covariance_marginal_pixel = Eigen::Matrix3d::Identity();  // rad^2, the pixel model alone
  Eigen::Matrix3d covariance_conditional = Eigen::Matrix3d::Identity();  // rad^2
  Eigen::Matrix3d covariance_paper = Eigen::Matrix3d::Identity();        // (J_w^T J_w)^-1, unscaled, 1/px^2
  double sigma_px = 0.0;              // estimated pixel noise (RMS Sampson residual, dof-corrected)
  double median_parallax_deg = 0.0;
  // Fraction of the essential-matrix inliers that a homography also explains
  // (same threshold): near 1 for a (near-)planar scene or a pure rotation.
  double homography_inlier_ratio = 0.0;
  std::vector<int> inliers;           // indices into the input correspondences
  double ransac_threshold_px = 0.0;   // inlier threshold of the robust estimation that gave this pose
  int refine_iterations = 0;
  TwoViewModel model = TwoViewModel::kEssential;
  // GRIC scores of the two models when both were fitted (lower wins), else NaN.
  double gric_essential = std::numeric_limits<double>::quiet_NaN();
  double gric_rotation = std::numeric_limits<double>::quiet_NaN();

  // The view-graph edge (1, 2) this pose measures: R_12 = R_21^T. `covariance`
  // is already that of the edge's right perturbation (see above).
  Eigen::Matrix3d EdgeRotation() const { return rotation.transpose(); }
};

// The smallest covariance at least as large as both a and b in every
// direction: b whitened by a, its eigenvalues raised to 1 (a itself if it is
// not positive definite or b is not finite).
Eigen::Matrix3d LoewnerMax(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b);

// The points at the given indices (a pose's inliers) in normalised image
// coordinates K^-1 x. Every index must be within points_px.
std::vector<Eigen::Vector2d> NormalisedPoints(const std::vector<Eigen::Vector2d>& points_px, const Eigen::Matrix3d& k,
                                              const std::vector<int>& indices);

// points1/points2: corresponding pixel coordinates (same length) in images
// with intrinsics K1/K2 (undistorted). Input that cannot be a pair of views
// (kInvalidInput) fails with the reason, as any other failure does.
RelativePoseResult EstimateRelativePoseWithCovariance(const std::vector<Eigen::Vector2d>& points1,
                                                      const std::vector<Eigen::Vector2d>& points2,
                                                      const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                                                      const RelativePoseOptions& options = RelativePoseOptions());

// Refines the pose (R_21, unit t_21) on the correspondences `inliers` (indices
// into points1/points2, pixels of images with intrinsics k1, k2):
// Levenberg-Marquardt on their Sampson errors, as the estimation's own
// refinement does. Returns its iterations.
int RefinePoseOnInliers(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                        const std::vector<int>& inliers, const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                        Eigen::Matrix3d* rotation, Eigen::Vector3d* translation, int max_iterations = 50);
// The same for the rotation-only model (R_21, no translation): Gauss-Newton
// on the transfer errors in image 2, as the estimation's own refinement
// does. Returns its steps, -1 if one was not finite.
int RefineRotationOnInliers(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                            const std::vector<int>& inliers, const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                            Eigen::Matrix3d* rotation, int max_iterations = 20);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_ESTIMATORS_RELATIVE_POSE_H_
