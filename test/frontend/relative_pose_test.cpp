#include "rotation_averaging/frontend/estimators/relative_pose.h"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <algorithm>
#include <limits>
#include <random>
#include <string>

#include "frontend/geometry/epipolar.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

struct Scene {
  Eigen::Matrix3d k;
  Eigen::Matrix3d rotation;  // R_21
  Eigen::Vector3d translation;
  std::vector<Eigen::Vector3d> points;  // in camera 1
};

Scene MakeScene(double baseline, std::mt19937& rng) {
  Scene s;
  s.k << 800, 0, 320, 0, 800, 240, 0, 0, 1;
  s.rotation = ExpSO3(Eigen::Vector3d(0.05, -0.2, 0.03));
  s.translation = baseline * Eigen::Vector3d(-1.0, 0.1, 0.05).normalized();
  std::uniform_real_distribution<double> xy(-2.0, 2.0), z(4.0, 8.0);
  while (s.points.size() < 300) {
    const Eigen::Vector3d p = DrawVector3(rng, xy, xy, z);
    const Eigen::Vector3d q = s.rotation * p + s.translation;
    const Eigen::Vector3d u1 = s.k * p, u2 = s.k * q;
    if (q.z() < 1.0) continue;
    const double x1 = u1.x() / u1.z(), y1 = u1.y() / u1.z(), x2 = u2.x() / u2.z(), y2 = u2.y() / u2.z();
    if (x1 < 0 || x1 > 640 || y1 < 0 || y1 > 480 || x2 < 0 || x2 > 640 || y2 < 0 || y2 > 480) continue;
    s.points.push_back(p);
  }
  return s;
}

void Observe(const Scene& s, double sigma_px, double outlier_ratio, std::mt19937& rng, std::vector<Eigen::Vector2d>* p1,
             std::vector<Eigen::Vector2d>* p2) {
  std::normal_distribution<double> noise(0.0, sigma_px);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  p1->clear();
  p2->clear();
  for (const Eigen::Vector3d& p : s.points) {
    const Eigen::Vector3d u1 = s.k * p, u2 = s.k * (s.rotation * p + s.translation);
    const Eigen::Vector2d e1 = DrawVector2(rng, noise);
    p1->emplace_back(u1.x() / u1.z() + e1.x(), u1.y() / u1.z() + e1.y());
    if (unit(rng) < outlier_ratio) {
      const Eigen::Vector2d o = DrawVector2(rng, unit);
      p2->emplace_back(640 * o.x(), 480 * o.y());
    } else {
      const Eigen::Vector2d e2 = DrawVector2(rng, noise);
      p2->emplace_back(u2.x() / u2.z() + e2.x(), u2.y() / u2.z() + e2.y());
    }
  }
}

// The pair's pose from the scene's points seen with pixel noise `sigma_px`
// and a share `outlier_ratio` of random correspondences.
RelativePoseResult EstimateOnScene(const Scene& s, double sigma_px, double outlier_ratio, std::mt19937& rng) {
  std::vector<Eigen::Vector2d> p1, p2;
  Observe(s, sigma_px, outlier_ratio, rng, &p1, &p2);
  return EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
}

