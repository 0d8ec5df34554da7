// Public header of rotation_averaging::core (docs/embedding.md).
// Robust, uncertainty-aware rotation averaging (Zhang, Larsson, Barath,
// "Revisiting Rotation Averaging: Uncertainties and Robust Losses", CVPR 2023).
//
// Finds world-to-camera orientations R_i minimising
//
//   sum over edges (i, j) of  rho( |D_ij^T r_ij|^2 ) / 2,   r_ij = Log(M_ij^T R_i R_j^T),
//
// with D_ij D_ij^T = W_ij the edge's information (see EdgeWeighting) and rho a
// robust loss. Each connected component is solved on its own, with its own
// gauge (one view held fixed), initialised from a maximum spanning tree or
// warm-started from given orientations.
#ifndef ROTATION_AVERAGING_CORE_ESTIMATORS_ROTATION_AVERAGING_H_
#define ROTATION_AVERAGING_CORE_ESTIMATORS_ROTATION_AVERAGING_H_

#include <Eigen/Core>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "rotation_averaging/core/estimators/robust_loss.h"
#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

// How each edge's information W_ij = D_ij D_ij^T is formed.
//  kNone:       W = I. Residuals in radians.
//  kInliers:    W = (n_ij / median n) I. Residuals in (about) radians.
//  kTrace:      W = (median tr C / tr C_ij) I.
//  kFrobenius:  W = (median |C|_F / |C_ij|_F) I.
//  kCovariance: W = C_ij^-1 (full 3x3), see CovarianceNormalization.
// The scalar weightings are normalised by their median so that the loss scale
// keeps the unit of the unweighted residual (radians). Edges that lack what a
// weighting needs (no covariance, no inlier count) get the median weight.
enum class EdgeWeighting { kNone, kInliers, kTrace, kFrobenius, kCovariance };

// How covariances are turned into information for kCovariance.
//  kStandardDeviations (default): W = C^-1 with C in rad^2, so the whitened
//    residual D^T r is in standard deviations and the loss scale is in
//    standard deviations too. Principled: a calibrated covariance makes the
//    inlier whitened residual chi(3) with unit scale, whatever the dataset.
//  kPaper: the paper's code: W = C^-1 / paper_covariance_scale (1e8), with
//    sigma_max = 0.02 in those units. Reproduces the published setting for
//    covariances computed as unscaled (J^T J)^-1 of pixel residuals.
enum class CovarianceNormalization { kStandardDeviations, kPaper };

enum class SolverType {
  kIrls,    // sparse IRLS / Gauss-Newton in the tangent space, 3x3 block weights (fast)
  kCeres,   // Ceres nonlinear least squares over quaternions with the loss (the paper's setting)
  kL1Irls,  // baseline: Chatterjee-Govindu L1 (ADMM) then IRLS with Geman-McClure, unweighted (Theia)
};

// Weight of an edge when building the initial maximum spanning tree.
enum class SpanningTreeWeight { kAuto, kUniform, kInliers, kInformation };

// What a solve does when its covariances turn out optimistic (covariance
// weighting in standard deviations; see auto_scale_threshold).
//  kLossScale: widen the loss scale by the residual scale sigma_hat, i.e.
//    treat every covariance as sigma_hat^2 times too small.
//  kFloor: add an isotropic covariance C + s^2 I to every edge, with s^2
//    estimated from the residuals of the solve (EstimateCovarianceFloor in
//    component_problem.h), and solve again from the start at the loss scale
//    as given; the floor is estimated again from that solve, and so on until
//    it settles (at most five rounds: the first solve's residuals, under the
//    optimistic covariances, overstate it). Estimated at any residual scale (it is zero when the residuals
//    fit the covariances); the loss is still widened if the residual scale
//    stays above auto_scale_threshold.
//    For errors that do not shrink with the number of matches behind an
//    edge (correlated feature errors, biased matches): two-view covariances
//    from pixel noise are least calibrated on the pairs with the most
//    inliers (results/frontend.md, "Calibration", NEES by inlier count), so
//    a scale factor that fits those makes weak pairs look far too uncertain.
enum class CovarianceSelfCalibration { kLossScale, kFloor };

