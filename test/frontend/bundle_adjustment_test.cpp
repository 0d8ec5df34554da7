#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <iostream>
#include <map>
#include <random>
#include <set>
#include <string>
#include <vector>

#include "frontend/refinement_test_util.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

constexpr double kFocal = kArcSceneFocal;
using Scene = ArcScene;

Scene MakeScene(int views, double noise_px, std::uint32_t seed) { return MakeArcScene(views, noise_px, seed); }

TEST(BundleAdjustment, ExactWithoutNoiseAndCentresUpToScale) {
  const Scene scene = MakeScene(6, 0.0, 1);
  ViewOrientations orientations = Perturbed(scene.truth, 1.0, 2);
  BundleAdjustmentSummary summary;
  std::unordered_map<ViewId, Eigen::Vector3d> centres;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &orientations, &summary,
                                                  &centres))
      << summary.Report();
  EXPECT_LT(MaxErrorDeg(orientations, scene.truth), 1e-5) << summary.Report();
  EXPECT_EQ(summary.views, 6);
  EXPECT_EQ(summary.edges_used, 15);
  EXPECT_EQ(summary.tracks, 300);
  EXPECT_EQ(summary.observations, 6u * 300u);
  EXPECT_EQ(summary.observations_dropped, 0u);
  EXPECT_LT(summary.final_rms_sigmas, 1e-3);
  // The centres are the true ones in the frame of the estimate (view 0
  // fixed at the origin), up to one scale.
  ASSERT_EQ(centres.size(), 6u);
  const Eigen::Matrix3d align = orientations.at(0).transpose() * scene.truth.at(0);  // truth world -> estimate world
  const double scale = centres.at(5).norm() / (scene.centres[5] - scene.centres[0]).norm();
  for (int v = 0; v < 6; ++v) {
    const Eigen::Vector3d expected = scale * align * (scene.centres[v] - scene.centres[0]);
    EXPECT_LT((centres.at(v) - expected).norm(), 1e-5 * scale) << v;
  }
}

TEST(BundleAdjustment, TracksPinRotationsBetterThanThePairsAlone) {
  // Half a pixel of noise. Each pair's own translation direction lets the
  // pairwise refinement trade rotation for translation; shared centres and
  // points do not.
  double adjusted_sum = 0.0, pairwise_sum = 0.0;
  for (std::uint32_t seed = 1; seed <= 3; ++seed) {
    const Scene scene = MakeScene(8, 0.5, seed);
    ViewOrientations adjusted = Perturbed(scene.truth, 0.5, 10 + seed);
    ViewOrientations pairwise = adjusted;
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &adjusted, &summary))
        << summary.Report();
    CorrespondenceRefinementSummary refinement;
    ASSERT_TRUE(
        RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &pairwise, &refinement));
    // Whitened by the true noise, the residuals are about one sigma.
    EXPECT_NEAR(summary.final_rms_sigmas, 1.0, 0.15) << summary.Report();
    EXPECT_EQ(summary.observations_dropped, 0u) << summary.Report();
    EXPECT_EQ(summary.failed_steps, 0) << summary.Report();
    EXPECT_LT(MaxErrorDeg(adjusted, scene.truth), MaxErrorDeg(pairwise, scene.truth)) << summary.Report();
    // The minimum it reaches is the one at the truth.
    ViewOrientations from_truth = scene.truth;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &from_truth, &summary));
    EXPECT_LT(MaxErrorDeg(adjusted, from_truth), 1e-3);
    adjusted_sum += MaxErrorDeg(adjusted, scene.truth);
    pairwise_sum += MaxErrorDeg(pairwise, scene.truth);
  }
  EXPECT_LT(adjusted_sum, 0.7 * pairwise_sum) << adjusted_sum << " vs " << pairwise_sum;
}

TEST(BundleAdjustmentSummary, TheReportTellsOfFailedStepsOnlyWhereThereWereAny) {
  BundleAdjustmentSummary summary;
  summary.iterations = 40;
  EXPECT_NE(summary.Report().find("40 iterations, "), std::string::npos) << summary.Report();
  EXPECT_EQ(summary.Report().find("failed"), std::string::npos) << summary.Report();
  summary.failed_steps = 21;
  EXPECT_NE(summary.Report().find("40 iterations (21 failed steps), "), std::string::npos) << summary.Report();
}

TEST(BundleAdjustment, StartedFromAnEarlierAdjustmentsCentresItSettlesSooner) {
  const Scene scene = MakeScene(10, 0.5, 4);
  ViewOrientations cold = Perturbed(scene.truth, 0.3, 5);
  BundleAdjustmentSummary first;
  std::unordered_map<ViewId, Eigen::Vector3d> centres;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &cold, &first, &centres))
      << first.Report();
  // The same views again from the adjusted orientations and centres: it
  // starts at the minimum.
  ViewOrientations warm = cold;
  BundleAdjustmentSummary second;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &warm, &second, nullptr,
                                                  nullptr, nullptr, &centres))
      << second.Report();
  EXPECT_TRUE(second.converged) << second.Report();
  EXPECT_GT(first.initial_rms_sigmas, 10.0) << first.Report();
  EXPECT_LT(second.initial_rms_sigmas, 1.5) << second.Report();
  EXPECT_LT(second.iterations, first.iterations / 2) << first.Report() << "\n" << second.Report();
  EXPECT_LT(MaxErrorDeg(warm, cold), 1e-4);
  // Less one view's centre (a keyframe added since): that one is placed
  // among the others, which keep the frame and the scale they had (the
  // gauge is of views whose centres were given).
  std::unordered_map<ViewId, Eigen::Vector3d> start = centres;
  start.erase(9);
  ViewOrientations added = cold;
  std::unordered_map<ViewId, Eigen::Vector3d> after;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &added, &second, &after,
                                                  nullptr, nullptr, &start))
      << second.Report();
  EXPECT_TRUE(second.converged) << second.Report();
  EXPECT_LT(MaxErrorDeg(added, cold), 1e-4);
  for (const auto& [id, c] : centres) EXPECT_LT((after.at(id) - c).norm(), 1e-3 * c.norm() + 1e-6) << id;
}

