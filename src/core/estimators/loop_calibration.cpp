#include "rotation_averaging/core/estimators/loop_calibration.h"

#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <sstream>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// The graph with every edge moved by the parameters e (first order, as in
// the header), in the same edge order.
ViewGraph Perturbed(const ViewGraph& graph, const std::vector<EdgeParameterDerivative>& derivatives,
                    const Eigen::VectorXd& e) {
  std::vector<Eigen::Vector3d> step(graph.NumEdges(), Eigen::Vector3d::Zero());
  for (const EdgeParameterDerivative& d : derivatives) step[d.edge] += e[d.parameter] * d.derivative;
  ViewGraph out(graph.Validation());
  for (const View& v : graph.Views()) out.AddView(v.id, v.name);
  for (std::size_t k = 0; k < graph.NumEdges(); ++k) {
    RelativeRotation edge = graph.Edges()[k];
    if (!step[k].isZero()) edge.rotation = edge.rotation * ExpSO3(step[k]);
    out.AddEdge(edge, nullptr, DuplicatePolicy::kKeepBoth);
  }
  return out;
}

// What is wrong with the inputs ("" when nothing is).
std::string CheckInputs(const ViewGraph& graph, const std::vector<EdgeParameterDerivative>& derivatives,
                        const LoopCalibrationOptions& options) {
  const int n = static_cast<int>(options.prior_center.size());
  std::string error;
  if (!options.averaging.Validate(&error)) return error;
  if (n == 0 || options.prior_sigma.size() != options.prior_center.size()) {
    return "one prior centre and standard deviation per parameter are needed";
  }
  for (int p = 0; p < n; ++p) {
    if (!(options.prior_sigma[p] > 0.0) || !std::isfinite(options.prior_sigma[p]) ||
        !std::isfinite(options.prior_center[p])) {
      return "parameter " + std::to_string(p) + "'s prior is not a finite centre and positive deviation";
    }
  }
  if (!(options.first_step_fraction > 0.0) || !(options.min_step > 0.0) || options.newton_steps < 1) {
    return "first_step_fraction and min_step must be positive and newton_steps at least 1";
  }
  for (const EdgeParameterDerivative& d : derivatives) {
    if (d.edge >= graph.NumEdges() || d.parameter < 0 || d.parameter >= n || !d.derivative.allFinite()) {
      return "a derivative names edge " + std::to_string(d.edge) + " and parameter " + std::to_string(d.parameter) +
             " (or is not finite), which the graph does not have";
    }
  }
  return "";
}

// The solve at e = 0 (into `start`), which fixes the loss scale and gives
// every later solve its start; `averaging` gets the options of those solves
// and `noise_scale` the residual scale to divide their costs by. False when
// it fails.
bool SolveAtZero(const ViewGraph& graph, const LoopCalibrationOptions& options, ViewOrientations* start,
                 RotationAveragingOptions* averaging, double* noise_scale, std::string* error) {
  *averaging = options.averaging;
  averaging->posterior_covariance_max_views = 0;
  RotationAveragingSummary summary;
  if (!SolveRotationAveraging(graph, *averaging, start, &summary) || !summary.Success()) {
    *error = "the averaging at the given parameters failed: " + summary.error;
    return false;
  }
  // Two-view covariances are optimistic (results/frontend.md,
  // "Calibration"): the solve measures by how much (the residual scale
  // sigma_hat of its largest component), and the cost, in units of the
  // covariances given, is a log-likelihood only once divided by its square.
  const ComponentSummary* largest = nullptr;
  for (const ComponentSummary& c : summary.components) {
    if (!largest || c.num_views > largest->num_views) largest = &c;
  }
  *noise_scale = largest ? std::max(1.0, largest->noise_scale) : 1.0;
  averaging->loss_scale = summary.loss_scale;
  averaging->auto_scale_threshold = 0.0;
  // Each evaluation starts where the solution at e = 0 is: the cost is
  // compared between solutions of one basin, not between robust starts.
  averaging->warm_start = true;
  averaging->robust_start.l1_initialization = false;
  averaging->robust_start.compare_tree_start = false;
  averaging->robust_start.warm_start_min_fraction = 0.0;
  return true;
}

