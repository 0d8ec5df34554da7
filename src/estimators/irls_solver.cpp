// Fast IRLS rotation averaging in the tangent space with 3x3 block weights.
//
// Each iteration linearises r_ij = Log(M_ij^T R_i R_j^T) under the left
// updates R_i <- Exp(d_i) R_i:
//
//   r_ij(d) ~ r_ij + Jr^-1(r_ij) (Rc_ij^T d_i - d_j),   Rc_ij = R_i R_j^T,
//
// weights each edge by w_ij = rho'(|D^T r|^2) times its information W_ij, and
// solves the normal equations  sum A^T (w W) A d = -sum A^T (w W) r  by a sparse
// Cholesky factorisation whose symbolic analysis is done once per component.
// This is Gauss-Newton with IRLS weights (the Theia / GLOMAP scheme) extended
// to full covariance weights and the exact Jacobian. A step that raises the
// robust cost is halved (up to 4 times); a factorisation that fails is
// retried with Levenberg regularisation.
#include <algorithm>
#include <cmath>

#include "rotation_averaging/estimators/block_sparse_system.h"
#include "rotation_averaging/estimators/component_problem.h"
#include "rotation_averaging/geometry/so3.h"

namespace rotation_averaging {

IrlsWorkspace::IrlsWorkspace() = default;
IrlsWorkspace::~IrlsWorkspace() = default;

void SolveComponentIrls(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                        ComponentSummary* summary, IrlsWorkspace* workspace) {
  const int n = static_cast<int>(problem->view_ids.size());
  IrlsWorkspace local;
  IrlsWorkspace& ws = workspace ? *workspace : local;
  if (!ws.system) {
    ws.var.assign(n, -1);
    int free_blocks = 0;
    for (int v = 0; v < n; ++v)
      if (v != problem->gauge) ws.var[v] = free_blocks++;
    std::vector<std::pair<int, int>> pairs;
    pairs.reserve(problem->edges.size());
    for (const ComponentEdge& e : problem->edges) {
      if (ws.var[e.i] >= 0 && ws.var[e.j] >= 0) pairs.emplace_back(ws.var[e.i], ws.var[e.j]);
    }
    ws.system = std::make_unique<BlockSparseSystem>(free_blocks, pairs);
  }
  const std::vector<int>& var = ws.var;
  BlockSparseSystem& system = *ws.system;
  const int num_free = system.NumBlocks();

  const std::size_t m = problem->edges.size();
  std::vector<Eigen::Vector3d> residuals(m);
  auto evaluate = [&](const std::vector<Eigen::Matrix3d>& rotations, std::vector<Eigen::Vector3d>* res) {
    double cost = 0.0, rho[3];
    for (std::size_t k = 0; k < m; ++k) {
      const ComponentEdge& e = problem->edges[k];
      (*res)[k] = ComponentProblem::ResidualOf(e, rotations);
      loss.Evaluate((e.sqrt_information * (*res)[k]).squaredNorm(), rho);
      cost += 0.5 * rho[0];
    }
    return cost;
  };

  double cost = evaluate(problem->rotations, &residuals);
  summary->initial_cost = cost;
  summary->converged = false;
  summary->status = "maximum iterations reached";
  if (!std::isfinite(cost)) {
    summary->status = "initial cost is not finite";
    summary->final_cost = cost;
    return;
  }

  std::vector<Eigen::Matrix3d> candidate(n);
  std::vector<Eigen::Vector3d> candidate_residuals(m);
  Eigen::VectorXd delta;
  int iteration = 0;
  for (; iteration < options.max_iterations; ++iteration) {
    system.SetZero();
    Eigen::VectorXd& rhs = system.Rhs();
    double rho[3];
    for (std::size_t k = 0; k < m; ++k) {
      const ComponentEdge& e = problem->edges[k];
      const Eigen::Vector3d& r = residuals[k];
      loss.Evaluate((e.sqrt_information * r).squaredNorm(), rho);
      if (rho[1] <= 0.0) continue;
      const Eigen::Matrix3d weighted = rho[1] * e.information;
      const Eigen::Matrix3d jinv = RightJacobianInverseSO3(r);
      const int vi = var[e.i], vj = var[e.j];
      // A_i = Jinv Rc^T, A_j = -Jinv.
      const Eigen::Matrix3d a_i = jinv * (problem->rotations[e.j] * problem->rotations[e.i].transpose());
      const Eigen::Matrix3d w_jinv = weighted * jinv;
      const Eigen::Vector3d w_r = weighted * r;
      if (vi >= 0) {
        const Eigen::Matrix3d a_i_t_w = a_i.transpose() * weighted;
        system.AddBlock(vi, vi, a_i_t_w * a_i);
        rhs.segment<3>(3 * vi) -= a_i.transpose() * w_r;
        if (vj >= 0) system.AddSymmetric(vi, vj, -a_i_t_w * jinv);
      }
      if (vj >= 0) {
        system.AddBlock(vj, vj, jinv.transpose() * w_jinv);
        rhs.segment<3>(3 * vj) += jinv.transpose() * w_r;
      }
    }
    if (!system.Solve(1e-12, 6, &delta)) {
      summary->status = "linear solve failed even with regularisation";
      break;
    }
    // Apply the step, halving it while the robust cost goes up.
    double step = 1.0, new_cost = cost;
    bool accepted = false;
    for (int attempt = 0; attempt < 5; ++attempt, step *= 0.5) {
      for (int v = 0; v < n; ++v) {
        candidate[v] = var[v] < 0 ? problem->rotations[v]
                                  : ExpSO3(step * delta.segment<3>(3 * var[v])) * problem->rotations[v];
      }
      new_cost = evaluate(candidate, &candidate_residuals);
      if (std::isfinite(new_cost) && new_cost <= cost * (1.0 + 1e-12) + 1e-300) {
        accepted = true;
        break;
      }
    }
    if (!accepted) {
      summary->converged = true;
      summary->status = "converged: no step decreases the cost";
      break;
    }
    const double max_step = num_free > 0 ? step * delta.reshaped(3, num_free).colwise().norm().maxCoeff() : 0.0;
    const double decrease = cost - new_cost;
    problem->rotations.swap(candidate);
    residuals.swap(candidate_residuals);
    cost = new_cost;
    if (max_step < options.step_tolerance_rad) {
      summary->converged = true;
      summary->status = "converged: step below tolerance";
      ++iteration;
      break;
    }
    if (decrease <= options.function_tolerance * cost) {
      summary->converged = true;
      summary->status = "converged: cost decrease below tolerance";
      ++iteration;
      break;
    }
  }
  // Keep the rotations exactly orthonormal after many small updates.
  for (Eigen::Matrix3d& r : problem->rotations) r = ProjectToSO3(r);
  summary->iterations += iteration;
  summary->factorizations = system.NumFactorizations();
  summary->preconditioned_solves = system.NumPreconditionedSolves();
  summary->final_cost = evaluate(problem->rotations, &residuals);
}

}  // namespace rotation_averaging
