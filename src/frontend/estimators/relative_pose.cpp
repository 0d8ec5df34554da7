#include "rotation_averaging/frontend/estimators/relative_pose.h"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <random>
#include <opencv2/calib3d.hpp>
#include <opencv2/core.hpp>

#include "rotation_averaging/util/option_check.h"
#include "frontend/estimators/two_view_internal.h"
#include "frontend/geometry/epipolar.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

double SampsonPx(const Eigen::Matrix3d& f, const Eigen::Vector2d& p1, const Eigen::Vector2d& p2) {
  return SampsonError<double>(f, p1.homogeneous(), p2.homogeneous());
}

// The fundamental matrix in pixels of the pose (R, t): K2^-T [t]x R K1^-1.
Eigen::Matrix3d FundamentalPx(const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                              const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t) {
  return k2_inv.transpose() * Hat(t) * rotation * k1_inv;
}

// The Sampson refinement moves the pose (R, t) by omega and beta:
// R <- Exp(omega) R, t <- (t + B beta) / |t + B beta|, B an orthonormal basis
// of the plane orthogonal to t. The marginal and conditional covariances of
// omega do not depend on the choice of B.
using Matrix5d = Eigen::Matrix<double, 5, 5>;
using Vector5d = Eigen::Matrix<double, 5, 1>;

Eigen::Matrix<double, 3, 2> TangentBasis(const Eigen::Vector3d& t) {
  const Eigen::Vector3d other = std::abs(t.x()) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
  Eigen::Matrix<double, 3, 2> basis;
  basis.col(0) = t.cross(other).normalized();
  basis.col(1) = t.cross(basis.col(0)).normalized();
  return basis;
}

// Sum of squared Sampson errors (pixels) of the correspondences `indices`.
double SampsonSumSquares(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                         const std::vector<int>& indices, const Eigen::Matrix3d& f) {
  double sum = 0.0;
  for (int i : indices) {
    const double r = SampsonPx(f, points1[i], points2[i]);
    sum += r * r;
  }
  return sum;
}

// Gauss-Newton normal equations J^T J, J^T r of the Sampson errors of
// `indices` in (omega, beta) at (R, t), with closed-form derivatives: F is
// linear in its perturbation, dF/domega_k = K2^-T [t]x [e_k]x R K1^-1 and
// dF/dbeta_j = K2^-T [b_j]x R K1^-1, and dr/dF is SampsonErrorAndGradient.
struct SampsonSystem {
  Matrix5d jtj = Matrix5d::Zero();
  Vector5d jtr = Vector5d::Zero();
  double sum_squares = 0.0;
};

// F at (R, t) and its derivatives in (omega, beta), as 9-vectors.
struct SampsonLinearisation {
  Eigen::Matrix3d f;
  Eigen::Matrix<double, 9, 5> df;
};

SampsonLinearisation LineariseSampson(const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                                      const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t,
                                      const Eigen::Matrix<double, 3, 2>& basis) {
  const Eigen::Matrix3d right = rotation * k1_inv, left = k2_inv.transpose();
  const Eigen::Matrix3d left_t = left * Hat(t);
  SampsonLinearisation out;
  out.f = left_t * right;
  for (int k = 0; k < 3; ++k) {
    const Eigen::Matrix3d d = left_t * Hat(Eigen::Vector3d::Unit(k)) * right;
    out.df.col(k) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(d.data());
  }
  for (int j = 0; j < 2; ++j) {
    const Eigen::Matrix3d d = left * Hat(basis.col(j)) * right;
    out.df.col(3 + j) = Eigen::Map<const Eigen::Matrix<double, 9, 1>>(d.data());
  }
  return out;
}

// Adds the Sampson error of one correspondence to `system`.
void AccumulateSampson(const SampsonLinearisation& lin, const Eigen::Vector2d& p1, const Eigen::Vector2d& p2,
                       SampsonSystem* system) {
  Eigen::Matrix3d gradient;
  const double r = SampsonErrorAndGradient(lin.f, p1.homogeneous(), p2.homogeneous(), &gradient);
  const Eigen::Matrix<double, 1, 5> j = Eigen::Map<const Eigen::Matrix<double, 1, 9>>(gradient.data()) * lin.df;
  system->jtj.noalias() += j.transpose() * j;
  system->jtr.noalias() += r * j.transpose();
  system->sum_squares += r * r;
}

SampsonSystem BuildSampsonSystem(const std::vector<Eigen::Vector2d>& points1,
                                 const std::vector<Eigen::Vector2d>& points2, const std::vector<int>& indices,
                                 const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                                 const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t,
                                 const Eigen::Matrix<double, 3, 2>& basis) {
  const SampsonLinearisation lin = LineariseSampson(k1_inv, k2_inv, rotation, t, basis);
  SampsonSystem system;
  for (int i : indices) AccumulateSampson(lin, points1[i], points2[i], &system);
  return system;
}