// The refinement's closed-form derivative of the Sampson error against
// automatic differentiation of the same formula, on fundamental matrices of
// pixel scale and points near and far from their epipolar lines.
TEST(RelativePose, SampsonGradientMatchesAutomaticDerivatives) {
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> pixel(0.0, 640.0), entry(-1.0, 1.0);
  using Jet = ceres::Jet<double, 9>;
  for (int trial = 0; trial < 200; ++trial) {
    Eigen::Matrix3d f;
    for (int i = 0; i < 9; ++i) f.data()[i] = entry(rng) * (i % 3 == 2 || i >= 6 ? 1e-2 : 1e-5);
    const Eigen::Vector2d q1 = DrawVector2(rng, pixel);
    const Eigen::Vector2d q2 = DrawVector2(rng, pixel);
    const Eigen::Vector3d x1(q1.x(), q1.y(), 1.0), x2(q2.x(), q2.y(), 1.0);
    Eigen::Matrix<Jet, 3, 3> f_jet;
    for (int i = 0; i < 9; ++i) f_jet.data()[i] = Jet(f.data()[i], i);
    const Jet expected = SampsonError<Jet>(f_jet, x1.cast<Jet>(), x2.cast<Jet>());
    Eigen::Matrix3d gradient;
    const double r = SampsonErrorAndGradient(f, x1, x2, &gradient);
    EXPECT_NEAR(r, expected.a, 1e-9 * (1.0 + std::abs(expected.a)));
    const double scale = expected.v.cwiseAbs().maxCoeff();
    for (int i = 0; i < 9; ++i) EXPECT_NEAR(gradient.data()[i], expected.v[i], 1e-9 * scale) << "entry " << i;
  }
}

TEST(RelativePose, RecoversThePoseWithOutliers) {
  std::mt19937 rng(1);
  const Scene s = MakeScene(0.8, rng);
  const RelativePoseResult r = EstimateOnScene(s, 0.5, 0.2, rng);
  ASSERT_TRUE(r.success) << r.message;
  // Within three predicted standard deviations (this geometry, with its
  // rotation-translation ambiguity, gives about 0.15 deg at 0.5 px), and small.
  const double error = AngularDistanceRad(r.rotation, s.rotation);
  EXPECT_LT(error, 3.0 * std::sqrt(r.covariance.trace()));
  EXPECT_LT(RadToDeg(error), 0.5);
  EXPECT_LT(RadToDeg(std::acos(std::min(1.0, r.translation.dot(s.translation.normalized())))), 2.0);
  EXPECT_NEAR(r.sigma_px, 0.5, 0.1);  // the Sampson distance has one residual dimension: RMS sigma
  // 300 correspondences, about 60 replaced by random points: the true inliers
  // are kept and the random ones (a few may land near an epipolar line) not.
  EXPECT_GT(r.inliers.size(), 225u);
  EXPECT_LT(r.inliers.size(), 255u);
}

// Monte Carlo: over many noise draws, the pixel model's marginal covariance
// must predict the spread of the rotation estimates (e^T C^-1 e ~ chi2(3),
// mean 3); the conditional one (t held fixed) is never larger, so it is more
// confident. With independent noise the cell jackknife has nothing to add but
// its own sampling noise: the covariance with it, the larger of the two in
// every direction, stays close to the pixel model's.
TEST(RelativePose, MarginalCovariancePredictsTheSpreadOfEstimates) {
  std::mt19937 rng(7);
  const Scene s = MakeScene(0.6, rng);
  std::vector<Eigen::Vector2d> p1, p2;
  RelativePoseOptions pixel_model, jackknife;  // the library's default, and rotavg images'
  jackknife.jackknife_grid = 4;
  double nees_marginal = 0.0, nees_conditional = 0.0, nees_jackknife = 0.0;
  Eigen::Matrix3d empirical = Eigen::Matrix3d::Zero(), predicted = Eigen::Matrix3d::Zero(),
                  predicted_jackknife = Eigen::Matrix3d::Zero();
  int runs = 0;
  for (int k = 0; k < 120; ++k) {
    Observe(s, 1.0, 0.0, rng, &p1, &p2);
    const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, pixel_model);
    const RelativePoseResult d = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, jackknife);
    ASSERT_TRUE(r.success) << r.message;
    ASSERT_TRUE(d.success) << d.message;
    EXPECT_LT(AngularDistanceRad(d.rotation, r.rotation), 1e-12);  // the jackknife changes no estimate
    const Eigen::Vector3d e = LogSO3(r.rotation * s.rotation.transpose());  // R = Exp(e) R_true
    nees_marginal += e.dot(r.covariance_marginal.ldlt().solve(e));
    nees_conditional += e.dot(r.covariance_conditional.ldlt().solve(e));
    nees_jackknife += e.dot(d.covariance.ldlt().solve(e));
    EXPECT_TRUE(d.covariance_conditional.isApprox(r.covariance_conditional));
    empirical += e * e.transpose();
    predicted += r.covariance_marginal;
    predicted_jackknife += d.covariance;
    ++runs;
  }
  nees_marginal /= runs;
  nees_conditional /= runs;
  nees_jackknife /= runs;
  EXPECT_GT(nees_marginal, 2.2);
  EXPECT_LT(nees_marginal, 3.9);
  EXPECT_GT(nees_conditional, nees_marginal);
  EXPECT_NEAR(empirical.trace() / predicted.trace(), 1.0, 0.35);
  EXPECT_LE(nees_jackknife, nees_marginal);
  EXPECT_GT(nees_jackknife, 1.5);
  EXPECT_LT(predicted_jackknife.trace() / predicted.trace(), 1.8);
}