const char* EdgeWeightingName(EdgeWeighting w);
bool ParseEdgeWeighting(const std::string& text, EdgeWeighting* w);
const char* SolverTypeName(SolverType s);
bool ParseSolverType(const std::string& text, SolverType* s);
const char* CovarianceNormalizationName(CovarianceNormalization n);
bool ParseCovarianceNormalization(const std::string& text, CovarianceNormalization* n);
const char* SpanningTreeWeightName(SpanningTreeWeight w);  // "auto", "uniform", "inliers", "information"
bool ParseSpanningTreeWeight(const std::string& text, SpanningTreeWeight* w);
const char* CovarianceSelfCalibrationName(CovarianceSelfCalibration c);  // "loss_scale", "floor"
bool ParseCovarianceSelfCalibration(const std::string& text, CovarianceSelfCalibration* c);
const std::vector<EdgeWeighting>& AllEdgeWeightings();
// Every name the parsers above take, "a, b, c", for messages that list them.
std::string EdgeWeightingChoices();
std::string SolverTypeChoices();
std::string CovarianceNormalizationChoices();
std::string SpanningTreeWeightChoices();
std::string CovarianceSelfCalibrationChoices();

// How a solve starts: the spanning tree, the L1 fit and graduated
// non-convexity, and when they run (the robust start).
struct RobustStartOptions {
  SpanningTreeWeight spanning_tree_weight = SpanningTreeWeight::kAuto;
  // Refine a spanning-tree start by an L1 fit before the robust solve (not
  // used when every view is warm-started). The paper starts the robust loss
  // directly from the tree, which a single outlier in the tree can defeat.
  // The L1 fit minimises sum |r_ij| (unweighted, rotation-invariant norm) by
  // IRLS with a smoothed L1 loss (Soft L1 at l1_init_smoothing_rad) on the
  // scalar-Laplacian system, which leaves fewer views off than
  // Chatterjee-Govindu's coordinate-wise L1 by ADMM, in less time
  // (results/core_benchmark.md, robustness); the ADMM stage stays in the
  // paper's L1-IRLS baseline.
  bool l1_initialization = true;
  // The L1 start and GNC run only when more than this fraction of edges
  // disagree with the spanning tree beyond the MAGSAC cut-off (k * loss
  // scale). Clean SLAM pose graphs have none (measured on the shared data) and
  // skip both; a tree that contains an outlier makes many edges disagree.
  double l1_initialization_min_disagreement = 0.02;
  // New views in a warm-started component are placed from their warm
  // neighbours (the prediction most of their edges agree with). When at least
  // this fraction of the views is warm, the start is kept as it is: no L1
  // start or GNC over the graph. 1 (default) = only when every view is warm,
  // so a solve after new keyframes still runs the robust start when the start
  // disagrees with the edges. 0.99 re-solves a growing graph several times
  // faster, but keyframes an outlier edge placed wrongly before their later
  // edges arrived stay wrong, and the error spreads (results/online.md, the
  // warm_start_min_fraction row: thousands of keyframes more than 5 deg off).
  double warm_start_min_fraction = 1.0;
  // A warm start with new views (not all warm, as above) is also solved
  // from the spanning tree alone, as a first solve starts, refined under the
  // final loss in the warm solution's gauge, and the lower cost is kept: the
  // old views' basin, chosen on a smaller graph, can be the wrong one for
  // the edges that came since. It costs one more solve under the final loss
  // per warm-started component (full solves; local solves hold their
  // boundary and never compare). Off: the warm start's solution is kept.
  // What it costs a full re-solve of a large graph: results/online.md.
  bool compare_tree_start = true;
  int l1_init_max_iterations = 20;       // IRLS iterations of the L1 start
  double l1_init_smoothing_rad = 0.01;   // Soft L1 scale: quadratic below ~0.6 deg
  double l1_init_function_tolerance = 1e-4;  // a start needs no more
  // Graduated non-convexity for redescending losses (MAGSAC, Tukey,
  // Geman-McClure): start at gnc_initial_scale_factor times the loss scale
  // and divide it by gnc_scale_step until it reaches the loss scale. Protects
  // against outliers in the spanning tree. 1 disables it.
  double gnc_initial_scale_factor = 8.0;
  double gnc_scale_step = 2.0;
  int gnc_stage_max_iterations = 3;    // iterations of each intermediate GNC stage
};

