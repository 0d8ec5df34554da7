#include "rotation_averaging/core/estimators/rotation_averaging.h"

#include <Eigen/Eigenvalues>
#include <chrono>
#include <limits>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <iterator>
#include <sstream>

#include "core/estimators/component_problem.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "core/util/backends.h"
#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {
namespace {

template <typename Enum, std::size_t N>
bool ParseByName(const std::string& text, const Enum (&all)[N], const char* (*name)(Enum), Enum* out) {
  for (Enum e : all) {
    if (text == name(e)) {
      *out = e;
      return true;
    }
  }
  return false;
}

template <typename Enum, std::size_t N>
std::string JoinNames(const Enum (&all)[N], const char* (*name)(Enum)) {
  std::string names;
  for (Enum e : all) names += (names.empty() ? "" : ", ") + std::string(name(e));
  return names;
}

constexpr EdgeWeighting kAllWeightings[] = {EdgeWeighting::kNone, EdgeWeighting::kInliers, EdgeWeighting::kTrace,
                                            EdgeWeighting::kFrobenius, EdgeWeighting::kCovariance};
constexpr SpanningTreeWeight kAllTreeWeights[] = {SpanningTreeWeight::kAuto, SpanningTreeWeight::kUniform,
                                                 SpanningTreeWeight::kInliers, SpanningTreeWeight::kInformation};
constexpr SolverType kAllSolvers[] = {SolverType::kIrls, SolverType::kCeres, SolverType::kL1Irls};
constexpr CovarianceNormalization kAllNormalizations[] = {CovarianceNormalization::kStandardDeviations,
                                                          CovarianceNormalization::kPaper};
constexpr CovarianceSelfCalibration kAllSelfCalibrations[] = {CovarianceSelfCalibration::kLossScale,
                                                              CovarianceSelfCalibration::kFloor};

// Covariance floor (CovarianceSelfCalibration::kFloor): at most this many
// estimate-and-solve rounds; a floor within this fraction of the last one
// has settled.
constexpr int kCovarianceFloorRounds = 5;
constexpr double kCovarianceFloorSettled = 0.05;
// Relative cost decrease for a start from the spanning tree to replace a
// warm-started solution: far above what two solves converging into one
// basin differ by (function_tolerance 1e-8 per iteration), so a warm
// solution is replaced only by another basin's.
constexpr double kTreeStartMinImprovement = 1e-6;

bool IsRedescending(LossType type) {
  return type == LossType::kMagsac || type == LossType::kTukey || type == LossType::kGemanMcClure;
}

// Default scales. Whitened residuals in standard deviations (calibrated
// covariances): inlier |D^T r| follows chi(3), whose 99% quantile is 3.37, so
// sigma_max = 3 keeps inliers whose covariance is up to ~3x too optimistic
// while cutting at 3.37 * 3 = 10 standard deviations. Unweighted residuals
// in radians: 5 degrees (the L1-IRLS baseline's Geman-McClure scale).
constexpr double kScaleStandardDeviations = 3.0;
constexpr double kScalePaper = 0.02;
constexpr double kScaleRadians = 5.0 * kPi / 180.0;

double DefaultScaleFor(EdgeWeighting weighting, CovarianceNormalization normalization) {
  if (weighting == EdgeWeighting::kCovariance) {
    return normalization == CovarianceNormalization::kPaper ? kScalePaper : kScaleStandardDeviations;
  }
  return kScaleRadians;
}

// Residuals of the problem's edges at its rotations: those the last IRLS
// solve on `workspace` ended with when they are for these rotations (they
// do not depend on the loss or the information), computed otherwise.
std::vector<Eigen::Vector3d> CurrentResiduals(const ComponentProblem& problem, const IrlsWorkspace& workspace) {
  if (workspace.residuals.size() == problem.edges.size() && workspace.residual_rotations == problem.rotations) {
    return workspace.residuals;
  }
  std::vector<Eigen::Vector3d> residuals;
  residuals.reserve(problem.edges.size());
  for (const ComponentEdge& e : problem.edges) residuals.push_back(problem.Residual(e));
  return residuals;
}

// sigma_hat = sqrt(median |D^T r|^2 / 2.366): the scale of the whitened
// residuals (1 for calibrated covariances; 2.366 is the median of chi2(3)).
double WhitenedResidualScale(const ComponentProblem& problem, const std::vector<Eigen::Vector3d>& residuals) {
  std::vector<double> s;
  s.reserve(problem.edges.size());
  for (std::size_t k = 0; k < problem.edges.size(); ++k)
    s.push_back((problem.edges[k].sqrt_information * residuals[k]).squaredNorm());
  if (s.empty()) return 1.0;
  std::nth_element(s.begin(), s.begin() + s.size() / 2, s.end());
  return std::sqrt(s[s.size() / 2] / 2.366);
}

// Fraction of edges whose whitened residual at the current (spanning-tree)
// estimate lies beyond the MAGSAC cut-off k * scale.
double TreeDisagreement(const ComponentProblem& problem, double scale) {
  if (problem.edges.empty()) return 0.0;
  const double cutoff = MagsacLoss::kChiQuantile * MagsacLoss::kChiQuantile * scale * scale;
  std::size_t beyond = 0;
  for (const ComponentEdge& e : problem.edges) {
    if ((e.sqrt_information * problem.Residual(e)).squaredNorm() > cutoff) ++beyond;
  }
  return static_cast<double>(beyond) / problem.edges.size();
}

// Solves a copy of the problem whose edges carry isotropic information
// s(W) I (a scalar-Laplacian IRLS solve, cheap) and takes its rotations as
// the new start when the solve ends finite. Returns its iterations.
template <typename IsotropicScale>
int SolveSurrogate(const RotationAveragingOptions& options, const RobustLoss& loss, IsotropicScale scale_of,
                   ComponentProblem* problem, IrlsWorkspace* workspace) {
  ComponentProblem surrogate = *problem;
  for (ComponentEdge& e : surrogate.edges) {
    const double s = scale_of(e.information);
    e.information = s * Eigen::Matrix3d::Identity();
    e.sqrt_information = std::sqrt(s) * Eigen::Matrix3d::Identity();
  }
  ComponentSummary summary;
  SolveComponentIrls(options, loss, &surrogate, &summary, workspace);
  bool finite = std::isfinite(summary.final_cost);
  for (const Eigen::Matrix3d& r : surrogate.rotations) finite = finite && r.allFinite();
  if (finite) problem->rotations = surrogate.rotations;
  return summary.iterations;
}

}  // namespace

