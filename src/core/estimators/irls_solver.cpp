// Fast IRLS rotation averaging in the tangent space with 3x3 block weights.
//
// Each iteration linearises r_ij = Log(M_ij^T R_i R_j^T) under the right
// updates R_i <- R_i Exp(x_i):
//
//   r_ij(x) ~ r_ij + Jr^-1(r_ij) R_j (x_i - x_j),
//
// weights each edge by w_ij = rho'(|D^T r|^2) times its information W_ij, and
// solves the normal equations  sum A^T (w W) A x = -sum A^T (w W) r. With
// G_ij = R_j^T Jr^-T (w W) Jr^-1 R_j (symmetric, positive semi-definite) the
// normal matrix is a matrix-weighted graph Laplacian: G_ij on the diagonal
// blocks of both views and -G_ij off the diagonal. Its null space (before
// the gauge view is held) is the three constant vectors x_i = c, exactly as
// for a scalar Laplacian, which is what lets aggregation multigrid precondition
// it (AggregationAmg::SetupBlocks). This is Gauss-Newton with IRLS weights
// (the Theia / GLOMAP scheme) extended to full covariance weights and the
// exact Jacobian. A step that raises the robust cost is halved (up to 4
// times); a linear solve that fails is retried with Levenberg regularisation.
//
// Isotropic information (W_ij = s_ij I on every edge: no weighting, inlier,
// trace or Frobenius weights, isotropic covariances) takes a cheaper path:
// with Jr^-1 replaced by I, G_ij = w s_ij I and the normal equations become a
// scalar weighted graph Laplacian L (weights w_ij = rho' s_ij) with three
// right-hand sides, one per coordinate: L has a ninth of the nonzeros of the
// block system and its factorisation ~27x fewer flops. The fixed points are
// unchanged, not approximated: for W = s I the exact gradient term
// (Jr^-1 R_j)^T W r = s R_j^T Jr^-T(r) r equals s R_j^T r, because
// Jr^-T(r) r = r. Only the curvature is approximated, which the step halving
// guards.
#include <algorithm>
#include <cmath>
#include <vector>