TEST(BundleAdjustment, AFirstViewNextToTheSecondDoesNotHoldTheScale) {
  // View 1 a hundredth of the arc's spacing from view 0 (the camera turned
  // almost in place): the scale is held by the view farthest from view 0,
  // and the adjustment settles within the node's 20 iterations per stage.
  Scene scene = MakeScene(10, 0.5, 6);
  std::mt19937 rng(7);
  std::normal_distribution<double> noise(0.0, 0.5 / kFocal);
  scene.centres[1] = scene.centres[0] + 0.01 * (scene.centres[2] - scene.centres[0]);
  for (std::size_t p = 0; p < scene.points.size(); ++p) {
    scene.keypoints[1][p] = (scene.truth.at(1) * (scene.points[p] - scene.centres[1])).hnormalized() +
                            Eigen::Vector2d(noise(rng), noise(rng));
  }
  scene.edges.clear();
  AddSceneEdges(0.5, {}, 0, &scene);
  BundleAdjustmentOptions options;
  options.max_iterations = 20;
  ViewOrientations adjusted = Perturbed(scene.truth, 0.3, 8);
  BundleAdjustmentSummary summary;
  std::unordered_map<ViewId, Eigen::Vector3d> centres;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, options, &adjusted, &summary, &centres))
      << summary.Report();
  EXPECT_TRUE(summary.converged) << summary.Report();
  EXPECT_NEAR(summary.final_rms_sigmas, 1.0, 0.15) << summary.Report();
  ViewOrientations from_truth = scene.truth;
  BundleAdjustmentSummary reference;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &from_truth, &reference));
  EXPECT_LT(MaxErrorDeg(adjusted, from_truth), 1e-3) << summary.Report();
}

// `covariance` without its jackknives: Relative gives the pixel model's alone.
BundleAdjustmentCovariance PixelModelAlone(const BundleAdjustmentCovariance& covariance) {
  BundleAdjustmentCovariance pixel = covariance;
  pixel.jackknife.resize(0, 0);
  pixel.track_jackknife.resize(0, 0);
  return pixel;
}

// NEES of every view but view 0 relative to it, d = Log(R_hat_v R_hat_0^T R_0
// R_v^T), against `covariance` (Relative, or the pixel model's alone).
std::vector<double> NeesRelativeToViewZero(const ViewOrientations& estimate, const ViewOrientations& truth,
                                           const BundleAdjustmentCovariance& covariance, bool pixel_model_alone) {
  std::vector<double> out;
  const BundleAdjustmentCovariance pixel = pixel_model_alone ? PixelModelAlone(covariance) : covariance;
  for (const auto& [v, r] : estimate) {
    if (v == 0) continue;
    Eigen::Matrix3d c;
    if (!covariance.Relative(v, 0, &c)) continue;
    if (pixel_model_alone) EXPECT_TRUE(pixel.Relative(v, 0, &c));
    const Eigen::Vector3d d = LogSO3(r * estimate.at(0).transpose() * truth.at(0) * truth.at(v).transpose());
    out.push_back(d.dot(c.ldlt().solve(d)));
  }
  return out;
}

// Adjusts `scene` from `adjusted` with the default options, its orientations'
// covariance asked for.
testing::AssertionResult AdjustedWithCovariance(const Scene& scene, ViewOrientations* adjusted,
                                                BundleAdjustmentCovariance* covariance) {
  BundleAdjustmentSummary summary;
  if (RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), adjusted, &summary, nullptr,
                                          covariance)) {
    return testing::AssertionSuccess();
  }
  return testing::AssertionFailure() << summary.Report();
}

double Mean(const std::vector<double>& values) {
  double sum = 0.0;
  for (double v : values) sum += v;
  return values.empty() ? 0.0 : sum / values.size();
}

TEST(BundleAdjustmentCovariance, CalibratedOnIndependentPixelNoise) {
  // Half a pixel of Gaussian noise, as the edges' sigma says: the pixel
  // model's NEES is chi-square with 3 degrees of freedom (mean 3), and the
  // jackknife, which only ever widens it, does little (its estimate is
  // unbiased here, but from 9 cells a view a noisy one, and the larger of the
  // two in every direction is wider than either).
  std::vector<double> pixel, both;
  for (std::uint32_t seed = 1; seed <= 30; ++seed) {
    const Scene scene = MakeScene(6, 0.5, seed);
    ViewOrientations adjusted = Perturbed(scene.truth, 0.3, 100 + seed);
    BundleAdjustmentCovariance covariance;
    ASSERT_TRUE(AdjustedWithCovariance(scene, &adjusted, &covariance));
    ASSERT_EQ(covariance.index.size(), 6u);
    EXPECT_NEAR(covariance.variance_factor, 1.0, 0.15);
    EXPECT_GE(covariance.cells, 6 * 8);  // 3 x 3 (the default) of each view's
    EXPECT_LE(covariance.cells, 6 * 9);
    Eigen::Matrix3d zero;
    ASSERT_TRUE(covariance.Relative(3, 3, &zero));
    EXPECT_EQ(zero, Eigen::Matrix3d::Zero());
    EXPECT_FALSE(covariance.Relative(3, 17, &zero));
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, true)) pixel.push_back(n);
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, false)) both.push_back(n);
  }
  std::cout << "mean NEES: pixel model " << Mean(pixel) << ", with the jackknife " << Mean(both) << "\n";
  ASSERT_EQ(pixel.size(), 150u);
  EXPECT_GT(Mean(pixel), 2.4);
  EXPECT_LT(Mean(pixel), 3.6);
  EXPECT_LE(Mean(both), Mean(pixel) + 1e-12);
  EXPECT_GT(Mean(both), 0.75 * Mean(pixel));
}

