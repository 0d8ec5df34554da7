#include "rotation_averaging/eval/rotation_evaluation.h"

#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <numeric>
#include <sstream>

#include "rotation_averaging/geometry/so3.h"

namespace rotation_averaging {
namespace {

double MedianOf(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::infinity();
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

}  // namespace

double RecallAuc(const std::vector<double>& errors_deg, std::size_t num_total, double threshold_deg) {
  if (num_total == 0 || !(threshold_deg > 0.0)) return 0.0;
  // Integral of recall(x) over [0, t] = sum over errors e < t of (t - e) / N.
  double area = 0.0;
  for (double e : errors_deg) {
    if (e < threshold_deg) area += threshold_deg - std::max(e, 0.0);
  }
  return area / (threshold_deg * static_cast<double>(num_total));
}

Eigen::Matrix3d AlignRotations(const std::vector<Eigen::Matrix3d>& gt, const std::vector<Eigen::Matrix3d>& est) {
  const std::size_t n = std::min(gt.size(), est.size());
  if (n == 0) return Eigen::Matrix3d::Identity();
  std::vector<Eigen::Matrix3d> g(n);
  for (std::size_t i = 0; i < n; ++i) g[i] = gt[i].transpose() * est[i];
  // Robust initial guess: the candidate with the smallest median distance to
  // all G_i, over (at most) 64 evenly spaced candidates.
  const std::size_t stride = std::max<std::size_t>(1, n / 64);
  Eigen::Matrix3d best = g[0];
  double best_median = std::numeric_limits<double>::infinity();
  std::vector<double> d(n);
  for (std::size_t c = 0; c < n; c += stride) {
    for (std::size_t i = 0; i < n; ++i) d[i] = AngularDistanceRad(g[c], g[i]);
    const double med = MedianOf(d);
    if (med < best_median) {
      best_median = med;
      best = g[c];
    }
  }
  // Iteratively reweighted Cauchy fit in the tangent space at G.
  Eigen::Matrix3d align = best;
  for (int it = 0; it < 100; ++it) {
    std::vector<Eigen::Vector3d> logs(n);
    for (std::size_t i = 0; i < n; ++i) {
      logs[i] = LogSO3(align.transpose() * g[i]);
      d[i] = logs[i].norm();
    }
    const double c = std::max(MedianOf(d), 1e-12);
    Eigen::Vector3d step = Eigen::Vector3d::Zero();
    double weight_sum = 0.0;
    for (std::size_t i = 0; i < n; ++i) {
      const double w = 1.0 / (1.0 + (d[i] / c) * (d[i] / c));
      step += w * logs[i];
      weight_sum += w;
    }
    step /= weight_sum;
    align = align * ExpSO3(step);
    if (step.norm() < 1e-14) break;
  }
  return ProjectToSO3(align);
}

EvaluationResult EvaluateOrientations(const NamedOrientations& estimate, const NamedOrientations& ground_truth,
                                      const std::vector<double>& thresholds) {
  EvaluationResult result;
  result.views_in_ground_truth = ground_truth.size();
  result.views_estimated = estimate.size();
  std::vector<Eigen::Matrix3d> gt, est;
  std::vector<std::string> names;
  for (const auto& [name, r_gt] : ground_truth) {
    auto it = estimate.find(name);
    if (it == estimate.end()) continue;
    names.push_back(name);
    gt.push_back(r_gt);
    est.push_back(it->second);
  }
  result.views_common = names.size();
  result.alignment = AlignRotations(gt, est);
  std::vector<double> errors;
  for (std::size_t i = 0; i < names.size(); ++i) {
    const double e = RadToDeg(AngularDistanceRad(gt[i] * result.alignment, est[i]));
    errors.push_back(e);
    result.errors_deg.emplace_back(names[i], e);
  }
  result.median_error_deg = MedianOf(errors);
  result.mean_error_deg = errors.empty() ? std::numeric_limits<double>::infinity()
                                         : std::accumulate(errors.begin(), errors.end(), 0.0) / errors.size();
  for (double t : thresholds) result.auc.emplace_back(t, RecallAuc(errors, ground_truth.size(), t));
  return result;
}

std::string EvaluationResult::ToText() const {
  std::ostringstream out;
  out << "views in ground truth: " << views_in_ground_truth << "\nviews estimated: " << views_estimated
      << "\nviews common: " << views_common << std::fixed << std::setprecision(4)
      << "\nmedian error: " << median_error_deg << " deg\nmean error: " << mean_error_deg << " deg";
  for (const auto& [t, a] : auc) {
    std::ostringstream threshold;
    threshold << t;  // shortest form: 2, 0.5
    out << "\nAUC@" << threshold.str() << ": " << std::setprecision(2) << 100.0 * a << " %";
  }
  return out.str();
}

std::string EvaluationResult::ToJson() const {
  std::ostringstream out;
  auto number = [&out](double v) {
    if (std::isfinite(v)) out << std::setprecision(10) << v; else out << "null";
  };
  out << "{\"views_in_ground_truth\": " << views_in_ground_truth << ", \"views_estimated\": " << views_estimated
      << ", \"views_common\": " << views_common << ", \"median_error_deg\": ";
  number(median_error_deg);
  out << ", \"mean_error_deg\": ";
  number(mean_error_deg);
  out << ", \"auc\": {";
  for (std::size_t k = 0; k < auc.size(); ++k) {
    out << (k ? ", " : "") << "\"" << auc[k].first << "\": ";
    number(auc[k].second);
  }
  out << "}}";
  return out.str();
}

EdgeCalibration EvaluateEdgeCovariances(const ViewGraph& graph, const NamedOrientations& ground_truth,
                                        double floor_rad) {
  EdgeCalibration result;
  result.edges = graph.NumEdges();
  result.floor_rad = floor_rad;
  const Eigen::Matrix3d floor = floor_rad * floor_rad * Eigen::Matrix3d::Identity();
  std::vector<double> errors, nees;
  for (const RelativeRotation& e : graph.Edges()) {
    if (!e.has_covariance) continue;
    const View* v1 = graph.FindView(e.view1);
    const View* v2 = graph.FindView(e.view2);
    if (!v1 || !v2) continue;
    const auto a = ground_truth.find(v1->name), b = ground_truth.find(v2->name);
    if (a == ground_truth.end() || b == ground_truth.end()) continue;
    const Eigen::Vector3d eta = LogSO3((a->second * b->second.transpose()).transpose() * e.rotation);
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(e.covariance + floor);
    const double n = eta.dot(ldlt.solve(eta));
    if (ldlt.info() != Eigen::Success || !std::isfinite(n)) continue;
    result.scored.push_back({v1->name, v2->name, eta.norm() * 180.0 / M_PI, n});
    errors.push_back(result.scored.back().error_deg);
    nees.push_back(n);
  }
  result.edges_scored = nees.size();
  if (nees.empty()) {
    result.median_error_deg = result.nees_median = result.nees_mean = result.within_95 =
        std::numeric_limits<double>::quiet_NaN();
    return result;
  }
  // The 95% quantile of chi-square with 3 degrees of freedom.
  constexpr double kChiSquare3Quantile95 = 7.8147;
  result.median_error_deg = MedianOf(errors);
  result.nees_median = MedianOf(nees);
  result.nees_mean = std::accumulate(nees.begin(), nees.end(), 0.0) / nees.size();
  result.within_95 = static_cast<double>(std::count_if(nees.begin(), nees.end(),
                                                       [](double n) { return n <= kChiSquare3Quantile95; })) /
                     nees.size();
  return result;
}

std::string EdgeCalibration::ToText() const {
  std::ostringstream out;
  out << "edges: " << edges << "\nedges scored: " << edges_scored << std::fixed << std::setprecision(4)
      << "\ncovariance floor: " << floor_rad * 180.0 / M_PI << " deg"
      << "\nmedian edge error: " << median_error_deg << " deg" << std::setprecision(2)
      << "\nNEES median: " << nees_median << " (calibrated: 2.37)\nNEES mean: " << nees_mean
      << " (calibrated: 3)\nNEES within the 95% quantile: " << std::setprecision(1) << 100.0 * within_95
      << " % (calibrated: 95 %)";
  return out.str();
}

}  // namespace rotation_averaging