// Levenberg-Marquardt on the Sampson errors of `indices` from (rotation, t)
// (a trust region on the scaled diagonal, as Ceres' default, to relative
// tolerances of 1e-12 on the cost and the step). Returns the iterations.
int RefineSampson(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                  const std::vector<int>& indices, const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                  int max_iterations, Eigen::Matrix3d* rotation, Eigen::Vector3d* t) {
  Eigen::Matrix<double, 3, 2> basis = TangentBasis(*t);
  SampsonSystem system = BuildSampsonSystem(points1, points2, indices, k1_inv, k2_inv, *rotation, *t, basis);
  double lambda = 1e-4;
  int iterations = 0;
  while (iterations < max_iterations) {
    ++iterations;
    Matrix5d damped = system.jtj;
    damped.diagonal() += lambda * system.jtj.diagonal().cwiseMax(1e-6);
    const Vector5d step = damped.ldlt().solve(-system.jtr);
    if (!step.allFinite()) break;
    const Eigen::Matrix3d rotation_new = ExpSO3(step.head<3>()) * *rotation;
    const Eigen::Vector3d t_new = (*t + basis * step.tail<2>()).normalized();
    const double cost_new =
        SampsonSumSquares(points1, points2, indices, FundamentalPx(k1_inv, k2_inv, rotation_new, t_new));
    if (!(cost_new < system.sum_squares)) {
      lambda *= 10.0;
      if (lambda > 1e16) break;
      continue;
    }
    const double decrease = system.sum_squares - cost_new;
    *rotation = rotation_new;
    *t = t_new;
    if (decrease <= 1e-12 * system.sum_squares || step.norm() <= 1e-12) break;
    lambda = std::max(lambda / 10.0, 1e-16);
    basis = TangentBasis(*t);
    system = BuildSampsonSystem(points1, points2, indices, k1_inv, k2_inv, *rotation, *t, basis);
  }
  return iterations;
}

// Delete-one-cell jackknife covariance of the rotation: the inliers grouped by
// the cell of a grid x grid partition of their bounding box in image 1, the
// pose re-estimated without each non-empty cell in turn (t too: a marginal
// covariance), C = (g-1)/g sum_c (w_c - mean)(w_c - mean)^T over the g
// cells. Errors shared within a region of the image (a group of wrong
// matches on a repeated structure, a local bias of the keypoints) move the
// pose together when their cell is left out, where the pixel model counts
// them as independent. Zero when fewer than two cells hold inliers.
// Each re-estimate is one Gauss-Newton step from the full optimum on the
// normal equations without the cell, (H - H_c) d = -(g - g_c): leaving out
// a sixteenth of the inliers moves the pose by a fraction of its standard
// deviation, where the Sampson errors are linear in it. One pass over the
// inliers builds every cell's H_c and g_c, where refining each cell's pose
// on its own passed over all of them several times per cell.
Eigen::Matrix3d CellJackknifeCovariance(const std::vector<Eigen::Vector2d>& points1,
                                        const std::vector<Eigen::Vector2d>& points2, const std::vector<int>& inliers,
                                        const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                                        const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t, int grid) {
  double x0 = INFINITY, x1 = -INFINITY, y0 = INFINITY, y1 = -INFINITY;
  for (int i : inliers) {
    x0 = std::min(x0, points1[i].x());
    x1 = std::max(x1, points1[i].x());
    y0 = std::min(y0, points1[i].y());
    y1 = std::max(y1, points1[i].y());
  }
  const auto cell_index = [grid](double v, double lo, double hi) {
    return hi > lo ? std::clamp(static_cast<int>((v - lo) / (hi - lo) * grid), 0, grid - 1) : 0;
  };
  const SampsonLinearisation lin = LineariseSampson(k1_inv, k2_inv, rotation, t, TangentBasis(t));
  std::vector<SampsonSystem> cells(static_cast<size_t>(grid) * grid);
  std::vector<int> counts(cells.size(), 0);
  for (int i : inliers) {
    const size_t c =
        static_cast<size_t>(cell_index(points1[i].y(), y0, y1)) * grid + cell_index(points1[i].x(), x0, x1);
    AccumulateSampson(lin, points1[i], points2[i], &cells[c]);
    ++counts[c];
  }
  SampsonSystem total;
  for (const SampsonSystem& cell : cells) {
    total.jtj += cell.jtj;
    total.jtr += cell.jtr;
  }
  std::vector<Eigen::Vector3d> moves;
  for (size_t c = 0; c < cells.size(); ++c) {
    if (counts[c] == 0) continue;
    const Matrix5d h = total.jtj - cells[c].jtj;
    const Eigen::LDLT<Matrix5d> ldlt(h);
    if (ldlt.info() != Eigen::Success || !ldlt.isPositive()) continue;  // the rest does not constrain the pose
    const Vector5d step = ldlt.solve(-(total.jtr - cells[c].jtr));
    if (!step.allFinite()) continue;
    moves.push_back(step.head<3>());
  }
  const int g = static_cast<int>(moves.size());
  if (g < 2) return Eigen::Matrix3d::Zero();
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const Eigen::Vector3d& m : moves) mean += m / g;
  Eigen::Matrix3d c = Eigen::Matrix3d::Zero();
  for (const Eigen::Vector3d& m : moves) c.noalias() += (m - mean) * (m - mean).transpose();
  return static_cast<double>(g - 1) / g * c;
}

// Standard deviation of Gaussian residuals from their absolute values
// (1.4826 x the median: robust to the outliers among them); reorders them.
double RobustSigma(std::vector<double>* absolute) {
  std::nth_element(absolute->begin(), absolute->begin() + absolute->size() / 2, absolute->end());
  return 1.4826 * (*absolute)[absolute->size() / 2];
}

Eigen::Matrix3d CvToEigen3(const cv::Mat& m) {
  Eigen::Matrix3d out;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) out(r, c) = m.at<double>(r, c);
  return out;
}