TEST(BundleAdjustmentCovariance, TheJackknifesBreadIsTheRobustCostsHessian) {
  // The jackknives' moves are scaled by sum w / sum w^2 of Cauchy's weights
  // (the normal equations' information over the robust cost's expected
  // Hessian): 1.17 for Gaussian noise at the edges' sigma with the loss at 3
  // sigma (E[w] 0.84, E[w^2] 0.72 over chi-square with 2 degrees of
  // freedom; the fitted residuals are a little shorter: 1.12 here). With
  // the edges' sigma five times the noise the weights are all near one, and
  // so is it.
  std::vector<double> ratios, unbread;
  for (std::uint32_t seed = 1; seed <= 12; ++seed) {
    const Scene scene = MakeScene(6, 0.5, seed);
    Scene wide = scene;
    for (EdgeCorrespondences& e : wide.edges) e.sigma *= 5.0;
    // Both from the same start.
    const auto adjust = [&](const Scene& edges_of, BundleAdjustmentCovariance* covariance) {
      ViewOrientations adjusted = Perturbed(scene.truth, 0.3, 100 + seed);
      return AdjustedWithCovariance(edges_of, &adjusted, covariance);
    };
    BundleAdjustmentCovariance as_said, looser;
    ASSERT_TRUE(adjust(scene, &as_said));
    ASSERT_TRUE(adjust(wide, &looser));
    EXPECT_GT(as_said.jackknife_bread, 1.10) << "seed " << seed;
    EXPECT_LT(as_said.jackknife_bread, 1.20) << "seed " << seed;
    EXPECT_GT(looser.jackknife_bread, 1.0);
    EXPECT_LT(looser.jackknife_bread, 1.01) << "seed " << seed;
    // The same data: with weights near one the jackknife is least
    // squares'. Cauchy's, its moves lengthened by the bread, is as wide
    // (wider by the loss' lost efficiency, 1.035 in variance at 3 sigma);
    // without the bread it was a quarter narrower.
    ASSERT_EQ(as_said.jackknife.rows(), looser.jackknife.rows());
    const double ratio = as_said.jackknife.trace() / looser.jackknife.trace();
    std::cout << "seed " << seed << ": bread " << as_said.jackknife_bread << " (" << looser.jackknife_bread
              << " with sigma x5), cell jackknife's trace over least squares' " << ratio << "\n";
    EXPECT_GT(ratio, 0.9) << "seed " << seed;
    EXPECT_LT(ratio, 1.15) << "seed " << seed;
    ratios.push_back(ratio);
    unbread.push_back(ratio / std::pow(as_said.jackknife_bread, 2));
  }
  std::cout << "mean ratio " << Mean(ratios) << ", without the bread " << Mean(unbread) << "\n";
  EXPECT_GT(Mean(ratios), 0.98);
  EXPECT_LT(Mean(ratios), 1.08);
  EXPECT_LT(Mean(unbread), 0.85);
}

TEST(BundleAdjustment, HeldViewsKeepTheirOrientationsAndHoldTheFrame) {
  // Views 0 and 1 held at the truth (the keyframes before a window, as
  // published), the others a degree off: without noise every view comes
  // back to the truth in the held views' frame, not only relative to view 0.
  // With half a pixel, the covariance is of the problem in which the held
  // views turn (they are estimates too): relative to view 0 it describes
  // every view, the held one included, and the views the hold pins better
  // than that are within it.
  const std::set<ViewId> held = {0, 1};
  {
    const Scene scene = MakeScene(8, 0.0, 3);
    ViewOrientations orientations = Perturbed(scene.truth, 1.0, 4);
    orientations[0] = scene.truth.at(0);
    orientations[1] = scene.truth.at(1);
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &orientations, &summary,
                                                    nullptr, nullptr, nullptr, nullptr, nullptr, &held))
        << summary.Report();
    EXPECT_EQ(summary.views_held, 2);
    EXPECT_NE(summary.Report().find("8 views (2 held)"), std::string::npos) << summary.Report();
    EXPECT_EQ(orientations.at(0), scene.truth.at(0));
    EXPECT_EQ(orientations.at(1), scene.truth.at(1));
    for (const auto& [v, r] : scene.truth) {
      EXPECT_LT(RadToDeg(RotationAngleRad(orientations.at(v) * r.transpose())), 1e-5) << v;
    }
  }
  std::vector<double> pixel;
  for (std::uint32_t seed = 1; seed <= 30; ++seed) {
    const Scene scene = MakeScene(8, 0.5, seed);
    ViewOrientations adjusted = Perturbed(scene.truth, 0.3, 100 + seed);
    adjusted[0] = scene.truth.at(0);
    adjusted[1] = scene.truth.at(1);
    BundleAdjustmentSummary summary;
    BundleAdjustmentCovariance covariance;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &adjusted, &summary,
                                                    nullptr, &covariance, nullptr, nullptr, nullptr, &held))
        << summary.Report();
    Eigen::Matrix3d between;
    ASSERT_TRUE(covariance.Relative(1, 0, &between));
    EXPECT_GT(between.trace(), 0.0);  // as if view 1 turned
    const std::vector<double> nees = NeesRelativeToViewZero(adjusted, scene.truth, covariance, true);
    ASSERT_EQ(nees.size(), 7u);
    pixel.insert(pixel.end(), nees.begin() + 1, nees.end());
  }
  std::cout << "mean NEES of the pixel model, relative to view 0: " << Mean(pixel) << "\n";
  EXPECT_GT(Mean(pixel), 1.0);
  EXPECT_LT(Mean(pixel), 3.3);
}