#include "core/linalg/block_sparse_system.h"
#include "core/estimators/component_problem.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// W = s I up to rounding, for every edge.
bool AllIsotropic(const std::vector<ComponentEdge>& edges) {
  for (const ComponentEdge& e : edges) {
    const double s = e.information.trace() / 3.0;
    if (!(s > 0.0) || ((e.information - s * Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > 1e-9 * s)) {
      return false;
    }
  }
  return true;
}


// Median over the edges of InformationAnisotropy (from at most 10,000 edges
// evenly spread), once per workspace: only systems large enough for
// multigrid need it.
double MedianAnisotropy(const ComponentProblem& problem, IrlsWorkspace* ws) {
  if (ws->median_anisotropy < 0.0) {
    ws->median_anisotropy = 1.0;
    if (!ws->isotropic && !problem.edges.empty()) {
      const std::size_t stride = std::max<std::size_t>(1, problem.edges.size() / 10000);
      std::vector<double> anisotropy;
      for (std::size_t k = 0; k < problem.edges.size(); k += stride)
        anisotropy.push_back(InformationAnisotropy(problem.edges[k].information));
      std::nth_element(anisotropy.begin(), anisotropy.begin() + anisotropy.size() / 2, anisotropy.end());
      ws->median_anisotropy = anisotropy[anisotropy.size() / 2];
    }
  }
  return ws->median_anisotropy;
}

// The normal-equation pattern of a component, once per workspace.
void PrepareWorkspace(const ComponentProblem& problem, IrlsWorkspace* workspace) {
  IrlsWorkspace& ws = *workspace;
  // A workspace passes from the isotropic surrogate of the robust start to
  // the problem itself: kept (with its symbolic analysis and factor) when
  // that is isotropic too, rebuilt for 3x3 blocks otherwise.
  const bool isotropic = AllIsotropic(problem.edges);
  // Per-edge s of W = s I, refreshed on every call: a kept workspace may
  // come from the robust start's surrogate, whose s is 1.
  ws.scalar_information.clear();
  if (isotropic) {
    ws.scalar_information.reserve(problem.edges.size());
    for (const ComponentEdge& e : problem.edges) ws.scalar_information.push_back(e.information(0, 0));
  }
  if (ws.system && ws.isotropic == isotropic) return;
  const int n = static_cast<int>(problem.view_ids.size());
  ws.var.assign(n, -1);
  int free_blocks = 0;
  for (int v = 0; v < n; ++v)
    if (!problem.IsFixed(v)) ws.var[v] = free_blocks++;
  std::vector<std::pair<int, int>> pairs;
  pairs.reserve(problem.edges.size());
  for (const ComponentEdge& e : problem.edges) {
    if (ws.var[e.i] >= 0 && ws.var[e.j] >= 0) pairs.emplace_back(ws.var[e.i], ws.var[e.j]);
  }
  ws.isotropic = isotropic;
  // The measurements as unit quaternions, conjugated (the surrogate of the
  // robust start shares the problem's measurements and this workspace).
  ws.measured_conjugate.resize(problem.edges.size());
  for (std::size_t k = 0; k < problem.edges.size(); ++k) {
    ws.measured_conjugate[k] = Eigen::Quaterniond(problem.edges[k].measured).normalized().conjugate();
  }
  ws.system = ws.isotropic ? std::make_unique<BlockSparseSystem>(free_blocks, pairs, 1, 3)
                           : std::make_unique<BlockSparseSystem>(free_blocks, pairs);
  ws.median_anisotropy = -1.0;  // MedianAnisotropy computes it when multigrid is considered
  // Slot of each edge's off-diagonal block in its column (-1: touches the gauge).
  ws.offdiagonal_slot.assign(problem.edges.size(), -1);
  for (std::size_t k = 0; k < problem.edges.size(); ++k) {
    const int a = ws.var[problem.edges[k].i], b = ws.var[problem.edges[k].j];
    if (a >= 0 && b >= 0 && a != b) ws.offdiagonal_slot[k] = ws.system->Locate(std::max(a, b), std::min(a, b));
  }
  ws.ends.resize(problem.edges.size());
  for (std::size_t k = 0; k < problem.edges.size(); ++k) ws.ends[k] = {problem.edges[k].i, problem.edges[k].j};
  ws.offdiagonal_index.clear();
  ws.diagonal_index.clear();
  if (ws.isotropic) {
    ws.offdiagonal_index.assign(problem.edges.size(), -1);
    for (std::size_t k = 0; k < problem.edges.size(); ++k) {
      const int a = ws.var[problem.edges[k].i], b = ws.var[problem.edges[k].j];
      if (ws.offdiagonal_slot[k] >= 0) ws.offdiagonal_index[k] = ws.system->ScalarIndex(std::max(a, b), std::min(a, b));
    }
    ws.diagonal_index.resize(free_blocks);
    for (int v = 0; v < free_blocks; ++v) ws.diagonal_index[v] = ws.system->ScalarIndex(v, v);
  }
}

// The IRLS normal equations at `residuals` (of the problem's rotations), in
// the right updates: a scalar Laplacian with three right-hand sides
// (isotropic information) or 3x3 blocks, see the comment at the top.
void Assemble(const ComponentProblem& component, const std::vector<Eigen::Vector3d>& residuals,
              const std::vector<double>& weights, IrlsWorkspace* workspace) {
  const ComponentProblem* problem = &component;
  const std::vector<int>& var = workspace->var;
  const std::vector<int>& slot = workspace->offdiagonal_slot;
  const bool isotropic = workspace->isotropic;
  BlockSparseSystem& system = *workspace->system;
  const std::size_t m = component.edges.size();
  system.SetZero();
  Eigen::MatrixXd& rhs = system.Rhs();
  if (isotropic) {
    // Right-hand side rows and diagonal entries are gathered per view (four
    // adjacent numbers) and written into the system at the end.
    std::vector<Eigen::Vector4d>& accumulated = workspace->accumulated;
    accumulated.assign(system.NumBlocks(), Eigen::Vector4d::Zero());
    const std::vector<double>& information = workspace->scalar_information;
    const std::vector<std::pair<int, int>>& ends = workspace->ends;
    const std::vector<int>& offdiagonal = workspace->offdiagonal_index;
    for (std::size_t k = 0; k < m; ++k) {
      if (weights[k] <= 0.0) continue;
      const auto [i, j] = ends[k];
      const double w = weights[k] * information[k];
      // e_ij = R_j^T r_ij: the residual in the frame of the right updates.
      Eigen::Vector4d w_e;
      w_e.head<3>() = w * (problem->rotations[j].transpose() * residuals[k]);
      w_e(3) = w;
      const int vi = var[i], vj = var[j];
      if (vi >= 0) accumulated[vi] += Eigen::Vector4d(-w_e(0), -w_e(1), -w_e(2), w);
      if (vj >= 0) accumulated[vj] += w_e;
      if (offdiagonal[k] >= 0) system.AddScalarAtIndex(offdiagonal[k], -w);
    }
    const std::vector<int>& diagonal = workspace->diagonal_index;
    for (std::size_t v = 0; v < accumulated.size(); ++v) system.AddScalarAtIndex(diagonal[v], accumulated[v](3));
    for (int c = 0; c < 3; ++c) {
      double* column = rhs.col(c).data();
      for (std::size_t v = 0; v < accumulated.size(); ++v) column[v] = accumulated[v](c);
    }
  }
  for (std::size_t k = 0; !isotropic && k < m; ++k) {
    const Eigen::Vector3d& r = residuals[k];
    if (weights[k] <= 0.0) continue;
    const ComponentEdge& e = problem->edges[k];
    // A = Jr^-1 R_j for view i and -A for view j.
    const Eigen::Matrix3d a = RightJacobianInverseSO3(r) * problem->rotations[e.j];
    const Eigen::Matrix3d a_t_w = a.transpose() * (weights[k] * e.information);
    const Eigen::Matrix3d g = a_t_w * a;
    const Eigen::Vector3d g_r = a_t_w * r;
    const int vi = var[e.i], vj = var[e.j];
    if (vi >= 0) {
      system.AddBlockAt(vi, 0, g);
      rhs.col(0).segment<3>(3 * vi) -= g_r;
    }
    if (vj >= 0) {
      system.AddBlockAt(vj, 0, g);
      rhs.col(0).segment<3>(3 * vj) += g_r;
    }
    if (slot[k] >= 0) system.AddBlockAt(std::min(vi, vj), slot[k], -g);  // symmetric: either triangle
  }
}

// The IRLS / Gauss-Newton iterations of one component on its workspace
// (SolveComponentIrls).
class IrlsIterations {
 public:
  IrlsIterations(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                 ComponentSummary* summary, IrlsWorkspace* ws)
      : options_(options),
        loss_(loss),
        problem_(*problem),
        summary_(*summary),
        ws_(*ws),
        n_(static_cast<int>(problem->view_ids.size())),
        m_(problem->edges.size()),
        isotropic_(ws->isotropic),
        system_(*ws->system),
        num_free_(system_.NumBlocks()),
        residuals_(m_),
        weights_(m_),
        quaternions_(n_),
        candidate_(n_),
        candidate_residuals_(m_),
        candidate_weights_(m_),
        extrapolation_(n_),
        extrapolation_residuals_(m_),
        extrapolation_weights_(m_) {}

  void Run() {
    // The residuals a previous solve on this workspace ended with (GNC
    // stages, the final and auto-scaled solves) are reused when the
    // rotations are still the same: they do not depend on the loss.
    double cost = 0.0;
    if (ws_.residuals.size() == m_ && ws_.residual_rotations == problem_.rotations) {
      residuals_ = ws_.residuals;
      cost = CostOf(residuals_, &weights_);
    } else {
      cost = Evaluate(problem_.rotations, &residuals_, &weights_);
    }
    summary_.initial_cost = cost;
    summary_.converged = false;
    summary_.status = "maximum iterations reached";
    if (!std::isfinite(cost)) {
      summary_.status = "initial cost is not finite";
      summary_.final_cost = cost;
      return;
    }
    const bool multigrid =
        options_.linear.multigrid_min_views > 0 && num_free_ >= options_.linear.multigrid_min_views &&
        (isotropic_ || MedianAnisotropy(problem_, &ws_) <= options_.linear.block_multigrid_max_anisotropy);
    system_.SetUseMultigrid(multigrid);
    system_.SetBlockCholeskyMaxColumnCount(options_.linear.block_cholesky_max_column_count);
    system_.SetPcgTolerance(multigrid ? std::max(options_.linear.linear_solve_tolerance,
                                                 options_.linear.multigrid_linear_solve_tolerance)
                                      : options_.linear.linear_solve_tolerance);
    int iteration = 0;
    for (; iteration < options_.max_iterations; ++iteration) {
      if (!Iterate(&cost)) break;
      if (summary_.converged) {
        ++iteration;
        break;
      }
    }
    // Keep the rotations exactly orthonormal after many small updates.
    for (Eigen::Matrix3d& r : problem_.rotations) r = ProjectToSO3(r);
    summary_.iterations += iteration;
    summary_.factorizations = system_.NumFactorizations();
    summary_.preconditioned_solves = system_.NumPreconditionedSolves();
    summary_.multigrid_solves = system_.NumMultigridSolves();
    summary_.final_cost = Evaluate(problem_.rotations, &residuals_, &weights_);
    ws_.residuals = residuals_;
    ws_.residual_rotations = problem_.rotations;
  }

 private:
  // |D^T r|^2 of edge k: s |r|^2 for isotropic information (one number per
  // edge instead of the 3x3 square root: the edge loops stream less memory).
  double WhitenedSquared(std::size_t k, const Eigen::Vector3d& r) const {
    return isotropic_ ? ws_.scalar_information[k] * r.squaredNorm()
                      : (problem_.edges[k].sqrt_information * r).squaredNorm();
  }
  // Robust cost of edge k at residual r; its weight rho' into w[k], kept for
  // the next assembly (the loss is not evaluated twice).
  double EdgeCost(std::size_t k, const Eigen::Vector3d& r, std::vector<double>* w) const {
    double rho[3];
    loss_.Evaluate(WhitenedSquared(k, r), rho);
    (*w)[k] = rho[1];
    return 0.5 * rho[0];
  }
  double CostOf(const std::vector<Eigen::Vector3d>& res, std::vector<double>* w) const {
    double cost = 0.0;
    for (std::size_t k = 0; k < m_; ++k) cost += EdgeCost(k, res[k], w);
    return cost;
  }
  // Residuals, robust weights and cost in one pass over the edges.
  double Evaluate(const std::vector<Eigen::Matrix3d>& rotations, std::vector<Eigen::Vector3d>* res,
                  std::vector<double>* w) {
    // r_ij = Log(conj(m_ij) q_i conj(q_j)): two quaternion products (32
    // multiplications) instead of two 3x3 matrix products (54), and 32
    // bytes per measurement streamed instead of 72.
    for (int v = 0; v < n_; ++v) quaternions_[v] = Eigen::Quaterniond(rotations[v]);
    double cost = 0.0;
    for (std::size_t k = 0; k < m_; ++k) {
      const auto [i, j] = ws_.ends[k];
      (*res)[k] = LogUnitQuaternion(ws_.measured_conjugate[k] * quaternions_[i] * quaternions_[j].conjugate());
      cost += EdgeCost(k, (*res)[k], w);
    }
    return cost;
  }
  // `from` moved by `scale` times the last step, into `to`.
  void Apply(double scale, const std::vector<Eigen::Matrix3d>& from, std::vector<Eigen::Matrix3d>* to) const {
    for (int v = 0; v < n_; ++v) {
      if (ws_.var[v] < 0) {
        (*to)[v] = from[v];
      } else if (isotropic_) {
        (*to)[v] = from[v] * ExpSO3(scale * delta_.row(ws_.var[v]).transpose());
      } else {
        (*to)[v] = from[v] * ExpSO3(scale * delta_.col(0).segment<3>(3 * ws_.var[v]));
      }
    }
  }

  // One iteration from the rotations at `cost`. False when it stops the
  // solve without a step (the linear solve failed, or no step decreases the
  // cost); a step that converges sets summary_.converged.
  bool Iterate(double* cost) {
    Assemble(problem_, residuals_, weights_, &ws_);
    if (!system_.Solve(1e-12, 6, &delta_)) {
      summary_.status = "linear solve failed even with regularisation";
      return false;
    }
    // Apply the step, halving it while the robust cost goes up.
    double step = 1.0, new_cost = *cost;
    bool accepted = false;
    for (int attempt = 0; attempt < 5; ++attempt, step *= 0.5) {
      Apply(step, problem_.rotations, &candidate_);
      new_cost = Evaluate(candidate_, &candidate_residuals_, &candidate_weights_);
      if (std::isfinite(new_cost) && new_cost <= *cost * (1.0 + 1e-12) + 1e-300) {
        accepted = true;
        break;
      }
    }
    if (!accepted) {
      summary_.converged = true;
      summary_.status = "converged: no step decreases the cost";
      return false;
    }
    const double extrapolated = options_.irls_extrapolation ? Extrapolate(step, &new_cost) : 0.0;
    const double max_step =
        num_free_ == 0 ? 0.0
                       : (step + extrapolated) * (isotropic_ ? delta_.rowwise().norm().maxCoeff()
                                                             : delta_.col(0).reshaped(3, num_free_).colwise().norm().maxCoeff());
    const double decrease = *cost - new_cost;
    problem_.rotations.swap(candidate_);
    residuals_.swap(candidate_residuals_);
    weights_.swap(candidate_weights_);
    *cost = new_cost;
    if (max_step < options_.step_tolerance_rad) {
      summary_.converged = true;
      summary_.status = "converged: step below tolerance";
    } else if (decrease <= options_.function_tolerance * *cost) {
      summary_.converged = true;
      summary_.status = "converged: cost decrease below tolerance";
    }
    return true;
  }

  // IRLS converges linearly; with redescending losses a view whose inliers
  // sit near the cut-off crawls (a fixed fraction closer per iteration,
  // still far from the minimum when the cost test stops). When two
  // consecutive full steps point the same way and shrink geometrically, the
  // rest of the geometric series is tried in one jump and kept only if it
  // lowers the cost (one extra evaluation). Returns the factor of the step
  // taken beyond the candidate (0: none); `new_cost` is the candidate's.
  double Extrapolate(double step, double* new_cost) {
    double extrapolated = 0.0;
    const Eigen::Map<const Eigen::VectorXd> flat(delta_.data(), delta_.size());
    if (previous_update_.size() == flat.size() && step == 1.0) {
      const double norm = flat.norm(), previous_norm = previous_update_.norm();
      const double cosine = flat.dot(previous_update_) / std::max(norm * previous_norm, 1e-300);
      const double ratio = norm / std::max(previous_norm, 1e-300);
      if (cosine > 0.95 && ratio > 0.3 && ratio < 0.99) {
        const double factor = std::min(ratio / (1.0 - ratio), 10.0);
        Apply(factor, candidate_, &extrapolation_);
        const double extrapolated_cost = Evaluate(extrapolation_, &extrapolation_residuals_, &extrapolation_weights_);
        if (std::isfinite(extrapolated_cost) && extrapolated_cost < *new_cost) {
          candidate_.swap(extrapolation_);
          candidate_residuals_.swap(extrapolation_residuals_);
          candidate_weights_.swap(extrapolation_weights_);
          *new_cost = extrapolated_cost;
          extrapolated = factor;
          ++summary_.extrapolations;
        }
      }
    }
    if (extrapolated > 0.0) previous_update_.resize(0); else previous_update_ = step * flat;
    return extrapolated;
  }

  const RotationAveragingOptions& options_;
  const RobustLoss& loss_;
  ComponentProblem& problem_;
  ComponentSummary& summary_;
  IrlsWorkspace& ws_;
  const int n_;
  const std::size_t m_;
  const bool isotropic_;
  BlockSparseSystem& system_;
  const int num_free_;
  std::vector<Eigen::Vector3d> residuals_;
  std::vector<double> weights_;  // robust weights rho' of each edge at residuals_
  std::vector<Eigen::Quaterniond> quaternions_;
  std::vector<Eigen::Matrix3d> candidate_;
  std::vector<Eigen::Vector3d> candidate_residuals_;
  std::vector<double> candidate_weights_;
  std::vector<Eigen::Matrix3d> extrapolation_;
  std::vector<Eigen::Vector3d> extrapolation_residuals_;
  std::vector<double> extrapolation_weights_;
  Eigen::VectorXd previous_update_;
  Eigen::MatrixXd delta_;
};

}  // namespace

