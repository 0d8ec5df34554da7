// Stable interface of rotation_averaging::core (README.md, "Embedding the averager").
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
#ifndef ROTATION_AVERAGING_EVAL_ROTATION_EVALUATION_H_
#define ROTATION_AVERAGING_EVAL_ROTATION_EVALUATION_H_

#include <Eigen/Core>
#include <map>
#include <string>
#include <vector>

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

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_EVAL_ROTATION_EVALUATION_H_