TEST(BundleAdjustmentCovariance, TheJackknifeWidensWhatARegionOfAnImageShares) {
  // Each view's keypoints in each cell of a 4 x 4 grid over them share an
  // offset of 0.1 px (a local bias the pixel model counts as
  // independent noise), on top of a tenth of a pixel of independent noise.
  std::vector<double> pixel, both;
  for (std::uint32_t seed = 1; seed <= 20; ++seed) {
    Scene scene = MakeScene(6, 0.1, seed);
    std::mt19937 rng(1000 + seed);
    std::normal_distribution<double> bias(0.0, 0.1 / kFocal);
    std::vector<std::vector<Eigen::Vector2d>> offsets(6);
    std::vector<Eigen::Vector2d> lo(6, Eigen::Vector2d::Constant(INFINITY)), hi(6, -lo[0]);
    for (int v = 0; v < 6; ++v) {
      for (int q = 0; q < 16; ++q) offsets[v].push_back(DrawVector2(rng, bias));
      for (const Eigen::Vector2d& x : scene.keypoints[v]) {
        lo[v] = lo[v].cwiseMin(x);
        hi[v] = hi[v].cwiseMax(x);
      }
    }
    const auto shifted = [&](ViewId v, const Eigen::Vector2d& x) {
      const Eigen::Vector2d f = (x - lo[v]).cwiseQuotient(hi[v] - lo[v]) * 4.0;
      return x + offsets[v][std::clamp(static_cast<int>(f.y()), 0, 3) * 4 + std::clamp(static_cast<int>(f.x()), 0, 3)];
    };
    for (EdgeCorrespondences& e : scene.edges) {
      for (Eigen::Vector2d& x : e.points1) x = shifted(e.view1, x);
      for (Eigen::Vector2d& x : e.points2) x = shifted(e.view2, x);
    }
    ViewOrientations adjusted = Perturbed(scene.truth, 0.3, 100 + seed);
    BundleAdjustmentSummary summary;
    BundleAdjustmentCovariance covariance;
    BundleAdjustmentOptions options;
    options.covariance_cell_grid = 4;  // the cells of the offsets
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, options, &adjusted, &summary, nullptr, &covariance))
        << summary.Report();
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, true)) pixel.push_back(n);
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, false)) both.push_back(n);
  }
  // The pixel model is over-confident (mean NEES about 18 here); the cell
  // jackknife takes it to about 8 (its leverage correction takes each cell's
  // leverage on its own view with the others held, and so undercorrects),
  // with the track clusters' (the tracks that start in one cell share its
  // offset in their first view) to about 7.
  std::cout << "mean NEES: pixel model " << Mean(pixel) << ", with the jackknife " << Mean(both) << "\n";
  EXPECT_GT(Mean(pixel), 10.0);
  EXPECT_GT(Mean(both), 2.0);
  EXPECT_LT(Mean(both), 0.6 * Mean(pixel));
}

// Cameras along a corridor, every 0.4 m past a wall of points 4-8 m away,
// each seeing the points within its field of view: a long window whose
// tracks span a dozen views, as a refinement's windows over a stream do.
// With `drift_px`, each point's keypoints also walk from view to view by
// steps of that deviation, as a tracker's drift along a track.
Scene MakeCorridorScene(int views, double noise_px, std::uint32_t seed, double drift_px = 0.0) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px / kFocal);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  Scene scene;
  const double length = 0.4 * (views - 1);
  for (int k = 0; k < 60 * views; ++k) {
    const Eigen::Vector3d d = DrawVector3(rng, u);
    scene.points.emplace_back(0.5 * length + (0.5 * length + 4.0) * d.x(), 2.0 * d.y(), 6.0 + 2.0 * d.z());
  }
  std::vector<std::vector<bool>> visible;
  for (int v = 0; v < views; ++v) {
    const Eigen::Vector3d centre(0.4 * v, 0.1 * u(rng), 0.1 * u(rng));
    const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(DegToRad(3.0) * u(rng), DegToRad(3.0) * u(rng), DegToRad(3.0) * u(rng)));
    ObservePoints(r, centre, 1.0, 0.5, &noise, &rng, &scene, &visible);
  }
  if (drift_px > 0.0) {
    std::normal_distribution<double> step(0.0, drift_px / kFocal);
    std::vector<Eigen::Vector2d> walk(scene.points.size(), Eigen::Vector2d::Zero());
    for (int v = 0; v < views; ++v) {
      for (std::size_t p = 0; p < walk.size(); ++p) {
        walk[p] += DrawVector2(rng, step);
        scene.keypoints[v][p] += walk[p];
      }
    }
  }
  AddSceneEdges(noise_px, visible, 30, &scene);
  return scene;
}

TEST(BundleAdjustmentCovariance, TheJackknifeStaysWithThePixelModelAlongALongWindowOfIndependentNoise) {
  // Independent pixel noise, as the edges' sigma says, along a corridor of 30
  // views: the jackknife estimates the pixel model's covariance, the same at
  // the window's far end as near its held view. Its leverage correction
  // widens each cell's score on its own view; the same corrected residuals
  // pull the other views that see the cell's points, or the cell pushes the
  // whole window about its held view, and the far end's deviation grows
  // with the window's length (over seven times the pixel model's here).
  std::vector<double> ratio, both;
  for (std::uint32_t seed = 1; seed <= 6; ++seed) {
    const Scene scene = MakeCorridorScene(30, 0.5, seed);
    ViewOrientations adjusted = Perturbed(scene.truth, 0.2, 100 + seed);
    BundleAdjustmentCovariance covariance;
    ASSERT_TRUE(AdjustedWithCovariance(scene, &adjusted, &covariance));
    ASSERT_EQ(covariance.index.size(), 30u);
    Eigen::Matrix3d with_jackknife, pixel_model;
    ASSERT_TRUE(covariance.Relative(29, 0, &with_jackknife));
    ASSERT_TRUE(PixelModelAlone(covariance).Relative(29, 0, &pixel_model));
    ratio.push_back(std::sqrt(with_jackknife.trace() / pixel_model.trace()));
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, false)) both.push_back(n);
  }
  std::cout << "deviation at the far end, with the jackknife / the pixel model's: mean " << Mean(ratio)
            << "; mean NEES with the jackknife " << Mean(both) << "\n";
  EXPECT_LT(Mean(ratio), 1.5);
  EXPECT_GT(Mean(both), 1.5);
}

