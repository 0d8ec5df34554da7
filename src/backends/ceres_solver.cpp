// Ceres rotation averaging (the paper's setting): one unit quaternion per
// view (w, x, y, z) on Ceres' QuaternionManifold, residual D^T Log(M^T R_i R_j^T)
// by automatic differentiation, the robust loss applied to its squared norm.
#include <ceres/ceres.h>
#include <ceres/rotation.h>

#include <cmath>

#include "backends/backends_internal.h"
#include "core/estimators/component_problem.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

class LossAdapter : public ceres::LossFunction {
 public:
  explicit LossAdapter(const RobustLoss& loss) : loss_(loss) {}
  void Evaluate(double s, double rho[3]) const override { loss_.Evaluate(s, rho); }

 private:
  const RobustLoss& loss_;
};

struct RelativeRotationCost {
  RelativeRotationCost(const Eigen::Matrix3d& measured, const Eigen::Matrix3d& sqrt_information)
      : sqrt_information_(sqrt_information) {
    const Eigen::Vector4d q = RotationToQuaternion(measured);
    // Store the conjugate: q(M^T).
    measured_inverse_[0] = q[0];
    measured_inverse_[1] = -q[1];
    measured_inverse_[2] = -q[2];
    measured_inverse_[3] = -q[3];
  }

  template <typename T>
  bool operator()(const T* qi, const T* qj, T* residual) const {
    const T qj_inv[4] = {qj[0], -qj[1], -qj[2], -qj[3]};
    T qi_qj_inv[4], error[4];
    ceres::QuaternionProduct(qi, qj_inv, qi_qj_inv);
    const T m_inv[4] = {T(measured_inverse_[0]), T(measured_inverse_[1]), T(measured_inverse_[2]),
                        T(measured_inverse_[3])};
    ceres::QuaternionProduct(m_inv, qi_qj_inv, error);
    // Shortest rotation: QuaternionToAngleAxis of -q equals that of q modulo 2 pi.
    if (error[0] < T(0)) {
      for (T& v : error) v = -v;
    }
    T aa[3];
    ceres::QuaternionToAngleAxis(error, aa);
    for (int r = 0; r < 3; ++r) {
      residual[r] = T(sqrt_information_(r, 0)) * aa[0] + T(sqrt_information_(r, 1)) * aa[1] +
                    T(sqrt_information_(r, 2)) * aa[2];
    }
    return true;
  }

  double measured_inverse_[4];
  Eigen::Matrix3d sqrt_information_;
};

}  // namespace

void CeresSolveComponent(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                         ComponentSummary* summary) {
  const int n = static_cast<int>(problem->view_ids.size());
  std::vector<Eigen::Vector4d> quaternions(n);
  for (int v = 0; v < n; ++v) quaternions[v] = RotationToQuaternion(problem->rotations[v]);

  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::TAKE_OWNERSHIP;
  problem_options.manifold_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  ceres::Problem ceres_problem(problem_options);
  ceres::QuaternionManifold manifold;
  for (const ComponentEdge& e : problem->edges) {
    auto* cost = new ceres::AutoDiffCostFunction<RelativeRotationCost, 3, 4, 4>(
        new RelativeRotationCost(e.measured, e.sqrt_information));
    ceres_problem.AddResidualBlock(cost, new LossAdapter(loss), quaternions[e.i].data(), quaternions[e.j].data());
  }
  for (int v = 0; v < n; ++v) {
    if (!ceres_problem.HasParameterBlock(quaternions[v].data())) continue;
    ceres_problem.SetManifold(quaternions[v].data(), &manifold);
  }
  for (int v = 0; v < n; ++v) {
    if (problem->IsFixed(v) && ceres_problem.HasParameterBlock(quaternions[v].data())) {
      ceres_problem.SetParameterBlockConstant(quaternions[v].data());
    }
  }

  ceres::Solver::Options solver_options;
  solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
  solver_options.max_num_iterations = options.max_iterations;
  solver_options.function_tolerance = std::max(options.function_tolerance, 1e-16);
  solver_options.parameter_tolerance = options.step_tolerance_rad;
  solver_options.gradient_tolerance = 1e-14;
  solver_options.num_threads = std::max(1, options.num_threads);
  solver_options.logging_type = ceres::SILENT;
  ceres::Solver::Summary ceres_summary;
  ceres::Solve(solver_options, &ceres_problem, &ceres_summary);

  for (int v = 0; v < n; ++v) {
    const Eigen::Vector4d& q = quaternions[v];
    problem->rotations[v] = QuaternionToRotation(q[0], q[1], q[2], q[3]);
  }
  summary->iterations += static_cast<int>(ceres_summary.iterations.size());
  summary->initial_cost = ceres_summary.initial_cost;
  summary->final_cost = problem->Cost(loss);
  summary->converged = ceres_summary.termination_type == ceres::CONVERGENCE;
  summary->status = "ceres: " + ceres_summary.message;
}

}  // namespace rotation_averaging
