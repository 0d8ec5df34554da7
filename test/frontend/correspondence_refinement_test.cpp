#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <random>
#include <vector>

#include "frontend/refinement_test_util.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {
namespace {

// Cameras on an arc around a box of points, every pair seeing the points in
// front of both, with Gaussian noise on the normalised coordinates.
struct Scene {
  ViewOrientations truth;
  std::vector<EdgeCorrespondences> edges;
};

constexpr double kFocal = 1000.0;  // pixels, for the noise level only

Scene MakeScene(int views, double noise_px, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px / kFocal);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<Eigen::Vector3d> points;
  for (int k = 0; k < 300; ++k) {
    const Eigen::Vector3d d = DrawVector3(rng, u);
    points.emplace_back(3.0 * d.x(), 2.0 * d.y(), 6.0 + 2.0 * d.z());
  }
  Scene scene;
  std::vector<Eigen::Vector3d> centers;
  for (int v = 0; v < views; ++v) {
    const double angle = DegToRad(-20.0 + 40.0 * v / (views - 1));
    const Eigen::Vector3d center(6.0 * std::sin(angle), 0.3 * u(rng), 6.0 - 6.0 * std::cos(angle));
    // Looks at the middle of the points, with a little roll.
    const Eigen::Vector3d z = (Eigen::Vector3d(0, 0, 6) - center).normalized();
    const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
    Eigen::Matrix3d camera_to_world;
    camera_to_world << x, z.cross(x), z;
    scene.truth[static_cast<ViewId>(v)] =
        (camera_to_world * Eigen::AngleAxisd(0.05 * u(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix()).transpose();
    centers.push_back(center);
  }
  for (int i = 0; i < views; ++i) {
    for (int j = i + 1; j < views; ++j) {
      EdgeCorrespondences e;
      e.view1 = static_cast<ViewId>(i);
      e.view2 = static_cast<ViewId>(j);
      const Eigen::Matrix3d& ri = scene.truth[e.view1];
      const Eigen::Matrix3d& rj = scene.truth[e.view2];
      for (const Eigen::Vector3d& p : points) {
        const Eigen::Vector3d a = ri * (p - centers[i]), b = rj * (p - centers[j]);
        e.points1.push_back(a.hnormalized() + DrawVector2(rng, noise));
        e.points2.push_back(b.hnormalized() + DrawVector2(rng, noise));
      }
      e.translation = (rj * (centers[i] - centers[j])).normalized();
      e.sigma = std::max(noise_px, 0.05) / kFocal;
      scene.edges.push_back(std::move(e));
    }
  }
  return scene;
}

// The minimum the refinement finds from the true orientations: the best an
// estimate from these correspondences can be.
ViewOrientations FromTruth(const Scene& scene, const std::vector<EdgeCorrespondences>& edges) {
  ViewOrientations o = scene.truth;
  CorrespondenceRefinementSummary summary;
  EXPECT_TRUE(RefineRotationsWithCorrespondences(edges, CorrespondenceRefinementOptions(), &o, &summary));
  return o;
}

TEST(CorrespondenceRefinement, ExactWithoutNoise) {
  const Scene scene = MakeScene(6, 0.0, 1);
  ViewOrientations orientations = Perturbed(scene.truth, 1.0, 2);
  CorrespondenceRefinementSummary summary;
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &orientations, &summary))
      << summary.Report();
  EXPECT_LT(MaxErrorDeg(orientations, scene.truth), 1e-5) << summary.Report();
}

TEST(CorrespondenceRefinement, ReachesTheMinimumFromAnAveragingOneDegreeOff) {
  const Scene scene = MakeScene(6, 0.5, 1);
  ViewOrientations orientations = Perturbed(scene.truth, 1.0, 2);
  ASSERT_GT(MaxErrorDeg(orientations, scene.truth), 0.5);
  CorrespondenceRefinementSummary summary;
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &orientations, &summary))
      << summary.Report();
  EXPECT_EQ(summary.edges_used, 15);
  EXPECT_EQ(summary.edges_contradicted, 0);
  EXPECT_EQ(summary.passes, 1);
  EXPECT_EQ(summary.correspondences, 15u * 300u);
  EXPECT_LT(summary.final_cost, summary.initial_cost);
  // 0.5 px of noise: the minimum is a few hundredths of a degree from the
  // truth (each pair's translation direction is free); the refinement gets
  // there from a start a degree off.
  const ViewOrientations best = FromTruth(scene, scene.edges);
  EXPECT_LT(MaxErrorDeg(best, scene.truth), 0.1);
  EXPECT_LT(MaxErrorDeg(orientations, best), 1e-4) << summary.Report();
}

TEST(CorrespondenceRefinement, TheSameBitForBitWhereverTheHeapPutsItsBlocks) {
  // Between runs the heap is left with holes of other sizes, so that the
  // orientations' blocks lie elsewhere and in another order: the result
  // must not change in its last bits.
  const Scene scene = MakeScene(10, 0.5, 4);
  const ViewOrientations start = Perturbed(scene.truth, 1.0, 5);
  std::vector<std::vector<char>> held;
  ViewOrientations first;
  for (int run = 0; run < 10; ++run) {
    std::vector<std::vector<char>> holes;
    for (int k = 0; k < 40; ++k) (k % 3 == run % 3 ? holes : held).emplace_back(48 + 16 * ((run + k) % 5));
    holes.clear();
    ViewOrientations orientations = start;
    CorrespondenceRefinementSummary summary;
    ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &orientations,
                                                   &summary))
        << summary.Report();
    if (run == 0) {
      first = orientations;
      continue;
    }
    for (const auto& [v, r] : first) EXPECT_EQ(r, orientations.at(v)) << "run " << run << ", view " << v;
    if (HasFailure()) break;
  }
}

