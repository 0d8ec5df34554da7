// The back-end library (CHOLMOD, OpenBLAS, Ceres) is loaded only when a
// solve needs it, and works once loaded. One test, in order: what the process
// has loaded cannot be undone.
#include "core/util/backends.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <fstream>
#include <string>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/scene/synthetic_graph.h"

namespace rotation_averaging {
namespace {

bool Mapped(const std::string& library) {
  std::ifstream maps("/proc/self/maps");
  std::string line;
  while (std::getline(maps, line)) {
    if (line.find(library) != std::string::npos) return true;
  }
  return false;
}

// Largest error of the relative orientations to view 0: gauge-free.
double MaxErrorDeg(const SyntheticGraph& g, const ViewOrientations& estimate) {
  const ViewId first = g.ground_truth.begin()->first;
  double worst = 0.0;
  for (const auto& [id, truth] : g.ground_truth) {
    const Eigen::Matrix3d estimated = estimate.at(id) * estimate.at(first).transpose();
    worst = std::max(worst, RadToDeg(AngularDistanceRad(estimated, truth * g.ground_truth.at(first).transpose())));
  }
  return worst;
}

SyntheticGraph Graph(int views, double mean_degree) {
  SyntheticGraphOptions o;
  o.num_views = views;
  o.mean_degree = mean_degree;
  o.noise_deg = 1.0;
  o.noise_spread = 5.0;  // per axis: full 3x3 covariances, the block path
  o.anisotropic = true;
  return MakeSyntheticGraph(o);
}

TEST(Backends, LoadedOnlyWhenASolveNeedsThem) {
  ASSERT_FALSE(BackendsLoaded());
  ASSERT_FALSE(Mapped("librotation_averaging_backends")) << "the core must not link the back ends";
  ASSERT_FALSE(Mapped("libcholmod"));
  ASSERT_FALSE(Mapped("libopenblas"));

  // A chain with full covariances: its factor is thin, Eigen factorises it.
  const SyntheticGraph chain = Graph(60, 2.0 * 59 / 60);
  ViewOrientations orientations;
  RotationAveragingSummary summary;
  ASSERT_TRUE(SolveRotationAveraging(chain.graph, RotationAveragingOptions(), &orientations, &summary));
  ASSERT_EQ(chain.graph.NumEdges(), 59u) << "a chain: the solution meets every edge";
  for (const RelativeRotation& e : chain.graph.Edges()) {
    const Eigen::Matrix3d solved = orientations.at(e.view1) * orientations.at(e.view2).transpose();
    EXPECT_LT(RadToDeg(AngularDistanceRad(solved, e.rotation)), 1e-6);
  }
  EXPECT_FALSE(BackendsLoaded());
  EXPECT_FALSE(Mapped("libcholmod"));

  // Random long edges fill the factor in: CHOLMOD's supernodal factor.
  const SyntheticGraph expander = Graph(300, 10.0);
  ASSERT_TRUE(SolveRotationAveraging(expander.graph, RotationAveragingOptions(), &orientations, &summary));
  EXPECT_LT(MaxErrorDeg(expander, orientations), 2.0);
#ifdef ROTAVG_HAVE_CHOLMOD
  EXPECT_TRUE(BackendsLoaded());
  EXPECT_TRUE(Mapped("libcholmod"));
#endif

  // The Ceres solver comes from the same library.
  const SyntheticGraph small = Graph(40, 6.0);
  RotationAveragingOptions ceres;
  ceres.solver = SolverType::kCeres;
  ASSERT_TRUE(SolveRotationAveraging(small.graph, ceres, &orientations, &summary));
  EXPECT_TRUE(BackendsLoaded());
  ASSERT_FALSE(summary.components.empty());
  EXPECT_EQ(summary.components[0].status.find("unavailable"), std::string::npos) << summary.components[0].status;
  EXPECT_LT(MaxErrorDeg(small, orientations), 5.0);
}

}  // namespace
}  // namespace rotation_averaging