const char* EdgeWeightingName(EdgeWeighting w) {
  switch (w) {
    case EdgeWeighting::kNone: return "none";
    case EdgeWeighting::kInliers: return "inliers";
    case EdgeWeighting::kTrace: return "trace";
    case EdgeWeighting::kFrobenius: return "frobenius";
    case EdgeWeighting::kCovariance: return "covariance";
  }
  return "?";
}
bool ParseEdgeWeighting(const std::string& text, EdgeWeighting* w) {
  return ParseByName(text, kAllWeightings, &EdgeWeightingName, w);
}
const char* SolverTypeName(SolverType s) {
  switch (s) {
    case SolverType::kIrls: return "irls";
    case SolverType::kCeres: return "ceres";
    case SolverType::kL1Irls: return "l1_irls";
  }
  return "?";
}
bool ParseSolverType(const std::string& text, SolverType* s) { return ParseByName(text, kAllSolvers, &SolverTypeName, s); }
const char* CovarianceNormalizationName(CovarianceNormalization n) {
  return n == CovarianceNormalization::kPaper ? "paper" : "std";
}
bool ParseCovarianceNormalization(const std::string& text, CovarianceNormalization* n) {
  return ParseByName(text, kAllNormalizations, &CovarianceNormalizationName, n);
}
const char* SpanningTreeWeightName(SpanningTreeWeight w) {
  switch (w) {
    case SpanningTreeWeight::kAuto: return "auto";
    case SpanningTreeWeight::kUniform: return "uniform";
    case SpanningTreeWeight::kInliers: return "inliers";
    case SpanningTreeWeight::kInformation: return "information";
  }
  return "?";
}
bool ParseSpanningTreeWeight(const std::string& text, SpanningTreeWeight* w) {
  return ParseByName(text, kAllTreeWeights, &SpanningTreeWeightName, w);
}
const char* CovarianceSelfCalibrationName(CovarianceSelfCalibration c) {
  return c == CovarianceSelfCalibration::kFloor ? "floor" : "loss_scale";
}
bool ParseCovarianceSelfCalibration(const std::string& text, CovarianceSelfCalibration* c) {
  return ParseByName(text, kAllSelfCalibrations, &CovarianceSelfCalibrationName, c);
}
const std::vector<EdgeWeighting>& AllEdgeWeightings() {
  static const std::vector<EdgeWeighting> kAll(std::begin(kAllWeightings), std::end(kAllWeightings));
  return kAll;
}

std::string EdgeWeightingChoices() { return JoinNames(kAllWeightings, &EdgeWeightingName); }
std::string SolverTypeChoices() { return JoinNames(kAllSolvers, &SolverTypeName); }
std::string CovarianceNormalizationChoices() { return JoinNames(kAllNormalizations, &CovarianceNormalizationName); }
std::string SpanningTreeWeightChoices() { return JoinNames(kAllTreeWeights, &SpanningTreeWeightName); }
std::string CovarianceSelfCalibrationChoices() {
  return JoinNames(kAllSelfCalibrations, &CovarianceSelfCalibrationName);
}

double DefaultLossScale(const RotationAveragingOptions& options) {
  return DefaultScaleFor(options.weighting, options.covariance_normalization);
}

