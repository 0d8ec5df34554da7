// Tests on the real third-party data in ../shared/data (test/common/test_data.h:
// skipped with a message where it is absent, failed where it is required).
#include <gtest/gtest.h>
#include "common/test_data.h"

#include <filesystem>
#include <random>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"

namespace rotation_averaging {
namespace {

std::string DataPath(const std::string& relative) { return SharedDataPath(relative); }

#define REQUIRE_DATA(relative) ROTAVG_REQUIRE_SHARED_DATA(DataPath(relative))

// 10th percentile of the angle of R_ij R_jk R_ki over triangles of the graph,
// read as is and with every edge transposed: the right convention makes
// consistent triangles close to identity. (A low percentile, because real
// 1DSfM graphs have so many outlier edges that the median triangle is bad
// either way.)
std::pair<double, double> TriangleErrorsDeg(const ViewGraph& g) {
  std::map<std::pair<ViewId, ViewId>, Eigen::Matrix3d> m;
  std::map<ViewId, std::vector<ViewId>> adj;
  for (const auto& e : g.Edges()) {
    m[{e.view1, e.view2}] = e.rotation;
    m[{e.view2, e.view1}] = e.rotation.transpose();
    adj[e.view1].push_back(e.view2);
    adj[e.view2].push_back(e.view1);
  }
  std::vector<double> as_is, transposed;
  for (const auto& e : g.Edges()) {
    for (ViewId k : adj[e.view2]) {
      if (k == e.view1 || !m.count({k, e.view1})) continue;
      const auto& a = m[{e.view1, e.view2}];
      const auto& b = m[{e.view2, k}];
      const auto& c = m[{k, e.view1}];
      as_is.push_back(RadToDeg(RotationAngleRad(a * b * c)));
      transposed.push_back(RadToDeg(RotationAngleRad(a.transpose() * b.transpose() * c.transpose())));
      if (as_is.size() > 20000) break;
    }
  }
  auto low = [](std::vector<double> v) {
    if (v.empty()) return 0.0;
    std::nth_element(v.begin(), v.begin() + v.size() / 10, v.end());
    return v[v.size() / 10];
  };
  EXPECT_GT(as_is.size(), 10u);
  return {low(as_is), low(transposed)};
}

TEST(RealData, OneDsfmConventionPassesTheTriangleTest) {
  // Pose graphs have (almost) no triangles, and the iRotAvg sequence too few:
  // their conventions are checked against ground truth below.
  REQUIRE_DATA("relative_rotations/madrid_metropolis/EGs.txt");
  ViewGraph g;
  ASSERT_TRUE(ReadOneDsfm(DataPath("relative_rotations/madrid_metropolis/EGs.txt"), "", &g).ok());
  const auto [as_is, transposed] = TriangleErrorsDeg(g);
  EXPECT_LT(as_is, 0.75 * transposed) << "as read " << as_is << " deg, transposed " << transposed;
}

TEST(RealData, TransposedG2oConventionWouldContradictGroundTruth) {
  // Chained ground truth from TORO, and the g2o version of the same noisy
  // graph: with R_ij = R_i R_j^T both must agree with ground truth per edge.
  REQUIRE_DATA("pose_graphs/sphere2500_groundtruth.txt");
  NamedOrientations gt;
  ASSERT_TRUE(ReadChainedGroundTruth(DataPath("pose_graphs/sphere2500_groundtruth.txt"), GraphFormat::kToro, &gt).ok());
  ViewGraph g;
  ASSERT_TRUE(ReadG2o(DataPath("pose_graphs/sphere2500.g2o"), &g).ok());
  std::vector<double> errors, transposed;
  for (const auto& e : g.Edges()) {
    const Eigen::Matrix3d truth = gt.at(std::to_string(e.view1)) * gt.at(std::to_string(e.view2)).transpose();
    errors.push_back(RadToDeg(AngularDistanceRad(truth, e.rotation)));
    transposed.push_back(RadToDeg(AngularDistanceRad(truth, e.rotation.transpose())));
  }
  std::nth_element(errors.begin(), errors.begin() + errors.size() / 2, errors.end());
  std::nth_element(transposed.begin(), transposed.begin() + transposed.size() / 2, transposed.end());
  EXPECT_LT(errors[errors.size() / 2], 5.0);
  EXPECT_GT(transposed[transposed.size() / 2], 4.0 * errors[errors.size() / 2]);
}

TEST(RealData, Sphere2500MedianErrorWithinTarget) {
  REQUIRE_DATA("pose_graphs/sphere2500.txt");
  ViewGraph g;
  ASSERT_TRUE(ReadToro(DataPath("pose_graphs/sphere2500.txt"), &g).ok());
  NamedOrientations gt;
  ASSERT_TRUE(ReadChainedGroundTruth(DataPath("pose_graphs/sphere2500_groundtruth.txt"), GraphFormat::kToro, &gt).ok());
  for (SolverType solver : {SolverType::kIrls, SolverType::kCeres}) {
    RotationAveragingOptions o;
    o.solver = solver;
    ViewOrientations out;
    RotationAveragingSummary summary;
    ASSERT_TRUE(SolveRotationAveraging(g, o, &out, &summary));
    const EvaluationResult e = EvaluateOrientations(NameOrientations(g, out), gt);
    EXPECT_EQ(e.views_common, 2500u);
    EXPECT_LE(e.median_error_deg, 1.6) << SolverTypeName(solver);
  }
}

TEST(RealData, EveryRealGraphSolvesToFiniteOrientations) {
  for (const std::string f : {"relative_rotations/madrid_metropolis", "relative_rotations/irotavg/ravg_input.txt",
                              "pose_graphs/parking-garage.g2o"}) {
    REQUIRE_DATA(f);
    ViewGraph g;
    ASSERT_TRUE(ReadViewGraph(DataPath(f), GraphFormat::kAuto, &g).ok()) << f;
    ViewOrientations out;
    RotationAveragingSummary summary;
    ASSERT_TRUE(SolveRotationAveraging(g, RotationAveragingOptions(), &out, &summary)) << f;
    EXPECT_GT(out.size(), 0.9 * g.NumViews()) << f;
    for (const auto& [id, r] : out) ASSERT_TRUE(IsRotationMatrix(r, 1e-9)) << f;
  }
}

}  // namespace
}  // namespace rotation_averaging