TEST(BundleAdjustmentCovariance, TheTrackJackknifeWidensWhatATrackCarriesAlongIt) {
  // Along the corridor, each point's keypoints drift from view to view by
  // 0.1 px steps, on top of 0.1 px of independent noise: errors that a
  // point's observations share across the views of its track, which the
  // pixel model and the cells (each a region of one view) count as
  // independent. The jackknife over clusters of whole tracks sees them.
  // (Not all of them: under least squares, a loss scale of 30 sigma, it
  // halves the pixel model's NEES; at Cauchy's 3 sigma, with its bread,
  // it takes four tenths off.)
  std::vector<double> pixel, cells, both;
  for (std::uint32_t seed = 1; seed <= 8; ++seed) {
    const Scene scene = MakeCorridorScene(16, 0.1, seed, 0.1);
    ViewOrientations adjusted = Perturbed(scene.truth, 0.2, 100 + seed);
    BundleAdjustmentCovariance covariance;
    ASSERT_TRUE(AdjustedWithCovariance(scene, &adjusted, &covariance));
    // Most tracks start in the first view or at the side of the image the
    // points come in from: a few clusters a view.
    EXPECT_GE(covariance.track_clusters, 2 * 16);
    EXPECT_LE(covariance.track_clusters, covariance.cells);
    BundleAdjustmentCovariance cells_alone = covariance;
    cells_alone.track_jackknife.resize(0, 0);
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, true)) pixel.push_back(n);
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, cells_alone, false)) cells.push_back(n);
    for (double n : NeesRelativeToViewZero(adjusted, scene.truth, covariance, false)) both.push_back(n);
  }
  std::cout << "mean NEES: pixel model " << Mean(pixel) << ", with the cells " << Mean(cells)
            << ", with the cells and the tracks " << Mean(both) << "\n";
  // About 6.3, 6.0 and 3.7.
  EXPECT_GT(Mean(cells), 0.95 * Mean(pixel));
  EXPECT_GT(Mean(cells), 5.0);
  EXPECT_LT(Mean(both), 0.85 * Mean(cells));
  EXPECT_GT(Mean(both), 3.0);
}

// Every view of a MakeRigScene as its capture's camera.
BundleAdjustmentRig TwoCameraRig(const Scene& scene) {
  BundleAdjustmentRig rig;
  for (const auto& [v, r] : scene.truth) {
    rig.views[v] = {static_cast<std::int64_t>(v / 2), v % 2 ? RigCameraFromRig() : Eigen::Matrix3d::Identity()};
  }
  return rig;
}

// RMS angle (deg) of camera 0's views relative to view 0 against the truth:
// what the adjustment determines with or without the rig.
double FirstCameraRmsErrorDeg(const ViewOrientations& estimate, const ViewOrientations& truth) {
  double sum = 0.0;
  int n = 0;
  for (const auto& [v, r] : truth) {
    if (v % 2 != 0) continue;
    sum += std::pow(RadToDeg(LogSO3(estimate.at(v) * estimate.at(0).transpose() * truth.at(0) * r.transpose()).norm()), 2);
    ++n;
  }
  return std::sqrt(sum / n);
}

TEST(BundleAdjustmentRig, ACapturesCamerasTurnTogetherAndEachCameraHoldsTheOther) {
  // Two cameras looking apart share no track: alone, each camera's
  // keyframes are held by its own tracks only. As a rig, every capture's
  // rotation is held by both cameras' tracks.
  double alone = 0.0, together = 0.0;
  std::vector<double> pixel;
  for (std::uint32_t seed = 1; seed <= 12; ++seed) {
    const Scene scene = MakeRigScene(8, 0.5, seed);
    const ViewOrientations start = Perturbed(scene.truth, 0.2, 200 + seed);
    ViewOrientations separate = start, joined = start;
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &separate, &summary))
        << summary.Report();
    BundleAdjustmentCovariance covariance;
    const BundleAdjustmentRig rig = TwoCameraRig(scene);
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &joined, &summary, nullptr,
                                                    &covariance, nullptr, nullptr, &rig))
        << summary.Report();
    for (int c = 0; c < 8; ++c) {
      EXPECT_LT(RotationAngleRad(joined.at(2 * c + 1) * (RigCameraFromRig() * joined.at(2 * c)).transpose()), 1e-12);
    }
    alone += FirstCameraRmsErrorDeg(separate, scene.truth) / 12.0;
    together += FirstCameraRmsErrorDeg(joined, scene.truth) / 12.0;
    // Both cameras' views relative to view 0: one group through the rig.
    ASSERT_EQ(covariance.index.size(), 16u);
    const std::vector<double> nees = NeesRelativeToViewZero(joined, scene.truth, covariance, true);
    ASSERT_EQ(nees.size(), 15u);
    pixel.insert(pixel.end(), nees.begin(), nees.end());
    // Each camera's own covariance, at the same solution: wider, and camera
    // 1's keyframes not tied to camera 0's by any track.
    BundleAdjustmentRig own = rig;
    own.joint_covariance = false;
    ViewOrientations again = start;
    BundleAdjustmentCovariance per_camera;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &again, &summary, nullptr,
                                                    &per_camera, nullptr, nullptr, &own));
    for (ViewId v = 1; v < 16; ++v) {
      EXPECT_EQ(again.at(v), joined.at(v));
      Eigen::Matrix3d wide, narrow;
      ASSERT_TRUE(covariance.Relative(v, 0, &narrow));
      if (v % 2) {
        EXPECT_FALSE(per_camera.Relative(v, 0, &wide));
        continue;
      }
      ASSERT_TRUE(per_camera.Relative(v, 0, &wide));
      EXPECT_GT(wide.trace(), narrow.trace());
    }
  }
  std::cout << "camera 0's RMS error: alone " << alone << " deg, as a rig " << together
            << " deg; mean NEES of the rig's pixel model " << Mean(pixel) << "\n";
  EXPECT_LT(together, 0.85 * alone);
  EXPECT_GT(Mean(pixel), 2.2);
  EXPECT_LT(Mean(pixel), 3.8);
}