bool RotationAveragingOptions::Validate(std::string* error) const {
  return OptionCheck()
      .Finite("loss_scale", loss_scale)
      .Above("paper_covariance_scale", paper_covariance_scale, 0.0)
      .Within("warm_start_min_fraction", robust_start.warm_start_min_fraction, 0.0, 1.0)
      .Within("l1_initialization_min_disagreement", robust_start.l1_initialization_min_disagreement, 0.0, 1.0)
      .AtLeast("l1_init_max_iterations", robust_start.l1_init_max_iterations, 0)
      .Above("l1_init_smoothing_rad", robust_start.l1_init_smoothing_rad, 0.0)
      .AtLeast("l1_init_function_tolerance", robust_start.l1_init_function_tolerance, 0.0)
      .NotNan("isotropic_presolve_max_anisotropy", linear.isotropic_presolve_max_anisotropy)
      .AtLeast("isotropic_presolve_function_tolerance", linear.isotropic_presolve_function_tolerance, 0.0)
      .AtLeast("gnc_initial_scale_factor", robust_start.gnc_initial_scale_factor, 1.0)
      .Above("gnc_scale_step", robust_start.gnc_scale_step, 1.0)
      .AtLeast("gnc_stage_max_iterations", robust_start.gnc_stage_max_iterations, 0)
      .NotNan("auto_scale_threshold", auto_scale_threshold)
      .AtLeast("max_iterations", max_iterations, 0)
      .AtLeast("step_tolerance_rad", step_tolerance_rad, 0.0)
      .AtLeast("function_tolerance", function_tolerance, 0.0)
      .Between("linear_solve_tolerance", linear.linear_solve_tolerance, 0.0, 1.0)
      .Between("robust_start_linear_solve_tolerance", linear.robust_start_linear_solve_tolerance, 0.0, 1.0)
      .AtLeast("multigrid_min_views", linear.multigrid_min_views, 0)
      .Above("block_multigrid_max_anisotropy", linear.block_multigrid_max_anisotropy, 0.0)
      .AtLeast("block_cholesky_max_column_count", linear.block_cholesky_max_column_count, 0.0)
      .Between("multigrid_linear_solve_tolerance", linear.multigrid_linear_solve_tolerance, 0.0, 1.0)
      .AtLeast("num_threads", num_threads, 1)
      .AtLeast("posterior_covariance_max_views", posterior_covariance_max_views, 0)
      .AtLeast("l1_max_iterations", l1_irls.l1_max_iterations, 0)
      .AtLeast("l1_admm_max_iterations", l1_irls.l1_admm_max_iterations, 0)
      .Above("l1_irls_sigma_deg", l1_irls.l1_irls_sigma_deg, 0.0)
      .AtLeast("l1_irls_max_iterations", l1_irls.l1_irls_max_iterations, 0)
      .Ok(error);
}

bool RotationAveragingSummary::Success() const {
  if (!error.empty()) return false;
  for (const ComponentSummary& c : components)
    if (!std::isfinite(c.final_cost)) return false;
  return true;
}

double RotationAveragingSummary::LargestComponentFloorRad() const {
  const ComponentSummary* largest = nullptr;
  for (const ComponentSummary& c : components)
    if (!largest || c.num_views > largest->num_views) largest = &c;
  return largest ? largest->covariance_floor_rad : 0.0;
}

std::string RotationAveragingSummary::Report() const {
  std::ostringstream out;
  if (!error.empty()) return "not solved: " + error + "\n";
  std::size_t views = 0, edges_in = 0;
  int iterations = 0;
  double initial = 0.0, final_cost = 0.0;
  for (const ComponentSummary& c : components) {
    views += c.num_views;
    edges_in += c.num_edges;
    iterations += c.iterations;
    initial += c.initial_cost;
    final_cost += c.final_cost;
  }
  out << "components solved: " << components.size() << " (" << views << " views, " << edges_in << " edges)";
  if (num_isolated_views) out << ", isolated views not oriented: " << num_isolated_views;
  out << "\niterations: " << iterations << "\ninitial cost: " << std::setprecision(8) << initial
      << "\nfinal cost: " << final_cost << "\nloss scale: " << loss_scale << "\noutlier edges (weight < 0.01): "
      << num_outlier_edges << "\nsolve time: " << std::setprecision(4) << solve_time_s << " s";
  for (std::size_t k = 0; k < components.size() && k < 5; ++k) {
    const ComponentSummary& c = components[k];
    out << "\n  component " << k << ": " << c.num_views << " views, " << c.num_edges << " edges, " << c.iterations
        << " iterations (" << c.factorizations << " factorisations, " << c.preconditioned_solves
        << " preconditioned solves, " << c.multigrid_solves << " multigrid solves, " << c.extrapolations << " extrapolations), loss scale " << c.loss_scale << " (residual scale " << c.noise_scale;
    if (c.covariance_floor_rad > 0.0) out << ", covariance floor " << RadToDeg(c.covariance_floor_rad) << " deg";
    out << "), " << c.status;
  }
  if (components.size() > 5) out << "\n  ... " << components.size() - 5 << " more components";
  for (const std::string& w : warnings) out << "\nwarning: " << w;
  return out.str();
}

void SolveComponentCeres(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                         ComponentSummary* summary) {
  // Ceres is in the back-end library (src/core/util/backends.h); if it cannot be
  // loaded (a warning says why), IRLS minimises the same cost.
  const Backends* backends = LoadBackends();
  if (backends && backends->solve_component_ceres) {
    backends->solve_component_ceres(options, loss, problem, summary);
    return;
  }
  SolveComponentIrls(options, loss, problem, summary);
  summary->status = "Ceres solver unavailable, solved by IRLS: " + summary->status;
}

