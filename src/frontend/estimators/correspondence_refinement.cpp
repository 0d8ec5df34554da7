#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"

#include <ceres/ceres.h>

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <sstream>
#include <utility>

#include "frontend/geometry/epipolar.h"

namespace rotation_averaging {
namespace {

// Whitened Sampson error of one correspondence in normalised coordinates for
// E = [t]x R_j R_i^T, the orientations as Eigen quaternions (x, y, z, w).
struct WhitenedSampson {
  WhitenedSampson(const Eigen::Vector2d& x1, const Eigen::Vector2d& x2, double inverse_sigma)
      : x1_(x1), x2_(x2), inverse_sigma_(inverse_sigma) {}

  template <typename T>
  bool operator()(const T* qi, const T* qj, const T* t, T* residual) const {
    const Eigen::Map<const Eigen::Quaternion<T>> q1(qi), q2(qj);
    const Eigen::Matrix<T, 3, 3> r21 = q2.toRotationMatrix() * q1.toRotationMatrix().transpose();
    const Eigen::Matrix<T, 3, 1> n1(T(x1_.x()), T(x1_.y()), T(1)), n2(T(x2_.x()), T(x2_.y()), T(1));
    residual[0] = T(inverse_sigma_) * SampsonError<T>(CrossMatrix(t) * r21, n1, n2);
    return true;
  }