// How the linear systems of the IRLS solver are solved: factorisations,
// conjugate gradients preconditioned with an earlier factor or with
// aggregation multigrid, and their tolerances: the time of a solve, not
// its minimum.
struct LinearSolverOptions {
  // A start that needs no robust start (clean pose graphs) but carries
  // anisotropic information is first solved with each W replaced by
  // (trace W / 3) I: a scalar-Laplacian IRLS solve, a fraction of the cost of
  // the 3x3 block system, which lands close enough that the exact solve then
  // needs fewer factorisations (same minimum). Only when every edge's
  // lambda_max/lambda_min is at most this: with nearly degenerate
  // covariances the isotropic optimum is too far off and the pre-solve
  // costs more than it saves. <= 1 disables it.
  double isotropic_presolve_max_anisotropy = 10.0;
  double isotropic_presolve_function_tolerance = 1e-4;
  // IRLS linear systems are first solved by conjugate gradients
  // preconditioned with the factor of an earlier iteration, to this relative
  // residual |H x - b| / |b|; a system that will not get there within a few
  // iterations is factorised anew.
  double linear_solve_tolerance = 1e-5;
  // The steps of the robust start (L1, GNC stages) only have to head into
  // the right basin, so their systems are solved loosely (same minimum).
  // Looser still saves factorisations but leaves more views in wrong basins
  // on the keyframe chain of results/online.md.
  double robust_start_linear_solve_tolerance = 1e-2;
  // IRLS systems of at least this many views are solved by conjugate
  // gradients preconditioned with aggregation multigrid (AggregationAmg),
  // set up in O(nonzeros) for each matrix, instead of through a sparse
  // Cholesky factor; a solve it does not finish falls back to the
  // factorisation. Scalar Laplacians (isotropic information: the L1 start,
  // no or scalar weighting) and the 3x3-block systems of full covariances
  // alike. The robust start's weights change too much between iterations
  // for an earlier factor to precondition the next matrix, so there every
  // step would be a fresh factorisation whose fill grows faster than the
  // graph (results/scale.md has both paths side by side). Below about 2,000
  // views a factorisation is cheaper. A system multigrid does not solve is
  // noticed within a few iterations and factorised, and the next ones with
  // it. 0: never.
  int multigrid_min_views = 2000;
  // 3x3-block systems go to multigrid only when the median over their edges
  // of lambda_max / lambda_min of the information is at most this. Its
  // hierarchy is built on the scalar Laplacian of each block's trace / 3,
  // which bounds the block matrix only within the edges' anisotropy: on the
  // anisotropic graphs of results/scale.md it converges in tens of
  // iterations; on nearly degenerate covariances (pose graphs whose median
  // ratio is orders of magnitude above this) it does not, and finding that
  // out costs more than the factorisation.
  double block_multigrid_max_anisotropy = 1000.0;
  // 3x3-block systems that are factorised are factorised block by block
  // (BlockCholesky: fixed-size 3x3 products, no per-entry index work) when
  // their factor, predicted from the block graph before any numbers, has at
  // most this many entries per column on average; denser factors go to
  // CHOLMOD's supernodal factor, whose dense kernels pay only there. The
  // default sits between the densities where each was measured faster
  // (results/core_benchmark.md, "Factorisation of 3x3-block systems").
  double block_cholesky_max_column_count = 64.0;
  // Systems solved by multigrid take max(linear_solve_tolerance, this): each
  // of its iterations costs a pass over the matrix, where the stale-factor
  // iterations of the factorisation path are nearly free to add. IRLS
  // converges linearly, so a step solved more accurately than that
  // contraction buys nothing (inexact Newton): at 1e-2 the scale graphs of
  // 10,000 and 100,000 views end at the final cost of 1e-4 to seven digits,
  // with its median error and views off, in a quarter less time with
  // anisotropic covariances at 100,000 views and a sixth less at 10,000;
  // isotropic ones take about the same time either way (results/scale.md,
  // "Multigrid solve tolerance").
  double multigrid_linear_solve_tolerance = 1e-2;
};

// The L1-IRLS baseline (SolverType::kL1Irls; Theia's RobustRotationEstimator
// defaults).
struct L1IrlsOptions {
  int l1_max_iterations = 5;              // outer L1 relinearisations
  int l1_admm_max_iterations = 200;       // ADMM iterations per L1 step (stops earlier when x moves < 1e-5 rad)
  double l1_irls_sigma_deg = 5.0;         // Geman-McClure scale of the IRLS stage, degrees
  int l1_irls_max_iterations = 100;
};