namespace {

std::size_t WarmViews(const ComponentProblem& problem) {
  std::size_t warm = 0;
  for (bool h : problem.has_initial) warm += h;
  return warm;
}

// Whether `warm` views of the problem's cover enough of the component (see
// warm_start_min_fraction).
bool AllWarm(const ComponentProblem& problem, std::size_t warm, double min_fraction) {
  return warm == problem.has_initial.size() ||
         (warm > 0 && static_cast<double>(warm) >= min_fraction * static_cast<double>(problem.has_initial.size()));
}

// A warm start with new views (the online averager's last solution, new
// keyframes placed from it) keeps the old views in the basin of an earlier,
// smaller graph: the edges that arrived since can favour another, which a
// start from the spanning tree alone, as a first solve has, reaches. That
// start is refined under the final loss too, in the warm solution's gauge,
// and the lower cost kept. `solve` runs the final loss from
// problem->rotations.
template <typename Solve>
void CompareTreeStart(const Solve& solve, const RobustLoss& loss, ComponentProblem* problem, ComponentSummary* cs) {
  const std::vector<Eigen::Matrix3d> ended = problem->rotations;
  const double ended_cost = cs->final_cost;
  const std::string ended_status = cs->status;
  const bool ended_converged = cs->converged;
  const double initial_cost = cs->initial_cost;
  const int gauge = problem->gauge;
  const std::vector<bool> has_initial = problem->has_initial;
  problem->has_initial.assign(has_initial.size(), false);
  InitializeBySpanningTree(problem);
  problem->has_initial = has_initial;
  // One rotation of the whole tree (the relative rotations, and so the
  // cost, do not change) puts the gauge view where the warm solution holds it.
  const Eigen::Matrix3d to_gauge = problem->rotations[problem->gauge].transpose() * ended[gauge];
  for (Eigen::Matrix3d& r : problem->rotations) r = r * to_gauge;
  problem->gauge = gauge;
  solve(loss);
  cs->initial_cost = initial_cost;
  // Lower beyond what two solves of one basin differ by.
  if (cs->final_cost < ended_cost * (1.0 - kTreeStartMinImprovement)) {
    std::ostringstream note;
    note << std::setprecision(6) << "; the warm start ended at " << ended_cost
         << ", a start from the spanning tree alone lower, at " << cs->final_cost << ": kept";
    cs->status += note.str();
    return;
  }
  problem->rotations = ended;
  cs->final_cost = ended_cost;
  cs->status = ended_status;
  cs->converged = ended_converged;
}

// One component's solve, phase by phase (SolveComponent runs them in order).
class ComponentSolve {
 public:
  ComponentSolve(const RotationAveragingOptions& options, double scale, ComponentProblem* problem)
      : options_(options), scale_(scale), component_scale_(scale), problem_(*problem) {
    cs_.num_views = problem_.view_ids.size();
    cs_.num_edges = problem_.edges.size();
    warm_views_ = WarmViews(problem_);
    all_warm_ = AllWarm(problem_, warm_views_, options.robust_start.warm_start_min_fraction);
    InitializeBySpanningTree(&problem_);
    cs_.gauge_view = problem_.view_ids[problem_.gauge];
    initial_rotations_ = problem_.rotations;
    component_loss_ = CreateLoss(options.loss, scale);
  }

  // The robust start, the solve, self-calibration of the covariance scale,
  // and the start refined where the robust solve ended above it.
  void Solve(EdgeWeighting weighting) {
    covariances_in_sigmas_ = weighting == EdgeWeighting::kCovariance &&
                             options_.covariance_normalization == CovarianceNormalization::kStandardDeviations;
    if (options_.solver == SolverType::kL1Irls) {
      SolveComponentL1Irls(options_, &problem_, &cs_);
      return;
    }
    double initial_cost = SolveFromStart();
    if (covariances_in_sigmas_ && options_.auto_scale_threshold > 0.0 && options_.loss_scale <= 0.0) {
      SelfCalibrate(&initial_cost);
    }
    // Both costs are reported under the final loss.
    cs_.initial_cost = std::isfinite(initial_cost)
                           ? initial_cost
                           : ComponentProblem::CostOf(problem_.edges, initial_rotations_, *component_loss_);
    if (cs_.final_cost > cs_.initial_cost * (1.0 + 1e-9) + 1e-300) RefineStartInstead();
    if (options_.robust_start.compare_tree_start && !all_warm_ && warm_views_ > 0 && problem_.fixed.empty()) {
      CompareTreeStart([this](const RobustLoss& l) { SolveWith(options_, l); }, *component_loss_, &problem_, &cs_);
    }
  }

  // A solve that produced non-finite numbers keeps the initial
  // orientations (with a warning in `summary`). Whether it was finite.
  bool KeepFinite(RotationAveragingSummary* summary) {
    bool finite = true;
    for (const Eigen::Matrix3d& r : problem_.rotations) finite = finite && r.allFinite();
    if (!finite || !std::isfinite(cs_.final_cost)) {
      problem_.rotations = initial_rotations_;
      cs_.status = "solve failed (non-finite result); kept the initial orientations: " + cs_.status;
      cs_.converged = false;
      cs_.final_cost = problem_.Cost(*component_loss_);
      summary->warnings.push_back(cs_.status);
    }
    return finite;
  }

  void PosteriorCovariances(RotationAveragingSummary* summary) const {
    std::vector<Eigen::Matrix3d> view_covariances;
    // A floor is a covariance in rad^2: only edges weighted by their
    // covariances have one to widen.
    if (ComputeViewCovariances(problem_, *component_loss_, &view_covariances, nullptr,
                               options_.posterior_covariance_floor && covariances_in_sigmas_)) {
      for (std::size_t v = 0; v < problem_.view_ids.size(); ++v) {
        summary->view_covariances[problem_.view_ids[v]] = view_covariances[v];
      }
    } else {
      summary->warnings.push_back("posterior covariances of a component of " +
                                  std::to_string(problem_.view_ids.size()) +
                                  " views skipped (normal matrix singular or its factor too dense)");
    }
  }

