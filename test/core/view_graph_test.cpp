#include "rotation_averaging/core/scene/view_graph.h"

#include <gtest/gtest.h>

#include <limits>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

RelativeRotation Edge(ViewId a, ViewId b, EdgeSource source = EdgeSource::kOther) {
  RelativeRotation e;
  e.view1 = a;
  e.view2 = b;
  e.rotation = ExpSO3(Eigen::Vector3d(0.1 * a, 0.2, -0.1 * b));
  e.source = source;
  return e;
}

ViewGraph ThreeViews() {
  ViewGraph g;
  for (ViewId v : {1, 2, 3}) g.AddView(v);
  return g;
}

TEST(ViewGraph, DuplicatePolicyReplacesSameSourceAndKeepsOtherSources) {
  ViewGraph g = ThreeViews();
  EXPECT_EQ(g.AddEdge(Edge(1, 2, EdgeSource::kSequential)), AddEdgeResult::kAdded);
  // Same pair and source, other direction: replaces.
  RelativeRotation again = Edge(2, 1, EdgeSource::kSequential);
  EXPECT_EQ(g.AddEdge(again), AddEdgeResult::kReplaced);
  EXPECT_EQ(g.NumEdges(), 1u);
  EXPECT_EQ(g.Edges()[0].view1, 2u);
  // Same pair, loop closure: a second, independent measurement.
  EXPECT_EQ(g.AddEdge(Edge(1, 2, EdgeSource::kLoopClosure)), AddEdgeResult::kAdded);
  EXPECT_EQ(g.NumEdges(), 2u);
  EXPECT_EQ(g.Stats().edges_replaced, 1u);
  EXPECT_TRUE(g.RemoveEdge(2, 1, EdgeSource::kLoopClosure));
  EXPECT_FALSE(g.RemoveEdge(2, 1, EdgeSource::kLoopClosure));
  EXPECT_EQ(g.NumEdges(), 1u);
}

TEST(ViewGraph, KeepBothPolicyKeepsRepeatedMeasurementsAndRemovalStaysConsistent) {
  ViewGraph g = ThreeViews();
  EXPECT_EQ(g.AddEdge(Edge(1, 2), nullptr, DuplicatePolicy::kKeepBoth), AddEdgeResult::kAdded);
  EXPECT_EQ(g.AddEdge(Edge(2, 3), nullptr, DuplicatePolicy::kKeepBoth), AddEdgeResult::kAdded);
  EXPECT_EQ(g.AddEdge(Edge(2, 1), nullptr, DuplicatePolicy::kKeepBoth), AddEdgeResult::kAdded);
  EXPECT_EQ(g.AddEdge(Edge(1, 3), nullptr, DuplicatePolicy::kKeepBoth), AddEdgeResult::kAdded);
  EXPECT_EQ(g.NumEdges(), 4u);
  // Removing the pair removes both of its measurements and keeps the others addressable.
  EXPECT_TRUE(g.RemoveEdge(1, 2, EdgeSource::kOther));
  EXPECT_EQ(g.NumEdges(), 2u);
  EXPECT_TRUE(g.RemoveEdge(3, 1, EdgeSource::kOther));
  ASSERT_EQ(g.NumEdges(), 1u);
  EXPECT_EQ(g.Edges()[0].view1, 2u);
  EXPECT_TRUE(g.RemoveEdge(2, 3, EdgeSource::kOther));
  EXPECT_EQ(g.NumEdges(), 0u);
  // Replace policy on top of a kept pair replaces the latest one.
  g.AddEdge(Edge(1, 2), nullptr, DuplicatePolicy::kKeepBoth);
  g.AddEdge(Edge(1, 2), nullptr, DuplicatePolicy::kKeepBoth);
  EXPECT_EQ(g.AddEdge(Edge(1, 2)), AddEdgeResult::kReplaced);
  EXPECT_EQ(g.NumEdges(), 2u);
  EXPECT_TRUE(g.RemoveView(1));
  EXPECT_EQ(g.NumEdges(), 0u);
}

