// Parameters of the relative rotations estimated from the loops of the
// averaging: each edge's measured rotation depends, to first order, on a few
// parameters shared by many edges (a camera's focal length: a focal length
// off by a fraction e bends the rotation of every pair that camera saw by
// about e times its angle), so
//   M_ij(e) = M_ij Exp(sum_p e_p g_ijp)          (right perturbation)
// with g_ijp the edge's derivative with respect to parameter p. A chain of
// edges cannot tell e: any e fits a tree. A loop can: 360 degrees measured
// as 360 (1 + e) degrees does not close, and the averaging's cost at its
// solution,
//   F(e) = min_R 1/2 sum rho(|D_ij^T Log(M_ij(e)^T R_i R_j^T)|^2),
// is lowest where the loops close best. A pair's own estimate of e (the focal
// check's, from the epipolar geometry of each pair) is a prior of standard
// deviation s_p:
//   e_hat = argmin F(e) / sigma_hat^2 + 1/2 sum_p ((e_p - c_p) / s_p)^2,
// with sigma_hat (>= 1) the residual scale the solve at e = 0 measures: the
// factor by which the edges' covariances are optimistic.
// F is evaluated by solving the averaging again (warm-started, with the loss
// scale fixed at that of the solve at e = 0, so that every evaluation
// minimises the same cost), and e_hat found by Newton steps on its quadratic
// fit from central differences (1 + 2n + n(n-1)/2 solves per step for n
// parameters): where the graph has no loop, F is flat and e_hat is the
// prior's centre.
#ifndef ROTATION_AVERAGING_CORE_ESTIMATORS_LOOP_CALIBRATION_H_
#define ROTATION_AVERAGING_CORE_ESTIMATORS_LOOP_CALIBRATION_H_

#include <Eigen/Core>
#include <cstddef>
#include <string>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

// How graph.Edges()[edge].rotation moves with parameter `parameter`: the
// right perturbation per unit of it. An edge may depend on several
// parameters (a pair of two cameras' views), one entry each.
struct EdgeParameterDerivative {
  std::size_t edge = 0;
  int parameter = 0;
  Eigen::Vector3d derivative = Eigen::Vector3d::Zero();
};

struct LoopCalibrationOptions {
  // The averaging whose cost is F; its loss scale is fixed at the value of
  // the solve at e = 0, and it does not self-calibrate (auto_scale_threshold
  // is set to 0), so that every evaluation minimises one cost.
  RotationAveragingOptions averaging;
  // Per parameter: the prior's centre c_p and standard deviation s_p (> 0).
  std::vector<double> prior_center;
  std::vector<double> prior_sigma;
  // Newton steps; the first differences at first_step_fraction s_p, later
  // ones at the standard deviation of the previous step's estimate (at least
  // min_step), where the fit is the most local that the cost's curvature
  // still resolves.
  int newton_steps = 2;
  double first_step_fraction = 0.1;
  double min_step = 1e-6;
};

struct LoopCalibrationResult {
  bool success = false;
  std::string message;          // why not, when not
  std::vector<double> value;    // e_hat
  // Standard deviation of e_hat from the curvature of the cost and the
  // prior together, and from the prior alone: their ratio is what the
  // loops add.
  std::vector<double> sigma;
  int solves = 0;                // averaging solves run
  double noise_scale = 1.0;      // sigma_hat
  double cost_at_zero = 0.0;     // F(0) / sigma_hat^2 + the prior's term
  double cost_at_value = 0.0;    // F(e_hat) / sigma_hat^2 + the prior's term
};

// `orientations`: a solution of the graph at e = 0 to warm-start from (may be
// empty: then it is solved first). Fails (success false) on options that do
// not validate, a derivative naming an edge or parameter that does not exist,
// a solve that fails, or a fitted curvature that is not positive definite.
LoopCalibrationResult EstimateParametersFromLoops(const ViewGraph& graph,
                                                 const std::vector<EdgeParameterDerivative>& derivatives,
                                                 const LoopCalibrationOptions& options,
                                                 const ViewOrientations& orientations);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_ESTIMATORS_LOOP_CALIBRATION_H_