// Least-squares depths (lambda1, lambda2) of lambda2 b2 = lambda1 R b1 + t:
// along b1 in camera 1 and b2 in camera 2, in units of |t|.
Eigen::Vector2d Depths(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t, const Eigen::Vector3d& b1,
                       const Eigen::Vector3d& b2) {
  Eigen::Matrix<double, 3, 2> a;
  a.col(0) = rotation * b1;
  a.col(1) = -b2;
  return (a.transpose() * a).ldlt().solve(a.transpose() * -t);
}

// True if the point seen along bearings b1, b2 triangulates in front of both
// cameras.
bool InFront(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t, const Eigen::Vector3d& b1,
             const Eigen::Vector3d& b2) {
  const Eigen::Vector2d depths = Depths(rotation, t, b1, b2);
  return depths[0] > 0.0 && depths[1] > 0.0;
}

// The pose an essential matrix holds: of its four decompositions (R1, t),
// (R2, t), (R1, -t), (R2, -t), the first with the most points of `mask` (n1,
// n2: normalised coordinates, one row each) at depths within (0,
// max_depth) baselines in both cameras, as cv::recoverPose chooses; `mask`
// keeps those points. recoverPose triangulates every point for each
// decomposition by a 4x4 SVD, the mask's outliers too: a tenth of the front
// end's CPU on a 20 Hz stream. Here the depths are least-squares ones, as
// for every other cheirality test of the estimation (InFront).
int PoseInFront(const cv::Mat& essential, const cv::Mat& n1, const cv::Mat& n2, double max_depth, cv::Mat* mask,
                Eigen::Matrix3d* rotation, Eigen::Vector3d* t) {
  cv::Mat r1, r2, t_cv;
  cv::decomposeEssentialMat(essential, r1, r2, t_cv);
  const Eigen::Vector3d t0(t_cv.at<double>(0), t_cv.at<double>(1), t_cv.at<double>(2));
  const Eigen::Matrix3d first = CvToEigen3(r1), second = CvToEigen3(r2);
  const Eigen::Matrix3d rotations[4] = {first, second, first, second};
  const Eigen::Vector3d translations[4] = {t0, t0, -t0, -t0};
  const int n = n1.rows;
  std::vector<unsigned char> good[4];
  int count[4] = {0, 0, 0, 0};
  for (int c = 0; c < 4; ++c) good[c].assign(n, 0);
  for (int i = 0; i < n; ++i) {
    if (!mask->empty() && !mask->at<unsigned char>(i)) continue;
    const Eigen::Vector3d b1(n1.at<double>(i, 0), n1.at<double>(i, 1), 1.0);
    const Eigen::Vector3d b2(n2.at<double>(i, 0), n2.at<double>(i, 1), 1.0);
    for (int c = 0; c < 4; ++c) {
      const Eigen::Vector2d d = Depths(rotations[c], translations[c], b1, b2);
      if (d[0] > 0.0 && d[1] > 0.0 && d[0] < max_depth && d[1] < max_depth) {
        good[c][i] = 1;
        ++count[c];
      }
    }
  }
  const int best = static_cast<int>(std::max_element(count, count + 4) - count);
  *rotation = rotations[best];
  *t = translations[best];
  mask->create(n, 1, CV_8U);
  for (int i = 0; i < n; ++i) mask->at<unsigned char>(i) = good[best][i];
  return count[best];
}

cv::Mat ToCv(const std::vector<Eigen::Vector2d>& points, const Eigen::Matrix3d& k_inv) {
  cv::Mat out(static_cast<int>(points.size()), 2, CV_64F);
  for (int i = 0; i < out.rows; ++i) {
    const Eigen::Vector3d n = k_inv * points[i].homogeneous();
    out.at<double>(i, 0) = n.x() / n.z();
    out.at<double>(i, 1) = n.y() / n.z();
  }
  return out;
}

constexpr int kHomographyIterations = 500;
// In baselines: the depth limit of cheirality (cv::recoverPose's), and none.
constexpr double kNearPointDistance = 50.0;
constexpr double kFarPointDistance = 1e9;

}  // namespace

RelativePoseResult TwoViewFail(TwoViewFailure failure, const std::string& message) {
  RelativePoseResult r;
  r.success = false;
  r.failure = failure;
  r.message = message;
  return r;
}

int RefinePoseOnInliers(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                        const std::vector<int>& inliers, const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                        Eigen::Matrix3d* rotation, Eigen::Vector3d* translation, int max_iterations) {
  *translation = translation->normalized();
  return RefineSampson(points1, points2, inliers, k1.inverse(), k2.inverse(), max_iterations, rotation, translation);
}

const char* RotationCovarianceModelName(RotationCovarianceModel model) {
  return model == RotationCovarianceModel::kConditional ? "conditional" : "marginal";
}

std::string RotationCovarianceModelChoices() {
  return std::string(RotationCovarianceModelName(RotationCovarianceModel::kMarginal)) + ", " +
         RotationCovarianceModelName(RotationCovarianceModel::kConditional);
}

const char* TwoViewModelName(TwoViewModel model) {
  return model == TwoViewModel::kRotation ? "rotation" : "essential";
}

bool ParseRotationCovarianceModel(const std::string& text, RotationCovarianceModel* model) {
  if (text == "marginal") *model = RotationCovarianceModel::kMarginal;
  else if (text == "conditional") *model = RotationCovarianceModel::kConditional;
  else return false;
  return true;
}