  Eigen::Vector2d x1_, x2_;
  double inverse_sigma_;
};

// Fraction of the correspondences whose whitened Sampson error under
// (r21, t) is within `scale`.
double FractionWithin(const EdgeCorrespondences& e, const Eigen::Matrix3d& r21, const Eigen::Vector3d& t, double scale) {
  const Eigen::Matrix3d essential = CrossMatrix(t.data()) * r21;
  int within = 0;
  for (std::size_t k = 0; k < e.points1.size(); ++k) {
    const double sampson = SampsonError<double>(essential, e.points1[k].homogeneous(), e.points2[k].homogeneous());
    within += std::abs(sampson) <= scale * e.sigma;
  }
  return e.points1.empty() ? 0.0 : static_cast<double>(within) / e.points1.size();
}

ViewId Root(std::map<ViewId, ViewId>* parent, ViewId v) {
  while ((*parent)[v] != v) v = (*parent)[v] = (*parent)[(*parent)[v]];
  return v;
}

// One solve over the edges that pass the checks and agree with `orientations`
// (fraction `gate`, 0: every edge). With `only_if_dropped`, solves only if the
// gate left an edge out. Fills the summary's counts, costs and iterations.
bool Pass(const std::vector<EdgeCorrespondences>& edges, const CorrespondenceRefinementOptions& options, double gate,
          bool only_if_dropped, ViewOrientations* orientations, CorrespondenceRefinementSummary* summary) {
  summary->edges_used = summary->edges_contradicted = summary->edges_skipped = summary->views = 0;
  summary->correspondences = 0;
  std::map<ViewId, Eigen::Quaterniond> quaternions;  // ordered: the gauge choice does not depend on hashing
  std::map<ViewId, ViewId> parent;
  const double scale = options.loss_scale_sigmas > 0.0 ? options.loss_scale_sigmas : 3.0;
  std::vector<const EdgeCorrespondences*> used;
  std::vector<Eigen::Vector3d> translations;  // start directions, then the estimates
  for (const EdgeCorrespondences& e : edges) {
    const auto a = orientations->find(e.view1), b = orientations->find(e.view2);
    if (e.view1 == e.view2 || a == orientations->end() || b == orientations->end() ||
        e.points1.size() != e.points2.size() ||
        static_cast<int>(e.points1.size()) < std::max(1, options.min_correspondences) || !CorrespondencesAreFinite(e) ||
        !a->second.allFinite() || !b->second.allFinite()) {
      ++summary->edges_skipped;
      continue;
    }
    const Eigen::Matrix3d r21 = b->second * a->second.transpose();
    const Eigen::Vector3d t = BestTranslationDirection(e, r21);
    if (gate > 0.0 && FractionWithin(e, r21, t, scale) < gate) {
      ++summary->edges_contradicted;
      continue;
    }
    used.push_back(&e);
    translations.push_back(t);
    for (const auto& [id, rotation] : {*a, *b}) {
      if (quaternions.count(id)) continue;
      quaternions[id] = Eigen::Quaterniond(rotation).normalized();
      parent[id] = id;
    }
    const ViewId ra = Root(&parent, e.view1), rb = Root(&parent, e.view2);
    if (ra != rb) parent[std::max(ra, rb)] = std::min(ra, rb);
  }
  if (used.empty()) {
    summary->status = "no edge with enough correspondences between oriented views that they agree with";
    return false;
  }
  if (only_if_dropped && summary->edges_contradicted == 0) return true;

  ceres::Problem::Options problem_options;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem problem(problem_options);
  ceres::EigenQuaternionManifold quaternion_manifold;
  ceres::SphereManifold<3> sphere_manifold;
  // The loss acts on whitened residuals, so one scale serves every edge.
  ceres::CauchyLoss loss(scale);
  // The orientations in one array, in view order: Ceres orders a group's
  // blocks by address (ParameterBlockOrdering holds a set of pointers), the
  // fill-reducing ordering of the Schur complement starts from that order,
  // and a different one changes the last bits; the map's nodes lie where
  // the heap puts them.
  std::vector<Eigen::Quaterniond> blocks;
  std::map<ViewId, double*> block;
  blocks.reserve(quaternions.size());
  for (const auto& [id, q] : quaternions) blocks.push_back(q);
  auto next = blocks.begin();
  for (const auto& [id, q] : quaternions) block[id] = (next++)->coeffs().data();
  auto* ordering = new ceres::ParameterBlockOrdering;
  for (const auto& [id, q] : block) {
    problem.AddParameterBlock(q, 4, &quaternion_manifold);
    ordering->AddElementToGroup(q, 1);
  }
  for (std::size_t k = 0; k < used.size(); ++k) {
    const EdgeCorrespondences& e = *used[k];
    problem.AddParameterBlock(translations[k].data(), 3, &sphere_manifold);
    // Each edge's direction only meets its own residuals: eliminated first.
    ordering->AddElementToGroup(translations[k].data(), 0);
    double* qi = block.at(e.view1);
    double* qj = block.at(e.view2);
    for (std::size_t m = 0; m < e.points1.size(); ++m) {
      problem.AddResidualBlock(new ceres::AutoDiffCostFunction<WhitenedSampson, 1, 4, 4, 3>(
                                   new WhitenedSampson(e.points1[m], e.points2[m], 1.0 / e.sigma)),
                               &loss, qi, qj, translations[k].data());
    }
    summary->correspondences += e.points1.size();
  }
  for (const auto& [id, q] : block) {
    if (Root(&parent, id) == id) problem.SetParameterBlockConstant(q);
  }
  summary->edges_used = static_cast<int>(used.size());
  summary->views = static_cast<int>(quaternions.size());

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::SPARSE_SCHUR;
  solver_options.linear_solver_ordering.reset(ordering);
  solver_options.max_num_iterations = std::max(1, options.max_iterations);
  // One thread: Ceres sums the gradient and the Schur complement over
  // threads in the order they finish, so more threads give results that
  // differ in the last bits from run to run.
  solver_options.num_threads = 1;
  solver_options.function_tolerance = 1e-10;
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(solver_options, &problem, &ceres_summary);
  ++summary->passes;
  summary->initial_cost = ceres_summary.initial_cost;
  summary->final_cost = ceres_summary.final_cost;
  summary->iterations += static_cast<int>(ceres_summary.iterations.size()) - 1;
  summary->converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  next = blocks.begin();
  for (auto& [id, q] : quaternions) q = *next++;
  bool finite = true;
  for (const auto& [id, q] : quaternions) finite = finite && q.coeffs().allFinite();
  if (!ceres_summary.IsSolutionUsable() || !finite || !(summary->final_cost <= summary->initial_cost)) {
    summary->converged = false;
    summary->status = "solver failed (" + ceres_summary.message + "): orientations kept";
    return false;
  }
  for (const auto& [id, q] : quaternions) (*orientations)[id] = q.normalized().toRotationMatrix();
  summary->status = summary->converged ? "" : ceres_summary.message;
  return true;
}

}  // namespace

EdgeCorrespondences MakeEdgeCorrespondences(ViewId view1, ViewId view2, std::vector<Eigen::Vector2d> points1,
                                            std::vector<Eigen::Vector2d> points2, const Eigen::Vector3d& translation,
                                            double sigma_px, double focal_px) {
  EdgeCorrespondences e;
  e.view1 = view1;
  e.view2 = view2;
  e.points1 = std::move(points1);
  e.points2 = std::move(points2);
  e.translation = translation;
  e.sigma = std::max(sigma_px, 1e-3) / focal_px;
  return e;
}

bool CorrespondencesAreFinite(const EdgeCorrespondences& e, bool allow_rotation_only) {
  if (!std::isfinite(e.sigma) || !(e.sigma > 0.0) || !e.translation.allFinite() ||
      !(e.translation.norm() > 0.0 || (allow_rotation_only && e.translation.isZero(0.0)))) {
    return false;
  }
  for (std::size_t k = 0; k < e.points1.size(); ++k) {
    if (!e.points1[k].allFinite() || !e.points2[k].allFinite()) return false;
  }
  return true;
}

Eigen::Vector3d BestTranslationDirection(const EdgeCorrespondences& e, const Eigen::Matrix3d& r21) {
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  for (std::size_t k = 0; k < e.points1.size(); ++k) {
    const Eigen::Vector3d m = (r21 * e.points1[k].homogeneous()).cross(e.points2[k].homogeneous());
    a += m * m.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(a);
  Eigen::Vector3d t = eigen.eigenvectors().col(0);
  if (t.dot(e.translation) < 0.0) t = -t;
  return t.allFinite() && t.norm() > 0.5 ? t.normalized() : e.translation.normalized();
}

std::string CorrespondenceRefinementSummary::Report() const {
  std::ostringstream out;
  out << "refined on the correspondences: " << views << " views, " << edges_used << " edges (" << edges_contradicted
      << " contradicted by the first pass, " << edges_skipped << " unusable), " << correspondences
      << " correspondences, cost " << initial_cost << " -> " << final_cost << " (last pass), " << passes << " passes, "
      << iterations << " iterations, " << time_s << " s" << (converged ? "" : " (not converged)");
  if (!status.empty()) out << ": " << status;
  return out.str();
}

bool RefineRotationsWithCorrespondences(const std::vector<EdgeCorrespondences>& edges,
                                        const CorrespondenceRefinementOptions& options,
                                        ViewOrientations* orientations, CorrespondenceRefinementSummary* summary) {
  const auto start = std::chrono::steady_clock::now();
  *summary = CorrespondenceRefinementSummary();
  // The averaging's orientations can be off enough on a hard scene that
  // correct pairs look contradicted by them: the first pass keeps every edge
  // (the loss bounds what a wrong one can do), the second judges the edges
  // against its result and, if it contradicts any, solves again without them.
  ViewOrientations refined = *orientations;
  bool ok = Pass(edges, options, 0.0, false, &refined, summary);
  if (ok && options.min_agreement_fraction > 0.0) {
    CorrespondenceRefinementSummary second = *summary;
    if (Pass(edges, options, options.min_agreement_fraction, true, &refined, &second) &&
        second.passes > summary->passes) {
      *summary = second;
    }
  }
  summary->time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (ok) *orientations = refined;
  return ok;
}

}  // namespace rotation_averaging