  // Per-edge results under the final loss and the weighting of the options
  // (the L1-IRLS baseline reports its own unweighted residuals).
  void EdgeResults(RotationAveragingSummary* summary) {
    const std::vector<Eigen::Vector3d> residuals = CurrentResiduals(problem_, workspace_);
    for (std::size_t k = 0; k < problem_.edges.size(); ++k) {
      const ComponentEdge& e = problem_.edges[k];
      EdgeResult& er = summary->edges[e.graph_index];
      const Eigen::Vector3d& r = residuals[k];
      er.residual_rad = r.norm();
      er.whitened_squared = (e.sqrt_information * r).squaredNorm();
      er.robust_weight = options_.solver == SolverType::kL1Irls
                             ? GemanMcClureLoss(DegToRad(options_.l1_irls.l1_irls_sigma_deg)).Weight(er.whitened_squared)
                             : component_loss_->Weight(er.whitened_squared);
      er.solved = true;
      if (er.robust_weight < 0.01) ++summary->num_outlier_edges;
    }
    cs_.loss_scale =
        options_.solver == SolverType::kL1Irls ? DegToRad(options_.l1_irls.l1_irls_sigma_deg) : component_scale_;
  }

  const ComponentSummary& Summary() const { return cs_; }

 private:
  void SolveWith(const RotationAveragingOptions& o, const RobustLoss& l) {
    if (o.solver == SolverType::kCeres) {
      SolveComponentCeres(o, l, &problem_, &cs_);
    } else {
      SolveComponentIrls(o, l, &problem_, &cs_, &workspace_);
    }
  }

  // The robust start and the solve under the final loss, from the
  // component's start. Returns the start's cost under that loss when the
  // solve reports it, NaN otherwise.
  double SolveFromStart() {
    problem_.rotations = initial_rotations_;
    // A start that already agrees with (almost) every edge needs neither
    // the L1 start nor graduated non-convexity.
    const bool needs_robust_start =
        !all_warm_ && TreeDisagreement(problem_, scale_) > options_.robust_start.l1_initialization_min_disagreement;
    if (options_.robust_start.l1_initialization && needs_robust_start) {
      // Unweighted, so the start does not depend on the covariances and
      // always takes the scalar-Laplacian path of the IRLS solver.
      RotationAveragingOptions l1_options = options_;
      l1_options.max_iterations = options_.robust_start.l1_init_max_iterations;
      l1_options.function_tolerance = options_.robust_start.l1_init_function_tolerance;
      l1_options.linear.linear_solve_tolerance = options_.linear.robust_start_linear_solve_tolerance;
      cs_.iterations += SolveSurrogate(l1_options, SoftL1Loss(options_.robust_start.l1_init_smoothing_rad),
                                       [](const Eigen::Matrix3d&) { return 1.0; }, &problem_, &workspace_);
    } else if (!all_warm_ && !needs_robust_start && options_.linear.isotropic_presolve_max_anisotropy > 1.0) {
      IsotropicPresolve();
    }
    // Graduated non-convexity for redescending losses started from a tree.
    if (IsRedescending(options_.loss) && needs_robust_start && options_.robust_start.gnc_initial_scale_factor > 1.0 &&
        options_.robust_start.gnc_scale_step > 1.0) {
      // Intermediate stages only need to move into the right basin: a few
      // iterations each, not convergence.
      RotationAveragingOptions stage_options = options_;
      stage_options.max_iterations = std::min(options_.max_iterations, options_.robust_start.gnc_stage_max_iterations);
      stage_options.linear.linear_solve_tolerance = options_.linear.robust_start_linear_solve_tolerance;
      for (double s = scale_ * options_.robust_start.gnc_initial_scale_factor; s > scale_ * 1.0001;
           s /= options_.robust_start.gnc_scale_step) {
        SolveWith(stage_options, *CreateLoss(options_.loss, s));
      }
    }
    // The IRLS solve reports the cost of its start under its loss: when
    // nothing ran before it and the loss stays, that is the start's cost
    // under the final loss, which the report needs.
    const bool from_initial = options_.solver == SolverType::kIrls && problem_.rotations == initial_rotations_;
    SolveWith(options_, *component_loss_);
    return from_initial ? cs_.initial_cost : std::numeric_limits<double>::quiet_NaN();
  }

  // Anisotropic information that is not far from isotropic: a first solve
  // with each edge's information replaced by its mean eigenvalue.
  void IsotropicPresolve() {
    // Stops at the first edge beyond the limit.
    double max_anisotropy = 1.0;
    for (const ComponentEdge& e : problem_.edges) {
      max_anisotropy = std::max(max_anisotropy, InformationAnisotropy(e.information));
      if (max_anisotropy > options_.linear.isotropic_presolve_max_anisotropy) break;
    }
    if (max_anisotropy > 1.0 + 1e-9 && max_anisotropy <= options_.linear.isotropic_presolve_max_anisotropy) {
      RotationAveragingOptions iso_options = options_;
      iso_options.function_tolerance = options_.linear.isotropic_presolve_function_tolerance;
      cs_.iterations += SolveSurrogate(iso_options, *component_loss_,
                                       [](const Eigen::Matrix3d& w) { return w.trace() / 3.0; }, &problem_,
                                       &workspace_);
    }
  }