struct RotationAveragingOptions {
  SolverType solver = SolverType::kIrls;
  LossType loss = LossType::kMagsac;
  // Loss scale a (sigma_max for MAGSAC) in the unit of the whitened residual
  // (standard deviations for covariance weighting, radians otherwise; see
  // above). <= 0 selects DefaultLossScale().
  double loss_scale = 0.0;
  EdgeWeighting weighting = EdgeWeighting::kCovariance;
  CovarianceNormalization covariance_normalization = CovarianceNormalization::kStandardDeviations;
  double paper_covariance_scale = 1e8;  // kPaper: W = C^-1 / this
  // Use orientations passed in as the starting point (views without one are
  // filled in along the spanning tree). The gauge view keeps its given value,
  // so a warm-started solution stays in the frame of the previous one.
  bool warm_start = true;
  // Covariance weighting in standard deviations: if the median whitened
  // squared residual at the solution says the covariances are optimistic
  // (estimated scale sigma_hat = sqrt(median / 2.366) above this), re-solve
  // with the loss scale multiplied by sigma_hat. 2.366 is the median of
  // chi2(3), so the estimate is robust to up to half the edges being
  // outliers. Real two-view covariances are optimistic (results/frontend.md, calibration).
  // self_calibration says how the solve then corrects them. <= 0 disables.
  double auto_scale_threshold = 1.5;
  // kLossScale in the library and the node, whose local re-solves reuse the
  // loss scale of the last full solve; `rotavg images` uses kFloor.
  CovarianceSelfCalibration self_calibration = CovarianceSelfCalibration::kLossScale;
  int max_iterations = 100;            // per component (IRLS iterations or Ceres iterations)
  double step_tolerance_rad = 1e-6;    // stop when every update is smaller than this (1e-6 rad = 0.00006 deg)
  double function_tolerance = 1e-8;    // relative cost decrease at which to stop
  int num_threads = 1;                 // Ceres threads; the IRLS solver is single-threaded
  // Posterior covariances of the views (RotationAveragingSummary::
  // view_covariances) for components of at most this many views (0: never).
  // Selected inversion of one sparse factorisation, a fraction of the solve
  // on sparse pose graphs; graphs whose factor is nearly dense are skipped
  // beyond a fixed work budget, with a warning. Off by default
  // in the library (an extra output, not part of the solve); the node turns
  // it on (covariance_max_keyframes).
  int posterior_covariance_max_views = 0;
  // The posterior covariances from edges widened by the covariance floor
  // their residuals show (ComputeViewCovariances in component_problem.h),
  // not only scaled by the residual variance factor, with covariance
  // weighting in standard deviations (other weightings have no covariance
  // to widen). The solution is the same either way.
  bool posterior_covariance_floor = true;
  // IRLS: jump along a geometrically shrinking step sequence (kept only when
  // it lowers the cost): fewer iterations, to a point closer to the minimum.
  bool irls_extrapolation = true;

  RobustStartOptions robust_start;
  LinearSolverOptions linear;
  L1IrlsOptions l1_irls;

  // True if every field (the sub-structs' too) is within its range;
  // otherwise false, with `error`
  // naming the first field that is not (e.g. "max_iterations must be at
  // least 0 (got -1)"). The solves refuse options that do not validate.
  bool Validate(std::string* error) const;
};

// The loss scale used when options.loss_scale <= 0, for this loss, weighting
// and normalisation.
double DefaultLossScale(const RotationAveragingOptions& options);

struct ComponentSummary {
  std::size_t num_views = 0;
  std::size_t num_edges = 0;
  ViewId gauge_view = 0;
  int iterations = 0;
  int factorizations = 0;        // numeric Cholesky factorisations (IRLS solver)
  double loss_scale = 0.0;       // scale used for this component (after auto-scaling)
  double noise_scale = 1.0;      // sigma_hat: estimated scale of the whitened residuals
  // Standard deviation s of the isotropic covariance floor C + s^2 I added to
  // every edge (CovarianceSelfCalibration::kFloor), rad; 0: none.
  double covariance_floor_rad = 0.0;
  int preconditioned_solves = 0; // IRLS steps solved by PCG with an earlier factor
  int multigrid_solves = 0;      // IRLS steps solved by multigrid-preconditioned CG
  int extrapolations = 0;        // IRLS extrapolation jumps taken
  // Both under the final loss (after auto-scaling): the start's cost and the
  // solution's; final_cost <= initial_cost except for the L1-IRLS baseline.
  double initial_cost = 0.0;
  double final_cost = 0.0;
  // The robust solve ended above its start, so the start was also refined
  // under the final loss and the lower of the two kept (status says which).
  bool refined_start = false;
  bool converged = false;
  std::string status;  // human-readable reason the solve stopped
};

