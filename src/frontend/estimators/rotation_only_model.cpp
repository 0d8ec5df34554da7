// The rotation-only model of a pair (a camera that turned without moving):
// its estimation and its refinement on fixed inliers.
#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "frontend/estimators/two_view_internal.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"

namespace rotation_averaging {
namespace {

// The rotation R minimising sum |b2 - R b1|^2 over unit bearings (Kabsch).
Eigen::Matrix3d FitRotation(const std::vector<Eigen::Vector3d>& b1, const std::vector<Eigen::Vector3d>& b2,
                            const std::vector<int>& subset) {
  Eigen::Matrix3d m = Eigen::Matrix3d::Zero();
  for (int i : subset) m += b2[i] * b1[i].transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(m, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

}  // namespace

bool TransferError(const Eigen::Matrix3d& k2, const Eigen::Matrix3d& rotation, const Eigen::Vector3d& b1,
                   const Eigen::Vector2d& p2, Eigen::Vector2d* error) {
  const Eigen::Vector3d u = k2 * (rotation * b1);
  if (!(u.z() > 0.0)) return false;
  *error = u.head<2>() / u.z() - p2;
  return true;
}

namespace {

// Gauss-Newton on omega, R = Exp(omega) R_hat, over the transfer errors of
// `inliers` (bearings b1 of image 1, pixels of image 2): at most
// max_iterations steps. Leaves J^T J and the sum of squared errors of the
// last linearisation; returns the steps taken, -1 if one was not finite.
int GaussNewtonRotation(const std::vector<Eigen::Vector3d>& b1, const std::vector<Eigen::Vector2d>& points2,
                        const Eigen::Matrix3d& k2, const std::vector<int>& inliers, int max_iterations,
                        Eigen::Matrix3d* rotation, Eigen::Matrix3d* information, double* sum_squares) {
  int it = 0;
  for (; it < max_iterations; ++it) {
    Eigen::Matrix3d jtj = Eigen::Matrix3d::Zero();
    Eigen::Vector3d jte = Eigen::Vector3d::Zero();
    *sum_squares = 0.0;
    for (int i : inliers) {
      const Eigen::Vector3d x = *rotation * b1[i];
      const Eigen::Vector3d u = k2 * x;
      if (!(u.z() > 0.0)) continue;
      const Eigen::Vector2d e = u.head<2>() / u.z() - points2[i];
      Eigen::Matrix<double, 2, 3> d_proj;
      d_proj << 1.0 / u.z(), 0.0, -u.x() / (u.z() * u.z()), 0.0, 1.0 / u.z(), -u.y() / (u.z() * u.z());
      const Eigen::Matrix<double, 2, 3> jac = d_proj * k2 * -Hat(x);  // d/d omega of Exp(omega) x = -[x]x
      jtj += jac.transpose() * jac;
      jte += jac.transpose() * e;
      *sum_squares += e.squaredNorm();
    }
    *information = jtj;
    const Eigen::Vector3d step = jtj.ldlt().solve(-jte);
    if (!step.allFinite()) return -1;
    *rotation = ExpSO3(step) * *rotation;
    if (step.norm() < 1e-12) return it;  // the step that converged is not counted
  }
  return it;
}

// sqrt of the 99% quantile of chi^2 with 2 degrees of freedom: the inlier
// radius of a 2-d error in units of its per-coordinate sigma.
constexpr double kChi2Radius99 = 3.035;
constexpr int kRotationRefineIterations = 20;

// The bearings of a pair's correspondences, with what deciding a rotation's
// inliers needs (the second image's points and camera).
struct RotationPair {
  int n = 0;
  std::vector<Eigen::Vector3d> b1, b2;
  const std::vector<Eigen::Vector2d>* points2 = nullptr;
  Eigen::Matrix3d k2;

  // The inliers of a rotation; with `beat`, it gives up (returning what it
  // has) as soon as it cannot find more than that many: a hypothesis with
  // no more support than the best so far is discarded anyway.
  std::vector<int> InliersOf(const Eigen::Matrix3d& rotation, double radius_px, std::size_t beat = 0) const {
    std::vector<int> in;
    Eigen::Vector2d e;
    for (int i = 0; i < n; ++i) {
      if (beat > 0 && in.size() + static_cast<std::size_t>(n - i) <= beat) break;
      if (TransferError(k2, rotation, b1[i], (*points2)[i], &e) && e.norm() < radius_px) in.push_back(i);
    }
    return in;
  }
};

// Two-point sampling with local optimisation: the rotation with the most
// inliers (`best`), stopping once `min_support` or the best support found
// makes more samples unlikely to beat it.
Eigen::Matrix3d SampleRotation(const RotationPair& pair, const RelativePoseOptions& options, int min_support,
                               std::vector<int>* best) {
  const int n = pair.n;
  // A fixed seed: the same pair gives the same model on every run and thread.
  std::mt19937 rng(0x5eedu + static_cast<unsigned>(n));
  std::uniform_int_distribution<int> pick(0, n - 1);
  best->clear();
  Eigen::Matrix3d best_rotation = Eigen::Matrix3d::Identity();
  const double log_failure = std::log(1.0 - options.ransac_confidence);
  auto iterations_for = [&](std::size_t support) {
    const double w = static_cast<double>(support) / n;
    const double miss = std::log(std::max(1e-12, 1.0 - w * w));
    return miss < 0.0 ? static_cast<int>(std::min<double>(std::ceil(log_failure / miss), options.ransac_max_iterations))
                      : options.ransac_max_iterations;
  };
  int needed = iterations_for(static_cast<std::size_t>(std::clamp(min_support, 0, n)));
  for (int it = 0; it < needed && it < options.ransac_max_iterations; ++it) {
    const int i = pick(rng), j = pick(rng);
    // Two bearings nearly along one line do not fix the rotation about it.
    if (i == j || pair.b1[i].cross(pair.b1[j]).norm() < 1e-3 || pair.b2[i].cross(pair.b2[j]).norm() < 1e-3) continue;
    Eigen::Matrix3d rotation = FitRotation(pair.b1, pair.b2, {i, j});
    std::vector<int> in = pair.InliersOf(rotation, options.ransac_threshold_px, best->size());
    if (in.size() <= best->size()) continue;
    // Local optimisation: refit on the support until it stops growing.
    for (int lo = 0; lo < 3; ++lo) {
      const Eigen::Matrix3d refit = FitRotation(pair.b1, pair.b2, in);
      std::vector<int> grown = pair.InliersOf(refit, options.ransac_threshold_px);
      if (grown.size() <= in.size()) break;
      in.swap(grown);
      rotation = refit;
    }
    best->swap(in);
    best_rotation = rotation;
    needed = std::min(needed, iterations_for(best->size()));
  }
  return best_rotation;
}

// Gauss-Newton on omega, R = Exp(omega) R_hat, over the inliers; the inliers
// are re-selected from all correspondences after each solve. Fills the
// rotation, its inliers, J^T J and the sum of squared transfer errors; a
// failure comes back as a failed result.
std::optional<RelativePoseResult> RefineRotationModel(const RotationPair& pair, const RelativePoseOptions& options,
                                                      Eigen::Matrix3d* rotation, std::vector<int>* inliers,
                                                      Eigen::Matrix3d* information, double* sum_squares,
                                                      int* iterations) {
  *information = Eigen::Matrix3d::Zero();
  *sum_squares = 0.0;
  *iterations = 0;
  for (int round = 0; round < kMaxReselectionRounds; ++round) {
    const int done = GaussNewtonRotation(pair.b1, *pair.points2, pair.k2, *inliers, kRotationRefineIterations,
                                         rotation, information, sum_squares);
    if (done < 0) return TwoViewFail(TwoViewFailure::kRefinementFailed, "rotation-model step is not finite");
    *iterations += done;
    std::vector<double> norms;
    norms.reserve(inliers->size());
    Eigen::Vector2d e;
    for (int i : *inliers) {
      norms.push_back(TransferError(pair.k2, *rotation, pair.b1[i], (*pair.points2)[i], &e) ? e.norm() : INFINITY);
    }
    std::nth_element(norms.begin(), norms.begin() + norms.size() / 2, norms.end());
    // The median norm of a 2-d Gaussian error is sigma sqrt(2 ln 2).
    const double sigma = norms[norms.size() / 2] / std::sqrt(2.0 * std::log(2.0));
    std::vector<int> selected = pair.InliersOf(*rotation, std::max(1e-3, kChi2Radius99 * sigma));
    if (static_cast<int>(selected.size()) < options.min_inliers) {
      return TwoViewFail(TwoViewFailure::kTooFewInliers, std::to_string(selected.size()) + " rotation-model inliers after refinement");
    }
    const bool settled = selected == *inliers;
    inliers->swap(selected);
    if (settled) break;
  }
  return std::nullopt;
}

}  // namespace

// Stopping at `min_support`: where the camera moved, the rotations explain
// few correspondences and the sampling would otherwise run to its iteration
// cap.
RelativePoseResult EstimateRotationOnly(const std::vector<Eigen::Vector2d>& points1,
                                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k1,
                                        const Eigen::Matrix3d& k2, const RelativePoseOptions& options,
                                        int min_support) {
  RotationPair pair;
  pair.n = static_cast<int>(points1.size());
  pair.points2 = &points2;
  pair.k2 = k2;
  const Eigen::Matrix3d k1_inv = k1.inverse(), k2_inv = k2.inverse();
  pair.b1.resize(pair.n);
  pair.b2.resize(pair.n);
  for (int i = 0; i < pair.n; ++i) {
    pair.b1[i] = (k1_inv * points1[i].homogeneous()).normalized();
    pair.b2[i] = (k2_inv * points2[i].homogeneous()).normalized();
  }
  std::vector<int> inliers;
  Eigen::Matrix3d rotation = SampleRotation(pair, options, min_support, &inliers);
  if (static_cast<int>(inliers.size()) < options.min_inliers) {
    return TwoViewFail(TwoViewFailure::kTooFewInliers, std::to_string(inliers.size()) + " rotation-model inliers");
  }
  Eigen::Matrix3d information;
  double sum_squares = 0.0;
  int iterations = 0;
  if (auto failed = RefineRotationModel(pair, options, &rotation, &inliers, &information, &sum_squares, &iterations)) {
    return *failed;
  }
  const int m = static_cast<int>(inliers.size());
  const double sigma2 = sum_squares / std::max(1, 2 * m - 3);  // per coordinate of the transfer error
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(information);
  const double min_eig = eig.eigenvalues().minCoeff(), max_eig = eig.eigenvalues().maxCoeff();
  if (!(min_eig > 0.0) || max_eig / min_eig > options.max_condition_number) {
    return TwoViewFail(TwoViewFailure::kSingularInformation, "rotation-model J^T J condition number " +
                                                          std::to_string(min_eig > 0.0 ? max_eig / min_eig : INFINITY));
  }
  const Eigen::Matrix3d information_inv =
      eig.eigenvectors() * eig.eigenvalues().cwiseInverse().asDiagonal() * eig.eigenvectors().transpose();
  RelativePoseResult result;
  result.success = true;
  result.model = TwoViewModel::kRotation;
  result.rotation = ProjectToSO3(rotation);
  result.translation.setZero();
  result.inliers = std::move(inliers);
  // The transfer error carries the noise of both images: per image, and in
  // the units of the essential model's Sampson error, sigma is 1/sqrt(2) of it.
  result.sigma_px = std::sqrt(0.5 * sigma2);
  result.refine_iterations = iterations;
  result.ransac_threshold_px = options.ransac_threshold_px;
  result.covariance_paper = information_inv;
  result.covariance_marginal = sigma2 * information_inv;
  result.covariance_marginal = 0.5 * (result.covariance_marginal + result.covariance_marginal.transpose()).eval();
  result.covariance_marginal_pixel = result.covariance_marginal;
  result.covariance_conditional = result.covariance_marginal;  // no translation to condition on
  result.covariance = result.covariance_marginal;
  return result;
}

int RefineRotationOnInliers(const std::vector<Eigen::Vector2d>& points1, const std::vector<Eigen::Vector2d>& points2,
                            const std::vector<int>& inliers, const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                            Eigen::Matrix3d* rotation, int max_iterations) {
  const Eigen::Matrix3d k1_inv = k1.inverse();
  std::vector<Eigen::Vector3d> b1(points1.size());
  for (int i : inliers) b1[i] = (k1_inv * points1[i].homogeneous()).normalized();
  Eigen::Matrix3d information;
  double sum_squares = 0.0;
  const int done = GaussNewtonRotation(b1, points2, k2, inliers, max_iterations, rotation, &information, &sum_squares);
  *rotation = ProjectToSO3(*rotation);
  return done;
}

}  // namespace rotation_averaging
