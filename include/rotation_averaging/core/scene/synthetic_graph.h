// Public header of rotation_averaging::core (docs/embedding.md).
// Synthetic view graphs with known ground truth, for tests and benchmarks.
#ifndef ROTATION_AVERAGING_CORE_SCENE_SYNTHETIC_GRAPH_H_
#define ROTATION_AVERAGING_CORE_SCENE_SYNTHETIC_GRAPH_H_

#include <cstdint>

#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

struct SyntheticGraphOptions {
  int num_views = 100;
  double mean_degree = 10.0;       // average number of edges per view
  double noise_deg = 3.0;          // per-axis standard deviation of inlier noise, degrees
  // Each edge's noise standard deviations are noise_deg times a factor drawn
  // log-uniformly in [1 / noise_spread, noise_spread] (one per axis when
  // anisotropic). 1 gives identical noise on every edge.
  double noise_spread = 1.0;
  bool anisotropic = false;        // random principal axes and per-axis scales
  double outlier_ratio = 0.0;      // fraction of edges replaced by random rotations
  bool with_covariance = true;     // store the true noise covariance on inlier edges
  // Outliers carry a covariance like an inlier's (a front end does not know it
  // is wrong).
  bool sequential_chain = true;    // edges (k, k+1) first, which keeps the graph connected
  // 0: the other edges join views drawn uniformly from the whole graph (an
  // expander: its Cholesky factor is nearly dense, fine up to a few thousand
  // views). > 0: views sit row by row on a square grid, as the cameras of a
  // city-scale capture do, and each other edge joins a view to one drawn from
  // the (2 locality + 1)^2 window around it (for the scale benchmark).
  int locality = 0;
  std::uint64_t seed = 1;
};

struct SyntheticGraph {
  ViewGraph graph;
  ViewOrientations ground_truth;           // world-to-camera, keyed by view id
  std::vector<bool> edge_is_outlier;   // in the order of graph.Edges()
};

SyntheticGraph MakeSyntheticGraph(const SyntheticGraphOptions& options);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_SCENE_SYNTHETIC_GRAPH_H_