// Per-edge result, in the order of ViewGraph::Edges().
struct EdgeResult {
  double residual_rad = 0.0;     // |Log(M^T R_i R_j^T)| at the solution
  double whitened_squared = 0.0; // |D^T r|^2
  double robust_weight = 0.0;    // rho'(s) in [0, 1]: 0 is a rejected outlier
  bool solved = false;           // false if the edge's component was not solved
};

struct RotationAveragingSummary {
  std::vector<ComponentSummary> components;
  std::vector<EdgeResult> edges;
  std::size_t num_isolated_views = 0;  // views with no edge: not oriented
  std::size_t num_outlier_edges = 0;   // edges whose final robust weight is < 0.01
  double loss_scale = 0.0;             // scale actually used
  double solve_time_s = 0.0;           // wall time of the solve (no I/O)
  // Posterior covariance per view, rad^2: left perturbation of the
  // world-to-camera rotation (R = Exp(d) R_hat), relative to its component's
  // gauge view (zero there); see ComputeViewCovariances in component_problem.h.
  std::map<ViewId, Eigen::Matrix3d> view_covariances;
  std::vector<std::string> warnings;
  // Why nothing was solved (options that do not validate); empty otherwise.
  std::string error;
  bool Success() const;
  std::string Report() const;  // multi-line text for logs and the CLI
  // The covariance floor of the largest component, rad (0: none, or no
  // component): the one floor of a graph that holds one scene.
  double LargestComponentFloorRad() const;
};

// Solves every connected component of two or more views. On input
// `orientations` may hold warm-start values; on output it holds the solution
// for every view of a solved component (isolated views are left out). The
// warm-start values of one component must share one frame: after new edges
// join components solved apart, pass only one side's (OnlineAverager does).
// Never throws on bad numbers: a component whose solve fails keeps its input
// (or spanning-tree) orientations and says so in its status.
bool SolveRotationAveraging(const ViewGraph& graph, const RotationAveragingOptions& options,
                            ViewOrientations* orientations, RotationAveragingSummary* summary);

// A local re-solve after a small change (a new keyframe and its edges, a
// loop closure): only the views within `hops` edges of the changed views (at
// most max_views of them, nearest first) move; their neighbours outside that
// region are held at their given orientations, so the rest of the solution
// and its gauge stay as they are. Costs in proportion to the region, not the
// graph. The robust start, loss and weighting are those of the options, with
// two differences: the loss scale comes from the last full solve when known
// (LocalSolveOptions::label_loss_scale; otherwise the region's edges are
// auto-scaled as in a full solve), and scalar
// weightings (inliers, trace, Frobenius) are normalised by the medians of
// the region's edges rather than the graph's. Not a substitute for full
// solves: the error of a long loop is spread over the region only, and views
// outside it are not revisited; the online averager runs full solves every
// few local ones (OnlineAveragerOptions::full_solve_every).
struct LocalSolveOptions {
  int hops = 3;                   // breadth-first depth of the region around the changed views
  std::size_t max_views = 1000;   // region size cap; more changed views than this: kNeedsFullSolve
  // Component label of each view (indexed by ViewId, -1 or beyond the end:
  // none) in the solution the orientations come from. When given, a change
  // that joins two labelled components (solved apart, each in its own gauge)
  // is refused with kNeedsFullSolve, and on kSolved the region's views get
  // the label of their component (a new one, 1 + the largest, for a
  // component without labelled views). Meant for dense ids (the online
  // averager's); views with ids far beyond the graph's size stay unlabelled.
  std::vector<int>* component_labels = nullptr;
  // Loss scale per label (e.g. each component's scale in the last full
  // solve), used when options.loss_scale <= 0: a region's few edges are a
  // poor basis for the auto-scaling.
  const std::vector<double>* label_loss_scale = nullptr;
};
enum class LocalSolveOutcome {
  kSolved,          // the region's views hold the new solution
  kNothingToSolve,  // no changed view is in the graph
  kNeedsFullSolve,  // too many changed views, a join of components, or the L1-IRLS solver: nothing changed
  kFailed,          // a component's solve failed (its initial orientations were kept)
};
// `orientations` holds the current solution on input (views without one are
// placed from their neighbours) and the updated region on output. The
// summary's components are those of the region; its edges are indexed like
// graph.Edges(), with solved = true for the region's edges only.
LocalSolveOutcome SolveRotationAveragingLocally(const ViewGraph& graph, const std::vector<ViewId>& changed,
                                                const LocalSolveOptions& local,
                                                const RotationAveragingOptions& options,
                                                ViewOrientations* orientations, RotationAveragingSummary* summary);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_ESTIMATORS_ROTATION_AVERAGING_H_
