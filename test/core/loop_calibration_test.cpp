#include "rotation_averaging/core/estimators/loop_calibration.h"

#include <gtest/gtest.h>

#include <cmath>
#include <random>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

constexpr double kPi = 3.14159265358979323846;

// A camera turning once about the vertical through `views` views, each
// view related to the next ones `hops` away (the first and the last too,
// where `closed`: the loop closes), each edge measured with its angle times
// 1 + error[c] for c = k % error.size() (cameras taking turns, their focal
// lengths off by those fractions) and a noise of noise_rad per axis. Each
// edge's derivative with respect to its camera's parameter is its turn:
// M Exp(e a), with a the turn's axis times its angle, turns by (1 + e) times
// the angle (the noise, which a focal length does not scale, stays).
struct Turn {
  ViewGraph graph;
  std::vector<EdgeParameterDerivative> derivatives;
};

Turn MakeTurn(int views, const std::vector<int>& hops, const std::vector<double>& error, bool closed,
              double noise_rad, unsigned seed) {
  Turn turn;
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_rad);
  for (int k = 0; k < views; ++k) turn.graph.AddView(k);
  const double step = 2.0 * kPi / views;
  for (int hop : hops) {
    for (int k = 0; k < views; ++k) {
      if (!closed && k + hop >= views) break;
      const int camera = k % static_cast<int>(error.size());
      RelativeRotation e;
      e.view1 = k;
      e.view2 = (k + hop) % views;
      // R_i = Rz(i step): R_12 = R_1 R_2^T = Rz(-hop step).
      const Eigen::Vector3d angle(0.0, 0.0, -hop * step * (1.0 + error[camera]));
      e.rotation = ExpSO3(angle) * ExpSO3(Eigen::Vector3d(noise(rng), noise(rng), noise(rng)));
      e.has_covariance = true;
      e.covariance = noise_rad * noise_rad * Eigen::Matrix3d::Identity();
      e.source = hop == 1 ? EdgeSource::kSequential : EdgeSource::kLoopClosure;
      turn.graph.AddEdge(e);
      turn.derivatives.push_back(EdgeParameterDerivative{turn.graph.NumEdges() - 1, camera, angle});
    }
  }
  return turn;
}

LoopCalibrationOptions Prior(int parameters, double sigma) {
  LoopCalibrationOptions o;
  o.prior_center.assign(parameters, 0.0);
  o.prior_sigma.assign(parameters, sigma);
  return o;
}

// One camera 0.05% off around a closed turn of 60 views, each related to
// the next three, with 0.01 deg of noise: the loop misses closing by
// 0.18 deg, and the estimate closes it, to a small fraction of the prior's
// 1% deviation. (A misclosure many times the noise would rather be put on
// the fewest edges by the robust loss, which then finds no curvature: the
// check's estimate comes first, the loops refine it.)
TEST(LoopCalibration, AClosedLoopFindsTheScaleThatClosesIt) {
  const double error = 0.0005;
  const Turn turn = MakeTurn(60, {1, 2, 3}, {error}, true, 0.01 * kPi / 180.0, 1);
  const LoopCalibrationResult r = EstimateParametersFromLoops(turn.graph, turn.derivatives, Prior(1, 0.01), {});
  ASSERT_TRUE(r.success) << r.message;
  ASSERT_EQ(r.value.size(), 1u);
  const double truth = -error / (1.0 + error);
  EXPECT_NEAR(r.value[0], truth, 3.0 * r.sigma[0]);
  EXPECT_LT(r.sigma[0], 2e-4);  // the loop, not the prior, decides
  EXPECT_LT(r.cost_at_value, r.cost_at_zero);
  EXPECT_GT(r.solves, 4);
}

// Two cameras taking turns, off by different amounts: the loop fixes their
// mean, and the edges two views apart (one camera's two steps, against the
// two cameras' one step each) their difference.
TEST(LoopCalibration, TwoParametersAreFoundTogether) {
  const std::vector<double> error = {0.0005, -0.0003};
  const Turn turn = MakeTurn(60, {1, 2}, error, true, 0.01 * kPi / 180.0, 2);
  const LoopCalibrationResult r = EstimateParametersFromLoops(turn.graph, turn.derivatives, Prior(2, 0.01), {});
  ASSERT_TRUE(r.success) << r.message;
  for (int p = 0; p < 2; ++p) {
    const double truth = -error[p] / (1.0 + error[p]);
    EXPECT_NEAR(r.value[p], truth, 3.0 * r.sigma[p]) << "parameter " << p;
    EXPECT_LT(r.sigma[p], 3e-4) << "parameter " << p;
  }
  EXPECT_GT(std::abs(r.value[0] - r.value[1]), 3.0 * std::hypot(r.sigma[0], r.sigma[1]));
}

// A turn that does not close says nothing about the scale: the estimate is
// the prior's centre, with the prior's deviation.
TEST(LoopCalibration, AnOpenChainKeepsThePrior) {
  const Turn turn = MakeTurn(60, {1, 2, 3}, {0.0005}, false, 0.01 * kPi / 180.0, 4);
  LoopCalibrationOptions options = Prior(1, 0.01);
  options.prior_center = {0.002};
  const LoopCalibrationResult r = EstimateParametersFromLoops(turn.graph, turn.derivatives, options, {});
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_NEAR(r.value[0], 0.002, 1e-4);
  EXPECT_NEAR(r.sigma[0], 0.01, 1e-3);
}

TEST(LoopCalibration, BadInputIsRefusedWithAReason) {
  const Turn turn = MakeTurn(10, {1}, {0.003}, true, 1e-3, 5);
  std::vector<EdgeParameterDerivative> beyond = turn.derivatives;
  beyond.push_back(EdgeParameterDerivative{turn.graph.NumEdges(), 0, Eigen::Vector3d::UnitZ()});
  LoopCalibrationResult r = EstimateParametersFromLoops(turn.graph, beyond, Prior(1, 0.01), {});
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("does not have"), std::string::npos) << r.message;
  std::vector<EdgeParameterDerivative> unknown_parameter = turn.derivatives;
  unknown_parameter[0].parameter = 1;
  r = EstimateParametersFromLoops(turn.graph, unknown_parameter, Prior(1, 0.01), {});
  EXPECT_FALSE(r.success);
  r = EstimateParametersFromLoops(turn.graph, turn.derivatives, Prior(1, 0.0), {});
  EXPECT_FALSE(r.success);
  EXPECT_NE(r.message.find("prior"), std::string::npos) << r.message;
  r = EstimateParametersFromLoops(turn.graph, turn.derivatives, LoopCalibrationOptions(), {});
  EXPECT_FALSE(r.success);
}

}  // namespace
}  // namespace rotation_averaging