// Errors shared by the matches of a region (a local bias of the keypoints, a
// group of wrong matches on a repeated structure that shift together) move
// the rotation more than the pixel model, which counts every residual as
// independent, predicts; leaving the region's cell out shows it. Each draw
// shifts the matches of each 80 x 80 px block of image 2 by its own Gaussian
// offset (0.4 px per coordinate), on top of 0.2 px of independent noise.
TEST(RelativePose, TheCellJackknifeCoversErrorsSharedByARegion) {
  std::mt19937 rng(21);
  const Scene s = MakeScene(0.6, rng);
  std::normal_distribution<double> block_noise(0.0, 0.4);
  std::vector<Eigen::Vector2d> p1, p2;
  RelativePoseOptions pixel_model, jackknife;
  jackknife.jackknife_grid = 4;
  std::vector<double> nees_pixel, nees_jackknife;
  for (int k = 0; k < 80; ++k) {
    Observe(s, 0.2, 0.0, rng, &p1, &p2);
    std::vector<Eigen::Vector2d> offsets(8 * 6);
    for (Eigen::Vector2d& o : offsets) o = DrawVector2(rng, block_noise);
    for (Eigen::Vector2d& p : p2) {
      const int bx = std::clamp(static_cast<int>(p.x() / 80.0), 0, 7), by = std::clamp(static_cast<int>(p.y() / 80.0), 0, 5);
      p += offsets[by * 8 + bx];
    }
    const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, pixel_model);
    const RelativePoseResult d = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, jackknife);
    ASSERT_TRUE(r.success && d.success);
    const Eigen::Vector3d e = LogSO3(d.rotation * s.rotation.transpose());
    nees_pixel.push_back(e.dot(r.covariance.ldlt().solve(e)));
    nees_jackknife.push_back(e.dot(d.covariance.ldlt().solve(e)));
  }
  const auto share_within = [](const std::vector<double>& nees) {  // chi2(3) 95% quantile
    return std::count_if(nees.begin(), nees.end(), [](double v) { return v < 7.815; }) / double(nees.size());
  };
  const auto median = [](std::vector<double> v) {
    std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
    return v[v.size() / 2];
  };
  RecordProperty("median_nees_pixel", std::to_string(median(nees_pixel)));
  RecordProperty("median_nees_jackknife", std::to_string(median(nees_jackknife)));
  RecordProperty("within_pixel", std::to_string(share_within(nees_pixel)));
  RecordProperty("within_jackknife", std::to_string(share_within(nees_jackknife)));
  // The pixel model is far too confident (calibrated: median 2.37, 95%
  // within); with the jackknife the median is within 1.5-6 and most pairs
  // are covered. Blocks that straddle two cells leave some correlation
  // between cells, which no cell's removal shows.
  EXPECT_GT(median(nees_pixel), 6.0);
  EXPECT_LT(share_within(nees_pixel), 0.6);
  EXPECT_GT(median(nees_jackknife), 1.5);
  EXPECT_LT(median(nees_jackknife), 6.0);
  EXPECT_GT(share_within(nees_jackknife), 0.75);
}