TEST(ViewGraph, RejectsBadInputAndCountsIt) {
  ViewGraph g = ThreeViews();
  std::string why;
  EXPECT_EQ(g.AddEdge(Edge(1, 1), &why), AddEdgeResult::kRejected);
  EXPECT_NE(why.find("itself"), std::string::npos);
  EXPECT_EQ(g.AddEdge(Edge(1, 9), &why), AddEdgeResult::kRejected);
  EXPECT_NE(why.find("unknown view 9"), std::string::npos);
  RelativeRotation nan_edge = Edge(1, 2);
  nan_edge.rotation(0, 0) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(g.AddEdge(nan_edge, &why), AddEdgeResult::kRejected);
  RelativeRotation scaled = Edge(1, 2);
  scaled.rotation *= 1.1;
  EXPECT_EQ(g.AddEdge(scaled, &why), AddEdgeResult::kRejected);
  RelativeRotation bad_cov = Edge(1, 2);
  bad_cov.has_covariance = true;
  bad_cov.covariance = -Eigen::Matrix3d::Identity();
  EXPECT_EQ(g.AddEdge(bad_cov, &why), AddEdgeResult::kRejected);
  bad_cov.covariance = Eigen::Matrix3d::Identity();
  bad_cov.covariance(0, 2) = std::numeric_limits<double>::infinity();
  EXPECT_EQ(g.AddEdge(bad_cov, &why), AddEdgeResult::kRejected);
  EXPECT_EQ(g.NumEdges(), 0u);
  const auto& s = g.Stats();
  EXPECT_EQ(s.rejected_self_loop, 1u);
  EXPECT_EQ(s.rejected_unknown_view, 1u);
  EXPECT_EQ(s.rejected_bad_rotation, 2u);
  EXPECT_EQ(s.rejected_bad_covariance, 2u);
  EXPECT_EQ(s.Rejected(), 6u);
}

TEST(ViewGraph, RepairsSlightlyAsymmetricOrSemidefiniteCovariance) {
  ViewGraph g = ThreeViews();
  RelativeRotation e = Edge(1, 2);
  e.has_covariance = true;
  e.covariance = Eigen::Vector3d(1e-4, 1e-4, 0.0).asDiagonal();  // singular
  e.covariance(0, 1) = 1e-9;                                      // slightly asymmetric
  EXPECT_EQ(g.AddEdge(e), AddEdgeResult::kAdded);
  const Eigen::Matrix3d& c = g.Edges()[0].covariance;
  EXPECT_LT((c - c.transpose()).norm(), 1e-20);
  EXPECT_GT(c.llt().info() == Eigen::Success ? 1 : 0, 0);
  EXPECT_EQ(g.Stats().repaired_covariance, 1u);
}

TEST(ViewGraph, InvertedEdgeMovesCovarianceToTheOtherFrame) {
  // M_12 = R_12 Exp(eta) with eta ~ N(0, C): sample and compare the empirical
  // covariance of the inverted edge's perturbation with Inverted().
  RelativeRotation e = Edge(1, 2);
  e.has_covariance = true;
  e.covariance = Eigen::Vector3d(1e-2, 4e-4, 1e-4).asDiagonal();
  const RelativeRotation inv = e.Inverted();
  EXPECT_LT((inv.rotation - e.rotation.transpose()).norm(), 1e-15);
  // eta' = -R_12 eta  =>  C' = R_12 C R_12^T.
  const Eigen::Vector3d eta(0.01, -0.02, 0.005);
  const Eigen::Matrix3d m21 = (e.rotation * ExpSO3(eta)).transpose();
  const Eigen::Vector3d eta_inv = LogSO3(e.rotation * m21);  // M_21 = R_21 Exp(eta')
  EXPECT_LT((eta_inv - (-e.rotation * eta)).norm(), 1e-9);
  EXPECT_LT((inv.covariance - e.rotation * e.covariance * e.rotation.transpose()).norm(), 1e-15);
}

TEST(ViewGraph, ConnectedComponentsLargestFirstAndRemoveView) {
  ViewGraph g;
  for (ViewId v = 1; v <= 7; ++v) g.AddView(v);
  g.AddEdge(Edge(1, 2));
  g.AddEdge(Edge(2, 3));
  g.AddEdge(Edge(5, 6));
  const auto components = g.ConnectedComponents();
  ASSERT_EQ(components.size(), 4u);
  EXPECT_EQ(components[0], (std::vector<ViewId>{1, 2, 3}));
  EXPECT_EQ(components[1], (std::vector<ViewId>{5, 6}));
  EXPECT_EQ(components[2].size(), 1u);
  EXPECT_TRUE(g.RemoveView(2));
  EXPECT_EQ(g.NumEdges(), 1u);
  EXPECT_EQ(g.ConnectedComponents()[0], (std::vector<ViewId>{5, 6}));
  EXPECT_FALSE(g.RemoveView(2));
  EXPECT_EQ(g.FindView(3)->name, "3");
}

}  // namespace
}  // namespace rotation_averaging
