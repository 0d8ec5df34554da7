#include "rotation_averaging/core/eval/rotation_evaluation.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <random>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

TEST(RecallAuc, MatchesHandComputedValues) {
  // Errors 1 and 3 deg of 2 views: at t = 2, recall is 0 on [0,1), 0.5 on
  // [1,2]: area 0.5, AUC 0.25. At t = 4: area 0.5*2 + 1*1... = (4-1 + 4-3)/2 = 2, AUC 0.5.
  EXPECT_NEAR(RecallAuc({1.0, 3.0}, 2, 2.0), 0.25, 1e-15);
  EXPECT_NEAR(RecallAuc({1.0, 3.0}, 2, 4.0), 0.5, 1e-15);
  // A missing view halves the AUC.
  EXPECT_NEAR(RecallAuc({1.0, 3.0}, 4, 4.0), 0.25, 1e-15);
  EXPECT_NEAR(RecallAuc({0.0}, 1, 5.0), 1.0, 1e-15);
  EXPECT_EQ(RecallAuc({}, 0, 5.0), 0.0);
}

TEST(Evaluation, AlignmentIsRobustToOutlierViews) {
  std::mt19937 rng(5);
  std::normal_distribution<double> normal;
  const Eigen::Matrix3d g = ExpSO3(Eigen::Vector3d(0.4, -1.0, 2.0));
  NamedOrientations gt, est;
  for (int i = 0; i < 100; ++i) {
    const std::string name = "v" + std::to_string(i);
    gt[name] = ExpSO3(DrawVector3(rng, normal));
    const double noise = i < 30 ? 1.0 : 0.001;  // 30% of views far off
    est[name] = gt[name] * g * ExpSO3(noise * DrawVector3(rng, normal));
  }
  gt["missing"] = Eigen::Matrix3d::Identity();
  const EvaluationResult r = EvaluateOrientations(est, gt);
  EXPECT_EQ(r.views_in_ground_truth, 101u);
  EXPECT_EQ(r.views_common, 100u);
  EXPECT_LT(AngularDistanceRad(r.alignment, g), 5e-4);
  EXPECT_LT(r.median_error_deg, 0.2);
  // The missing view and the 30 outliers cap AUC@2 below 70/101.
  EXPECT_LT(r.auc[0].second, 70.0 / 101.0);
  EXPECT_GT(r.auc[0].second, 0.6);
  EXPECT_NE(r.ToJson().find("\"median_error_deg\""), std::string::npos);
}

// Edges whose errors are drawn from their own anisotropic covariances, in the
// right perturbation R_12 = R_12_true Exp(eta). With `view_sd`, every pair of
// a view also sees that view turned, by the same d_k ~ N(0, view_sd^2 I) in
// all of them (`seen`): an error the pairs share.
struct CalibrationScene {
  ViewGraph graph;
  NamedOrientations truth, seen;
};
CalibrationScene MakeCalibrationScene(std::mt19937* rng, int num_views, double view_sd = 0.0,
                                      const Eigen::Vector3d& pair_sd = Eigen::Vector3d(0.001, 0.01, 0.1)) {
  std::normal_distribution<double> normal;
  auto gaussian = [&] { return DrawVector3(*rng, normal); };
  CalibrationScene scene;
  for (int i = 0; i < num_views; ++i) {
    const std::string name = "v" + std::to_string(i);
    scene.graph.AddView(i, name);
    scene.truth[name] = ExpSO3(gaussian());
    scene.seen[name] = view_sd > 0.0 ? ExpSO3(view_sd * gaussian()) * scene.truth[name] : scene.truth[name];
  }
  for (int i = 0; i < num_views; ++i) {
    for (int j = i + 1; j < num_views; ++j) {
      // Standard deviations along random axes (by default 0.001 to 0.1 rad:
      // the wrong perturbation side, left instead of right, would be far off).
      const Eigen::Matrix3d axes = ExpSO3(gaussian());
      RelativeRotation e;
      e.view1 = i;
      e.view2 = j;
      e.has_covariance = true;
      e.covariance = axes * pair_sd.cwiseAbs2().asDiagonal() * axes.transpose();
      const Eigen::Vector3d eta = axes * pair_sd.cwiseProduct(gaussian());
      const std::string a = "v" + std::to_string(i), b = "v" + std::to_string(j);
      e.rotation = scene.seen[a] * scene.seen[b].transpose() * ExpSO3(eta);
      scene.graph.AddEdge(e);
    }
  }
  return scene;
}