TEST(RelativePose, NearPlanarScenesAreReportedAndOptionallyRejected) {
  std::mt19937 rng(11);
  Scene s = MakeScene(0.8, rng);
  for (Eigen::Vector3d& p : s.points) p.z() = 5.0 + 0.1 * p.x();  // a (slanted) plane
  std::vector<Eigen::Vector2d> p1, p2;
  Observe(s, 0.3, 0.0, rng, &p1, &p2);
  const RelativePoseResult kept = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
  EXPECT_GE(kept.homography_inlier_ratio, 0.95);
  RelativePoseOptions strict;
  strict.max_homography_inlier_ratio = 0.8;
  const RelativePoseResult rejected = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, strict);
  EXPECT_FALSE(rejected.success);
  EXPECT_EQ(rejected.failure, TwoViewFailure::kNearPlanar);
  // A general scene is not flagged.
  std::mt19937 rng2(12);
  const Scene general = MakeScene(0.8, rng2);
  Observe(general, 0.3, 0.0, rng2, &p1, &p2);
  EXPECT_LT(EstimateRelativePoseWithCovariance(p1, p2, general.k, general.k).homography_inlier_ratio, 0.5);
}

TEST(RelativePose, DegenerateInputsFailWithAReason) {
  std::mt19937 rng(3);
  Scene s = MakeScene(0.8, rng);
  std::vector<Eigen::Vector2d> p1, p2;
  Observe(s, 0.5, 0.0, rng, &p1, &p2);
  // Too few correspondences.
  std::vector<Eigen::Vector2d> few1(p1.begin(), p1.begin() + 10), few2(p2.begin(), p2.begin() + 10);
  EXPECT_EQ(EstimateRelativePoseWithCovariance(few1, few2, s.k, s.k).failure, TwoViewFailure::kTooFewMatches);
  // Pure rotation without the rotation-only model: no parallax.
  s.translation.setZero();
  Observe(s, 0.3, 0.0, rng, &p1, &p2);
  RelativePoseOptions essential_only;
  essential_only.rotation_model = false;
  const RelativePoseResult pure = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k, essential_only);
  EXPECT_FALSE(pure.success);
  EXPECT_TRUE(pure.failure == TwoViewFailure::kPureRotation || pure.failure == TwoViewFailure::kTooFewInliers ||
              pure.failure == TwoViewFailure::kSingularInformation)
      << TwoViewFailureName(pure.failure);
  // Pure noise: no consistent geometry.
  std::uniform_real_distribution<double> u(0.0, 480.0);
  for (auto& p : p2) p = DrawVector2(rng, u);
  EXPECT_FALSE(EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k).success);
  // Input that cannot be a pair of views is refused as such, with the reason.
  p2.pop_back();
  RelativePoseResult invalid = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
  EXPECT_EQ(invalid.failure, TwoViewFailure::kInvalidInput);
  EXPECT_NE(invalid.message.find("differ in length"), std::string::npos) << invalid.message;
  p2.push_back(p2.back());
  EXPECT_EQ(EstimateRelativePoseWithCovariance(p1, p2, Eigen::Matrix3d::Zero(), s.k).failure,
            TwoViewFailure::kInvalidInput);
  Eigen::Matrix3d projective = s.k;
  projective(2, 0) = 1e-3;
  EXPECT_EQ(EstimateRelativePoseWithCovariance(p1, p2, s.k, projective).failure, TwoViewFailure::kInvalidInput);
  Observe(s, 0.3, 0.0, rng, &p1, &p2);
  p1[7].x() = std::numeric_limits<double>::quiet_NaN();
  invalid = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
  EXPECT_EQ(invalid.failure, TwoViewFailure::kInvalidInput);
  EXPECT_NE(invalid.message.find("correspondence 7"), std::string::npos) << invalid.message;
  p1[7].x() = std::numeric_limits<double>::infinity();
  EXPECT_EQ(EstimateRelativePoseWithCovariance(p2, p1, s.k, s.k).failure, TwoViewFailure::kInvalidInput);
  EXPECT_STREQ(TwoViewFailureName(TwoViewFailure::kInvalidInput), "invalid_input");
}

