// Internal to the package: may change between versions.
// One connected component of the view graph in solver form: dense view
// indices, edges with their information matrices, the current estimate.
// Shared by every solver; built by BuildComponentProblems().
#ifndef ROTATION_AVERAGING_SRC_CORE_ESTIMATORS_COMPONENT_PROBLEM_H_
#define ROTATION_AVERAGING_SRC_CORE_ESTIMATORS_COMPONENT_PROBLEM_H_

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <memory>
#include <vector>

#include "rotation_averaging/core/estimators/robust_loss.h"
#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

struct ComponentEdge {
  int i = 0, j = 0;                  // local view indices
  Eigen::Matrix3d measured;          // M_ij = R_i R_j^T (measured)
  Eigen::Matrix3d information;       // W = D D^T
  Eigen::Matrix3d sqrt_information;  // D^T, so that |D^T r|^2 = r^T W r
  double tree_weight = 1.0;          // for the maximum spanning tree
  std::size_t graph_index = 0;       // index in ViewGraph::Edges()
};

struct ComponentProblem {
  std::vector<ViewId> view_ids;
  std::vector<Eigen::Matrix3d> rotations;  // current world-to-camera estimates
  std::vector<bool> has_initial;           // rotation came from a warm start
  std::vector<ComponentEdge> edges;
  int gauge = 0;  // local index of the view held fixed
  // Further views held at their given rotations (a local re-solve's boundary,
  // see SolveRotationAveragingLocally); empty: only the gauge. The IRLS and
  // Ceres solvers honour it; the L1-IRLS baseline does not.
  std::vector<bool> fixed;
  bool IsFixed(int v) const { return v == gauge || (!fixed.empty() && fixed[v]); }

  // r_ij = Log(M_ij^T R_i R_j^T).
  Eigen::Vector3d Residual(const ComponentEdge& e) const {
    return ResidualOf(e, rotations);
  }
  static Eigen::Vector3d ResidualOf(const ComponentEdge& e, const std::vector<Eigen::Matrix3d>& rotations) {
    return LogSO3(e.measured.transpose() * rotations[e.i] * rotations[e.j].transpose());
  }
  // 0.5 * sum rho(|D^T r|^2).
  double Cost(const RobustLoss& loss) const;
  static double CostOf(const std::vector<ComponentEdge>& edges, const std::vector<Eigen::Matrix3d>& rotations,
                       const RobustLoss& loss);
};

// lambda_max / lambda_min of an information matrix (inf if singular).
double InformationAnisotropy(const Eigen::Matrix3d& information);

// Splits the graph into components of >= 2 views and fills edges with their
// information per the options. Warnings (e.g. covariance weighting asked for
// but missing on every edge, which falls back to no weighting) are appended
// to `warnings`; `effective_weighting` receives the weighting actually used.
std::vector<ComponentProblem> BuildComponentProblems(const ViewGraph& graph, const RotationAveragingOptions& options,
                                                     const ViewOrientations& initial, std::vector<std::string>* warnings,
                                                     EdgeWeighting* effective_weighting = nullptr);

// Variance s^2 (rad^2) of the isotropic covariance floor that makes the
// residuals of a solve consistent with the covariances C + s^2 I of its
// edges (covariance weighting in standard deviations: C = W^-1 of `edges`),
// 0 when they already are or when there are too few redundant edges to tell.
// free_views: the views the solve could move (all but the gauge). A variance
// component estimate that outliers do not move: s^2 starts where the median
// whitened squared residual is that of chi2(3), then is re-solved on the
// edges whose whitened squared residual lies below chi2(3)'s 99% quantile, so
// that their sum equals its expectation there, the truncated mean of chi2(3)
// times their redundancy (edges minus free views: the residuals of a fit are
// smaller than the errors), until that set is stable.
double EstimateCovarianceFloor(const std::vector<ComponentEdge>& edges, const std::vector<Eigen::Vector3d>& residuals,
                               int free_views);

// The edges with every information W replaced by (W^-1 + variance I)^-1.
std::vector<ComponentEdge> WithCovarianceFloor(const std::vector<ComponentEdge>& edges, double variance);