BundleAdjustmentFocal OneCamera(const Scene& scene) {
  BundleAdjustmentFocal focal;
  for (const auto& [v, r] : scene.truth) focal.camera[v] = "cam";
  return focal;
}

TEST(BundleAdjustmentFocal, AFocalLengthThreePercentOffIsFoundWithinItsDeviation) {
  // camera_info 3% short: the true focal length is 1/0.97 of the one in use.
  // Held at the wrong one, the adjustment bends the orientations; estimated,
  // it lands within 0.5% and within three of its deviations, and the
  // orientations are as good as with the right focal length.
  const double truth = 1.0 / 0.97;
  for (std::uint32_t seed = 1; seed <= 4; ++seed) {
    const Scene scene = MakePathScene(10, 0.5, truth, seed);
    ViewOrientations held = Perturbed(scene.truth, 0.3, 20 + seed), estimated = held;
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &held, &summary));
    BundleAdjustmentFocal focal = OneCamera(scene);
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &estimated, &summary,
                                                    nullptr, nullptr, &focal))
        << summary.Report();
    ASSERT_EQ(focal.estimates.size(), 1u);
    const BundleAdjustmentFocal::Estimate& e = focal.estimates.at("cam");
    std::cout << "seed " << seed << ": x" << e.scale << " +- " << e.sigma << " (matches " << e.sigma_matches
              << ", principal point " << e.sigma_principal_point << "), error held "
              << MaxErrorDeg(held, scene.truth) << " deg, estimated " << MaxErrorDeg(estimated, scene.truth)
              << " deg\n";
    EXPECT_TRUE(e.determined);
    EXPECT_EQ(e.views, 10);
    EXPECT_NEAR(e.scale, truth, 0.005 * truth);
    EXPECT_LT(std::abs(e.scale - truth), 3.0 * e.sigma);
    // Precise enough to tell a 3% error from none.
    EXPECT_LT(3.0 * e.sigma, truth - 1.0);
    EXPECT_NEAR(summary.final_rms_sigmas, 1.0, 0.15) << summary.Report();
    EXPECT_LT(MaxErrorDeg(estimated, scene.truth), 0.5 * MaxErrorDeg(held, scene.truth));
  }
}

TEST(BundleAdjustmentFocal, ARightFocalLengthStaysAndViewsNotListedKeepTheirs) {
  int within = 0;
  for (std::uint32_t seed = 1; seed <= 6; ++seed) {
    const Scene scene = MakePathScene(10, 0.5, 1.0, seed);
    ViewOrientations plain = Perturbed(scene.truth, 0.3, 40 + seed), listed_none = plain;
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &plain, &summary));
    BundleAdjustmentFocal none;  // no view listed: exactly the adjustment without it
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &listed_none, &summary,
                                                    nullptr, nullptr, &none));
    EXPECT_TRUE(none.estimates.empty());
    for (const auto& [v, r] : plain) EXPECT_EQ(r, listed_none.at(v)) << v;
    BundleAdjustmentFocal focal = OneCamera(scene);
    ViewOrientations estimated = Perturbed(scene.truth, 0.3, 40 + seed);
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &estimated, &summary,
                                                    nullptr, nullptr, &focal));
    const BundleAdjustmentFocal::Estimate& e = focal.estimates.at("cam");
    within += std::abs(e.scale - 1.0) < 3.0 * e.sigma;
    EXPECT_LT(std::abs(e.scale - 1.0), 0.005);
  }
  EXPECT_GE(within, 5);
}

TEST(BundleAdjustmentFocal, TheSameBitForBitWhereverTheHeapPutsItsBlocks) {
  // Two cameras, so two focal blocks among the views'. Between runs the
  // heap is left in another state (blocks of other sizes held), so that
  // whatever the adjustment allocates lies elsewhere: the orientations and
  // the estimates must not change in their last bits (a replay publishes
  // the same on every run).
  const Scene scene = MakePathScene(10, 0.5, 1.0 / 0.97, 5);
  BundleAdjustmentFocal cameras;
  for (const auto& [v, r] : scene.truth) cameras.camera[v] = v % 2 ? "left" : "right";
  const ViewOrientations start = Perturbed(scene.truth, 0.3, 60);
  std::vector<std::vector<char>> held;
  ViewOrientations first;
  std::map<std::string, BundleAdjustmentFocal::Estimate> first_estimates;
  for (int run = 0; run < 12; ++run) {
    for (int k = 0; k < 3 * run; ++k) held.emplace_back(16 + 40 * ((run * 7 + k * 13) % 23));
    ViewOrientations adjusted = start;
    BundleAdjustmentFocal focal = cameras;
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &adjusted, &summary,
                                                    nullptr, nullptr, &focal))
        << summary.Report();
    ASSERT_EQ(focal.estimates.size(), 2u);
    if (run == 0) {
      first = adjusted;
      first_estimates = focal.estimates;
      continue;
    }
    for (const auto& [v, r] : first) EXPECT_EQ(r, adjusted.at(v)) << "run " << run << ", view " << v;
    for (const auto& [camera, e] : first_estimates) {
      EXPECT_EQ(e.scale, focal.estimates.at(camera).scale) << "run " << run << ", " << camera;
      EXPECT_EQ(e.sigma, focal.estimates.at(camera).sigma) << "run " << run << ", " << camera;
    }
    if (HasFailure()) break;
  }
}