// A camera that turned on the spot: the essential matrix has no translation to
// find, the rotation-only model holds and wins the model selection, with a
// covariance that predicts its error.
TEST(RelativePose, PureRotationIsEstimatedByTheRotationModel) {
  std::mt19937 rng(21);
  Scene s = MakeScene(0.8, rng);
  s.translation.setZero();
  double nees = 0.0;
  const int runs = 40;
  for (int run = 0; run < runs; ++run) {
    std::vector<Eigen::Vector2d> p1, p2;
    Observe(s, 0.5, 0.2, rng, &p1, &p2);
    const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
    ASSERT_TRUE(r.success) << r.message;
    ASSERT_EQ(r.model, TwoViewModel::kRotation) << "run " << run;
    EXPECT_LT(RadToDeg(AngularDistanceRad(r.rotation, s.rotation)), 0.05);
    EXPECT_TRUE(r.translation.isZero());
    EXPECT_NEAR(r.sigma_px, 0.5, 0.1);  // per image, as for the essential model
    EXPECT_GT(r.inliers.size(), 200u);  // of the 240 or so that are not outliers
    const Eigen::Vector3d e = LogSO3(r.rotation * s.rotation.transpose());
    nees += e.dot(r.covariance.inverse() * e);
  }
  nees /= runs;
  EXPECT_GT(nees, 1.5);  // 3 for a calibrated covariance
  EXPECT_LT(nees, 5.0);
}

// With parallax the general model wins, even where a homography explains
// most of the points (a slanted plane).
TEST(RelativePose, ParallaxKeepsTheEssentialModel) {
  for (const bool planar : {false, true}) {
    std::mt19937 rng(22);
    Scene s = MakeScene(0.8, rng);
    if (planar) {
      for (Eigen::Vector3d& p : s.points) p.z() = 5.0 + 0.1 * p.x();
    }
    std::vector<Eigen::Vector2d> p1, p2;
    Observe(s, 0.3, 0.1, rng, &p1, &p2);
    const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
    ASSERT_TRUE(r.success) << r.message;
    EXPECT_EQ(r.model, TwoViewModel::kEssential) << "planar " << planar;
    EXPECT_LT(RadToDeg(AngularDistanceRad(r.rotation, s.rotation)), 0.5);
    if (planar) {
      // Both models were fitted and scored; the general one scored lower.
      ASSERT_TRUE(std::isfinite(r.gric_essential) && std::isfinite(r.gric_rotation));
      EXPECT_LT(r.gric_essential, r.gric_rotation);
    }
  }
}

// A short step in front of distant structure: every point lies 67-133
// baselines away, beyond the 50 within which the pose's cheirality counts
// a point first (the limit that rejects a plane's twisted-pair solution).
// The pair is then decided with its far points: its pose, its translation's
// sign and nearly all of its correspondences.
TEST(RelativePose, AShortBaselinePairIsDecidedWithItsFarPoints) {
  std::mt19937 rng(31);
  const Scene s = MakeScene(0.06, rng);
  const RelativePoseResult r = EstimateOnScene(s, 0.2, 0.0, rng);
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_EQ(r.model, TwoViewModel::kEssential);
  EXPECT_LT(RadToDeg(AngularDistanceRad(r.rotation, s.rotation)), 0.2);
  EXPECT_LT(RadToDeg(std::acos(std::min(1.0, r.translation.dot(s.translation.normalized())))), 10.0);
  EXPECT_GT(r.inliers.size(), 270u);
}

