#include "rotation_averaging/core/eval/rotation_evaluation.h"

#include <Eigen/Sparse>
#include <Eigen/Cholesky>
#include <Eigen/SparseCholesky>
#include <algorithm>
#include <cmath>
#include <iomanip>
#include <limits>
#include <map>
#include <numeric>
#include <sstream>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

double MedianOf(std::vector<double> v) {
  if (v.empty()) return std::numeric_limits<double>::infinity();
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The 95% quantile of chi-square with 3 degrees of freedom.
constexpr double kChiSquare3Quantile95 = 7.8147;

// The median, the mean and the fraction within chi-square's 95% bound of
// whitened squared errors (not empty).
void SummariseNees(const std::vector<double>& nees, double* median, double* mean, double* within_95) {
  *median = MedianOf(nees);
  *mean = std::accumulate(nees.begin(), nees.end(), 0.0) / static_cast<double>(nees.size());
  *within_95 = static_cast<double>(std::count_if(nees.begin(), nees.end(),
                                                 [](double n) { return n <= kChiSquare3Quantile95; })) /
               static_cast<double>(nees.size());
}

// The per-view offsets d (3 per view, stacked) that minimise
// sum_e sqrt(r_e^T C_e^-1 r_e), r_e = eta_e - (A_e d_1 - d_2), A_e = R_2 R_1^T:
// iteratively reweighted least squares (weights 1 / whitened |r_e|). Whitened,
// so that an edge's loose directions do not leak into the offsets its precise
// ones are held by. The world rotation common to all views is a null space
// (d_k = R_k w changes no edge), held by a ridge far below the data.
std::vector<Eigen::Vector3d> FitViewOffsets(int num_views, const std::vector<std::pair<int, int>>& edges,
                                            const std::vector<Eigen::Matrix3d>& a,
                                            const std::vector<Eigen::Vector3d>& eta,
                                            const std::vector<Eigen::Matrix3d>& information) {
  std::vector<Eigen::Vector3d> d(num_views, Eigen::Vector3d::Zero());
  if (edges.empty()) return d;
  auto whitened = [&](std::size_t k, const Eigen::Vector3d& r) { return std::sqrt(r.dot(information[k] * r)); };
  std::vector<double> norms;
  for (std::size_t k = 0; k < edges.size(); ++k) norms.push_back(whitened(k, eta[k]));
  // Residuals below this count as this (a small fraction of the typical
  // error), so that an edge explained exactly does not take all the weight.
  const double epsilon = std::max(1e-3 * MedianOf(norms), 1e-15);
  const int n = 3 * num_views;
  std::vector<double> weights(edges.size(), 1.0);
  double previous_cost = std::numeric_limits<double>::infinity();
  for (int iteration = 0; iteration < 100; ++iteration) {
    std::vector<Eigen::Triplet<double>> triplets;  // A^T W A; duplicates are summed
    Eigen::VectorXd diagonal = Eigen::VectorXd::Zero(n);
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(n);
    auto add = [&](int bi, int bj, const Eigen::Matrix3d& m) {
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) triplets.emplace_back(3 * bi + r, 3 * bj + c, m(r, c));
        if (bi == bj) diagonal[3 * bi + r] += m(r, r);
      }
    };
    for (std::size_t k = 0; k < edges.size(); ++k) {
      const auto [i, j] = edges[k];
      const Eigen::Matrix3d w = weights[k] * information[k];
      // Residual eta - (A d_i - d_j): blocks A (view i) and -I (view j).
      add(i, i, a[k].transpose() * w * a[k]);
      add(j, j, w);
      add(i, j, -a[k].transpose() * w);
      add(j, i, -w * a[k]);
      rhs.segment<3>(3 * i) += a[k].transpose() * w * eta[k];
      rhs.segment<3>(3 * j) -= w * eta[k];
    }
    const double ridge = 1e-10 * diagonal.maxCoeff() + 1e-300;
    for (int r = 0; r < n; ++r) triplets.emplace_back(r, r, ridge);
    Eigen::SparseMatrix<double> normal(n, n);
    normal.setFromTriplets(triplets.begin(), triplets.end());
    const Eigen::SimplicialLDLT<Eigen::SparseMatrix<double>> solver(normal);
    if (solver.info() != Eigen::Success) break;
    const Eigen::VectorXd x = solver.solve(rhs);
    if (!x.allFinite()) break;
    std::vector<Eigen::Vector3d> next(num_views);
    for (int v = 0; v < num_views; ++v) next[v] = x.segment<3>(3 * v);
    double cost = 0.0;
    std::vector<double> next_weights(edges.size());
    for (std::size_t k = 0; k < edges.size(); ++k) {
      const auto [i, j] = edges[k];
      const double r = whitened(k, eta[k] - (a[k] * next[i] - next[j]));
      cost += r;
      next_weights[k] = 1.0 / std::max(r, epsilon);
    }
    if (cost >= previous_cost) break;  // converged: keep the better offsets
    const bool small_change = cost > previous_cost * (1.0 - 1e-9);
    d.swap(next);
    weights.swap(next_weights);
    previous_cost = cost;
    if (small_change) break;
  }
  return d;
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
  // For the per-view offsets, per scored edge: its views (dense indices),
  // A = R_2 R_1^T, its measured rotation, (C + s^2 I)^-1, and its error eta
  // (then its residual once the views are offset).
  std::map<std::string, int> view_index;
  std::vector<std::string> view_names;
  std::vector<std::pair<int, int>> pairs;
  std::vector<Eigen::Matrix3d> transports, measured, information;
  std::vector<Eigen::Vector3d> residuals;
  auto index_of = [&](const std::string& name) {
    const auto [it, inserted] = view_index.emplace(name, static_cast<int>(view_names.size()));
    if (inserted) view_names.push_back(name);
    return it->second;
  };
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
    pairs.emplace_back(index_of(v1->name), index_of(v2->name));
    transports.push_back(b->second * a->second.transpose());
    measured.push_back(e.rotation);
    information.push_back((e.covariance + floor).inverse());
    residuals.push_back(eta);
  }
  result.edges_scored = nees.size();
  if (nees.empty()) {
    result.median_error_deg = result.nees_median = result.nees_mean = result.within_95 =
        result.median_view_offset_deg = result.median_error_after_view_offsets_deg =
            result.nees_median_after_view_offsets =
            std::numeric_limits<double>::quiet_NaN();
    return result;
  }
  // The fit is linear in the offsets about the reference; it is repeated
  // about the offset views until they stop moving, so that offsets larger
  // than the edges' standard deviations are not mistaken for pair errors.
  std::vector<Eigen::Matrix3d> moved(view_names.size());
  for (std::size_t v = 0; v < view_names.size(); ++v) moved[v] = ground_truth.at(view_names[v]);
  for (int round = 0; round < 20; ++round) {
    const std::vector<Eigen::Vector3d> step =
        FitViewOffsets(static_cast<int>(view_names.size()), pairs, transports, residuals, information);
    double largest = 0.0;
    for (std::size_t v = 0; v < view_names.size(); ++v) {
      moved[v] = ExpSO3(step[v]) * moved[v];
      largest = std::max(largest, step[v].norm());
    }
    for (std::size_t k = 0; k < pairs.size(); ++k) {
      const Eigen::Matrix3d& r1 = moved[pairs[k].first];
      const Eigen::Matrix3d& r2 = moved[pairs[k].second];
      transports[k] = r2 * r1.transpose();
      residuals[k] = LogSO3((r1 * r2.transpose()).transpose() * measured[k]);
    }
    if (largest < 1e-12) break;
  }
  // The offsets are defined up to a rotation of the world common to all
  // views; they are reported after the robust alignment the scoring of
  // orientations uses (EvaluateOrientations), so that they read as each
  // view's error there.
  std::vector<Eigen::Matrix3d> reference_rotations;
  for (const std::string& name : view_names) reference_rotations.push_back(ground_truth.at(name));
  const Eigen::Matrix3d g = AlignRotations(reference_rotations, moved);
  for (const View& v : graph.Views()) {
    const auto it = view_index.find(v.name);
    if (it == view_index.end()) continue;
    const Eigen::Matrix3d aligned = ground_truth.at(v.name) * g;
    result.view_offsets.push_back({v.name, LogSO3(moved[it->second] * aligned.transpose()) * 180.0 / M_PI});
  }
  std::vector<double> errors_after, nees_after;
  for (std::size_t k = 0; k < pairs.size(); ++k) {
    const Eigen::Vector3d& r = residuals[k];
    result.scored[k].error_after_view_offsets_deg = r.norm() * 180.0 / M_PI;
    result.scored[k].nees_after_view_offsets = r.dot(information[k] * r);
    errors_after.push_back(result.scored[k].error_after_view_offsets_deg);
    nees_after.push_back(result.scored[k].nees_after_view_offsets);
  }
  std::vector<double> offset_norms;
  for (const EdgeCalibration::ViewOffset& v : result.view_offsets) offset_norms.push_back(v.offset_deg.norm());
  result.median_view_offset_deg = MedianOf(offset_norms);
  result.median_error_after_view_offsets_deg = MedianOf(errors_after);
  result.nees_median_after_view_offsets = MedianOf(nees_after);
  result.median_error_deg = MedianOf(errors);
  SummariseNees(nees, &result.nees_median, &result.nees_mean, &result.within_95);
  return result;
}