const char* TwoViewFailureName(TwoViewFailure failure) {
  switch (failure) {
    case TwoViewFailure::kNone: return "none";
    case TwoViewFailure::kTooFewMatches: return "too_few_matches";
    case TwoViewFailure::kEssentialFailed: return "essential_failed";
    case TwoViewFailure::kTooFewInliers: return "too_few_inliers";
    case TwoViewFailure::kPureRotation: return "pure_rotation";
    case TwoViewFailure::kNearPlanar: return "near_planar";
    case TwoViewFailure::kRefinementFailed: return "refinement_failed";
    case TwoViewFailure::kSingularInformation: return "singular_information";
    case TwoViewFailure::kInvalidInput: return "invalid_input";
  }
  return "?";
}

namespace {

// The essential matrix of the robust estimation, as a fundamental matrix in
// pixels, and its inliers before the cheirality test: the general-motion
// model that the rotation-only model competes with, even when the pose could
// not be recovered from it.
struct EssentialFit {
  bool found = false;
  Eigen::Matrix3d f_px = Eigen::Matrix3d::Zero();
  std::vector<int> inliers;
};

// The steps of EstimateAtThreshold. Each that can fail returns false with
// the result to return in `failure`.

// 1. Robust essential matrix on normalised coordinates `n1`, `n2`, then
// cheirality: the pose and its inliers.
bool RobustEssentialPose(const cv::Mat& n1, const cv::Mat& n2, int n, const Eigen::Matrix3d& k1_inv,
                         const Eigen::Matrix3d& k2_inv, double threshold_normalised, const RelativePoseOptions& options,
                         EssentialFit* fit, Eigen::Matrix3d* rotation, Eigen::Vector3d* t, std::vector<int>* inliers,
                         RelativePoseResult* failure) {
  cv::Mat mask;
  cv::Mat essential;
  try {
    essential = cv::findEssentialMat(n1, n2, cv::Mat::eye(3, 3, CV_64F), cv::USAC_MAGSAC, options.ransac_confidence,
                                     threshold_normalised, options.ransac_max_iterations, mask);
  } catch (const cv::Exception& e) {
    *failure = TwoViewFail(TwoViewFailure::kEssentialFailed, std::string("OpenCV: ") + e.what());
    return false;
  }
  if (essential.rows < 3 || essential.cols != 3) {
    *failure = TwoViewFail(TwoViewFailure::kEssentialFailed, "no essential matrix");
    return false;
  }
  essential = essential.rowRange(0, 3).clone();
  if (fit) {
    fit->found = true;
    fit->f_px = k2_inv.transpose() * CvToEigen3(essential) * k1_inv;
    fit->inliers.clear();
    for (int i = 0; i < n; ++i)
      if (mask.at<unsigned char>(i)) fit->inliers.push_back(i);
  }
  int in_front = 0;
  try {
    const cv::Mat ransac_mask = mask.clone();
    in_front = PoseInFront(essential, n1, n2, kNearPointDistance, &mask, rotation, t);
    if (in_front < options.min_inliers) {
      // The depth limit drops points farther than 50 baselines, which takes
      // every point of a short-baseline pair (a step of 0.1 m in front of a
      // wall 6 m away) out of the inliers. Such a pair is decided with its far
      // points; the others keep the limit, which also rejects the twisted-pair
      // solution of a plane (it puts the plane's points near infinity).
      mask = ransac_mask;
      in_front = PoseInFront(essential, n1, n2, kFarPointDistance, &mask, rotation, t);
    }
  } catch (const cv::Exception& e) {
    *failure = TwoViewFail(TwoViewFailure::kEssentialFailed, std::string("OpenCV: ") + e.what());
    return false;
  }
  inliers->clear();
  for (int i = 0; i < n; ++i)
    if (mask.at<unsigned char>(i)) inliers->push_back(i);
  if (in_front < options.min_inliers || static_cast<int>(inliers->size()) < options.min_inliers) {
    *failure = TwoViewFail(TwoViewFailure::kTooFewInliers, std::to_string(inliers->size()) + " inliers");
    return false;
  }
  *rotation = ProjectToSO3(*rotation);
  t->normalize();
  return true;
}

// Planarity: the share of the inliers a homography explains as well.
double HomographyInlierRatio(const cv::Mat& n1, const cv::Mat& n2, const std::vector<int>& inliers,
                             double threshold_normalised) {
  cv::Mat h1(static_cast<int>(inliers.size()), 2, CV_64F), h2(h1.rows, 2, CV_64F);
  for (int r = 0; r < h1.rows; ++r) {
    n1.row(inliers[r]).copyTo(h1.row(r));
    n2.row(inliers[r]).copyTo(h2.row(r));
  }
  cv::Mat h_mask;
  try {
    // Plain RANSAC on the (already clean) essential-matrix inliers: USAC
    // MAGSAC here cost 20x the rest of the pair's estimation.
    const cv::Mat h =
        cv::findHomography(h1, h2, cv::RANSAC, threshold_normalised, h_mask, kHomographyIterations, 0.999);
    if (!h.empty()) return static_cast<double>(cv::countNonZero(h_mask)) / h1.rows;
  } catch (const cv::Exception&) {
  }
  return 0.0;
}

// 2. Parallax: the median angle between rotated bearings (deg); ~0 for a
// pure rotation.
double MedianParallaxDeg(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                         const std::vector<int>& inliers, const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                         const Eigen::Matrix3d& rotation) {
  std::vector<double> parallax;
  parallax.reserve(inliers.size());
  for (int i : inliers) {
    const Eigen::Vector3d b1 = rotation * (k1_inv * points1[i].homogeneous()).normalized();
    const Eigen::Vector3d b2 = (k2_inv * points2[i].homogeneous()).normalized();
    parallax.push_back(std::atan2(b1.cross(b2).norm(), b1.dot(b2)));
  }
  std::nth_element(parallax.begin(), parallax.begin() + parallax.size() / 2, parallax.end());
  return RadToDeg(parallax[parallax.size() / 2]);
}

// The Sampson error is the same for t and -t, so the refinement cannot
// tell them apart; cheirality can. A robust model off along the
// rotation-translation valley can have its points in front only with the
// mirrored translation, and the refinement then brings R back and keeps
// t mirrored: every point behind the cameras. So t takes the sign that
// puts more of the inliers in front.
void OrientTranslationByCheirality(const std::vector<Eigen::Vector2d>& points1,
                                   const std::vector<Eigen::Vector2d>& points2, const std::vector<int>& inliers,
                                   const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                                   const Eigen::Matrix3d& rotation, Eigen::Vector3d* t) {
  int in_front_count = 0, behind_count = 0;
  for (int i : inliers) {
    const Eigen::Vector3d b1 = k1_inv * points1[i].homogeneous(), b2 = k2_inv * points2[i].homogeneous();
    if (InFront(rotation, *t, b1, b2)) ++in_front_count;
    else if (InFront(rotation, -*t, b1, b2)) ++behind_count;
  }
  if (behind_count > in_front_count) *t = -*t;
}

// The correspondences within 3 sigma of the pose (|Sampson|, sigma from the
// median absolute residual of the current `inliers`) and in front of both
// cameras.
std::vector<int> ReselectInliers(const std::vector<Eigen::Vector2d>& points1,
                                 const std::vector<Eigen::Vector2d>& points2, const std::vector<int>& inliers,
                                 const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                                 const Eigen::Matrix3d& rotation, const Eigen::Vector3d& t) {
  const int n = static_cast<int>(points1.size());
  const Eigen::Matrix3d f = FundamentalPx(k1_inv, k2_inv, rotation, t);
  std::vector<double> residual(n), absolute;
  absolute.reserve(n);
  for (int i = 0; i < n; ++i) {
    residual[i] = SampsonPx(f, points1[i], points2[i]);
    absolute.push_back(std::abs(residual[i]));
  }
  std::vector<double> inlier_abs;
  for (int i : inliers) inlier_abs.push_back(absolute[i]);
  const double sigma = RobustSigma(&inlier_abs);
  std::vector<int> selected;
  for (int i = 0; i < n; ++i) {
    if (absolute[i] > 3.0 * sigma) continue;
    const Eigen::Vector3d b1 = k1_inv * points1[i].homogeneous(), b2 = k2_inv * points2[i].homogeneous();
    if (InFront(rotation, t, b1, b2)) selected.push_back(i);
  }
  return selected;
}

// 3. Sampson refinement of (omega, t) over the inliers. The robust
// estimator's inlier set is cut at its own (less accurate) model, which
// biases the refinement towards that model and truncates the noise estimate:
// so after each refinement, inliers are re-selected from all correspondences
// (ReselectInliers) and the refinement repeated until the set settles.
bool RefineWithReselection(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                           const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                           const RelativePoseOptions& options, Eigen::Matrix3d* rotation, Eigen::Vector3d* t,
                           std::vector<int>* inliers, int* refine_iterations, RelativePoseResult* failure) {
  *refine_iterations = 0;
  for (int round = 0; round < kMaxReselectionRounds; ++round) {
    const Eigen::Matrix3d rotation_before = *rotation;
    *refine_iterations +=
        RefineSampson(points1, points2, *inliers, k1_inv, k2_inv, options.refine_max_iterations, rotation, t);
    const double moved = AngularDistanceRad(*rotation, rotation_before);
    if (!rotation->allFinite() || !t->allFinite() || !(moved <= 0.5)) {
      *failure = TwoViewFail(TwoViewFailure::kRefinementFailed,
                      "refinement moved the rotation by " + std::to_string(RadToDeg(moved)) + " deg or diverged");
      return false;
    }
    OrientTranslationByCheirality(points1, points2, *inliers, k1_inv, k2_inv, *rotation, t);
    std::vector<int> selected = ReselectInliers(points1, points2, *inliers, k1_inv, k2_inv, *rotation, *t);
    if (static_cast<int>(selected.size()) < options.min_inliers) {
      *failure = TwoViewFail(TwoViewFailure::kTooFewInliers, std::to_string(selected.size()) + " inliers after refinement");
      return false;
    }
    const bool settled = selected == *inliers;
    inliers->swap(selected);
    if (settled) break;
  }
  return true;
}

// 4. The covariances from the Jacobian at the optimum w.r.t. omega (3) and
// the tangent of t (2), into `result` (whose pose and inliers are set).
bool CovarianceAtOptimum(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                         const Eigen::Matrix3d& k1_inv, const Eigen::Matrix3d& k2_inv,
                         const RelativePoseOptions& options, RelativePoseResult* result, RelativePoseResult* failure) {
  const SampsonSystem at_optimum = BuildSampsonSystem(points1, points2, result->inliers, k1_inv, k2_inv,
                                                      result->rotation, result->translation,
                                                      TangentBasis(result->translation));
  const Matrix5d& jtj = at_optimum.jtj;
  if (!jtj.allFinite() || !std::isfinite(at_optimum.sum_squares)) {
    *failure = TwoViewFail(TwoViewFailure::kRefinementFailed, "Jacobian is not finite");
    return false;
  }
  const int m = static_cast<int>(result->inliers.size());
  const double sigma2 = at_optimum.sum_squares / std::max(1, m - 5);
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 5, 5>> eig(jtj);
  const double min_eig = eig.eigenvalues().minCoeff(), max_eig = eig.eigenvalues().maxCoeff();
  if (!(min_eig > 0.0) || max_eig / min_eig > options.max_condition_number) {
    *failure = TwoViewFail(TwoViewFailure::kSingularInformation,
                    "J^T J condition number " + std::to_string(min_eig > 0.0 ? max_eig / min_eig : INFINITY));
    return false;
  }
  const Eigen::Matrix<double, 5, 5> jtj_inv =
      eig.eigenvectors() * eig.eigenvalues().cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  result->sigma_px = std::sqrt(sigma2);
  result->covariance_paper = jtj.topLeftCorner<3, 3>().inverse();
  result->covariance_conditional = sigma2 * result->covariance_paper;
  result->covariance_marginal = sigma2 * jtj_inv.topLeftCorner<3, 3>();
  result->covariance_marginal = 0.5 * (result->covariance_marginal + result->covariance_marginal.transpose()).eval();
  result->covariance_marginal_pixel = result->covariance_marginal;
  result->covariance = options.covariance_model == RotationCovarianceModel::kConditional
                           ? result->covariance_conditional
                           : result->covariance_marginal;
  return true;
}

// One robust estimation (inlier threshold `threshold_px`), refinement and
// covariance; the inputs are checked by the caller.
RelativePoseResult EstimateAtThreshold(const std::vector<Eigen::Vector2d>& points1,
                                       const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k1,
                                       const Eigen::Matrix3d& k2, double threshold_px,
                                       const RelativePoseOptions& options, EssentialFit* fit = nullptr) {
  const int n = static_cast<int>(points1.size());
  const Eigen::Matrix3d k1_inv = k1.inverse(), k2_inv = k2.inverse();
  const double focal = 0.25 * (k1(0, 0) + k1(1, 1) + k2(0, 0) + k2(1, 1));
  const cv::Mat n1 = ToCv(points1, k1_inv), n2 = ToCv(points2, k2_inv);
  RelativePoseResult failure;
  Eigen::Matrix3d rotation;
  Eigen::Vector3d t;
  std::vector<int> inliers;
  if (!RobustEssentialPose(n1, n2, n, k1_inv, k2_inv, threshold_px / focal, options, fit, &rotation, &t, &inliers,
                           &failure)) {
    return failure;
  }
  // Always at the first threshold, whichever found the inliers: the share
  // describes the scene and is compared with fixed ratios.
  const double homography_ratio = HomographyInlierRatio(n1, n2, inliers, options.ransac_threshold_px / focal);
  if (homography_ratio > options.max_homography_inlier_ratio) {
    RelativePoseResult r = TwoViewFail(TwoViewFailure::kNearPlanar, "a homography explains " +
                                                                 std::to_string(100.0 * homography_ratio) + "% of the inliers");
    r.homography_inlier_ratio = homography_ratio;
    return r;
  }
  const double median_parallax_deg = MedianParallaxDeg(points1, points2, inliers, k1_inv, k2_inv, rotation);
  // Without the rotation model, a pair without parallax is rejected here.
  // With it, model selection decides: a pair the general model still wins has
  // a translation the data show, and its marginal covariance carries how
  // weakly that translation is observed.
  if (!options.rotation_model && median_parallax_deg < options.min_median_parallax_deg) {
    RelativePoseResult r = TwoViewFail(TwoViewFailure::kPureRotation, "median parallax " + std::to_string(median_parallax_deg) + " deg");
    r.median_parallax_deg = median_parallax_deg;
    return r;
  }
  int refine_iterations = 0;
  if (!RefineWithReselection(points1, points2, k1_inv, k2_inv, options, &rotation, &t, &inliers, &refine_iterations,
                             &failure)) {
    return failure;
  }
  RelativePoseResult result;
  result.success = true;
  result.rotation = rotation;
  result.translation = t;
  result.inliers = std::move(inliers);
  result.median_parallax_deg = median_parallax_deg;
  result.homography_inlier_ratio = homography_ratio;
  result.refine_iterations = refine_iterations;
  result.ransac_threshold_px = threshold_px;
  if (!CovarianceAtOptimum(points1, points2, k1_inv, k2_inv, options, &result, &failure)) return failure;
  return result;
}

// Torr's Geometric Robust Information Criterion of a model with manifold
// dimension d and k parameters, from squared residuals in units of the noise
// (r = 4 data dimensions per correspondence, lambda1 = ln r, lambda2 = ln rn,
// residuals capped at lambda3 (r - d) with lambda3 = 2).
double Gric(const std::vector<double>& normalised_squares, int d, int k) {
  const double r = 4.0, n = static_cast<double>(normalised_squares.size());
  double sum = 0.0;
  for (double e2 : normalised_squares) sum += std::min(e2, 2.0 * (r - d));
  return sum + std::log(r) * d * n + std::log(r * n) * k;
}

// Scores both models on the correspondences either counts as an inlier, in
// units of the pair's noise measured under the general-motion model f_px:
// it fits a pure rotation as well as a general motion, so that sigma holds in
// either case.
void SelectModel(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                 const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2, const Eigen::Matrix3d& f_px,
                 const std::vector<int>& essential_inliers, double sigma_px, const RelativePoseResult& rotation,
                 double* gric_essential, double* gric_rotation) {
  std::vector<int> both = essential_inliers;
  both.insert(both.end(), rotation.inliers.begin(), rotation.inliers.end());
  std::sort(both.begin(), both.end());
  both.erase(std::unique(both.begin(), both.end()), both.end());
  const Eigen::Matrix3d k1_inv = k1.inverse();
  const double sigma2 = std::max(1e-12, sigma_px * sigma_px);
  std::vector<double> e_squares, r_squares;
  for (int i : both) {
    const double s = SampsonPx(f_px, points1[i], points2[i]);
    e_squares.push_back(s * s / sigma2);
    Eigen::Vector2d e;
    const bool front = TransferError(k2, rotation.rotation, (k1_inv * points1[i].homogeneous()).normalized(),
                                     points2[i], &e);
    r_squares.push_back(front ? 0.5 * e.squaredNorm() / sigma2 : INFINITY);
  }
  *gric_essential = Gric(e_squares, 3, 5);
  *gric_rotation = Gric(r_squares, 2, 3);
}

// Below this share of the essential-matrix inliers explained by a homography,
// no rotation (a special homography) can explain enough of them to win.
constexpr double kRotationModelMinHomographyRatio = 0.5;

// The essential-matrix model at the first threshold, then again at the
// pair's own noise level; the inputs are checked by the caller.
RelativePoseResult EstimateEssentialPixelModel(const std::vector<Eigen::Vector2d>& points1,
                                               const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k1,
                                               const Eigen::Matrix3d& k2, const RelativePoseOptions& options,
                                               EssentialFit* fit) {
  const int n = static_cast<int>(points1.size());
  const Eigen::Matrix3d k1_inv = k1.inverse(), k2_inv = k2.inverse();
  RelativePoseResult first = EstimateAtThreshold(points1, points2, k1, k2, options.ransac_threshold_px, options, fit);
  if (!first.success || !(options.adaptive_threshold_sigmas > 0.0)) return first;
  // A threshold far above the pixel noise lets wrong matches that happen to
  // lie near their epipolar lines (repeated structure) vote, and a few of
  // them can pull the model along the rotation-translation valley of a pair.
  // Once the noise of this pair is measured, the robust estimation is run
  // again with a threshold that scale of noise calls for.
  const double threshold =
      std::max(options.min_adaptive_threshold_px, options.adaptive_threshold_sigmas * first.sigma_px);
  if (!(threshold < options.ransac_threshold_px)) return first;
  // Only the correspondences within the first threshold of the first model
  // take part: the others cannot be inliers of a model this close to it, and
  // without them the robust estimation stops after far fewer samples.
  const Eigen::Matrix3d f = FundamentalPx(k1_inv, k2_inv, first.rotation, first.translation);
  std::vector<int> candidates;
  std::vector<Eigen::Vector2d> q1, q2;
  for (int i = 0; i < n; ++i) {
    if (std::abs(SampsonPx(f, points1[i], points2[i])) >= options.ransac_threshold_px) continue;
    candidates.push_back(i);
    q1.push_back(points1[i]);
    q2.push_back(points2[i]);
  }
  if (static_cast<int>(candidates.size()) < std::max(options.min_inliers, 5)) return first;
  RelativePoseResult second = EstimateAtThreshold(q1, q2, k1, k2, threshold, options);
  if (!second.success) return first;
  for (int& i : second.inliers) i = candidates[i];
  return second;
}

// The essential-matrix pose, its marginal covariance widened by the cell
// jackknife (RelativePoseOptions::jackknife_grid) once, on the pose that is
// returned: of the two robust estimations above, only one is kept.
RelativePoseResult EstimateEssential(const std::vector<Eigen::Vector2d>& points1,
                                     const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k1,
                                     const Eigen::Matrix3d& k2, const RelativePoseOptions& options,
                                     EssentialFit* fit) {
  RelativePoseResult result = EstimateEssentialPixelModel(points1, points2, k1, k2, options, fit);
  if (!result.success || options.jackknife_grid < 2 || !result.covariance_marginal.allFinite()) return result;
  result.covariance_marginal =
      LoewnerMax(result.covariance_marginal,
                 CellJackknifeCovariance(points1, points2, result.inliers, k1.inverse(), k2.inverse(), result.rotation,
                                         result.translation, options.jackknife_grid));
  if (options.covariance_model == RotationCovarianceModel::kMarginal) result.covariance = result.covariance_marginal;
  return result;
}

}  // namespace

