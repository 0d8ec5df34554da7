#include "rotation_averaging/core/scene/synthetic_graph.h"

#include <algorithm>
#include <cmath>
#include <random>
#include <set>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

Eigen::Matrix3d RandomRotation(std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  Eigen::Quaterniond q = DrawQuaternion(rng, normal);
  q.normalize();
  return q.toRotationMatrix();
}

}  // namespace

SyntheticGraph MakeSyntheticGraph(const SyntheticGraphOptions& options) {
  SyntheticGraph out;
  std::mt19937_64 rng(options.seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> uniform(0.0, 1.0);
  const int n = options.num_views;
  for (int v = 0; v < n; ++v) {
    out.graph.AddView(static_cast<ViewId>(v));
    out.ground_truth[v] = RandomRotation(rng);
  }
  const std::size_t target_edges = static_cast<std::size_t>(std::llround(0.5 * options.mean_degree * n));
  std::set<std::pair<int, int>> pairs;
  if (options.sequential_chain) {
    for (int v = 0; v + 1 < n && pairs.size() < target_edges; ++v) pairs.insert({v, v + 1});
  }
  std::uniform_int_distribution<int> pick(0, std::max(0, n - 1));
  const int side = std::max(1, static_cast<int>(std::ceil(std::sqrt(static_cast<double>(n)))));
  const int window = options.locality > 0 ? std::min(options.locality, side) : 0;
  std::uniform_int_distribution<int> offset(-window, window);
  const std::size_t max_pairs =
      window > 0 ? static_cast<std::size_t>(n) * static_cast<std::size_t>((2 * window + 1) * (2 * window + 1) - 1) / 2
                 : static_cast<std::size_t>(n) * (n - 1) / 2;
  while (pairs.size() < std::min(target_edges, max_pairs)) {
    int a = pick(rng), b;
    if (window > 0) {
      const int row = a / side + offset(rng), col = a % side + offset(rng);
      if (row < 0 || col < 0 || col >= side) continue;
      b = row * side + col;
      if (b >= n) continue;
    } else {
      b = pick(rng);
    }
    if (a == b) continue;
    pairs.insert({std::min(a, b), std::max(a, b)});
  }
  const double sigma = DegToRad(options.noise_deg);
  const double log_spread = std::log(std::max(1.0, options.noise_spread));
  for (const auto& [a, b] : pairs) {
    Eigen::Vector3d stddev;
    for (int k = 0; k < 3; ++k) {
      const double f = std::exp((2.0 * uniform(rng) - 1.0) * log_spread);
      stddev[k] = sigma * f;
      if (!options.anisotropic) {
        stddev.setConstant(stddev[0]);
        break;
      }
    }
    const Eigen::Matrix3d axes = options.anisotropic ? RandomRotation(rng) : Eigen::Matrix3d::Identity();
    const Eigen::Matrix3d covariance = axes * stddev.cwiseAbs2().asDiagonal() * axes.transpose();
    RelativeRotation edge;
    edge.view1 = a;
    edge.view2 = b;
    edge.source = b == a + 1 ? EdgeSource::kSequential : EdgeSource::kOther;
    const bool outlier = uniform(rng) < options.outlier_ratio;
    const Eigen::Matrix3d truth = out.ground_truth[a] * out.ground_truth[b].transpose();
    if (outlier) {
      edge.rotation = RandomRotation(rng);
    } else {
      const Eigen::Vector3d eta = axes * stddev.cwiseProduct(DrawVector3(rng, normal));
      edge.rotation = truth * ExpSO3(eta);
    }
    edge.has_covariance = options.with_covariance;
    edge.covariance = covariance;
    edge.num_inliers = 100;
    out.graph.AddEdge(edge);
    out.edge_is_outlier.push_back(outlier);
  }
  return out;
}

}  // namespace rotation_averaging