TEST(BundleAdjustmentFocal, AnArcAroundAnObjectKnowsItsFocalLengthLessWell) {
  // Optical axes meeting at one point: the critical configuration of focal
  // self-calibration, where a focal length error is explained by the
  // points' depths (and the principal point). The deviation says so: about
  // three times the path's, on as many views and as much noise, and on both
  // the errors are within it (RMS of error / deviation near 1).
  std::vector<double> path_sigma, arc_sigma, path_z, arc_z;
  for (std::uint32_t seed = 1; seed <= 12; ++seed) {
    const Scene path = MakePathScene(10, 0.5, 1.0, seed);
    const Scene arc = MakeScene(10, 0.5, seed);
    BundleAdjustmentFocal on_path = OneCamera(path), on_arc = OneCamera(arc);
    ViewOrientations a = Perturbed(path.truth, 0.3, 5), b = Perturbed(arc.truth, 0.3, 5);
    BundleAdjustmentSummary summary;
    ASSERT_TRUE(RefineRotationsWithBundleAdjustment(path.edges, BundleAdjustmentOptions(), &a, &summary, nullptr,
                                                    nullptr, &on_path));
    ASSERT_TRUE(
        RefineRotationsWithBundleAdjustment(arc.edges, BundleAdjustmentOptions(), &b, &summary, nullptr, nullptr, &on_arc));
    const auto& p = on_path.estimates.at("cam");
    const auto& r = on_arc.estimates.at("cam");
    path_sigma.push_back(p.sigma);
    arc_sigma.push_back(r.sigma);
    path_z.push_back(std::pow((p.scale - 1.0) / p.sigma, 2));
    arc_z.push_back(std::pow((r.scale - 1.0) / r.sigma, 2));
  }
  std::cout << "focal deviation: path " << Mean(path_sigma) << ", arc " << Mean(arc_sigma)
            << "; RMS error / deviation: path " << std::sqrt(Mean(path_z)) << ", arc " << std::sqrt(Mean(arc_z)) << "\n";
  EXPECT_GT(Mean(arc_sigma), 2.5 * Mean(path_sigma));
  for (const std::vector<double>* z : {&path_z, &arc_z}) {
    EXPECT_GT(std::sqrt(Mean(*z)), 0.5);
    EXPECT_LT(std::sqrt(Mean(*z)), 1.6);
  }
}

// A camera that turned in place (the front end's rotation-only model: zero
// translation) gives no direction between centres, but its matches are
// observations of the same points. View 1 here is taken from view 0's centre,
// 8 deg to the side, and only that pair relates it to the others: it joins
// the tracks from view 0's centre, and the scale is held by a view that is
// not at the first view's centre.
TEST(BundleAdjustment, RotationOnlyPairsJoinTheTracks) {
  const Scene base = MakeScene(6, 0.3, 7);
  auto renumbered = [](ViewId v) { return v == 0 ? v : v + 1; };
  Scene scene;
  scene.points = base.points;
  for (const auto& [id, r] : base.truth) scene.truth[renumbered(id)] = r;
  const Eigen::Matrix3d turned = ExpSO3(Eigen::Vector3d(0.0, DegToRad(8.0), 0.0)) * base.truth.at(0);
  scene.truth[1] = turned;
  std::mt19937 rng(8);
  std::normal_distribution<double> noise(0.0, 0.3 / kFocal);
  std::vector<Eigen::Vector2d> seen;
  for (const Eigen::Vector3d& p : base.points) {
    seen.push_back((turned * (p - base.centres[0])).hnormalized() + DrawVector2(rng, noise));
  }
  for (EdgeCorrespondences e : base.edges) {
    e.view1 = renumbered(e.view1);
    e.view2 = renumbered(e.view2);
    scene.edges.push_back(std::move(e));
  }
  EdgeCorrespondences in_place = base.edges.front();  // view 0's keypoints, and view 1's
  in_place.view2 = 1;
  in_place.points2 = seen;
  in_place.translation.setZero();
  scene.edges.push_back(in_place);

  ViewOrientations orientations = Perturbed(scene.truth, 0.5, 9);
  const double start = MaxErrorDeg(orientations, scene.truth);
  BundleAdjustmentSummary summary;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &orientations, &summary))
      << summary.Report();
  EXPECT_EQ(summary.views, 7);
  EXPECT_EQ(summary.edges_used, 16);
  EXPECT_EQ(summary.edges_rotation_only, 1);
  EXPECT_EQ(summary.edges_skipped, 0);
  EXPECT_EQ(summary.observations, 7u * 300u) << summary.Report();
  EXPECT_NEAR(summary.final_rms_sigmas, 1.0, 0.15) << summary.Report();
  EXPECT_LT(MaxErrorDeg(orientations, scene.truth), 0.05) << "from " << start << " deg; " << summary.Report();
  // The pairwise refinement has no use for a pair without a direction.
  ViewOrientations pairwise = Perturbed(scene.truth, 0.5, 9);
  CorrespondenceRefinementSummary refinement;
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &pairwise, &refinement));
  EXPECT_EQ(refinement.edges_skipped, 1) << refinement.Report();
}