std::vector<Eigen::Vector2d> NormalisedPoints(const std::vector<Eigen::Vector2d>& points_px, const Eigen::Matrix3d& k,
                                              const std::vector<int>& indices) {
  const Eigen::Matrix3d k_inv = k.inverse();
  std::vector<Eigen::Vector2d> out;
  out.reserve(indices.size());
  for (int i : indices) out.push_back((k_inv * points_px[i].homogeneous()).hnormalized());
  return out;
}

bool RelativePoseOptions::Validate(std::string* error) const {
  return OptionCheck()
      .Above("ransac_threshold_px", ransac_threshold_px, 0.0)
      .AtLeast("adaptive_threshold_sigmas", adaptive_threshold_sigmas, 0.0)
      .AtLeast("min_adaptive_threshold_px", min_adaptive_threshold_px, 0.0)
      .Between("ransac_confidence", ransac_confidence, 0.0, 1.0)
      .AtLeast("ransac_max_iterations", ransac_max_iterations, 1)
      .AtLeast("min_inliers", min_inliers, 5)
      .AtLeast("min_median_parallax_deg", min_median_parallax_deg, 0.0)
      .Within("max_homography_inlier_ratio", max_homography_inlier_ratio, 0.0, 1.0)
      .Within("near_planar_report_ratio", near_planar_report_ratio, 0.0, 1.0)
      .AtLeast("refine_max_iterations", refine_max_iterations, 0)
      .Above("max_condition_number", max_condition_number, 1.0)
      .Within("jackknife_grid", jackknife_grid, 0, 16)
      .Ok(error);
}