std::string EdgeCalibration::ToText() const {
  std::ostringstream out;
  out << "edges: " << edges << "\nedges scored: " << edges_scored << std::fixed << std::setprecision(4)
      << "\ncovariance floor: " << floor_rad * 180.0 / M_PI << " deg"
      << "\nmedian edge error: " << median_error_deg << " deg" << std::setprecision(2)
      << "\nNEES median: " << nees_median << " (calibrated: 2.37)\nNEES mean: " << nees_mean
      << " (calibrated: 3)\nNEES within the 95% quantile: " << std::setprecision(1) << 100.0 * within_95
      << " % (calibrated: 95 %)" << std::setprecision(4)
      << "\nmedian per-view offset: " << median_view_offset_deg << " deg"
      << "\nmedian edge error after per-view offsets: " << median_error_after_view_offsets_deg << " deg"
      << std::setprecision(2) << "\nNEES median after per-view offsets: " << nees_median_after_view_offsets;
  return out.str();
}

double ViewTermRad(const EdgeCalibration& against_adjusted) {
  std::vector<double> squared;
  for (const EdgeCalibration::ViewOffset& v : against_adjusted.view_offsets) {
    squared.push_back((v.offset_deg * M_PI / 180.0).squaredNorm());
  }
  if (squared.empty()) return std::numeric_limits<double>::quiet_NaN();
  constexpr double kChiSquare3Median = 2.3660;
  return std::sqrt(MedianOf(squared) / kChiSquare3Median);
}