TEST(EdgeCalibration, CovariancesThatDescribeTheErrorsAreCalibrated) {
  std::mt19937 rng(11);
  const CalibrationScene scene = MakeCalibrationScene(&rng, 40);  // 780 edges
  const EdgeCalibration c = EvaluateEdgeCovariances(scene.graph, scene.truth);
  EXPECT_EQ(c.edges, 780u);
  EXPECT_EQ(c.edges_scored, 780u);
  EXPECT_NEAR(c.nees_median, 2.37, 0.3);
  EXPECT_NEAR(c.nees_mean, 3.0, 0.35);
  EXPECT_NEAR(c.within_95, 0.95, 0.025);
  EXPECT_NE(c.ToText().find("NEES median"), std::string::npos);
}

TEST(EdgeCalibration, OverconfidentCovariancesAndTheFloor) {
  std::mt19937 rng(12);
  CalibrationScene scene = MakeCalibrationScene(&rng, 30);
  const EdgeCalibration calibrated = EvaluateEdgeCovariances(scene.graph, scene.truth);
  // Covariances ten times too confident in standard deviation: NEES x100.
  ViewGraph overconfident;
  for (const View& v : scene.graph.Views()) overconfident.AddView(v.id, v.name);
  for (RelativeRotation e : scene.graph.Edges()) {
    e.covariance *= 0.01;
    overconfident.AddEdge(e);
  }
  const EdgeCalibration c = EvaluateEdgeCovariances(overconfident, scene.truth);
  EXPECT_NEAR(c.nees_median / calibrated.nees_median, 100.0, 1e-6);
  EXPECT_LT(c.within_95, 0.2);
  // A floor can only lower every edge's NEES; one far above every standard
  // deviation leaves them near zero.
  const EdgeCalibration floored = EvaluateEdgeCovariances(overconfident, scene.truth, 0.01);
  ASSERT_EQ(floored.scored.size(), c.scored.size());
  for (std::size_t k = 0; k < c.scored.size(); ++k) EXPECT_LE(floored.scored[k].nees, c.scored[k].nees * (1 + 1e-12));
  EXPECT_LT(EvaluateEdgeCovariances(overconfident, scene.truth, 10.0).nees_mean, 1e-3);
  EXPECT_DOUBLE_EQ(floored.floor_rad, 0.01);
}

TEST(EdgeCalibration, PerViewOffsetsSeparateAReferencesErrorFromThePairs) {
  std::mt19937 rng(14);
  const CalibrationScene scene = MakeCalibrationScene(&rng, 30);  // 435 edges
  // A reference whose every view is off by 0.05 rad about a random axis,
  // most edges' standard deviations or more: the pairs look over-confident.
  std::normal_distribution<double> normal;
  NamedOrientations reference;
  std::map<std::string, Eigen::Vector3d> offset;
  for (const auto& [name, r] : scene.truth) {
    offset[name] = 0.05 * DrawVector3(rng, normal).normalized();
    reference[name] = ExpSO3(offset[name]) * r;
  }
  const EdgeCalibration truth = EvaluateEdgeCovariances(scene.graph, scene.truth);
  const EdgeCalibration c = EvaluateEdgeCovariances(scene.graph, reference);
  EXPECT_GT(c.nees_median, 50.0 * truth.nees_median);
  // The offsets explain the reference's error: what remains is the pairs'
  // own, about as against the truth (the fit takes 29 of 435 edges' worth).
  EXPECT_NEAR(c.nees_median_after_view_offsets / truth.nees_median, 1.0, 0.2);
  EXPECT_NEAR(c.median_error_after_view_offsets_deg / truth.median_error_deg, 1.0, 0.2);
  // ... and the same whatever the reference: the views' offsets absorb it.
  EXPECT_NEAR(c.nees_median_after_view_offsets / truth.nees_median_after_view_offsets, 1.0, 0.05);
  EXPECT_LE(truth.nees_median_after_view_offsets, truth.nees_median);
  // The fitted offsets are the reference's, reversed (up to the world
  // rotation common to all views, which no edge sees).
  ASSERT_EQ(c.view_offsets.size(), 30u);
  double agreement = 0.0;
  for (const EdgeCalibration::ViewOffset& v : c.view_offsets) {
    agreement += -v.offset_deg.dot(offset[v.name]) / (v.offset_deg.norm() * offset[v.name].norm());
    EXPECT_NEAR(v.offset_deg.norm(), 0.05 * 180.0 / M_PI, 0.4 * 0.05 * 180.0 / M_PI);
  }
  EXPECT_GT(agreement / 30.0, 0.9);
  EXPECT_NEAR(c.median_view_offset_deg, 0.05 * 180.0 / M_PI, 0.2 * 0.05 * 180.0 / M_PI);
  EXPECT_LT(truth.median_view_offset_deg, 0.2 * c.median_view_offset_deg);
  // A floor only lowers NEES.
  const EdgeCalibration floored = EvaluateEdgeCovariances(scene.graph, reference, 0.01);
  EXPECT_LT(floored.nees_median_after_view_offsets, c.nees_median_after_view_offsets);
  EXPECT_NE(c.ToText().find("after per-view offsets"), std::string::npos);
}