  // Self-calibration of the covariance scale (see auto_scale_threshold).
  // `initial_cost`: as SolveFromStart returns it, for the last solve.
  void SelfCalibrate(double* initial_cost) {
    cs_.noise_scale = WhitenedResidualScale(problem_, CurrentResiduals(problem_, workspace_));
    if (options_.self_calibration == CovarianceSelfCalibration::kFloor) EstimateFloor(initial_cost);
    // Still optimistic (or kLossScale): widen the loss.
    if (cs_.noise_scale > options_.auto_scale_threshold) {
      component_scale_ = scale_ * cs_.noise_scale;
      component_loss_ = CreateLoss(options_.loss, component_scale_);
      SolveWith(options_, *component_loss_);
      *initial_cost = std::numeric_limits<double>::quiet_NaN();
    }
  }

  // The floor is estimated whatever the residual scale: it is zero when
  // the residuals fit the covariances. The first residuals come from a
  // solve that trusted the optimistic covariances (and so rejected
  // correct edges and leaned on others), which inflates them; as in
  // Helmert's variance component estimation, each floor is estimated
  // from the solve weighted by the one before, until it settles.
  void EstimateFloor(double* initial_cost) {
    const std::vector<ComponentEdge> unfloored = problem_.edges;
    int free_views = 0;
    for (int v = 0; v < static_cast<int>(problem_.view_ids.size()); ++v) free_views += !problem_.IsFixed(v);
    double variance = 0.0;
    for (int round = 0; round < kCovarianceFloorRounds; ++round) {
      const double next = EstimateCovarianceFloor(unfloored, CurrentResiduals(problem_, workspace_), free_views);
      if (!(next > 0.0) || (variance > 0.0 && std::abs(next - variance) <= kCovarianceFloorSettled * variance)) {
        break;
      }
      variance = next;
      problem_.edges = WithCovarianceFloor(unfloored, variance);
      workspace_.median_anisotropy = -1.0;  // of the information it was computed from
      // Afresh: the first solve's basin was chosen under the optimistic
      // covariances (an edge they made rigid can have pulled a view off).
      *initial_cost = SolveFromStart();
    }
    if (variance > 0.0) {
      cs_.covariance_floor_rad = std::sqrt(variance);
      cs_.noise_scale = WhitenedResidualScale(problem_, CurrentResiduals(problem_, workspace_));
    }
  }

  // The robust start (L1, graduated non-convexity from a wider scale, the
  // re-solve after auto-scaling) can settle in a basin that costs more
  // under the final loss than the starting point itself: a loop whose
  // misclosure is either one outlier edge or noise spread over all of
  // them. Then the start is refined under the final loss as well and the
  // lower of the two kept, so a solve never ends above its start.
  void RefineStartInstead() {
    const std::vector<Eigen::Matrix3d> ended = problem_.rotations;
    const double ended_cost = cs_.final_cost;
    const std::string ended_status = cs_.status;
    const bool ended_converged = cs_.converged;
    const double start_cost = cs_.initial_cost;
    problem_.rotations = initial_rotations_;
    SolveWith(options_, *component_loss_);
    cs_.initial_cost = start_cost;
    cs_.refined_start = true;
    if (!(cs_.final_cost < ended_cost)) {
      problem_.rotations = ended;
      cs_.final_cost = ended_cost;
      cs_.status = ended_status;
      cs_.converged = ended_converged;
    }
    std::ostringstream note;
    note << std::setprecision(6) << "; the robust solve ended above its start (" << ended_cost << " > "
         << cs_.initial_cost << " under the final loss): the start refined under it gives " << cs_.final_cost;
    cs_.status += note.str();
  }

  const RotationAveragingOptions& options_;
  const double scale_;
  double component_scale_;
  // Edges weighted by their covariances, in standard deviations (the
  // weighting the solve took effect with).
  bool covariances_in_sigmas_ = false;
  ComponentProblem& problem_;
  ComponentSummary cs_;
  std::size_t warm_views_ = 0;
  bool all_warm_ = false;
  std::vector<Eigen::Matrix3d> initial_rotations_;
  std::unique_ptr<RobustLoss> component_loss_;
  IrlsWorkspace workspace_;
};

// Initialises one component problem (spanning tree from its warm views) and
// solves it with the options' robust start, loss and auto-scaling; writes
// its per-edge results into summary->edges (by graph_index) and, when asked,
// its posterior covariances.
ComponentSummary SolveComponent(const RotationAveragingOptions& options, EdgeWeighting weighting, double scale,
                                bool covariances, ComponentProblem* problem, RotationAveragingSummary* summary) {
  ComponentSolve solve(options, scale, problem);
  solve.Solve(weighting);
  const bool finite = solve.KeepFinite(summary);
  if (finite && covariances && options.solver != SolverType::kL1Irls && options.posterior_covariance_max_views > 0 &&
      static_cast<int>(problem->view_ids.size()) <= options.posterior_covariance_max_views) {
    solve.PosteriorCovariances(summary);
  }
  solve.EdgeResults(summary);
  return solve.Summary();
}

}  // namespace

