// Public header of rotation_averaging::frontend (docs/embedding.md).
// Refinement of averaged orientations on the point correspondences of every
// edge, not only on the edges' two-view summaries (rotation, covariance).
//
// Rotation averaging sees each pair through a Gaussian approximation of its
// rotation: the covariance is the local curvature of the pair's Sampson cost
// at its own optimum. Where a pair's cost is a long, curved valley (rotation
// and translation direction trade off) or a few wrong matches moved that
// optimum, the approximation is poor. This refinement minimises the pairs'
// Sampson errors themselves, jointly:
//
//   min over R_i and one unit t_ij per edge of
//     sum_edges sum_matches rho((sampson(x_j, [t_ij]x R_j R_i^T, x_i) / sigma_ij)^2)
//
// with rho Cauchy's loss. No points and no global translations are
// estimated; each edge keeps its own translation direction, which is the
// rotation-only bundle adjustment of Lee & Civera (CVPR 2021) written with
// the Sampson error instead of their eigenvalue cost (the same minimum over
// t to first order, in pixels rather than algebraic units). The orientations
// of the averaging are the start; it converges to the nearest minimum, so it
// refines a good averaging and cannot repair a bad one.
#ifndef ROTATION_AVERAGING_FRONTEND_ESTIMATORS_CORRESPONDENCE_REFINEMENT_H_
#define ROTATION_AVERAGING_FRONTEND_ESTIMATORS_CORRESPONDENCE_REFINEMENT_H_

#include <Eigen/Core>
#include <string>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

// The inlier correspondences of one edge. Camera 1 is view1: a point seen at
// x1 in view1 and x2 in view2 satisfies x2^T [t]x R_21 x1 = 0 with
// R_21 = R_view2 R_view1^T (world-to-camera orientations).
struct EdgeCorrespondences {
  ViewId view1 = 0, view2 = 0;
  std::vector<Eigen::Vector2d> points1, points2;  // normalised image coordinates (K^-1 x, undistorted)
  // Start of t_21 (the two-view estimate); zero for a pair of the
  // rotation-only model (no measurable translation, so no direction).
  Eigen::Vector3d translation = Eigen::Vector3d::UnitX();
  // Standard deviation of the Sampson residual in normalised coordinates
  // (the two-view estimate's pixel noise over the focal length): each edge's
  // residuals are whitened by it, so noisy pairs count for less.
  double sigma = 0.0;
};

// The edge of a two-view estimate: its inliers in normalised coordinates, its
// translation t_21 as the start (zero for the rotation-only model), and its
// pixel noise sigma_px over the focal length focal_px. sigma_px is floored at
// 1e-3 px so that a noiseless (synthetic) pair keeps finite weights.
EdgeCorrespondences MakeEdgeCorrespondences(ViewId view1, ViewId view2, std::vector<Eigen::Vector2d> points1,
                                            std::vector<Eigen::Vector2d> points2, const Eigen::Vector3d& translation,
                                            double sigma_px, double focal_px);

// True if the edge's sigma is positive, its points are finite and its
// translation is finite and not zero; with allow_rotation_only, a zero
// translation (a pair of the rotation-only model) passes too.
bool CorrespondencesAreFinite(const EdgeCorrespondences& e, bool allow_rotation_only = false);

// The translation direction that best explains the edge's correspondences
// under the relative rotation r21: x2^T [t]x R x1 = t . (R x1 x x2), so t is
// the eigenvector of the smallest eigenvalue of sum m m^T, m = R x1 x x2,
// with the sign of e.translation (which it falls back to if degenerate).
Eigen::Vector3d BestTranslationDirection(const EdgeCorrespondences& e, const Eigen::Matrix3d& r21);

struct CorrespondenceRefinementOptions {
  // Cauchy scale in standard deviations of each edge's residual. 3: the rule
  // the two-view refinement selects its inliers with, so a match the
  // two-view estimate kept as an inlier at its own optimum starts in the
  // loss' quadratic part, and one the other edges push beyond it loses
  // its pull.
  double loss_scale_sigmas = 3.0;
  int max_iterations = 50;
  // Edges with fewer correspondences than this are left out.
  int min_correspondences = 8;
  // After a first pass over every edge, an edge is left out when, under
  // its result (and the translation direction that fits it best), fewer
  // than this fraction of its correspondences are within the loss scale:
  // the rest of the graph contradicts it (a wrong pair on a repetitive or
  // symmetric scene), and its matches, all beyond the scale, would still
  // pull together. If any is, a second pass solves without them. 0: one pass.
  double min_agreement_fraction = 0.5;
};

struct CorrespondenceRefinementSummary {
  // Of the last pass.
  int edges_used = 0;
  int edges_contradicted = 0;     // fewer than min_agreement_fraction within the scale after the first pass
  int edges_skipped = 0;          // too few correspondences, unknown views, bad numbers
  std::size_t correspondences = 0;
  int views = 0;
  int passes = 0;
  int iterations = 0;             // of every pass
  double initial_cost = 0.0;      // Ceres cost (robustified, whitened) at the start of the last pass
  double final_cost = 0.0;        // and at its end
  double time_s = 0.0;
  bool converged = false;
  std::string status;
  std::string Report() const;     // one line for logs and the CLI
};

// Refines `orientations` (world-to-camera, as SolveRotationAveraging gives
// them) in place. Views without an orientation and edges touching one are
// left out; one view per connected component of the used edges is held
// fixed (the gauge). Returns false, leaving `orientations` as they were, if
// nothing could be refined or the solver failed.
bool RefineRotationsWithCorrespondences(const std::vector<EdgeCorrespondences>& edges,
                                        const CorrespondenceRefinementOptions& options,
                                        ViewOrientations* orientations, CorrespondenceRefinementSummary* summary);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_ESTIMATORS_CORRESPONDENCE_REFINEMENT_H_