TEST(EdgeCalibration, TheViewTermFromAnAdjustmentCalibratesPairsThatShareAnErrorPerView) {
  // Each view's pairs all see it turned by d_k ~ N(0, 0.01^2 I) rad (as if
  // its keypoints were shifted), beyond their own noise (sd 0.001-0.004
  // rad): the pairs agree with each other, not with the true poses.
  std::mt19937 rng(15);
  const double view_sd = 0.01;
  const CalibrationScene scene = MakeCalibrationScene(&rng, 40, view_sd, Eigen::Vector3d(0.001, 0.002, 0.004));
  const ViewGraph& graph = scene.graph;
  const NamedOrientations& truth = scene.truth;
  const NamedOrientations& seen = scene.seen;
  // An adjustment that recovered the true poses sees the views' offsets;
  // the pairs' own scale comes back from their median.
  const EdgeCalibration alone = EvaluateEdgeCovariances(graph, truth);
  const double view_rad = ViewTermRad(alone);
  EXPECT_NEAR(view_rad, view_sd, 0.25 * view_sd);
  // Against the truth, the pairs alone are far too confident; with the view
  // term on both views they are calibrated.
  const EdgeCalibration with_views = EvaluateEdgeCovariances(graph, truth, FloorWithViewTermRad(0.0, view_rad));
  EXPECT_GT(alone.nees_median, 20.0);
  EXPECT_NEAR(with_views.nees_median, 2.37, 0.6);
  EXPECT_NEAR(with_views.within_95, 0.95, 0.04);
  // An adjustment that shares the pairs' per-view error sees no view term.
  EXPECT_LT(ViewTermRad(EvaluateEdgeCovariances(graph, seen)), 0.2 * view_sd);
  EXPECT_DOUBLE_EQ(FloorWithViewTermRad(0.003, 0.002), std::sqrt(0.003 * 0.003 + 2 * 0.002 * 0.002));
  EXPECT_TRUE(std::isnan(ViewTermRad(EdgeCalibration())));
}

TEST(EdgeCalibration, EdgesWithoutCovarianceOrGroundTruthAreNotScored) {
  std::mt19937 rng(13);
  CalibrationScene scene = MakeCalibrationScene(&rng, 4);  // 6 edges
  scene.truth.erase("v3");                                 // 3 of them lose a view
  RelativeRotation plain;
  plain.view1 = 0;
  plain.view2 = 1;
  plain.rotation = scene.truth["v0"] * scene.truth["v1"].transpose();
  plain.has_covariance = false;
  plain.channel = 1;
  ASSERT_EQ(scene.graph.AddEdge(plain, nullptr, DuplicatePolicy::kKeepBoth), AddEdgeResult::kAdded);
  const EdgeCalibration c = EvaluateEdgeCovariances(scene.graph, scene.truth);
  EXPECT_EQ(c.edges, scene.graph.NumEdges());
  EXPECT_EQ(c.edges_scored, 3u);
  for (const EdgeCalibration::Edge& e : c.scored) EXPECT_TRUE(e.name1 != "v3" && e.name2 != "v3");
  const EdgeCalibration none = EvaluateEdgeCovariances(scene.graph, NamedOrientations());
  EXPECT_EQ(none.edges_scored, 0u);
  EXPECT_TRUE(std::isnan(none.nees_median));
  EXPECT_TRUE(std::isnan(none.nees_median_after_view_offsets));
  EXPECT_TRUE(std::isnan(none.median_view_offset_deg));
  EXPECT_TRUE(none.view_offsets.empty());
}