// The gradient and Hessian of `cost` at `e` (whose cost is `at_e`) by
// central differences of steps `h`.
template <typename Cost>
void FiniteDifferences(const Cost& cost, const Eigen::VectorXd& e, const Eigen::VectorXd& h, double at_e,
                       Eigen::VectorXd* gradient, Eigen::MatrixXd* hessian) {
  const int n = static_cast<int>(e.size());
  Eigen::VectorXd plus(n), minus(n);
  gradient->resize(n);
  for (int p = 0; p < n; ++p) {
    Eigen::VectorXd x = e;
    x[p] += h[p];
    plus[p] = cost(x);
    x[p] = e[p] - h[p];
    minus[p] = cost(x);
    (*gradient)[p] = (plus[p] - minus[p]) / (2.0 * h[p]);
    (*hessian)(p, p) = (plus[p] + minus[p] - 2.0 * at_e) / (h[p] * h[p]);
  }
  for (int p = 0; p < n; ++p) {
    for (int q = p + 1; q < n; ++q) {
      Eigen::VectorXd x = e;
      x[p] += h[p];
      x[q] += h[q];
      (*hessian)(p, q) = (*hessian)(q, p) = (cost(x) - plus[p] - plus[q] + at_e) / (h[p] * h[q]);
    }
  }
}

}  // namespace

LoopCalibrationResult EstimateParametersFromLoops(const ViewGraph& graph,
                                                 const std::vector<EdgeParameterDerivative>& derivatives,
                                                 const LoopCalibrationOptions& options,
                                                 const ViewOrientations& orientations) {
  LoopCalibrationResult result;
  const int n = static_cast<int>(options.prior_center.size());
  auto fail = [&result](const std::string& why) {
    result.success = false;
    result.message = why;
    return result;
  };
  std::string error = CheckInputs(graph, derivatives, options);
  if (!error.empty()) return fail(error);
  RotationAveragingOptions averaging;
  ViewOrientations start = orientations;
  double noise_scale = 1.0;
  if (!SolveAtZero(graph, options, &start, &averaging, &noise_scale, &error)) return fail(error);
  ++result.solves;
  result.noise_scale = noise_scale;

  const Eigen::Map<const Eigen::VectorXd> center(options.prior_center.data(), n);
  const Eigen::Map<const Eigen::VectorXd> sigma(options.prior_sigma.data(), n);
  const Eigen::VectorXd information = sigma.cwiseInverse().cwiseAbs2();
  auto prior = [&](const Eigen::VectorXd& e) { return 0.5 * (e - center).cwiseAbs2().dot(information); };
  bool failed = false;
  auto cost = [&](const Eigen::VectorXd& e) {
    ViewOrientations r = start;
    RotationAveragingSummary s;
    ++result.solves;
    if (!SolveRotationAveraging(Perturbed(graph, derivatives, e), averaging, &r, &s) || !s.Success()) {
      failed = true;
      return 0.0;
    }
    double f = 0.0;
    for (const ComponentSummary& c : s.components) f += c.final_cost;
    return f / (noise_scale * noise_scale) + prior(e);
  };

  Eigen::VectorXd e = Eigen::VectorXd::Zero(n);
  Eigen::VectorXd h = options.first_step_fraction * sigma;
  result.cost_at_zero = cost(e);
  double at_e = result.cost_at_zero;
  Eigen::MatrixXd hessian(n, n);
  for (int step = 0; step < options.newton_steps; ++step) {
    Eigen::VectorXd gradient;
    FiniteDifferences(cost, e, h, at_e, &gradient, &hessian);
    if (failed) return fail("an averaging solve at perturbed parameters failed");
    const Eigen::LLT<Eigen::MatrixXd> llt(hessian);
    if (llt.info() != Eigen::Success) {
      std::ostringstream why;
      why << "the cost's curvature is not positive definite (diagonal " << hessian.diagonal().transpose() << ")";
      return fail(why.str());
    }
    const Eigen::VectorXd next = e - llt.solve(gradient);
    const double at_next = cost(next);
    if (failed) return fail("an averaging solve at perturbed parameters failed");
    // A quadratic fit is only trusted where it lowers the cost: a step that
    // raises it ends the search where it stands.
    if (!(at_next <= at_e)) break;
    e = next;
    at_e = at_next;
    const Eigen::VectorXd deviation = llt.solve(Eigen::MatrixXd::Identity(n, n)).diagonal().cwiseSqrt();
    h = deviation.cwiseMax(options.min_step).cwiseMin(h);
  }
  const Eigen::MatrixXd covariance = hessian.inverse();
  result.success = true;
  result.value.assign(e.data(), e.data() + n);
  result.sigma.resize(n);
  for (int p = 0; p < n; ++p) result.sigma[p] = std::sqrt(std::max(0.0, covariance(p, p)));
  result.cost_at_value = at_e;
  return result;
}

}  // namespace rotation_averaging
