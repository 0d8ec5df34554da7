#include "core/estimators/component_problem.h"

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <limits>
#include <queue>
#include <unordered_map>

#include "core/linalg/block_cholesky.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

double InformationAnisotropy(const Eigen::Matrix3d& information) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(information, Eigen::EigenvaluesOnly);
  const Eigen::Vector3d l = eig.eigenvalues();  // ascending
  return l(0) > 0.0 ? l(2) / l(0) : std::numeric_limits<double>::infinity();
}
namespace {

double Median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const std::size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + mid, values.end());
  return values[mid];
}

// W = s C^-1 for a symmetric positive definite C (ViewGraph validates it
// and floors its eigenvalues), and a square root S of it (S^T S = W, so
// |S r|^2 = r^T W r): with C = L L^T, S = sqrt(s) L^-1, from the closed-form
// 3x3 factor, which is a visible part of building the component problems of
// pose graphs of a few thousand edges when done by a general factorisation
// and solve (one for C, one more for the root of W). The eigendecomposition
// remains for a C that is not numerically positive definite after all.
void InformationFromCovariance(const Eigen::Matrix3d& covariance, double scale, Eigen::Matrix3d* information,
                               Eigen::Matrix3d* sqrt_information) {
  Eigen::Matrix3d inverse_factor;
  if (InverseCholeskyFactor(covariance, &inverse_factor)) {
    *sqrt_information = std::sqrt(scale) * inverse_factor;
    *information = sqrt_information->transpose() * *sqrt_information;
    if (information->allFinite() && sqrt_information->allFinite()) return;
  }
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(covariance);
  const Eigen::Vector3d inv = eig.eigenvalues().cwiseMax(1e-300).cwiseInverse() * scale;
  *information = eig.eigenvectors() * inv.asDiagonal() * eig.eigenvectors().transpose();
  *sqrt_information = inv.cwiseSqrt().asDiagonal() * eig.eigenvectors().transpose();
}

// chi2(3): median, 99% quantile, and mean below that quantile.
constexpr double kChi2Median3 = 2.366;
constexpr double kChi2Quantile99 = 11.345;
constexpr double kChi2TruncatedMean99 = 2.894;
// With fewer redundant edges the floor is not estimated: with one or two,
// its estimate would rest on a single loop's misclosure.
constexpr int kMinRedundantEdges = 3;

// The covariance C = W^-1 of an information matrix as its axes (the
// eigenvectors of W) and the variances along them (infinite where W has no
// positive eigenvalue).
void CovarianceAxes(const Eigen::Matrix3d& information, Eigen::Matrix3d* axes, Eigen::Vector3d* variances) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig;
  eig.computeDirect(information);
  *axes = eig.eigenvectors();
  for (int i = 0; i < 3; ++i) {
    const double l = eig.eigenvalues()(i);
    (*variances)(i) = l > 0.0 ? 1.0 / l : std::numeric_limits<double>::infinity();
  }
}

}  // namespace