// Views of one component whose estimate errs from the truth by d_k drawn
// from N(0, C_k) (a left perturbation relative to the gauge view 0, whose
// estimate is exact), in a world frame rotated by `world`, each covariance
// given to the check multiplied by `stated`. View 1 shares the gauge's
// capture (zero covariance, as a rig camera of it).
PosteriorCalibration PosteriorCheck(int views, double stated, NamedOrientations* truth_out = nullptr) {
  std::mt19937 rng(7);
  std::normal_distribution<double> normal(0.0, 1.0);
  const Eigen::Matrix3d world = ExpSO3(Eigen::Vector3d(0.3, -1.1, 0.7));  // estimate frame = truth frame * world
  NamedOrientations truth, estimate;
  std::map<std::string, Eigen::Matrix3d> covariances;
  std::map<std::string, int> component;
  for (int k = 0; k < views; ++k) {
    const std::string name = "v" + std::to_string(k);
    truth[name] = ExpSO3(DrawVector3(rng, normal));
    // An anisotropic covariance with random axes, 0.01-0.1 rad per axis.
    const Eigen::Matrix3d axes = ExpSO3(DrawVector3(rng, normal));
    const Eigen::Vector3d sigma(0.01, 0.03, 0.1);
    const Eigen::Matrix3d c = k < 2 ? Eigen::Matrix3d::Zero()
                                    : Eigen::Matrix3d(axes * sigma.cwiseAbs2().asDiagonal() * axes.transpose());
    const Eigen::Vector3d d = axes * sigma.cwiseProduct(DrawVector3(rng, normal));
    estimate[name] = (k < 2 ? Eigen::Matrix3d::Identity() : ExpSO3(d)) * truth[name] * world;
    covariances[name] = stated * c;
    component[name] = 0;
  }
  if (truth_out) *truth_out = truth;
  return EvaluatePosteriorCovariances(estimate, covariances, component, truth);
}

TEST(PosteriorCalibration, CovariancesThatDescribeTheErrorsGiveChiSquare) {
  const PosteriorCalibration honest = PosteriorCheck(2002, 1.0);
  EXPECT_EQ(honest.views_with_covariance, 2002u);
  EXPECT_EQ(honest.views_scored, 2000u);  // the gauge and the camera of its capture are held
  EXPECT_EQ(honest.views.count("v0") + honest.views.count("v1"), 0u);
  EXPECT_NEAR(honest.nees_median, 2.37, 0.2);
  EXPECT_NEAR(honest.nees_mean, 3.0, 0.25);
  EXPECT_NEAR(honest.within_95, 0.95, 0.015);
  EXPECT_NE(honest.Describe().find("2000 keyframes"), std::string::npos) << honest.Describe();
}

TEST(PosteriorCalibration, OverconfidentCovariancesAreFoundOut) {
  // Stated four times too small: NEES four times chi-square's.
  const PosteriorCalibration overconfident = PosteriorCheck(2002, 0.25);
  EXPECT_NEAR(overconfident.nees_median, 4 * 2.37, 0.8);
  EXPECT_LT(overconfident.within_95, 0.6);
}

TEST(PosteriorCalibration, NothingIsScoredWithoutTheGaugesTruth) {
  NamedOrientations truth;
  PosteriorCheck(10, 1.0, &truth);
  NamedOrientations estimate = truth;
  std::map<std::string, Eigen::Matrix3d> covariances;
  std::map<std::string, int> component;
  for (const auto& [name, r] : truth) {
    covariances[name] = name == "v0" ? Eigen::Matrix3d::Zero() : Eigen::Matrix3d(1e-4 * Eigen::Matrix3d::Identity());
    component[name] = 0;
  }
  truth.erase("v0");
  const PosteriorCalibration none = EvaluatePosteriorCovariances(estimate, covariances, component, truth);
  EXPECT_EQ(none.views_scored, 0u);
  EXPECT_TRUE(std::isnan(none.nees_median));
  EXPECT_NE(none.Describe().find("none scored"), std::string::npos);
}

}  // namespace
}  // namespace rotation_averaging
