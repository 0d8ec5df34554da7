// Public header of rotation_averaging::core (docs/embedding.md).
// Scoring an orientation estimate against ground truth.
//
// Both are world-to-camera rotations keyed by view name. The estimate lives in
// an arbitrary world frame, so it is first aligned by one global rotation G
// (R_est_i ~ R_gt_i G): a robust initial guess (the per-view G_i = R_gt_i^T R_est_i
// with the smallest median distance to the others), then an iteratively
// reweighted Cauchy fit in the tangent space. The per-view error is the angle
// between R_gt_i G and R_est_i.
//
// AUC at threshold t: the area under the recall curve (fraction of ground-truth
// views with error <= x) for x in [0, t], divided by t. Views missing from the
// estimate count as failures (their error is infinite).
#ifndef ROTATION_AVERAGING_CORE_EVAL_ROTATION_EVALUATION_H_
#define ROTATION_AVERAGING_CORE_EVAL_ROTATION_EVALUATION_H_

#include <Eigen/Core>
#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

using NamedOrientations = std::map<std::string, Eigen::Matrix3d>;

struct EvaluationResult {
  std::size_t views_in_ground_truth = 0;
  std::size_t views_estimated = 0;
  std::size_t views_common = 0;
  Eigen::Matrix3d alignment = Eigen::Matrix3d::Identity();  // G
  std::vector<std::pair<std::string, double>> errors_deg;   // common views, by name
  double median_error_deg = 0.0;  // over common views (inf if none)
  double mean_error_deg = 0.0;
  std::vector<std::pair<double, double>> auc;  // (threshold deg, AUC in [0, 1])
  std::string ToText() const;
  std::string ToJson() const;
};

// AUC of the recall curve up to `threshold_deg` (see above); `num_total` is
// the number of ground-truth views (missing ones count as failures).
double RecallAuc(const std::vector<double>& errors_deg, std::size_t num_total, double threshold_deg);

// Robust single-rotation alignment G minimising sum Cauchy(angle(R_gt_i G, R_est_i)).
Eigen::Matrix3d AlignRotations(const std::vector<Eigen::Matrix3d>& ground_truth,
                               const std::vector<Eigen::Matrix3d>& estimate);

EvaluationResult EvaluateOrientations(const NamedOrientations& estimate, const NamedOrientations& ground_truth,
                                      const std::vector<double>& auc_thresholds_deg = {2.0, 5.0, 10.0, 20.0});

// Calibration of a view graph's edge covariances against ground truth. For
// every edge with a covariance whose two views the ground truth has (by view
// name), eta = Log(R_12_true^T R_12) is the edge's error in its right
// perturbation, the frame of its covariance, and NEES = eta^T (C + s^2 I)^-1 eta
// with s the isotropic floor given (0: the edge's own covariance). Calibrated
// covariances give chi-square with 3 degrees of freedom: mean 3, median 2.37,
// 95% of edges below 7.81. No alignment is needed: relative rotations do not
// depend on the world frame. The reference's own error counts as the edges'.
//
// The errors are then split into what belongs to views and what to pairs:
// the offsets d_k (a left perturbation of each view's true rotation,
// R_k -> Exp(d_k) R_k) that best explain every scored edge's error,
// eta_12 ~ R_2 R_1^T d_1 - d_2, fitted by least absolute whitened edge error
// (sum of sqrt(r^T (C + s^2 I)^-1 r), iteratively reweighted; the offsets'
// common rotation of the world left free), linearised about the reference
// and fitted again about the offset views until they settle. This is the
// averaging of the pairs started from the reference: what remains is the
// pairs' disagreement with each other, the same whatever the reference. An
// offset that all of a view's pairs share leaves the pairs consistent with
// each other, so neither the averaging's residuals nor the covariance floor
// estimated from them can see it: it is either the reference's own error for
// that view, or an effect of that image (its intrinsics, a lens shift) that
// every pair of it inherits. The fit has 3 (views - 1) parameters per
// connected set of views for 3 values per edge, so it also absorbs a part of
// independent pair errors, the more the fewer edges a view has.
struct EdgeCalibration {
  struct Edge {
    std::string name1, name2;
    double error_deg = 0.0;
    double nees = 0.0;
    double error_after_view_offsets_deg = 0.0;
    double nees_after_view_offsets = 0.0;
  };
  struct ViewOffset {
    std::string name;
    // d_k in the view's camera frame, after the alignment of the views'
    // orientations to the reference that EvaluateOrientations uses.
    Eigen::Vector3d offset_deg = Eigen::Vector3d::Zero();
  };
  std::size_t edges = 0;              // in the graph
  std::size_t edges_scored = 0;       // with a covariance and both views in the ground truth
  double floor_rad = 0.0;
  double median_error_deg = 0.0;      // NaN if no edge is scored
  double nees_median = 0.0;
  double nees_mean = 0.0;
  double within_95 = 0.0;             // fraction of scored edges with NEES <= 7.81
  double median_view_offset_deg = 0.0;               // median |d_k| over the views; NaN if no edge is scored
  double median_error_after_view_offsets_deg = 0.0;  // NaN if no edge is scored
  double nees_median_after_view_offsets = 0.0;
  std::vector<Edge> scored;           // in the graph's edge order
  std::vector<ViewOffset> view_offsets;  // views of the scored edges, in the graph's view order
  std::string ToText() const;
};
EdgeCalibration EvaluateEdgeCovariances(const ViewGraph& graph, const NamedOrientations& ground_truth,
                                        double floor_rad = 0.0);