RelativePoseResult EstimateRelativePoseWithCovariance(const std::vector<Eigen::Vector2d>& points1,
                                                      const std::vector<Eigen::Vector2d>& points2,
                                                      const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                                                      const RelativePoseOptions& options) {
  std::string options_error;
  if (!options.Validate(&options_error)) return TwoViewFail(TwoViewFailure::kInvalidInput, "options: " + options_error);
  const int n = static_cast<int>(std::min(points1.size(), points2.size()));
  if (points1.size() != points2.size()) {
    return TwoViewFail(TwoViewFailure::kInvalidInput, "point lists differ in length (" + std::to_string(points1.size()) +
                                                   " and " + std::to_string(points2.size()) + ")");
  }
  // Refused here with the reason, not left to OpenCV's estimator, whose
  // outcome on such input (if it fails at all) would not name the cause.
  for (int i = 0; i < n; ++i) {
    if (!points1[i].allFinite() || !points2[i].allFinite()) {
      return TwoViewFail(TwoViewFailure::kInvalidInput, "correspondence " + std::to_string(i) + " is not finite");
    }
  }
  for (const Eigen::Matrix3d* k : {&k1, &k2}) {
    if (!IsCameraIntrinsics(*k)) {
      return TwoViewFail(TwoViewFailure::kInvalidInput,
                  std::string(k == &k1 ? "K1" : "K2") + " is not intrinsics (" + kCameraIntrinsicsRule + ")");
    }
  }
  if (n < std::max(options.min_inliers, 5)) {
    return TwoViewFail(TwoViewFailure::kTooFewMatches, std::to_string(n) + " correspondences");
  }
  const Eigen::Matrix3d k1_inv = k1.inverse(), k2_inv = k2.inverse();
  if (!k1_inv.allFinite() || !k2_inv.allFinite()) return TwoViewFail(TwoViewFailure::kInvalidInput, "singular intrinsics");
  EssentialFit fit;
  RelativePoseResult essential = EstimateEssential(points1, points2, k1, k2, options, &fit);
  if (!options.rotation_model) return essential;
  // A pair the user rejects as near-planar stays rejected: a rotation is a
  // homography too.
  if (!essential.success && (essential.failure == TwoViewFailure::kNearPlanar || !fit.found)) return essential;
  if (essential.success && !(essential.homography_inlier_ratio >= kRotationModelMinHomographyRatio)) return essential;
  // Half the general model's support, as for the homography share above.
  const std::size_t general_support = essential.success ? essential.inliers.size() : fit.inliers.size();
  RelativePoseResult rotation = EstimateRotationOnly(
      points1, points2, k1, k2, options,
      static_cast<int>(std::floor(kRotationModelMinHomographyRatio * static_cast<double>(general_support))));
  if (!rotation.success) return essential;
  double gric_essential = 0.0, gric_rotation = 0.0;
  if (essential.success) {
    SelectModel(points1, points2, k1, k2, FundamentalPx(k1_inv, k2_inv, essential.rotation, essential.translation),
                essential.inliers, essential.sigma_px, rotation, &gric_essential, &gric_rotation);
  } else {
    // The pose could not be recovered from the essential matrix (no
    // parallax, too few points in front, singular): its robust fit still
    // measures the noise and competes as the general-motion model.
    std::vector<double> absolute;
    for (int i : fit.inliers) absolute.push_back(std::abs(SampsonPx(fit.f_px, points1[i], points2[i])));
    if (absolute.empty()) return essential;
    SelectModel(points1, points2, k1, k2, fit.f_px, fit.inliers, RobustSigma(&absolute), rotation, &gric_essential,
                &gric_rotation);
  }
  RelativePoseResult& chosen = gric_rotation < gric_essential ? rotation : essential;
  chosen.gric_essential = gric_essential;
  chosen.gric_rotation = gric_rotation;
  if (essential.success) chosen.homography_inlier_ratio = essential.homography_inlier_ratio;
  chosen.median_parallax_deg = essential.median_parallax_deg;
  return chosen;
}

Eigen::Matrix3d LoewnerMax(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const Eigen::LLT<Eigen::Matrix3d> llt(a);
  if (llt.info() != Eigen::Success || !b.allFinite()) return a;
  const Eigen::Matrix3d l = llt.matrixL();
  const Eigen::Matrix3d l_inv = l.inverse();
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(l_inv * b * l_inv.transpose());
  const Eigen::Matrix3d out = l * eig.eigenvectors() * eig.eigenvalues().cwiseMax(1.0).asDiagonal() *
                              eig.eigenvectors().transpose() * l.transpose();
  return 0.5 * (out + out.transpose());
}

}  // namespace rotation_averaging
