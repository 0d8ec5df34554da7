#include "rotation_averaging/eval/rotation_evaluation.h"

#include <gtest/gtest.h>

#include <random>

#include "rotation_averaging/geometry/so3.h"

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
    gt[name] = ExpSO3(Eigen::Vector3d(normal(rng), normal(rng), normal(rng)));
    const double noise = i < 30 ? 1.0 : 0.001;  // 30% of views far off
    est[name] = gt[name] * g * ExpSO3(noise * Eigen::Vector3d(normal(rng), normal(rng), normal(rng)));
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

}  // namespace
}  // namespace rotation_averaging