// Chooses the gauge (the view with the largest total tree weight among the
// fixed views if there are any, else preferring warm-started views) and
// fills every view without a warm start by chaining edges along a maximum
// spanning tree grown from the warm-started views (or from the gauge, which
// is then set to identity).
void InitializeBySpanningTree(ComponentProblem* problem);

class BlockSparseSystem;

// State kept between IRLS solves of the same component (GNC stages, the final
// solve): the normal-equation pattern, its symbolic analysis and last factor.
struct IrlsWorkspace {
  IrlsWorkspace();
  ~IrlsWorkspace();
  std::unique_ptr<BlockSparseSystem> system;
  std::vector<int> var;  // local view -> free block (-1 for the gauge)
  bool isotropic = false;  // every edge has W = s I: scalar Laplacian system
  // Median over the edges of InformationAnisotropy (3x3-block systems; from
  // at most 10,000 edges evenly spread; < 0 until a solve needs it): see
  // block_multigrid_max_anisotropy.
  double median_anisotropy = -1.0;
  std::vector<int> offdiagonal_slot;  // per edge: BlockSparseSystem::Locate of its off-diagonal block
  // Isotropic problems (the scalar Laplacian), per edge: s of W = s I, the
  // views it joins, the index of its off-diagonal entry (-1: none); per free
  // view: the index of its diagonal entry. Compact copies of what the edge
  // loops read, so that they stream 20 bytes per edge, not the edge.
  std::vector<double> scalar_information;
  std::vector<std::pair<int, int>> ends;
  std::vector<int> offdiagonal_index, diagonal_index;
  std::vector<Eigen::Vector4d> accumulated;  // assembly buffer: rhs row and diagonal per view
  std::vector<Eigen::Quaterniond> measured_conjugate;  // per edge: conj(M_ij) as a unit quaternion
  // Residuals at the end of the last solve and the rotations they belong to.
  std::vector<Eigen::Vector3d> residuals;
  std::vector<Eigen::Matrix3d> residual_rotations;
};

// Solvers; each updates problem->rotations and fills the summary. The IRLS
// solver reuses `workspace` when given (same problem and gauge).
void SolveComponentIrls(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                        ComponentSummary* summary, IrlsWorkspace* workspace = nullptr);
// Posterior covariance of every view at the problem's rotations: the
// diagonal 3x3 blocks of the inverse of the IRLS normal matrix (robust
// weights times information), times the residual variance factor
// sigma^2 = sum w s / (3 sum w - 3 (n - 1)) when that redundancy is at least
// 10 (else 1: the information is trusted as given). With `with_floor`, the
// information is first that of C + s^2 I, with the floor s^2 the residuals
// show (EstimateCovarianceFloor; none when they fit C): a scale factor alone
// fits the edges with the most inliers, whose two-view covariances are the
// least calibrated, and leaves every view supported by them over-confident.
// Perturbation: left, of the world-to-camera rotation, R = Exp(d) R_hat, d in
// rad; relative to the gauge view, whose covariance is zero. `scale_used`
// receives sigma^2, `floor_used` s (rad, 0: none).
bool ComputeViewCovariances(const ComponentProblem& problem, const RobustLoss& loss, std::vector<Eigen::Matrix3d>* covariances,
                            double* scale_used = nullptr, bool with_floor = false, double* floor_used = nullptr);
void SolveComponentCeres(const RotationAveragingOptions& options, const RobustLoss& loss, ComponentProblem* problem,
                         ComponentSummary* summary);
// Chatterjee-Govindu L1 refinement (ADMM, world-frame linearisation); returns
// the number of ADMM iterations. Robust to outliers in the starting tree.
int RefineByL1(int max_outer_iterations, int max_admm_iterations, ComponentProblem* problem, std::string* status);
void SolveComponentL1Irls(const RotationAveragingOptions& options, ComponentProblem* problem,
                          ComponentSummary* summary);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_CORE_ESTIMATORS_COMPONENT_PROBLEM_H_