double FloorWithViewTermRad(double floor_rad, double view_term_rad) {
  return std::sqrt(floor_rad * floor_rad + 2.0 * view_term_rad * view_term_rad);
}

PosteriorCalibration EvaluatePosteriorCovariances(const NamedOrientations& estimate,
                                                  const std::map<std::string, Eigen::Matrix3d>& covariances,
                                                  const std::map<std::string, int>& component,
                                                  const NamedOrientations& ground_truth) {
  PosteriorCalibration out;
  out.nees_median = out.nees_mean = std::numeric_limits<double>::quiet_NaN();
  // The views with a covariance, by component.
  std::map<int, std::vector<std::string>> by_component;
  for (const auto& [name, c] : covariances) {
    const auto comp = component.find(name);
    if (comp == component.end() || !estimate.count(name) || !c.allFinite()) continue;
    by_component[comp->second].push_back(name);
    ++out.views_with_covariance;
  }
  std::vector<double> values;
  for (const auto& [index, names] : by_component) {
    std::vector<double> traces;
    for (const std::string& name : names) traces.push_back(covariances.at(name).trace());
    const auto smallest = std::min_element(traces.begin(), traces.end()) - traces.begin();
    const std::string& gauge = names[smallest];
    const auto gauge_truth = ground_truth.find(gauge);
    if (gauge_truth == ground_truth.end()) continue;
    const double held = 1e-6 * MedianOf(traces);
    // R_hat_g^T R_g: the estimate's world frame to the truth's, through the gauge.
    const Eigen::Matrix3d align = estimate.at(gauge).transpose() * gauge_truth->second;
    for (std::size_t k = 0; k < names.size(); ++k) {
      if (!(traces[k] > held)) continue;
      const auto truth = ground_truth.find(names[k]);
      if (truth == ground_truth.end()) continue;
      const Eigen::Matrix3d& c = covariances.at(names[k]);
      const Eigen::LDLT<Eigen::Matrix3d> ldlt(0.5 * (c + c.transpose()));
      if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) continue;
      const Eigen::Vector3d d = LogSO3(estimate.at(names[k]) * align * truth->second.transpose());
      const double nees = d.dot(ldlt.solve(d));
      out.views[names[k]] = PosteriorCalibration::View{nees, d, std::sqrt(c.trace() / 3.0), gauge};
      values.push_back(nees);
    }
  }
  out.views_scored = values.size();
  if (!values.empty()) SummariseNees(values, &out.nees_median, &out.nees_mean, &out.within_95);
  return out;
}

std::string PosteriorCalibration::Describe() const {
  std::ostringstream s;
  s.setf(std::ios::fixed);
  if (views_scored == 0) {
    s << "posterior covariances against the ground truth: none scored (" << views_with_covariance
      << " keyframes with a covariance)";
    return s.str();
  }
  s << "posterior covariances against the ground truth: NEES median " << std::setprecision(2) << nees_median
    << " (2.37 if honest), mean " << nees_mean << ", " << std::setprecision(1) << 100.0 * within_95
    << "% within chi-square's 95% bound, " << views_scored << " keyframes";
  return s.str();
}

}  // namespace rotation_averaging