TEST(CorrespondenceRefinement, AWrongPairIsLeftOutAndDoesNotPull) {
  Scene scene = MakeScene(6, 0.5, 3);
  // The pair (0, 1) matched against a view rotated by 10 degrees: its
  // correspondences are consistent with each other and with a wrong pose.
  EdgeCorrespondences& wrong = scene.edges.front();
  ASSERT_EQ(wrong.view2, 1u);
  const Eigen::Matrix3d twist = ExpSO3(Eigen::Vector3d(0.0, DegToRad(10.0), 0.0));
  for (Eigen::Vector2d& p : wrong.points2) p = (twist * p.homogeneous()).hnormalized();
  ViewOrientations orientations = Perturbed(scene.truth, 0.5, 4);
  CorrespondenceRefinementSummary summary;
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &orientations, &summary));
  EXPECT_EQ(summary.passes, 2) << summary.Report();
  EXPECT_EQ(summary.edges_contradicted, 1);
  EXPECT_EQ(summary.edges_used, 14);
  // As good as without the wrong pair.
  std::vector<EdgeCorrespondences> right(scene.edges.begin() + 1, scene.edges.end());
  const ViewOrientations best = FromTruth(scene, right);
  EXPECT_LT(MaxErrorDeg(orientations, best), 1e-4) << summary.Report();

  // One pass keeps it: the loss bounds its pull, but does not remove it.
  CorrespondenceRefinementOptions one_pass;
  one_pass.min_agreement_fraction = 0.0;
  ViewOrientations kept = Perturbed(scene.truth, 0.5, 4);
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, one_pass, &kept, &summary));
  EXPECT_EQ(summary.passes, 1);
  EXPECT_EQ(summary.edges_used, 15);
  EXPECT_GT(MaxErrorDeg(kept, best), 0.01);
}

TEST(CorrespondenceRefinement, BadEdgesAreLeftOutAndNothingToRefineChangesNothing) {
  Scene scene = MakeScene(4, 0.5, 7);
  std::vector<EdgeCorrespondences> edges = scene.edges;
  const std::vector<EdgeCorrespondences> bad = BadEdgeCorrespondences(edges);

  ViewOrientations orientations = Perturbed(scene.truth, 0.5, 8);
  const ViewOrientations start = orientations;
  CorrespondenceRefinementSummary summary;
  EXPECT_FALSE(RefineRotationsWithCorrespondences(bad, CorrespondenceRefinementOptions(), &orientations, &summary));
  EXPECT_EQ(summary.edges_skipped, 6);
  EXPECT_FALSE(summary.status.empty());
  for (const auto& [id, r] : start) EXPECT_EQ(orientations.at(id), r);

  // The good edges next to the bad ones: refined, the bad ones counted.
  edges.insert(edges.end(), bad.begin(), bad.end());
  ASSERT_TRUE(RefineRotationsWithCorrespondences(edges, CorrespondenceRefinementOptions(), &orientations, &summary));
  EXPECT_EQ(summary.edges_used, 6);
  EXPECT_EQ(summary.edges_skipped, 6);
  EXPECT_LT(MaxErrorDeg(orientations, FromTruth(scene, scene.edges)), 1e-4);

  // A view without an orientation: its edges are left out, it gets none.
  ViewOrientations partial = Perturbed(scene.truth, 0.5, 9);
  partial.erase(3);
  ASSERT_TRUE(RefineRotationsWithCorrespondences(scene.edges, CorrespondenceRefinementOptions(), &partial, &summary));
  EXPECT_EQ(summary.edges_used, 3);
  EXPECT_EQ(summary.edges_skipped, 3);
  EXPECT_EQ(partial.count(3), 0u);
}

TEST(CorrespondenceRefinement, EdgeOfATwoViewEstimateIsWhitenedByItsPixelNoise) {
  const std::vector<Eigen::Vector2d> p1 = {{0.1, 0.2}, {-0.3, 0.05}}, p2 = {{0.12, 0.18}, {-0.28, 0.07}};
  const Eigen::Vector3d t(0.0, 0.6, 0.8);
  const EdgeCorrespondences e = MakeEdgeCorrespondences(4, 7, p1, p2, t, 0.5, 1000.0);
  EXPECT_EQ(e.view1, 4u);
  EXPECT_EQ(e.view2, 7u);
  EXPECT_EQ(e.points1, p1);
  EXPECT_EQ(e.points2, p2);
  EXPECT_EQ(e.translation, t);
  EXPECT_DOUBLE_EQ(e.sigma, 0.5 / 1000.0);
  EXPECT_TRUE(CorrespondencesAreFinite(e));
  // A noiseless pair (sigma 0 px) is floored at 1e-3 px, so its weights stay finite.
  const EdgeCorrespondences exact = MakeEdgeCorrespondences(4, 7, p1, p2, t, 0.0, 1000.0);
  EXPECT_DOUBLE_EQ(exact.sigma, 1e-3 / 1000.0);
  EXPECT_TRUE(CorrespondencesAreFinite(exact));
  // The rotation-only model has no translation: valid only where allowed.
  const EdgeCorrespondences rotation_only = MakeEdgeCorrespondences(4, 7, p1, p2, Eigen::Vector3d::Zero(), 0.5, 1000.0);
  EXPECT_FALSE(CorrespondencesAreFinite(rotation_only));
  EXPECT_TRUE(CorrespondencesAreFinite(rotation_only, true));
}

}  // namespace
}  // namespace rotation_averaging
