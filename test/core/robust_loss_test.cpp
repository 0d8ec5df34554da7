#include "rotation_averaging/core/estimators/robust_loss.h"

#include <gtest/gtest.h>

#include <cmath>

namespace rotation_averaging {
namespace {

class AllLosses : public ::testing::TestWithParam<LossType> {};

TEST_P(AllLosses, DerivativesMatchFiniteDifferences) {
  const auto loss = CreateLoss(GetParam(), 0.7);
  for (double s : {1e-4, 0.01, 0.1, 0.3, 0.45, 1.0, 3.0, 10.0}) {
    if (GetParam() == LossType::kMagsac) {
      const double cutoff = MagsacLoss::kChiQuantile * MagsacLoss::kChiQuantile * 0.49;
      if (std::abs(s - cutoff) < 1e-3) continue;  // kink at the cut-off
    }
    if ((GetParam() == LossType::kHuber || GetParam() == LossType::kTukey) && std::abs(s - 0.49) < 1e-3) continue;
    const double h = 1e-7 * std::max(1.0, s);
    double rho[3], plus[3], minus[3];
    loss->Evaluate(s, rho);
    loss->Evaluate(s + h, plus);
    loss->Evaluate(s - h, minus);
    EXPECT_NEAR((plus[0] - minus[0]) / (2 * h), rho[1], 1e-5 * std::max(1.0, std::abs(rho[1]))) << s;
    EXPECT_NEAR((plus[1] - minus[1]) / (2 * h), rho[2], 1e-4 * std::max(1.0, std::abs(rho[2]))) << s;
  }
}

TEST_P(AllLosses, BehavesLikeLeastSquaresNearZeroAndIsMonotone) {
  const auto loss = CreateLoss(GetParam(), 0.7);
  double rho[3];
  loss->Evaluate(0.0, rho);
  EXPECT_NEAR(rho[0], 0.0, 1e-15);
  EXPECT_NEAR(rho[1], 1.0, 1e-12);
  double previous = 0.0;
  for (double s = 0.01; s < 20.0; s *= 1.5) {
    loss->Evaluate(s, rho);
    EXPECT_GE(rho[0], previous);
    EXPECT_GE(rho[1], 0.0);
    EXPECT_LE(rho[1], 1.0 + 1e-12);
    previous = rho[0];
  }
}

TEST_P(AllLosses, NamesRoundTrip) {
  LossType parsed;
  ASSERT_TRUE(ParseLossType(LossTypeName(GetParam()), &parsed));
  EXPECT_EQ(parsed, GetParam());
}

INSTANTIATE_TEST_SUITE_P(Losses, AllLosses, ::testing::ValuesIn(AllLossTypes()),
                         [](const auto& info) {
                           std::string n = LossTypeName(info.param);
                           for (char& c : n)
                             if (c == '.') c = '_';
                           return n;
                         });

// The closed form must equal w(0) - w(r) with w the marginal of the chi(3)
// density over sigma in [0, sigma_max], up to the constant normalisation.
TEST(MagsacLoss, ClosedFormMatchesNumericalMarginalisation) {
  const double sigma_max = 0.8, k = MagsacLoss::kChiQuantile;
  // w(r) = 1/sigma_max Int_{r/k}^{sigma_max} 2 C sigma^-3 r^2 exp(-r^2 / 2 sigma^2) d sigma (C cancels).
  auto weight = [&](double r) {
    if (r <= 0.0) return (1.0 - std::exp(-k * k / 2.0)) / sigma_max;  // limit r -> 0
    const double lo = r / k;
    if (lo >= sigma_max) return 0.0;
    const int n = 200000;
    double sum = 0.0;
    for (int i = 0; i < n; ++i) {  // midpoint rule
      const double sg = lo + (sigma_max - lo) * (i + 0.5) / n;
      sum += r * r / (sg * sg * sg) * std::exp(-r * r / (2 * sg * sg));
    }
    return sum * (sigma_max - lo) / n / sigma_max;
  };
  MagsacLoss loss(sigma_max);
  const double w0 = weight(0.0);
  double rho[3];
  // rho(s) / (w(0) - w(r)) must be the same constant for every r.
  loss.Evaluate(0.25, rho);
  const double ratio = rho[0] / (w0 - weight(0.5));
  for (double r : {0.1, 0.3, 0.8, 1.5, 2.5, 2.69}) {
    loss.Evaluate(r * r, rho);
    EXPECT_NEAR(rho[0] / (w0 - weight(r)), ratio, 1e-4 * ratio) << r;
  }
  // Beyond k sigma_max the loss is flat and the weight zero.
  loss.Evaluate(std::pow(k * sigma_max * 1.01, 2), rho);
  EXPECT_EQ(rho[1], 0.0);
  EXPECT_NEAR(rho[0], 2 * sigma_max * sigma_max * (1 - std::exp(-k * k / 2)), 1e-12);
}

TEST(MagsacLoss, WeightIsGaussianInsideTheCutoff) {
  MagsacLoss loss(2.0);
  EXPECT_NEAR(loss.Weight(4.0), std::exp(-4.0 / 8.0), 1e-15);
  EXPECT_EQ(loss.Weight(3.3682 * 3.3682 * 4.0 * 1.001), 0.0);
}

TEST(RobustLoss, RejectsNonPositiveScale) {
  EXPECT_THROW(CreateLoss(LossType::kCauchy, 0.0), std::invalid_argument);
  EXPECT_THROW(CreateLoss(LossType::kMagsac, std::nan("")), std::invalid_argument);
  EXPECT_NO_THROW(CreateLoss(LossType::kSquared, 0.0));
}

}  // namespace
}  // namespace rotation_averaging