// Sideways steps along an arc, as a camera passes an object: the rotation
// about the vertical axis and the sideways translation are nearly
// interchangeable for such pairs (the rotation-translation valley). A robust
// model off along that valley can have its points in front only with the
// mirrored translation; the Sampson refinement, blind to the sign of t, then
// brings R back with t mirrored. Every pair must still give its pose, with
// the translation's true sign.
TEST(RelativePose, SidewaysPairsGiveTheirPoseWhateverSignTheRobustModelHad) {
  std::mt19937 rng(31);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_real_distribution<double> x(-3.0, 3.0), y(-2.0, 2.0), z(5.0, 10.0);
  int failed = 0, pairs = 0;
  double worst_deg = 0.0, worst_sign = 1.0;
  for (; pairs < 150; ++pairs) {
    Scene s;
    s.k << 500, 0, 320, 0, 500, 240, 0, 0, 1;
    const Eigen::Vector3d jitter = DegToRad(1.5) * DrawVector3(rng, normal).normalized();
    s.rotation = ExpSO3(Eigen::Vector3d(0.0, DegToRad(-6.0), 0.0)) * ExpSO3(jitter);
    const Eigen::Vector3d step(0.31, 0.3 * normal(rng), 0.0);  // centre of camera 2 in camera 1
    s.translation = -s.rotation * step;
    while (s.points.size() < 400) {
      const Eigen::Vector3d p = DrawVector3(rng, x, y, z), q = s.rotation * p + s.translation;
      const Eigen::Vector3d u1 = s.k * p, u2 = s.k * q;
      const Eigen::Vector2d a = u1.hnormalized(), b = u2.hnormalized();
      if (q.z() > 1.0 && a.minCoeff() >= 0 && a.x() < 640 && a.y() < 480 && b.minCoeff() >= 0 && b.x() < 640 &&
          b.y() < 480) {
        s.points.push_back(p);
      }
    }
    std::vector<Eigen::Vector2d> p1, p2;
    Observe(s, 0.5, 0.1, rng, &p1, &p2);
    const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
    if (!r.success) {
      ++failed;
      ADD_FAILURE() << "pair " << pairs << ": " << TwoViewFailureName(r.failure) << " (" << r.message << ")";
      continue;
    }
    worst_deg = std::max(worst_deg, RadToDeg(AngularDistanceRad(r.rotation, s.rotation)));
    worst_sign = std::min(worst_sign, r.translation.dot(s.translation.normalized()));
  }
  EXPECT_EQ(failed, 0) << "of " << pairs;
  EXPECT_LT(worst_deg, 0.5);
  EXPECT_GT(worst_sign, 0.99);
}

// A translation far below what the points' depths can reveal: the rotation
// model is chosen, and its rotation is as good as the essential matrix's.
TEST(RelativePose, NearPureRotationChoosesTheRotationModel) {
  std::mt19937 rng(23);
  Scene s = MakeScene(0.002, rng);  // 2 mm against depths of 4-8 m: 0.1 px of parallax
  std::vector<Eigen::Vector2d> p1, p2;
  Observe(s, 0.5, 0.1, rng, &p1, &p2);
  const RelativePoseResult r = EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k);
  ASSERT_TRUE(r.success) << r.message;
  EXPECT_EQ(r.model, TwoViewModel::kRotation);
  EXPECT_LT(RadToDeg(AngularDistanceRad(r.rotation, s.rotation)), 0.05);
}

TEST(RelativePose, RotationModelRejectsNoise) {
  std::mt19937 rng(24);
  Scene s = MakeScene(0.0, rng);
  std::vector<Eigen::Vector2d> p1, p2;
  Observe(s, 0.5, 0.0, rng, &p1, &p2);
  std::uniform_real_distribution<double> u(0.0, 480.0);
  for (auto& p : p2) p = DrawVector2(rng, u);
  EXPECT_FALSE(EstimateRelativePoseWithCovariance(p1, p2, s.k, s.k).success);
}

}  // namespace
}  // namespace rotation_averaging