bool SolveRotationAveraging(const ViewGraph& graph, const RotationAveragingOptions& options,
                            ViewOrientations* orientations, RotationAveragingSummary* summary) {
  const auto start = std::chrono::steady_clock::now();
  *summary = RotationAveragingSummary();
  if (!options.Validate(&summary->error)) return false;
  EdgeWeighting weighting = options.weighting;
  std::vector<ComponentProblem> problems =
      BuildComponentProblems(graph, options, *orientations, &summary->warnings, &weighting);
  const double scale =
      options.loss_scale > 0.0 ? options.loss_scale : DefaultScaleFor(weighting, options.covariance_normalization);
  summary->loss_scale = scale;

  std::size_t solved_views = 0;
  summary->edges.assign(graph.NumEdges(), EdgeResult());
  for (ComponentProblem& problem : problems) {
    summary->components.push_back(SolveComponent(options, weighting, scale, /*covariances=*/true, &problem, summary));
    for (std::size_t v = 0; v < problem.view_ids.size(); ++v) {
      (*orientations)[problem.view_ids[v]] = problem.rotations[v];
    }
    solved_views += problem.view_ids.size();
  }
  summary->num_isolated_views = graph.NumViews() - solved_views;
  summary->solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary->Success();
}

namespace {

// The views' incident edges (ids need not be dense): views by index into
// graph.Views(), each edge's two ends, and the edges of view v at
// incident[offsets[v] .. offsets[v + 1]).
struct Adjacency {
  std::unordered_map<ViewId, int> index;
  int n = 0;
  std::vector<int> offsets, incident;
  std::vector<std::pair<int, int>> ends;

  int Other(int k, int v) const { return ends[k].first == v ? ends[k].second : ends[k].first; }
};

Adjacency BuildAdjacency(const ViewGraph& graph) {
  const std::vector<RelativeRotation>& edges = graph.Edges();
  Adjacency a;
  a.index.reserve(graph.NumViews());
  for (const View& v : graph.Views()) a.index.emplace(v.id, static_cast<int>(a.index.size()));
  a.n = static_cast<int>(a.index.size());
  a.offsets.assign(a.n + 1, 0);
  a.incident.resize(2 * edges.size());
  a.ends.resize(edges.size());
  for (std::size_t k = 0; k < edges.size(); ++k) {
    a.ends[k] = {a.index.at(edges[k].view1), a.index.at(edges[k].view2)};
    ++a.offsets[a.ends[k].first + 1];
    ++a.offsets[a.ends[k].second + 1];
  }
  for (int v = 0; v < a.n; ++v) a.offsets[v + 1] += a.offsets[v];
  std::vector<int> fill(a.offsets.begin(), a.offsets.end() - 1);
  for (std::size_t k = 0; k < edges.size(); ++k) {
    a.incident[fill[a.ends[k].first]++] = static_cast<int>(k);
    a.incident[fill[a.ends[k].second]++] = static_cast<int>(k);
  }
  return a;
}

// The region: breadth-first from the changed views, `hops` deep, at most
// max_views views (nearest first). kSolved when there is one.
LocalSolveOutcome LocalRegion(const Adjacency& a, const std::vector<ViewId>& changed, const LocalSolveOptions& local,
                              std::vector<int>* region) {
  std::vector<int> depth(a.n, -1);
  for (ViewId id : changed) {
    auto it = a.index.find(id);
    if (it == a.index.end() || depth[it->second] >= 0) continue;
    depth[it->second] = 0;
    region->push_back(it->second);
  }
  if (region->empty()) return LocalSolveOutcome::kNothingToSolve;
  if (region->size() > local.max_views) return LocalSolveOutcome::kNeedsFullSolve;
  for (std::size_t head = 0; head < region->size() && region->size() < local.max_views; ++head) {
    const int v = (*region)[head];
    if (depth[v] >= local.hops) break;  // breadth-first: every later view is as deep
    for (int p = a.offsets[v]; p < a.offsets[v + 1] && region->size() < local.max_views; ++p) {
      const int u = a.Other(a.incident[p], v);
      if (depth[u] < 0) {
        depth[u] = depth[v] + 1;
        region->push_back(u);
      }
    }
  }
  return LocalSolveOutcome::kSolved;
}

// The sub-graph: every edge with an end in the region whose other end is in
// the region or already oriented (a boundary view, held fixed); the graph's
// index of each of its edges in `sub_to_graph`.
ViewGraph LocalSubGraph(const ViewGraph& graph, const Adjacency& a, const std::vector<int>& region,
                        const std::vector<char>& in_region, const ViewOrientations& orientations,
                        std::vector<std::size_t>* sub_to_graph) {
  const std::vector<RelativeRotation>& edges = graph.Edges();
  ViewGraph sub(graph.Validation());
  std::vector<char> added(a.n, 0), taken(edges.size(), 0);
  const std::vector<View>& views = graph.Views();
  auto add_view = [&](int v) {
    if (!added[v]) {
      sub.AddView(views[v].id, views[v].name);
      added[v] = 1;
    }
  };
  for (int v : region) {
    for (int p = a.offsets[v]; p < a.offsets[v + 1]; ++p) {
      const int k = a.incident[p];
      const int u = a.Other(k, v);
      if (taken[k] || (!in_region[u] && !orientations.count(views[u].id))) continue;
      taken[k] = 1;
      add_view(v);
      add_view(u);
      if (sub.AddEdge(edges[k], nullptr, DuplicatePolicy::kKeepBoth) != AddEdgeResult::kRejected) {
        sub_to_graph->push_back(static_cast<std::size_t>(k));
      }
    }
  }
  return sub;
}

// Holds the views outside the region fixed and maps the problems' edges
// back to the graph; each problem's component label from the last full
// solve (-1: none) into `problem_label`. False when a problem joins
// components solved apart (each in its own gauge): that needs a full solve.
bool PrepareLocalProblems(const Adjacency& a, const std::vector<char>& in_region,
                          const std::vector<std::size_t>& sub_to_graph, const std::vector<int>* labels,
                          std::vector<ComponentProblem>* problems, std::vector<int>* problem_label) {
  auto label_of = [labels](ViewId id) { return labels && id < labels->size() ? (*labels)[id] : -1; };
  problem_label->assign(problems->size(), -1);
  for (std::size_t p = 0; p < problems->size(); ++p) {
    ComponentProblem& problem = (*problems)[p];
    problem.fixed.assign(problem.view_ids.size(), false);
    for (std::size_t v = 0; v < problem.view_ids.size(); ++v) {
      const ViewId id = problem.view_ids[v];
      problem.fixed[v] = !in_region[a.index.at(id)];
      const int label = label_of(id);
      if (label < 0) continue;
      if ((*problem_label)[p] >= 0 && (*problem_label)[p] != label) return false;
      (*problem_label)[p] = label;
    }
    for (ComponentEdge& e : problem.edges) e.graph_index = sub_to_graph[e.graph_index];
  }
  return true;
}

}  // namespace

