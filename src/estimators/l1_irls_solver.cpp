// The paper's baseline (Chatterjee & Govindu, "Robust Relative Rotation
// Averaging", TPAMI 2018, as in Theia's RobustRotationEstimator):
//
//  1. L1 stage. Linearise in the world frame with right updates
//     R_i <- R_i Exp(x_i): e_ij = Log(R_i^T M_ij R_j) becomes e_ij + x_j - x_i,
//     and minimise sum |e_ij + x_j - x_i|_1 (coordinate-wise) by ADMM. The
//     system matrix A^T A is the graph Laplacian (times I_3), the same for every
//     relinearisation and every coordinate, so it is factorised once.
//  2. IRLS stage with Geman-McClure (sigma = 5 degrees), unweighted edges.
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "rotation_averaging/estimators/component_problem.h"
#include "rotation_averaging/geometry/so3.h"

namespace rotation_averaging {
namespace {

double Shrink(double v, double kappa) { return v > kappa ? v - kappa : (v < -kappa ? v + kappa : 0.0); }

}  // namespace

int RefineByL1(const RotationAveragingOptions& options, ComponentProblem* problem, std::string* status) {
  const int n = static_cast<int>(problem->view_ids.size());
  const int m = static_cast<int>(problem->edges.size());
  std::vector<int> var(n, -1);
  int num_free = 0;
  for (int v = 0; v < n; ++v)
    if (v != problem->gauge) var[v] = num_free++;

  // Laplacian of the free views (the gauge is eliminated).
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(4 * m);
  for (const ComponentEdge& e : problem->edges) {
    const int a = var[e.i], b = var[e.j];
    if (a >= 0) triplets.emplace_back(a, a, 1.0);
    if (b >= 0) triplets.emplace_back(b, b, 1.0);
    if (a >= 0 && b >= 0) {
      triplets.emplace_back(a, b, -1.0);
      triplets.emplace_back(b, a, -1.0);
    }
  }
  Eigen::SparseMatrix<double> laplacian(num_free, num_free);
  laplacian.setFromTriplets(triplets.begin(), triplets.end());
  Eigen::SimplicialLLT<Eigen::SparseMatrix<double>> cholesky(laplacian);
  int iterations = 0;
  if (num_free > 0 && cholesky.info() != Eigen::Success) {
    *status = "L1 stage: Laplacian factorisation failed";
  } else if (num_free > 0) {
    // Each edge row: (A x)_e = x_j - x_i, b_e = -e_ij; per coordinate.
    Eigen::MatrixXd b(m, 3), z(m, 3), u(m, 3), ax(m, 3), x(num_free, 3), rhs(num_free, 3);
    auto apply_a = [&](const Eigen::MatrixXd& xs, Eigen::MatrixXd* out) {
      for (int k = 0; k < m; ++k) {
        const ComponentEdge& e = problem->edges[k];
        Eigen::RowVector3d row = Eigen::RowVector3d::Zero();
        if (var[e.j] >= 0) row += xs.row(var[e.j]);
        if (var[e.i] >= 0) row -= xs.row(var[e.i]);
        out->row(k) = row;
      }
    };
    auto apply_at = [&](const Eigen::MatrixXd& ys, Eigen::MatrixXd* out) {
      out->setZero();
      for (int k = 0; k < m; ++k) {
        const ComponentEdge& e = problem->edges[k];
        if (var[e.j] >= 0) out->row(var[e.j]) += ys.row(k);
        if (var[e.i] >= 0) out->row(var[e.i]) -= ys.row(k);
      }
    };
    const double rho = 1.0;  // ADMM penalty
    for (int outer = 0; outer < options.l1_max_iterations; ++outer) {
      for (int k = 0; k < m; ++k) {
        const ComponentEdge& e = problem->edges[k];
        b.row(k) = -LogSO3(problem->rotations[e.i].transpose() * e.measured * problem->rotations[e.j]).transpose();
      }
      z.setZero();
      u.setZero();
      x.setZero();
      for (int it = 0; it < options.l1_admm_max_iterations; ++it) {
        apply_at(b + z - u, &rhs);
        Eigen::MatrixXd x_new = cholesky.solve(rhs);
        apply_a(x_new, &ax);
        const Eigen::MatrixXd z_old = z;
        for (int k = 0; k < m; ++k)
          for (int c = 0; c < 3; ++c) z(k, c) = Shrink(ax(k, c) - b(k, c) + u(k, c), 1.0 / rho);
        u += ax - z - b;
        const double change = (x_new - x).cwiseAbs().maxCoeff();
        x.swap(x_new);
        ++iterations;
        // Primal residual A x - b - z and dual residual rho A^T (z - z_old).
        const double primal = (ax - b - z).norm();
        const double dual = rho * (z - z_old).norm();
        if (change < 1e-5 || (primal < 1e-6 * std::sqrt(m) && dual < 1e-6 * std::sqrt(m))) break;
      }
      double max_update = 0.0;
      for (int v = 0; v < n; ++v) {
        if (var[v] < 0) continue;
        const Eigen::Vector3d d = x.row(var[v]).transpose();
        max_update = std::max(max_update, d.norm());
        problem->rotations[v] = problem->rotations[v] * ExpSO3(d);
      }
      if (max_update < 1e-6) break;
    }
    for (Eigen::Matrix3d& r : problem->rotations) r = ProjectToSO3(r);
  }
  return iterations;
}

void SolveComponentL1Irls(const RotationAveragingOptions& options, ComponentProblem* problem,
                          ComponentSummary* summary) {
  std::string l1_status;
  const int iterations = RefineByL1(options, problem, &l1_status);

  // IRLS stage: unweighted Geman-McClure.
  for (ComponentEdge& e : problem->edges) {
    e.information.setIdentity();
    e.sqrt_information.setIdentity();
  }
  GemanMcClureLoss loss(DegToRad(options.l1_irls_sigma_deg));
  RotationAveragingOptions irls_options = options;
  irls_options.max_iterations = options.l1_irls_max_iterations;
  ComponentSummary irls_summary;
  SolveComponentIrls(irls_options, loss, problem, &irls_summary);
  summary->iterations += iterations + irls_summary.iterations;
  summary->initial_cost = irls_summary.initial_cost;
  summary->final_cost = irls_summary.final_cost;
  summary->converged = irls_summary.converged;
  summary->status = (l1_status.empty() ? "" : l1_status + "; ") + "L1 (" + std::to_string(iterations) +
                    " ADMM iterations) then IRLS: " + irls_summary.status;
}

}  // namespace rotation_averaging