IrlsWorkspace::IrlsWorkspace() = default;
IrlsWorkspace::~IrlsWorkspace() = default;

void SolveComponentIrls(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                        ComponentSummary* summary, IrlsWorkspace* workspace) {
  IrlsWorkspace local;
  IrlsWorkspace& ws = workspace ? *workspace : local;
  PrepareWorkspace(*problem, &ws);
  IrlsIterations(options, loss, problem, summary, &ws).Run();
}

}  // namespace rotation_averaging

namespace rotation_averaging {

bool ComputeViewCovariances(const ComponentProblem& given, const RobustLoss& loss,
                            std::vector<Eigen::Matrix3d>* covariances, double* scale_used, bool with_floor,
                            double* floor_used) {
  const int n = static_cast<int>(given.view_ids.size());
  covariances->assign(n, Eigen::Matrix3d::Zero());
  const std::size_t m = given.edges.size();
  std::vector<Eigen::Vector3d> residuals(m);
  for (std::size_t k = 0; k < m; ++k) residuals[k] = given.Residual(given.edges[k]);
  // The floor the residuals show, on a copy of the problem: the solution
  // stays the one solved under the edges as given.
  double floor_variance = 0.0;
  ComponentProblem floored_problem;
  if (with_floor) {
    int free_views = 0;
    for (int v = 0; v < n; ++v) free_views += !given.IsFixed(v);
    floor_variance = EstimateCovarianceFloor(given.edges, residuals, free_views);
    if (floor_variance > 0.0) {
      floored_problem = given;
      floored_problem.edges = WithCovarianceFloor(given.edges, floor_variance);
    }
  }
  if (floor_used) *floor_used = floor_variance > 0.0 ? std::sqrt(floor_variance) : 0.0;
  const ComponentProblem& problem = floor_variance > 0.0 ? floored_problem : given;
  IrlsWorkspace ws;
  PrepareWorkspace(problem, &ws);
  std::vector<double> weights(m);
  double weighted_sum = 0.0, weight_sum = 0.0, rho[3];
  for (std::size_t k = 0; k < m; ++k) {
    const double s = (problem.edges[k].sqrt_information * residuals[k]).squaredNorm();
    loss.Evaluate(s, rho);
    weights[k] = rho[1];
    weighted_sum += rho[1] * s;
    weight_sum += rho[1];
  }
  const double redundancy = 3.0 * weight_sum - 3.0 * (n - 1);
  const double scale = redundancy >= 10.0 ? weighted_sum / redundancy : 1.0;
  if (scale_used) *scale_used = scale;
  Assemble(problem, residuals, weights, &ws);
  std::vector<Eigen::Matrix3d> blocks;
  if (!ws.system->InverseDiagonalBlocks(&blocks)) return false;
  for (int v = 0; v < n; ++v) {
    const int b = ws.var[v];
    if (b < 0) continue;
    // Right updates x with R = R_hat Exp(x) = Exp(R_hat x) R_hat: the left
    // perturbation is d = R_hat x, so C_d = R_hat C_x R_hat^T (for a scalar
    // Laplacian's c I, c I itself).
    const Eigen::Matrix3d& r = problem.rotations[v];
    (*covariances)[v] = scale * (r * blocks[b] * r.transpose());
    if (!(*covariances)[v].allFinite()) return false;
  }
  for (Eigen::Matrix3d& c : *covariances) c = 0.5 * (c + c.transpose());
  return true;
}

}  // namespace rotation_averaging