LocalSolveOutcome SolveRotationAveragingLocally(const ViewGraph& graph, const std::vector<ViewId>& changed,
                                                const LocalSolveOptions& local,
                                                const RotationAveragingOptions& options,
                                                ViewOrientations* orientations, RotationAveragingSummary* summary) {
  const auto start = std::chrono::steady_clock::now();
  *summary = RotationAveragingSummary();
  if (!options.Validate(&summary->error)) return LocalSolveOutcome::kNeedsFullSolve;
  if (options.solver == SolverType::kL1Irls) return LocalSolveOutcome::kNeedsFullSolve;
  const Adjacency adjacency = BuildAdjacency(graph);
  std::vector<int> region;
  const LocalSolveOutcome found = LocalRegion(adjacency, changed, local, &region);
  if (found != LocalSolveOutcome::kSolved) return found;
  std::vector<char> in_region(adjacency.n, 0);
  for (int v : region) in_region[v] = 1;
  std::vector<std::size_t> sub_to_graph;
  const ViewGraph sub = LocalSubGraph(graph, adjacency, region, in_region, *orientations, &sub_to_graph);
  // Components of the sub-graph; views outside the region are held fixed.
  EdgeWeighting weighting = options.weighting;
  std::vector<ComponentProblem> problems =
      BuildComponentProblems(sub, options, *orientations, &summary->warnings, &weighting);
  std::vector<int>* labels = local.component_labels;
  std::vector<int> problem_label;
  if (!PrepareLocalProblems(adjacency, in_region, sub_to_graph, labels, &problems, &problem_label)) {
    return LocalSolveOutcome::kNeedsFullSolve;
  }
  const double default_scale =
      options.loss_scale > 0.0 ? options.loss_scale : DefaultScaleFor(weighting, options.covariance_normalization);
  summary->loss_scale = default_scale;
  summary->edges.assign(graph.Edges().size(), EdgeResult());
  int next_label = 0;
  if (labels) {
    for (int l : *labels) next_label = std::max(next_label, l + 1);
  }
  for (std::size_t p = 0; p < problems.size(); ++p) {
    ComponentProblem& problem = problems[p];
    RotationAveragingOptions component_options = options;
    const int label = problem_label[p];
    if (options.loss_scale <= 0.0 && local.label_loss_scale && label >= 0 &&
        static_cast<std::size_t>(label) < local.label_loss_scale->size() && (*local.label_loss_scale)[label] > 0.0) {
      component_options.loss_scale = (*local.label_loss_scale)[label];
    }
    const double scale = component_options.loss_scale > 0.0 ? component_options.loss_scale : default_scale;
    summary->components.push_back(
        SolveComponent(component_options, weighting, scale, /*covariances=*/false, &problem, summary));
    for (std::size_t v = 0; v < problem.view_ids.size(); ++v) {
      if (!problem.fixed[v]) (*orientations)[problem.view_ids[v]] = problem.rotations[v];
    }
    if (labels) {
      const int l = label >= 0 ? label : next_label++;
      for (ViewId id : problem.view_ids) {
        if (id >= labels->size()) {
          if (id > 2 * graph.NumViews() + 1024) continue;  // sparse ids are not labelled
          labels->resize(id + 1, -1);
        }
        (*labels)[id] = l;
      }
    }
  }
  summary->solve_time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return summary->Success() ? LocalSolveOutcome::kSolved : LocalSolveOutcome::kFailed;
}

}  // namespace rotation_averaging