// Calibration of posterior orientation covariances against ground truth.
// `covariances` (by view name) are of a left perturbation of the
// world-to-camera rotation, R = Exp(d) R_hat, relative to a gauge view held
// fixed in each connected component (`component`: view name -> index), as
// OnlineSolution::covariance gives them. A component's gauge is its view of
// the smallest covariance trace; views whose covariance is as small (trace
// below 1e-6 of the component's median: the gauge's rig capture) are held
// with it and not scored. The estimate is aligned to the truth through the
// gauge, d_k = Log(R_hat_k R_hat_g^T R_g R_k^T) (what the covariance
// describes: no fitted alignment adds its own error), and NEES_k = d_k^T C_k^-1
// d_k: chi-square with 3 degrees of freedom when the covariances are honest
// (median 2.37, 95% of views below 7.81).
struct PosteriorCalibration {
  std::size_t views_with_covariance = 0;
  std::size_t views_scored = 0;      // with their gauge in the ground truth, not held with it
  double nees_median = 0.0;          // NaN if no view is scored
  double nees_mean = 0.0;
  double within_95 = 0.0;            // fraction of scored views with NEES <= 7.81
  // A scored view: its NEES, d_k (radians), the root-mean-square standard
  // deviation of its covariance per axis, sqrt(trace / 3) (radians), and the
  // gauge view it is relative to.
  struct View {
    double nees = 0.0;
    Eigen::Vector3d error = Eigen::Vector3d::Zero();
    double sigma = 0.0;
    std::string gauge;
  };
  std::map<std::string, View> views;  // by view name
  // "posterior covariances against the ground truth: NEES median 4.12 (2.37 if
  // honest), 71.3% within chi-square's 95% bound, 118 keyframes"
  std::string Describe() const;
};
PosteriorCalibration EvaluatePosteriorCovariances(const NamedOrientations& estimate,
                                                  const std::map<std::string, Eigen::Matrix3d>& covariances,
                                                  const std::map<std::string, int>& component,
                                                  const NamedOrientations& ground_truth);

// The view term: the standard deviation per axis of an error that all of a
// view's pairs share, estimated from the views' offsets against orientations
// that can see it (`against_adjusted`: EvaluateEdgeCovariances against a
// bundle adjustment of the same images, which ties each view's points and
// centre to the other views', where every pair's summary has its own
// translation and depths). As an isotropic Gaussian's, from the median of
// |d_k|^2 (2.366 s^2 for three degrees of freedom), so that a view the
// adjustment moved for another reason (a pair with wrong matches) does not
// set it. NaN without offsets. No covariance of a single pair can hold it,
// and the floor cannot see it (see above); a pair's error against a
// reference then has covariance C + (floor^2 + 2 view^2) I, each of its two
// views adding its share: FloorWithViewTermRad.
double ViewTermRad(const EdgeCalibration& against_adjusted);
double FloorWithViewTermRad(double floor_rad, double view_term_rad);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_EVAL_ROTATION_EVALUATION_H_