TEST(BundleAdjustment, RepeatedStructureMatchesAreDroppedByTheirTracks) {
  // A quarter of pair (0, 3)'s matches go to the point one "window" to the
  // right (0.4 m along the façade), seen at its own keypoint in view 3: the
  // pair alone is biased by them, the other views of each track are not.
  Scene scene = MakeScene(8, 0.3, 5);
  // The same observations without the shifted points' tracks.
  Scene clean = scene;
  for (EdgeCorrespondences& e : clean.edges) {
    std::vector<Eigen::Vector2d> p1, p2;
    for (std::size_t k = 0; k < e.points1.size(); ++k) {
      if (k % 4 != 0) p1.push_back(e.points1[k]), p2.push_back(e.points2[k]);
    }
    e.points1 = p1;
    e.points2 = p2;
  }
  EdgeCorrespondences* pair = nullptr;
  for (EdgeCorrespondences& e : scene.edges) {
    if (e.view1 == 0 && e.view2 == 3) pair = &e;
  }
  ASSERT_NE(pair, nullptr);
  const Eigen::Matrix3d& r3 = scene.truth.at(3);
  int shifted = 0;
  for (std::size_t k = 0; k < pair->points2.size(); k += 4, ++shifted) {
    const Eigen::Vector3d neighbour = scene.points[k] + Eigen::Vector3d(0.4, 0.0, 0.0);
    pair->points2[k] = (r3 * (neighbour - scene.centres[3])).hnormalized();
  }
  const ViewOrientations start = Perturbed(scene.truth, 0.3, 6);
  ViewOrientations contaminated = start, reference = start;
  BundleAdjustmentSummary summary, clean_summary;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &contaminated, &summary));
  ASSERT_TRUE(
      RefineRotationsWithBundleAdjustment(clean.edges, BundleAdjustmentOptions(), &reference, &clean_summary));
  // Each shifted match links its point's track to a second keypoint in
  // view 3 (the other pairs with view 3 match the true one): the track is
  // inconsistent and left out, with its pull on the pair: the result is
  // the one without those points at all.
  EXPECT_EQ(summary.tracks_inconsistent, shifted) << summary.Report();
  EXPECT_EQ(summary.tracks, 300 - shifted) << summary.Report();
  EXPECT_EQ(clean_summary.tracks, 300 - shifted) << clean_summary.Report();
  EXPECT_LT(MaxErrorDeg(contaminated, reference), 1e-6) << summary.Report();
  EXPECT_LT(MaxErrorDeg(contaminated, scene.truth), 0.05) << summary.Report();
  EXPECT_GT(shifted, 50);
}

TEST(BundleAdjustment, TwoViewTracksAreLeftOutByDefault) {
  // 100 more matches in pair (0, 3) only, each between two keypoints no other
  // pair has, all 1.5 px above where they belong in view 3: wrong matches
  // near their epipolar lines, which no third view sees. As two-view tracks
  // they pull as they pull the pair; by default they are left out.
  Scene scene = MakeScene(8, 0.3, 11);
  const Scene clean = scene;
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (EdgeCorrespondences& e : scene.edges) {
    if (e.view1 != 0 || e.view2 != 3) continue;
    for (int k = 0; k < 100; ++k) {
      const Eigen::Vector3d d = DrawVector3(rng, u);
      const Eigen::Vector3d p(3.0 * d.x(), 2.0 * d.y(), 6.0 + 2.0 * d.z());
      e.points1.push_back((scene.truth.at(0) * (p - scene.centres[0])).hnormalized());
      e.points2.push_back((scene.truth.at(3) * (p - scene.centres[3])).hnormalized() + Eigen::Vector2d(0.0, 1.5 / kFocal));
    }
  }
  const ViewOrientations start = Perturbed(scene.truth, 0.3, 13);
  ViewOrientations reference = start, adjusted = start, with_pairs = start;
  BundleAdjustmentSummary summary;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(clean.edges, BundleAdjustmentOptions(), &reference, &summary));
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &adjusted, &summary));
  EXPECT_EQ(summary.tracks_short, 100) << summary.Report();
  EXPECT_EQ(summary.tracks, 300) << summary.Report();
  EXPECT_LT(MaxErrorDeg(adjusted, reference), 1e-6) << summary.Report();
  BundleAdjustmentOptions two_views;
  two_views.min_track_views = 2;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, two_views, &with_pairs, &summary));
  EXPECT_EQ(summary.tracks_short, 0) << summary.Report();
  EXPECT_GT(MaxErrorDeg(with_pairs, reference), 1e-3) << summary.Report();
}

TEST(BundleAdjustment, BadEdgesAreLeftOutAndNothingToAdjustChangesNothing) {
  Scene scene = MakeScene(4, 0.5, 7);
  std::vector<EdgeCorrespondences> edges = scene.edges;
  const std::vector<EdgeCorrespondences> bad = BadEdgeCorrespondences(edges);

  ViewOrientations orientations = Perturbed(scene.truth, 0.5, 8);
  const ViewOrientations start = orientations;
  BundleAdjustmentSummary summary;
  EXPECT_FALSE(RefineRotationsWithBundleAdjustment(bad, BundleAdjustmentOptions(), &orientations, &summary));
  EXPECT_EQ(summary.edges_skipped, 6);
  EXPECT_FALSE(summary.status.empty());
  for (const auto& [id, r] : start) EXPECT_EQ(orientations.at(id), r);

  // The good edges next to the bad ones: adjusted, the bad ones counted,
  // and the same numbers as without them.
  ViewOrientations alone = start;
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &alone, &summary));
  edges.insert(edges.end(), bad.begin(), bad.end());
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(edges, BundleAdjustmentOptions(), &orientations, &summary));
  EXPECT_EQ(summary.edges_used, 6);
  EXPECT_EQ(summary.edges_skipped, 6);
  EXPECT_LT(MaxErrorDeg(orientations, alone), 1e-9);

  // A view without an orientation: its edges are left out, it gets none.
  ViewOrientations partial = Perturbed(scene.truth, 0.5, 9);
  partial.erase(3);
  ASSERT_TRUE(RefineRotationsWithBundleAdjustment(scene.edges, BundleAdjustmentOptions(), &partial, &summary));
  EXPECT_EQ(summary.edges_used, 3);
  EXPECT_EQ(summary.edges_skipped, 3);
  EXPECT_EQ(partial.count(3), 0u);
}

}  // namespace
}  // namespace rotation_averaging