double EstimateCovarianceFloor(const std::vector<ComponentEdge>& edges, const std::vector<Eigen::Vector3d>& residuals,
                               int free_views) {
  const std::size_t m = edges.size();
  if (m == 0 || residuals.size() != m) return 0.0;
  // r^T (C + s I)^-1 r = sum_i (u_i^T r)^2 / (c_i + s) with C = U diag(c) U^T,
  // the eigenvectors of W = C^-1 and the inverses of its eigenvalues.
  std::vector<Eigen::Vector3d> variances(m), projected(m);
  std::vector<double> squared_norms(m);
  for (std::size_t k = 0; k < m; ++k) {
    Eigen::Matrix3d axes;
    CovarianceAxes(edges[k].information, &axes, &variances[k]);
    projected[k] = (axes.transpose() * residuals[k]).cwiseAbs2();
    squared_norms[k] = residuals[k].squaredNorm();
    if (!projected[k].allFinite()) projected[k].setZero();
  }
  auto whitened = [&](std::size_t k, double s) {
    double w = 0.0;
    for (int i = 0; i < 3; ++i) {
      const double c = variances[k](i) + s;
      if (c > 0.0 && std::isfinite(c)) w += projected[k](i) / c;
    }
    return w;
  };
  // Bisection for the root of a function that decreases in s on [0, hi].
  auto solve = [](double hi, auto excess) {
    double lo = 0.0;
    for (int i = 0; i < 100 && hi - lo > 1e-12 * hi; ++i) {
      const double mid = 0.5 * (lo + hi);
      (excess(mid) > 0.0 ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi);
  };
  // Start: the median whitened squared residual is chi2(3)'s.
  std::vector<double> w(m);
  auto median_whitened = [&](double s) {
    for (std::size_t k = 0; k < m; ++k) w[k] = whitened(k, s);
    std::nth_element(w.begin(), w.begin() + m / 2, w.end());
    return w[m / 2];
  };
  if (!(median_whitened(0.0) > kChi2Median3)) return 0.0;
  std::vector<double> norms = squared_norms;
  std::nth_element(norms.begin(), norms.begin() + m / 2, norms.end());
  double s = solve(norms[m / 2] / kChi2Median3, [&](double t) { return median_whitened(t) - kChi2Median3; });
  // Then the truncated moment equation on the edges below the quantile.
  std::vector<std::size_t> kept;
  for (int iteration = 0; iteration < 50; ++iteration) {
    kept.clear();
    double kept_norms = 0.0;
    for (std::size_t k = 0; k < m; ++k) {
      if (whitened(k, s) < kChi2Quantile99) {
        kept.push_back(k);
        kept_norms += squared_norms[k];
      }
    }
    const long redundancy = static_cast<long>(kept.size()) - free_views;
    if (redundancy < kMinRedundantEdges) return 0.0;
    const double target = kChi2TruncatedMean99 * static_cast<double>(redundancy);
    auto excess = [&](double t) {
      double sum = 0.0;
      for (std::size_t k : kept) sum += whitened(k, t);
      return sum - target;
    };
    // sum over kept of r^T (C + t I)^-1 r <= kept_norms / t, so the root lies below kept_norms / target.
    const double next = excess(0.0) <= 0.0 ? 0.0 : solve(kept_norms / target, excess);
    const bool settled = std::abs(next - s) <= 1e-6 * s;
    s = next;
    if (settled || s == 0.0) break;
  }
  return std::isfinite(s) ? s : 0.0;
}

std::vector<ComponentEdge> WithCovarianceFloor(const std::vector<ComponentEdge>& edges, double variance) {
  std::vector<ComponentEdge> floored = edges;
  if (!(variance > 0.0)) return floored;
  for (ComponentEdge& e : floored) {
    Eigen::Matrix3d axes;
    Eigen::Vector3d c;
    CovarianceAxes(e.information, &axes, &c);
    // Finite, or inf * 0 in the product below would give NaN.
    c = (c.cwiseMin(1e300).array() + variance).matrix();
    const Eigen::Matrix3d covariance = axes * c.asDiagonal() * axes.transpose();
    InformationFromCovariance(covariance, 1.0, &e.information, &e.sqrt_information);
  }
  return floored;
}

double ComponentProblem::CostOf(const std::vector<ComponentEdge>& edges, const std::vector<Eigen::Matrix3d>& rotations,
                                const RobustLoss& loss) {
  double cost = 0.0;
  double rho[3];
  for (const ComponentEdge& e : edges) {
    const Eigen::Vector3d w = e.sqrt_information * ResidualOf(e, rotations);
    loss.Evaluate(w.squaredNorm(), rho);
    cost += 0.5 * rho[0];
  }
  return cost;
}

double ComponentProblem::Cost(const RobustLoss& loss) const { return CostOf(edges, rotations, loss); }

namespace {

// The weighting a solve uses (the asked one, or none when no edge carries
// what it needs) and the graph-wide medians that normalise it.
struct EdgeWeightingScale {
  EdgeWeighting weighting = EdgeWeighting::kNone;
  bool any_inliers = false;
  double median_inliers = 0.0;
  double median_trace = 0.0;
  double median_norm = 0.0;
  double info_scale = 1.0;  // the paper's covariance scale, or 1
};

EdgeWeightingScale ScaleOfWeighting(const std::vector<RelativeRotation>& graph_edges,
                                    const RotationAveragingOptions& options, std::vector<std::string>* warnings) {
  std::vector<double> inliers, traces, norms;
  for (const RelativeRotation& e : graph_edges) {
    if (e.num_inliers > 0) inliers.push_back(e.num_inliers);
    if (e.has_covariance) {
      traces.push_back(e.covariance.trace());
      norms.push_back(e.covariance.norm());
    }
  }
  EdgeWeightingScale scale;
  scale.weighting = options.weighting;
  if ((scale.weighting == EdgeWeighting::kCovariance || scale.weighting == EdgeWeighting::kTrace ||
       scale.weighting == EdgeWeighting::kFrobenius) &&
      traces.empty() && !graph_edges.empty()) {
    if (warnings) {
      warnings->push_back(std::string("weighting '") + EdgeWeightingName(scale.weighting) +
                          "' needs covariances but no edge has one: using no weighting");
    }
    scale.weighting = EdgeWeighting::kNone;
  }
  if (scale.weighting == EdgeWeighting::kInliers && inliers.empty() && !graph_edges.empty()) {
    if (warnings) warnings->push_back("weighting 'inliers' but no edge has an inlier count: using no weighting");
    scale.weighting = EdgeWeighting::kNone;
  }
  scale.any_inliers = !inliers.empty();
  scale.median_inliers = Median(inliers);
  scale.median_trace = Median(traces);
  scale.median_norm = Median(norms);
  scale.info_scale = options.covariance_normalization == CovarianceNormalization::kPaper
                         ? 1.0 / options.paper_covariance_scale
                         : 1.0;
  return scale;
}

// Writes an edge's information and its square root into `ce`; returns false
// when the edge lacks what the weighting needs (it then gets the median weight).
bool SetEdgeInformation(const RelativeRotation& e, const EdgeWeightingScale& scale, ComponentEdge* ce) {
  double scalar = 1.0;
  bool complete = true;
  switch (scale.weighting) {
    case EdgeWeighting::kNone: break;
    case EdgeWeighting::kInliers:
      if (e.num_inliers > 0) scalar = e.num_inliers / scale.median_inliers; else complete = false;
      break;
    case EdgeWeighting::kTrace:
      if (e.has_covariance) scalar = scale.median_trace / e.covariance.trace(); else complete = false;
      break;
    case EdgeWeighting::kFrobenius:
      if (e.has_covariance) scalar = scale.median_norm / e.covariance.norm(); else complete = false;
      break;
    case EdgeWeighting::kCovariance: break;
  }
  if (scale.weighting == EdgeWeighting::kCovariance) {
    if (e.has_covariance) {
      InformationFromCovariance(e.covariance, scale.info_scale, &ce->information, &ce->sqrt_information);
      return true;
    }
    complete = false;
    scalar = (3.0 / scale.median_trace) * scale.info_scale;
  }
  ce->information = Eigen::Matrix3d::Identity() * scalar;
  ce->sqrt_information = Eigen::Matrix3d::Identity() * std::sqrt(scalar);
  return complete;
}

// One problem per connected component of two or more views, with its views,
// their starting rotations (the initial ones where warm-started) and no
// edges yet; `where` maps a view to (component, local index).
std::vector<ComponentProblem> ComponentsWithoutEdges(const ViewGraph& graph, const RotationAveragingOptions& options,
                                                     const ViewOrientations& initial,
                                                     std::unordered_map<ViewId, std::pair<int, int>>* where) {
  std::vector<ComponentProblem> problems;
  for (const std::vector<ViewId>& component : graph.ConnectedComponents()) {
    if (component.size() < 2) continue;
    ComponentProblem p;
    p.view_ids = component;
    p.rotations.assign(component.size(), Eigen::Matrix3d::Identity());
    p.has_initial.assign(component.size(), false);
    for (std::size_t v = 0; v < component.size(); ++v) {
      (*where)[component[v]] = {static_cast<int>(problems.size()), static_cast<int>(v)};
      if (options.warm_start) {
        auto it = initial.find(component[v]);
        if (it != initial.end() && IsRotationMatrix(it->second, 1e-6)) {
          p.rotations[v] = it->second;
          p.has_initial[v] = true;
        }
      }
    }
    problems.push_back(std::move(p));
  }
  return problems;
}

}  // namespace

std::vector<ComponentProblem> BuildComponentProblems(const ViewGraph& graph, const RotationAveragingOptions& options,
                                                     const ViewOrientations& initial, std::vector<std::string>* warnings,
                                                     EdgeWeighting* effective_weighting) {
  const std::vector<RelativeRotation>& graph_edges = graph.Edges();
  const EdgeWeightingScale scale = ScaleOfWeighting(graph_edges, options, warnings);
  if (effective_weighting) *effective_weighting = scale.weighting;

  SpanningTreeWeight tree_weight = options.robust_start.spanning_tree_weight;
  if (tree_weight == SpanningTreeWeight::kAuto) {
    tree_weight = scale.weighting != EdgeWeighting::kNone ? SpanningTreeWeight::kInformation
                  : scale.any_inliers                     ? SpanningTreeWeight::kInliers
                                                          : SpanningTreeWeight::kUniform;
  }

  std::unordered_map<ViewId, std::pair<int, int>> where;  // view -> (component, local index)
  std::vector<ComponentProblem> problems = ComponentsWithoutEdges(graph, options, initial, &where);
  std::vector<std::size_t> edges_of(problems.size(), 0);
  for (const RelativeRotation& e : graph_edges) ++edges_of[where.at(e.view1).first];
  for (std::size_t c = 0; c < problems.size(); ++c) problems[c].edges.reserve(edges_of[c]);
  std::size_t missing = 0;
  for (std::size_t k = 0; k < graph_edges.size(); ++k) {
    const RelativeRotation& e = graph_edges[k];
    const auto& a = where.at(e.view1);
    const auto& b = where.at(e.view2);
    ComponentEdge ce;
    ce.i = a.second;
    ce.j = b.second;
    ce.measured = e.rotation;
    if (!SetEdgeInformation(e, scale, &ce)) ++missing;
    switch (tree_weight) {
      case SpanningTreeWeight::kInliers: ce.tree_weight = std::max(e.num_inliers, 0); break;
      case SpanningTreeWeight::kInformation: ce.tree_weight = ce.information.trace(); break;
      default: ce.tree_weight = 1.0; break;
    }
    ce.graph_index = k;
    problems[a.first].edges.push_back(ce);
  }
  if (missing > 0 && warnings) {
    warnings->push_back(std::to_string(missing) + " edge(s) lack what weighting '" + EdgeWeightingName(scale.weighting) +
                        "' needs and were given the median weight");
  }
  return problems;
}

void InitializeBySpanningTree(ComponentProblem* problem) {
  const int n = static_cast<int>(problem->view_ids.size());
  const int m = static_cast<int>(problem->edges.size());
  // The edges of view v, in edge order: incident[incident_start[v] ..
  // incident_start[v + 1]) (one array: a vector per view cost more in
  // allocations than the tree itself on pose graphs of a few thousand views).
  std::vector<int> incident_start(n + 1, 0), incident(2 * m);
  std::vector<double> strength(n, 0.0);
  for (const ComponentEdge& e : problem->edges) {
    ++incident_start[e.i + 1];
    ++incident_start[e.j + 1];
    strength[e.i] += e.tree_weight;
    strength[e.j] += e.tree_weight;
  }
  for (int v = 0; v < n; ++v) incident_start[v + 1] += incident_start[v];
  {
    std::vector<int> next(incident_start.begin(), incident_start.end() - 1);
    for (int k = 0; k < m; ++k) {
      incident[next[problem->edges[k].i]++] = k;
      incident[next[problem->edges[k].j]++] = k;
    }
  }
  bool any_initial = false, any_fixed = false;
  for (int v = 0; v < n; ++v) {
    any_initial = any_initial || problem->has_initial[v];
    any_fixed = any_fixed || (!problem->fixed.empty() && problem->fixed[v]);
  }
  // The gauge is held: one of the held views when there are any.
  int gauge = -1;
  for (int v = 0; v < n; ++v) {
    if (any_fixed ? !problem->fixed[v] : (any_initial && !problem->has_initial[v])) continue;
    if (gauge < 0 || strength[v] > strength[gauge]) gauge = v;
  }
  problem->gauge = gauge;

  // Prim's algorithm grown from every warm-started view at once (or the gauge).
  // Warm views are all marked first, so only edges leaving them are queued.
  std::vector<bool> done(n, false);
  using Item = std::pair<double, int>;  // (tree weight, edge index)
  std::priority_queue<Item> queue;
  // An edge is queued only if it beats every edge queued so far towards the
  // same view: the others would be popped after it, when that view is
  // placed, and skipped. The tree is the same, with fewer heap operations.
  std::vector<Item> best_towards(n, Item(-std::numeric_limits<double>::infinity(), -1));
  auto visit = [&](int v) {
    done[v] = true;
    for (int q = incident_start[v]; q < incident_start[v + 1]; ++q) {
      const int k = incident[q];
      const ComponentEdge& e = problem->edges[k];
      const int other = e.i == v ? e.j : e.i;
      const Item item(e.tree_weight, k);
      if (!done[other] && best_towards[other] < item) {
        best_towards[other] = item;
        queue.push(item);
      }
    }
  };
  auto predict = [&](const ComponentEdge& e, int v) -> Eigen::Matrix3d {  // v's rotation from the other end
    return v == e.j ? Eigen::Matrix3d(e.measured.transpose() * problem->rotations[e.i])
                    : Eigen::Matrix3d(e.measured * problem->rotations[e.j]);
  };
  if (any_initial) {
    for (int v = 0; v < n; ++v) done[v] = problem->has_initial[v];
    for (int v = 0; v < n; ++v)
      if (problem->has_initial[v]) visit(v);
  } else {
    problem->rotations[gauge] = Eigen::Matrix3d::Identity();
    visit(gauge);
  }
  while (!queue.empty()) {
    const ComponentEdge& e = problem->edges[queue.top().second];
    queue.pop();
    if (done[e.i] && done[e.j]) continue;
    const int v = done[e.i] ? e.j : e.i;
    problem->rotations[v] = predict(e, v);
    if (any_initial) {
      // A view grown from warm neighbours: of the predictions of its edges to
      // views already placed, take the one the others agree with best (an
      // outlier edge does not decide where a new keyframe starts when it has
      // two or more good ones).
      std::vector<Eigen::Matrix3d> candidates;
      for (int q = incident_start[v]; q < incident_start[v + 1]; ++q) {
        const ComponentEdge& f = problem->edges[incident[q]];
        if (done[f.i == v ? f.j : f.i]) candidates.push_back(predict(f, v));
      }
      if (candidates.size() >= 3) {
        double best = std::numeric_limits<double>::infinity();
        for (const Eigen::Matrix3d& c : candidates) {
          double spread = 0.0;
          for (const Eigen::Matrix3d& d : candidates) spread += std::min(AngularDistanceRad(c, d), 0.1);
          if (spread < best) {
            best = spread;
            problem->rotations[v] = c;
          }
        }
      }
    }
    visit(v);
  }
}

}  // namespace rotation_averaging
