#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>

#include <Eigen/Geometry>
#include <atomic>
#include <fstream>
#include <iostream>
#include <iterator>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "frontend/refinement_test_util.h"
#include "rotation_averaging/frontend/controllers/focal_corrector.h"
#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

KeyframeKey Key(const std::string& camera, int view) { return {camera, 1000000000LL * (view + 1)}; }

// The scene's edges as one camera's keyframe pairs; `e` turns the camera
// (camera_from_rig: the rays of each keypoint and the translations rotate
// with it).
std::vector<KeyframeCorrespondences> Edges(const ArcScene& scene, const std::string& camera,
                                           const Eigen::Matrix3d& e = Eigen::Matrix3d::Identity()) {
  std::vector<KeyframeCorrespondences> out;
  for (const EdgeCorrespondences& edge : scene.edges) {
    KeyframeCorrespondences k{Key(camera, static_cast<int>(edge.view1)), Key(camera, static_cast<int>(edge.view2)),
                              edge};
    for (Eigen::Vector2d& p : k.points.points1) p = (e * p.homogeneous()).hnormalized();
    for (Eigen::Vector2d& p : k.points.points2) p = (e * p.homogeneous()).hnormalized();
    k.points.translation = e * edge.translation;
    out.push_back(std::move(k));
  }
  return out;
}

// An averaging solution: the truth perturbed by about `degrees` per keyframe.
OnlineSolution Averaged(const ArcScene& scene, const std::string& camera, double degrees, std::uint32_t seed,
                        const Eigen::Matrix3d& e = Eigen::Matrix3d::Identity()) {
  OnlineSolution solution;
  solution.sequence = 1;
  for (const auto& [id, r] : Perturbed(scene.truth, degrees, seed)) solution.orientations[Key(camera, id)] = e * r;
  return solution;
}

ViewOrientations ById(const OnlineSolution& solution, const std::string& camera, int views) {
  ViewOrientations out;
  for (int v = 0; v < views; ++v) out[v] = solution.orientations.at(Key(camera, v));
  return out;
}

TEST(KeyframeRefiner, CorrectionsTakeTheAveragingToTheTracksInItsFrame) {
  const ArcScene scene = MakeArcScene(8, 0.5, 3);
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 4);
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_EQ(published.refinement_sequence, 1u);
  const double before = MaxErrorDeg(ById(averaged, "cam", 8), scene.truth);
  const double after = MaxErrorDeg(ById(published, "cam", 8), scene.truth);
  EXPECT_GT(before, 0.2);
  EXPECT_LT(after, 0.25 * before) << before << " -> " << after;
  // The keyframes as a whole stay in the averaging's frame.
  std::vector<Eigen::Matrix3d> corrected, as_averaged;
  for (const auto& [key, r] : published.orientations) {
    corrected.push_back(r);
    as_averaged.push_back(averaged.orientations.at(key));
  }
  EXPECT_LT(RadToDeg(RotationAngleRad(AlignRotations(corrected, as_averaged))), 0.05);
  const KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.runs, 1u);
  EXPECT_EQ(stats.applied, 1u);
  EXPECT_EQ(stats.corrected_keyframes, 8u);
  EXPECT_EQ(stats.held_back, 0u);
  EXPECT_TRUE(stats.last_ok);
  EXPECT_GT(stats.median_correction_deg, 0.0);
  EXPECT_EQ(stats.times.Count(), 1u);
}

TEST(KeyframeRefiner, ARefinementStartsWhereTheLastOneLeftItsKeyframes) {
  // The next refinement of a map that has not changed much (here: the same
  // keyframes, the averaging re-solved) starts from the published
  // orientations and the last adjustment's centres: a fraction of the
  // iterations, and the same corrections. (Each with the focal length free:
  // held once it agrees, the second would solve another problem.)
  const ArcScene scene = MakeArcScene(10, 0.5, 5);
  KeyframeRefinerOptions options;
  options.hold_agreed_focal = false;
  KeyframeRefiner refiner{options};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(Averaged(scene, "cam", 0.3, 6))) << refiner.Stats().last_report;
  const int cold = refiner.Stats().last_iterations;
  OnlineSolution resolved = Averaged(scene, "cam", 0.3, 7);
  resolved.sequence = 2;
  ASSERT_TRUE(refiner.Refine(resolved)) << refiner.Stats().last_report;
  const int warm = refiner.Stats().last_iterations;
  EXPECT_LT(warm, cold / 2) << cold << " then " << warm;
  OnlineSolution published = resolved;
  refiner.Apply(&published);
  KeyframeRefiner fresh{options};
  fresh.Add(Edges(scene, "cam"));
  ASSERT_TRUE(fresh.Refine(resolved)) << fresh.Stats().last_report;
  OnlineSolution from_cold = resolved;
  fresh.Apply(&from_cold);
  EXPECT_LT(MaxErrorDeg(ById(published, "cam", 10), ById(from_cold, "cam", 10)), 1e-4);
  // After a reset it starts afresh.
  refiner.Reset();
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(resolved)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().last_iterations, fresh.Stats().last_iterations);
}

TEST(KeyframeRefiner, ARefinementWhoseCamerasHaveNotSettledChangesNothing) {
  // Two iterations per stage: the adjustment stops with its cameras still
  // moving, and what it found is no minimum.
  const ArcScene scene = MakeArcScene(8, 0.5, 3);
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 4);
  KeyframeRefinerOptions options;
  options.adjustment.max_iterations = 2;
  KeyframeRefiner refiner{options};
  refiner.Add(Edges(scene, "cam"));
  EXPECT_FALSE(refiner.Refine(averaged));
  const KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.runs, 1u);
  EXPECT_EQ(stats.applied, 0u);
  EXPECT_EQ(stats.failed, 1u);
  EXPECT_NE(stats.last_report.find("had not settled"), std::string::npos) << stats.last_report;
  EXPECT_TRUE(stats.focal.empty());
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_LT(MaxErrorDeg(ById(published, "cam", 8), ById(averaged, "cam", 8)), 1e-12);
}

// The averaging's covariances: (sigma_deg)^2 I per keyframe, zero for the
// gauge (view 0); `component` 0 for all.
void WithCovariances(OnlineSolution* solution, const std::string& camera, int views, double sigma_deg) {
  for (int v = 0; v < views; ++v) {
    const double s = DegToRad(sigma_deg);
    solution->covariance[Key(camera, v)] = v == 0 ? Eigen::Matrix3d::Zero() : Eigen::Matrix3d(s * s * Eigen::Matrix3d::Identity());
    solution->component[Key(camera, v)] = 0;
  }
}

TEST(KeyframeRefiner, TheCorrectedKeyframesCarryTheAdjustmentsCovariances) {
  // The averaging's covariances say 0.3 deg, as its errors; the adjustment
  // takes the errors to a few thousandths of a degree, and its covariances
  // say so: NEES against the truth, relative to the gauge keyframe, about 3.
  std::vector<double> nees;
  for (std::uint32_t seed = 1; seed <= 8; ++seed) {
    const ArcScene scene = MakeArcScene(8, 0.5, seed);
    OnlineSolution averaged = Averaged(scene, "cam", 0.3, 40 + seed);
    WithCovariances(&averaged, "cam", 8, 0.3);
    KeyframeRefinerOptions fixed_focal;
    fixed_focal.estimate_focal = false;  // (an arc: with the focal length free, its uncertainty is in every orientation's)
    KeyframeRefiner refiner{fixed_focal};
    refiner.Add(Edges(scene, "cam"));
    ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
    EXPECT_EQ(refiner.Stats().covariance_keyframes, 8u);
    OnlineSolution published = averaged;
    refiner.Apply(&published);
    EXPECT_EQ(published.covariance.at(Key("cam", 0)), Eigen::Matrix3d::Zero());  // the gauge's
    const Eigen::Matrix3d& r0 = published.orientations.at(Key("cam", 0));
    for (int v = 1; v < 8; ++v) {
      const Eigen::Matrix3d& c = published.covariance.at(Key("cam", v));
      EXPECT_LT(c.trace(), 0.05 * averaged.covariance.at(Key("cam", v)).trace());
      const Eigen::Vector3d d = LogSO3(published.orientations.at(Key("cam", v)) * r0.transpose() *
                                       scene.truth.at(0) * scene.truth.at(v).transpose());
      nees.push_back(d.dot(c.ldlt().solve(d)));
    }
  }
  double mean = 0.0;
  for (double n : nees) mean += n / nees.size();
  EXPECT_GT(mean, 1.0);
  EXPECT_LT(mean, 5.0);
}

TEST(KeyframeRefiner, TheReferencesOwnCovarianceIsAddedAndCanBeLeftOut) {
  const ArcScene scene = MakeArcScene(8, 0.5, 5);
  OnlineSolution averaged = Averaged(scene, "cam", 0.3, 6);
  WithCovariances(&averaged, "cam", 8, 0.3);
  // The gauge is outside the window (of another camera, no edges): the
  // reference is the keyframe the averaging holds best, view 2.
  averaged.covariance[Key("cam", 0)] = Eigen::Matrix3d::Identity();
  const double s2 = std::pow(DegToRad(0.1), 2);
  averaged.covariance[Key("cam", 2)] = s2 * Eigen::Matrix3d::Identity();
  KeyframeRefinerOptions fixed_focal;
  fixed_focal.estimate_focal = false;  // (an arc: with the focal length free, its uncertainty is in every orientation's)
  KeyframeRefiner refiner{fixed_focal};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_LT((published.covariance.at(Key("cam", 2)) - s2 * Eigen::Matrix3d::Identity()).norm(), 1e-12 * s2);
  for (int v : {1, 3, 7}) {
    const Eigen::Matrix3d c = published.covariance.at(Key("cam", v));
    EXPECT_GT(c.trace(), 3.0 * s2);
    EXPECT_LT(c.trace(), 3.3 * s2);  // the adjustment's own share is small
  }
  // Another component: the averaging's stays.
  OnlineSolution split = averaged;
  split.component[Key("cam", 5)] = 1;
  refiner.Apply(&split);
  EXPECT_EQ(split.covariance.at(Key("cam", 5)), averaged.covariance.at(Key("cam", 5)));
  // refinement_covariances: false leaves the averaging's.
  KeyframeRefinerOptions options;
  options.covariances = false;
  KeyframeRefiner without{options};
  without.Add(Edges(scene, "cam"));
  ASSERT_TRUE(without.Refine(averaged));
  OnlineSolution kept = averaged;
  without.Apply(&kept);
  ASSERT_EQ(kept.covariance.size(), averaged.covariance.size());
  for (const auto& [key, c] : averaged.covariance) EXPECT_EQ(kept.covariance.at(key), c) << key.stamp_ns;
  EXPECT_EQ(without.Stats().covariance_keyframes, 0u);
}

TEST(KeyframeRefiner, LaterSolutionsCarryTheCorrections) {
  const ArcScene scene = MakeArcScene(8, 0.5, 5);
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 6);
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged));
  // A later solve moved the whole map (a loop closure turning the world
  // frame) and added a keyframe the refinement has not seen.
  const Eigen::Matrix3d turn = ExpSO3(Eigen::Vector3d(0.02, -0.01, 0.03));
  OnlineSolution later;
  later.sequence = 2;
  for (const auto& [key, r] : averaged.orientations) later.orientations[key] = r * turn;
  const Eigen::Matrix3d newest = ExpSO3(Eigen::Vector3d(0.1, 0.2, 0.3));
  later.orientations[Key("cam", 8)] = newest;
  refiner.Apply(&later);
  EXPECT_TRUE(later.orientations.at(Key("cam", 8)).isApprox(newest, 1e-12));
  EXPECT_LT(MaxErrorDeg(ById(later, "cam", 8), scene.truth),
            0.25 * MaxErrorDeg(ById(averaged, "cam", 8), scene.truth));
}

TEST(KeyframeRefiner, TheCamerasOfARigCaptureShareOneCorrection) {
  const ArcScene scene = MakeArcScene(8, 0.5, 7);
  const Eigen::Matrix3d e = ExpSO3(Eigen::Vector3d(0.0, DegToRad(10.0), 0.0));
  OnlineSolution averaged = Averaged(scene, "front", 0.3, 8);
  const OnlineSolution side = Averaged(scene, "side", 0.3, 9, e);
  averaged.orientations.insert(side.orientations.begin(), side.orientations.end());
  KeyframeRefiner::RigCaptures rig;
  for (int v = 0; v < 8; ++v) {
    const KeyframeKey capture{"rig", Key("front", v).stamp_ns};
    rig[Key("front", v)] = {capture, Eigen::Matrix3d::Identity()};
    rig[Key("side", v)] = {capture, e};
  }
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(Edges(scene, "front"));
  refiner.Add(Edges(scene, "side", e));
  ASSERT_TRUE(refiner.Refine(averaged, rig)) << refiner.Stats().last_report;
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  for (int v = 0; v < 8; ++v) {
    // C_side = E C_front E^T: one correction of the rig, R_rig' = D R_rig.
    const Eigen::Matrix3d c_front =
        published.orientations.at(Key("front", v)) * averaged.orientations.at(Key("front", v)).transpose();
    const Eigen::Matrix3d c_side =
        published.orientations.at(Key("side", v)) * averaged.orientations.at(Key("side", v)).transpose();
    EXPECT_LT(RadToDeg(AngularDistanceRad(c_side, e * c_front * e.transpose())), 1e-9) << v;
  }
  EXPECT_EQ(refiner.Stats().corrected_keyframes, 16u);
}

TEST(KeyframeRefiner, ARigCaptureGetsTheCovarianceOfTheCameraItsTracksHoldBest) {
  // A rig of two cameras on one arc, no track between them; the side
  // camera sees an eighth of the points. With each camera's own
  // covariance, a capture is held at least as well as by the front
  // camera's tracks alone: it gets the front camera's covariance, relative
  // to the front camera's view of the reference capture (the side camera's
  // covariances relative to its own). The mean of the two would be more
  // than half the side camera's.
  const ArcScene scene = MakeArcScene(8, 0.5, 11);
  const Eigen::Matrix3d e = ExpSO3(Eigen::Vector3d(0.0, DegToRad(10.0), 0.0));
  std::vector<KeyframeCorrespondences> sparse = Edges(scene, "side", e);
  for (KeyframeCorrespondences& k : sparse) {
    EdgeCorrespondences kept = k.points;
    kept.points1.clear();
    kept.points2.clear();
    const ViewId view1 = static_cast<ViewId>(k.keyframe1.stamp_ns / 1000000000LL - 1);
    for (std::size_t i = 0; i < k.points.points1.size(); ++i) {
      // Of every eighth point of the scene, as each view sees it: the
      // tracks stay whole.
      for (std::size_t p = 0; p < scene.points.size(); p += 8) {
        if ((e * scene.keypoints[view1][p].homogeneous()).hnormalized().isApprox(k.points.points1[i], 1e-12)) {
          kept.points1.push_back(k.points.points1[i]);
          kept.points2.push_back(k.points.points2[i]);
        }
      }
    }
    k.points = std::move(kept);
  }
  ASSERT_GE(sparse.front().points.points1.size(), 30u);
  OnlineSolution averaged = Averaged(scene, "front", 0.3, 12);
  const OnlineSolution side = Averaged(scene, "side", 0.3, 13, e);
  averaged.orientations.insert(side.orientations.begin(), side.orientations.end());
  WithCovariances(&averaged, "front", 8, 0.3);
  WithCovariances(&averaged, "side", 8, 0.3);
  KeyframeRefiner::RigCaptures rig;
  for (int v = 0; v < 8; ++v) {
    const KeyframeKey capture{"rig", Key("front", v).stamp_ns};
    rig[Key("front", v)] = {capture, Eigen::Matrix3d::Identity()};
    rig[Key("side", v)] = {capture, e};
  }
  KeyframeRefinerOptions options;
  options.estimate_focal = false;  // (an arc: with the focal length free, its uncertainty is in every orientation's)
  options.rig_joint_covariance = false;
  const auto published = [&](const std::vector<std::vector<KeyframeCorrespondences>>& cameras,
                             const KeyframeRefiner::RigCaptures& given) {
    KeyframeRefiner refiner{options};
    for (const auto& edges : cameras) refiner.Add(edges);
    EXPECT_TRUE(refiner.Refine(averaged, given)) << refiner.Stats().last_report;
    OnlineSolution out = averaged;
    refiner.Apply(&out);
    return out;
  };
  const OnlineSolution both = published({Edges(scene, "front"), sparse}, rig);
  const OnlineSolution front_alone = published({Edges(scene, "front")}, {});
  const OnlineSolution side_alone = published({sparse}, {});
  for (int v = 1; v < 8; ++v) {
    const Eigen::Matrix3d& front = both.covariance.at(Key("front", v));
    EXPECT_LT((both.covariance.at(Key("side", v)) - e * front * e.transpose()).norm(), 1e-9 * front.norm()) << v;
    const double alone = front_alone.covariance.at(Key("front", v)).trace();
    EXPECT_GT(front.trace(), 0.7 * alone) << v;
    EXPECT_LT(front.trace(), 1.4 * alone) << v;
    EXPECT_LT(front.trace(), 0.4 * side_alone.covariance.at(Key("side", v)).trace()) << v;
  }
}

// A MakeRigScene's views as keyframes of cameras "c0" and "c1", captures
// one second apart.
KeyframeKey RigKey(ViewId v) { return Key(v % 2 ? "c1" : "c0", static_cast<int>(v / 2)); }

TEST(KeyframeRefiner, ARigsCamerasHoldEachOthersKeyframes) {
  // Two cameras looking apart, no track between them: with the rig's
  // extrinsics the adjustment turns each capture by both cameras' tracks.
  // Per seed, RMS error (deg) of the published keyframes relative to the
  // first capture, with the rig given and without.
  double with_rig = 0.0, without = 0.0;
  for (std::uint32_t seed = 1; seed <= 6; ++seed) {
    const ArcScene scene = MakeRigScene(8, 0.5, seed);
    // The averaging holds a capture as one orientation: its error is the
    // rig's, shared by both cameras.
    const ViewOrientations rigs = Perturbed(scene.truth, 0.2, 300 + seed);
    OnlineSolution averaged;
    averaged.sequence = 1;
    KeyframeRefiner::RigCaptures rig;
    for (const auto& [v, r] : scene.truth) {
      const Eigen::Matrix3d e = v % 2 ? RigCameraFromRig() : Eigen::Matrix3d::Identity();
      averaged.orientations[RigKey(v)] = e * rigs.at(v - v % 2) * scene.truth.at(v - v % 2).transpose() * e.transpose() * r;
      rig[RigKey(v)] = {KeyframeKey{"rig", RigKey(v).stamp_ns}, e};
    }
    std::vector<KeyframeCorrespondences> edges;
    for (const EdgeCorrespondences& e : scene.edges) edges.push_back({RigKey(e.view1), RigKey(e.view2), e});
    const auto rms_error = [&](const KeyframeRefiner::RigCaptures& given) {
      KeyframeRefiner refiner{KeyframeRefinerOptions()};
      refiner.Add(edges);
      EXPECT_TRUE(refiner.Refine(averaged, given)) << refiner.Stats().last_report;
      OnlineSolution published = averaged;
      refiner.Apply(&published);
      double sum = 0.0;
      for (const auto& [v, r] : scene.truth) {
        const Eigen::Matrix3d estimate = published.orientations.at(RigKey(v)) *
                                         published.orientations.at(RigKey(0)).transpose();
        sum += std::pow(RadToDeg(AngularDistanceRad(estimate, r * scene.truth.at(0).transpose())), 2);
      }
      return std::sqrt(sum / scene.truth.size());
    };
    with_rig += rms_error(rig) / 6.0;
    without += rms_error({}) / 6.0;
  }
  std::cout << "RMS error: with the rig " << with_rig << " deg, without " << without << " deg\n";
  EXPECT_LT(with_rig, 0.9 * without);
}

TEST(KeyframeRefiner, ARefinementThatMovesTooManyKeyframesTooFarChangesNothing) {
  const ArcScene scene = MakeArcScene(8, 0.5, 11);
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 12);
  KeyframeRefinerOptions options;
  options.max_correction_deg = 0.01;
  KeyframeRefiner refiner(options);
  refiner.Add(Edges(scene, "cam"));
  EXPECT_FALSE(refiner.Refine(averaged));
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_EQ(published.refinement_sequence, 0u);
  for (const auto& [key, r] : averaged.orientations) EXPECT_TRUE(published.orientations.at(key).isApprox(r, 0.0));
  const KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.failed, 1u);
  EXPECT_FALSE(stats.last_ok);
  EXPECT_NE(stats.last_report.find("the averaging's orientations kept"), std::string::npos) << stats.last_report;
}

TEST(KeyframeRefiner, AKeyframeMovedTooFarKeepsWhatItHad) {
  const ArcScene scene = MakeArcScene(8, 0.5, 13);
  OnlineSolution averaged = Averaged(scene, "cam", 0.05, 14);
  // One keyframe far off: the adjustment moves it by about 0.8 deg.
  averaged.orientations[Key("cam", 5)] = ExpSO3(Eigen::Vector3d(0.0, DegToRad(0.8), 0.0)) * scene.truth.at(5);
  KeyframeRefinerOptions options;
  options.max_correction_deg = 0.4;
  KeyframeRefiner refiner(options);
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_TRUE(published.orientations.at(Key("cam", 5)).isApprox(averaged.orientations.at(Key("cam", 5)), 0.0));
  const KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.held_back, 1u);
  EXPECT_EQ(stats.corrected_keyframes, 7u);
  EXPECT_LE(stats.max_correction_deg, 0.4);
}

TEST(KeyframeRefiner, BadCorrespondencesAreNotHeld) {
  const ArcScene scene = MakeArcScene(6, 0.5, 15);
  std::vector<KeyframeCorrespondences> bad;
  for (EdgeCorrespondences& e : BadEdgeCorrespondences(scene.edges)) {
    bad.push_back({Key("cam", static_cast<int>(e.view1)), Key("cam", static_cast<int>(e.view2)), std::move(e)});
  }
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(bad);
  // Only the edge to an unknown keyframe is well formed (the solution does
  // not have that keyframe: nothing to adjust).
  EXPECT_EQ(refiner.Stats().edges_held, 1u);
  EXPECT_FALSE(refiner.Refine(Averaged(scene, "cam", 0.3, 16)));
  EXPECT_EQ(refiner.Stats().corrected_keyframes, 0u);
}

TEST(KeyframeRefiner, WithoutTheSweepBackTheWindowLetsGoOfEdgesOlderThanIt) {
  const ArcScene scene = MakeArcScene(8, 0.5, 17);
  KeyframeRefinerOptions options;
  options.max_keyframes = 4;
  options.sweep_back = false;
  KeyframeRefiner refiner(options);
  refiner.Add(Edges(scene, "cam"));
  EXPECT_EQ(refiner.Stats().edges_held, 28u);
  const std::size_t bytes = refiner.Stats().bytes;
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 18);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  const KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.corrected_keyframes, 4u);  // the newest four
  EXPECT_EQ(stats.edges_held, 28u - 6u);     // the pairs among the oldest four are let go
  EXPECT_LT(stats.bytes, bytes);
  OnlineSolution published = averaged;
  refiner.Apply(&published);
  EXPECT_TRUE(published.orientations.at(Key("cam", 0)).isApprox(averaged.orientations.at(Key("cam", 0)), 0.0));
  refiner.Reset();
  EXPECT_EQ(refiner.Stats().edges_held, 0u);
  EXPECT_EQ(refiner.Stats().bytes, 0u);
}

TEST(KeyframeRefiner, ARefinementOfTheSameSolutionSweepsBackOverTheKeyframesTheWindowHadNoRoomFor) {
  // A trajectory: each keyframe paired with its next two.
  ArcScene scene = MakeArcScene(10, 0.5, 31);
  scene.edges.erase(std::remove_if(scene.edges.begin(), scene.edges.end(),
                                   [](const EdgeCorrespondences& e) {
                                     return std::abs(static_cast<int>(e.view1) - static_cast<int>(e.view2)) > 2;
                                   }),
                    scene.edges.end());
  KeyframeRefinerOptions options;
  options.max_keyframes = 4;
  KeyframeRefiner refiner(options);
  refiner.Add(Edges(scene, "cam"));
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 32);
  EXPECT_EQ(refiner.Pending(averaged), 10u);
  // The first refinement of a solution: the newest four.
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().corrected_keyframes, 4u);
  EXPECT_EQ(refiner.Pending(averaged), 6u);
  EXPECT_EQ(refiner.Stats().edges_held, 17u);  // the sweep needs them all
  OnlineSolution first = averaged;
  refiner.Apply(&first);
  // Again: the newest four of the other six, with those the first one
  // adjusted that their edges reach held as published (its newer end, two
  // keyframes) and the two older ones as averaged; then the last two.
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().corrected_keyframes, 8u);
  EXPECT_NE(refiner.Stats().last_report.find("views (4 held)"), std::string::npos) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Pending(averaged), 2u);
  OnlineSolution second = averaged;
  refiner.Apply(&second);
  for (int v = 0; v < 10; ++v) {
    const Eigen::Matrix3d& r = second.orientations.at(Key("cam", v));
    if (v >= 6) {
      EXPECT_EQ(r, first.orientations.at(Key("cam", v))) << v;  // held as published
    } else if (v >= 2) {
      EXPECT_NE(r, averaged.orientations.at(Key("cam", v))) << v;  // swept
    } else {
      EXPECT_EQ(r, averaged.orientations.at(Key("cam", v))) << v;  // next
    }
  }
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().corrected_keyframes, 10u);
  EXPECT_EQ(refiner.Pending(averaged), 0u);
  // Nothing left: the newest again. A later solution has them all pending.
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Pending(averaged), 0u);
  OnlineSolution later = averaged;
  later.sequence = 2;
  EXPECT_EQ(refiner.Pending(later), 10u);
  // Without the sweep back nothing is pending, and the second refinement
  // adjusts the newest four again.
  options.sweep_back = false;
  KeyframeRefiner newest(options);
  newest.Add(Edges(scene, "cam"));
  ASSERT_TRUE(newest.Refine(averaged));
  EXPECT_EQ(newest.Pending(averaged), 0u);
  ASSERT_TRUE(newest.Refine(averaged));
  EXPECT_EQ(newest.Stats().corrected_keyframes, 4u);
}

TEST(KeyframeRefiner, WithTheSweepBackTheOldestEdgesGoBeyondTheBudget) {
  const ArcScene scene = MakeArcScene(10, 0.5, 33);
  KeyframeRefinerOptions options;
  KeyframeRefiner all(options);
  all.Add(Edges(scene, "cam"));
  const std::size_t bytes = all.Stats().bytes;
  options.max_correspondence_mib = 0.5 * static_cast<double>(bytes) / (1024.0 * 1024.0);
  KeyframeRefiner budget(options);
  budget.Add(Edges(scene, "cam"));
  const KeyframeRefinerStats stats = budget.Stats();
  EXPECT_LE(static_cast<double>(stats.bytes), 0.9 * 0.5 * static_cast<double>(bytes));
  EXPECT_LT(stats.edges_held, 45u);
  // The edges among the oldest keyframes went first: the pair of the newest
  // two is held, and a refinement of them adjusts both.
  options.max_keyframes = 2;
  KeyframeRefiner newest(options);
  newest.Add(Edges(scene, "cam"));
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 34);
  ASSERT_TRUE(newest.Refine(averaged)) << newest.Stats().last_report;
  EXPECT_EQ(newest.Stats().corrected_keyframes, 2u);
  OnlineSolution published = averaged;
  newest.Apply(&published);
  EXPECT_NE(published.orientations.at(Key("cam", 8)), averaged.orientations.at(Key("cam", 8)));
  EXPECT_NE(published.orientations.at(Key("cam", 9)), averaged.orientations.at(Key("cam", 9)));
  KeyframeRefinerOptions bad;
  bad.max_correspondence_mib = 0.0;
  std::string error;
  EXPECT_FALSE(bad.Validate(&error));
  EXPECT_NE(error.find("refinement_max_correspondence_mib"), std::string::npos) << error;
}

// The arc's oldest five keyframes where the truth has them (a well-held
// stretch of the map), the newest five 0.3 deg off: the averaging of a long
// run whose window (five keyframes) has moved on.
OnlineSolution OldestFiveTrue(const ArcScene& scene, std::uint32_t seed) {
  OnlineSolution averaged = Averaged(scene, "cam", 0.3, seed);
  for (int v = 0; v < 5; ++v) averaged.orientations[Key("cam", v)] = scene.truth.at(v);
  return averaged;
}

// Largest angle (deg) of the keyframes from..to-1 from the truth, in the
// truth's frame (no gauge taken out).
double WorstInTheTruthsFrame(const OnlineSolution& published, const ArcScene& scene, int from, int to) {
  double worst = 0.0;
  for (int v = from; v < to; ++v) {
    worst = std::max(worst, RadToDeg(AngularDistanceRad(published.orientations.at(Key("cam", v)), scene.truth.at(v))));
  }
  return worst;
}

TEST(KeyframeRefiner, KeyframesBeforeTheWindowHoldItWhereTheAveragingHasThem) {
  // Held (hold_outside), the older keyframes the window's edges reach put
  // its keyframes in their frame; without them the window is an arc of its
  // own, turned to the averaging's keyframes of the window as a whole, and
  // keeps their common error.
  const ArcScene scene = MakeArcScene(10, 0.5, 23);
  double with_hold = 0.0, without = 0.0;
  for (bool hold : {true, false}) {
    KeyframeRefinerOptions options;
    options.max_keyframes = 5;
    options.hold_outside = hold;
    KeyframeRefiner refiner(options);
    refiner.Add(Edges(scene, "cam"));
    const OnlineSolution averaged = OldestFiveTrue(scene, 24);
    ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
    EXPECT_EQ(refiner.Stats().last_report.find("(5 held)") != std::string::npos, hold) << refiner.Stats().last_report;
    EXPECT_EQ(refiner.Stats().corrected_keyframes, 5u);
    OnlineSolution published = averaged;
    refiner.Apply(&published);
    for (int v = 0; v < 5; ++v) {
      EXPECT_EQ(published.orientations.at(Key("cam", v)), averaged.orientations.at(Key("cam", v)));  // not corrected
    }
    (hold ? with_hold : without) = WorstInTheTruthsFrame(published, scene, 5, 10);
  }
  std::cout << "the window's worst error in the truth's frame: older keyframes held " << with_hold << " deg, not held "
            << without << " deg\n";
  EXPECT_GT(WorstInTheTruthsFrame(OldestFiveTrue(scene, 24), scene, 5, 10), 0.2);
  EXPECT_LT(with_hold, 0.05);
  EXPECT_LT(with_hold, 0.5 * without);
}

TEST(KeyframeRefiner, BackgroundRefinementCallsBackAndApplies) {
  const ArcScene scene = MakeArcScene(8, 0.5, 19);
  auto averaged = std::make_shared<const OnlineSolution>(Averaged(scene, "cam", 0.3, 20));
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(Edges(scene, "cam"));
  std::atomic<int> called{0};
  std::atomic<bool> result{false};
  // `done` runs on the refinement's thread: its nice value is the caller's
  // plus background_niceness (the default, 10), and this thread's is as it was.
  errno = 0;
  const int caller_nice = getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)));
  ASSERT_EQ(errno, 0);
  std::atomic<int> refinement_nice{-100};
  ASSERT_TRUE(refiner.RefineInBackground(averaged, {}, [&](bool ok) {
    result = ok;
    refinement_nice = getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid)));
    ++called;
  }));
  refiner.Wait();
  EXPECT_EQ(called.load(), 1);
  EXPECT_TRUE(result.load());
  EXPECT_EQ(refinement_nice.load(), std::min(19, caller_nice + 10));
  EXPECT_EQ(getpriority(PRIO_PROCESS, static_cast<id_t>(syscall(SYS_gettid))), caller_nice);
  EXPECT_FALSE(refiner.Running());
  OnlineSolution published = *averaged;
  refiner.Apply(&published);
  EXPECT_EQ(published.refinement_sequence, 1u);
}

// Staged (the replay): what a background refinement finds lands at Commit,
// not when its thread ends, and is what the same refinement in the calling
// thread finds.
TEST(KeyframeRefiner, AStagedRefinementLandsAtCommit) {
  const ArcScene scene = MakeArcScene(8, 0.5, 19);
  auto averaged = std::make_shared<const OnlineSolution>(Averaged(scene, "cam", 0.3, 20));
  KeyframeRefiner here{KeyframeRefinerOptions()};
  here.Add(Edges(scene, "cam"));
  ASSERT_TRUE(here.Refine(*averaged));
  KeyframeRefiner staged{KeyframeRefinerOptions()};
  staged.Add(Edges(scene, "cam"));
  EXPECT_FALSE(staged.Commit());  // nothing staged
  ASSERT_TRUE(staged.RefineInBackground(averaged, {}, nullptr, true));
  staged.Wait();
  EXPECT_TRUE(staged.Corrections().empty());
  EXPECT_EQ(staged.Stats().runs, 0u);
  OnlineSolution published = *averaged;
  staged.Apply(&published);
  EXPECT_EQ(published.refinement_sequence, 0u);
  EXPECT_TRUE(staged.Commit());
  EXPECT_FALSE(staged.Commit());  // taken once
  EXPECT_EQ(staged.Stats().runs, 1u);
  EXPECT_EQ(staged.Stats().applied, 1u);
  const auto expected = here.Corrections();
  const auto corrections = staged.Corrections();
  ASSERT_EQ(corrections.size(), expected.size());
  for (const auto& [key, c] : expected) EXPECT_TRUE(corrections.at(key).isApprox(c, 1e-12)) << key.stamp_ns;
  staged.Apply(&published);
  EXPECT_EQ(published.refinement_sequence, 1u);
}

// A camera's focal length corrected by a factor (focal_calibration: apply):
// the points held, normalised with the former one, are divided by it, and
// the refinement is as if they had been normalised right.
TEST(KeyframeRefiner, ACorrectedFocalLengthRescalesThePointsHeld) {
  const ArcScene scene = MakeArcScene(8, 0.3, 21);
  const OnlineSolution averaged = Averaged(scene, "cam", 0.3, 22);
  auto refined_error = [&](double held_scale, double corrected_by) {
    std::vector<KeyframeCorrespondences> edges = Edges(scene, "cam");
    for (KeyframeCorrespondences& e : edges) {
      for (Eigen::Vector2d& p : e.points.points1) p *= held_scale;
      for (Eigen::Vector2d& p : e.points.points2) p *= held_scale;
    }
    KeyframeRefinerOptions options;
    options.estimate_focal = false;  // (with it, the adjustment would take up the wrong focal length itself)
    KeyframeRefiner refiner{options};
    refiner.Add(edges);
    refiner.ScaleCamera("other_camera", 2.0);  // not this one's: nothing changes
    if (corrected_by != 1.0) refiner.ScaleCamera("cam", corrected_by);
    EXPECT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
    OnlineSolution published = averaged;
    refiner.Apply(&published);
    return MaxErrorDeg(ById(published, "cam", 8), scene.truth);
  };
  const double right = refined_error(1.0, 1.0);
  const double wrong = refined_error(1.05, 1.0);
  const double corrected = refined_error(1.05, 1.05);
  EXPECT_GT(wrong, 2.0 * right) << right << " " << wrong;
  EXPECT_NEAR(corrected, right, 1e-6);
}

// A path (turned about every axis) seen with camera_info's focal length 3%
// short, and an averaging of it about 0.2 deg off.
struct ShortFocalPath {
  double truth = 1.0 / 0.97;
  ArcScene scene = MakePathScene(10, 0.5, truth, 5);  // (after truth: members are initialised in order)
  OnlineSolution averaged;
  ShortFocalPath() {
    averaged.sequence = 1;
    for (const auto& [id, r] : Perturbed(scene.truth, 0.2, 6)) averaged.orientations[Key("cam", id)] = r;
  }
};

// The refinement estimates each camera's focal length (general motion: a
// path, turned about every axis), relative to the one in use: camera_info
// 3% short is found within 0.5% and its deviation, and a correction
// (ScaleCamera) is taken into the estimate held and into the next
// refinement's, which then agrees with the corrected focal length.
TEST(KeyframeRefiner, EachCamerasFocalLengthIsEstimatedRelativeToTheOneInUse) {
  const ShortFocalPath path;
  const double truth = path.truth;
  const ArcScene& scene = path.scene;
  const OnlineSolution& averaged = path.averaged;
  KeyframeRefinerOptions options;
  options.hold_agreed_focal = false;  // every refinement estimates it
  KeyframeRefiner refiner{options};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  KeyframeRefinerStats stats = refiner.Stats();
  ASSERT_EQ(stats.focal.size(), 1u);
  BundleAdjustmentFocal::Estimate e = stats.focal.at("cam");
  EXPECT_EQ(stats.focal_refinement, 1u);
  EXPECT_EQ(e.views, 10);
  EXPECT_NEAR(e.scale, truth, 0.005);
  EXPECT_LT(std::abs(e.scale - truth), 3.0 * e.sigma + 1e-9);
  EXPECT_LT(3.0 * e.sigma, 0.01);
  // Corrected by the estimate: what is held is relative to the new focal length.
  const double corrected_by = e.scale;
  refiner.ScaleCamera("cam", corrected_by);
  e = refiner.Stats().focal.at("cam");
  EXPECT_NEAR(e.scale, 1.0, 1e-12);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  stats = refiner.Stats();
  EXPECT_EQ(stats.focal_refinement, 2u);
  e = stats.focal.at("cam");
  EXPECT_NEAR(e.scale * corrected_by, truth, 0.005);
  EXPECT_LT(std::abs(e.scale - 1.0), std::max(0.005, 3.0 * e.sigma));
  // A refinement under way when a correction lands: its estimate is taken
  // relative to the focal length in use by then.
  ASSERT_TRUE(refiner.RefineInBackground(std::make_shared<const OnlineSolution>(averaged), {}, nullptr, true));
  refiner.Wait();
  refiner.ScaleCamera("cam", 2.0);
  ASSERT_TRUE(refiner.Commit());
  EXPECT_NEAR(refiner.Stats().focal.at("cam").scale, e.scale / 2.0, 1e-9);

  KeyframeRefinerOptions fixed;
  fixed.estimate_focal = false;
  KeyframeRefiner without{fixed};
  without.Add(Edges(scene, "cam"));
  ASSERT_TRUE(without.Refine(averaged));
  EXPECT_TRUE(without.Stats().focal.empty());
}

TEST(KeyframeRefiner, AFocalLengthThatAgreesIsHeldUntilItIsCorrected) {
  // hold_agreed_focal: a camera_info 3% short is estimated (disagrees, not
  // held); once corrected, the next refinement finds the new focal length
  // agreeing, and the one after holds it (no estimate); a correction frees
  // it again.
  const ShortFocalPath path;
  const ArcScene& scene = path.scene;
  const OnlineSolution& averaged = path.averaged;
  KeyframeRefinerOptions options;
  options.hold_agreed_focal = true;
  KeyframeRefiner refiner{options};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  ASSERT_EQ(refiner.Stats().focal_refinement, 1u);
  const double found = refiner.Stats().focal.at("cam").scale;
  EXPECT_NEAR(found, path.truth, 0.005);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().focal_refinement, 2u);  // disagreed: estimated again
  refiner.ScaleCamera("cam", found);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  KeyframeRefinerStats stats = refiner.Stats();
  EXPECT_EQ(stats.focal_refinement, 3u);
  const BundleAdjustmentFocal::Estimate agreed = stats.focal.at("cam");
  ASSERT_EQ(JudgeFocalEstimate(agreed, options.focal_min_correction), FocalVerdict::kAgrees);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  stats = refiner.Stats();
  EXPECT_EQ(stats.runs, 4u);
  EXPECT_EQ(stats.focal_refinement, 3u);  // held: no new estimate
  EXPECT_EQ(stats.focal.at("cam").scale, agreed.scale);
  refiner.ScaleCamera("cam", 1.001);
  ASSERT_TRUE(refiner.Refine(averaged)) << refiner.Stats().last_report;
  EXPECT_EQ(refiner.Stats().focal_refinement, 5u);  // freed by the correction

  // Without the option every refinement estimates it.
  KeyframeRefinerOptions each_time;
  each_time.hold_agreed_focal = false;
  KeyframeRefiner free{each_time};
  free.Add(Edges(scene, "cam"));
  for (int run = 0; run < 2; ++run) ASSERT_TRUE(free.Refine(averaged));
  EXPECT_EQ(free.Stats().focal_refinement, 2u);
}

// A saved map keeps the corrections: written and read back to the bit of
// their quaternions, and a damaged file is refused with the reason.
TEST(KeyframeRefiner, CorrectionsAreSavedAndReadBackAndDamageIsRefused) {
  const ArcScene scene = MakeArcScene(8, 0.5, 23);
  KeyframeRefiner refiner{KeyframeRefinerOptions()};
  refiner.Add(Edges(scene, "cam"));
  ASSERT_TRUE(refiner.Refine(Averaged(scene, "cam", 0.3, 24)));
  char pattern[] = "/tmp/rotavg_refiner_XXXXXX";
  const std::string dir = mkdtemp(pattern);
  const std::string path = dir + "/map.refinement";
  std::string error;
  ASSERT_TRUE(refiner.SaveCorrections(path, &error)) << error;
  std::map<KeyframeKey, Eigen::Matrix3d> read;
  ASSERT_TRUE(KeyframeRefiner::ReadCorrections(path, &read, &error)) << error;
  const std::map<KeyframeKey, Eigen::Matrix3d> held = refiner.Corrections();
  ASSERT_EQ(read.size(), 8u);
  for (const auto& [key, c] : held) EXPECT_LT(RadToDeg(AngularDistanceRad(read.at(key), c)), 1e-9);

  // Taken by another refiner (a restarted node): applied as they were.
  KeyframeRefiner restarted{KeyframeRefinerOptions()};
  restarted.SetCorrections(read, true);
  OnlineSolution a = Averaged(scene, "cam", 0.3, 24), b = a;
  refiner.Apply(&a);
  restarted.Apply(&b);
  for (const auto& [key, r] : a.orientations) EXPECT_LT(RadToDeg(AngularDistanceRad(b.orientations.at(key), r)), 1e-9);
  // Beside those held, a keyframe held keeps its own.
  std::map<KeyframeKey, Eigen::Matrix3d> other = {{Key("cam", 0), Eigen::Matrix3d::Identity()},
                                                  {Key("other", 0), Eigen::Matrix3d::Identity()}};
  restarted.SetCorrections(other, false);
  EXPECT_EQ(restarted.Corrections().size(), 9u);
  EXPECT_FALSE(restarted.Corrections().at(Key("cam", 0)).isIdentity(1e-12));

  std::ifstream in(path);
  const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  auto refused = [&](const std::string& content, const std::string& why) {
    const std::string damaged = dir + "/damaged.refinement";
    std::ofstream(damaged) << content;
    std::map<KeyframeKey, Eigen::Matrix3d> none;
    std::string message;
    EXPECT_FALSE(KeyframeRefiner::ReadCorrections(damaged, &none, &message)) << why;
    EXPECT_NE(message.find(why), std::string::npos) << message;
    EXPECT_TRUE(none.empty());
  };
  refused(text.substr(0, text.rfind("END")), "no END record");
  refused("# another file\n" + text, "not a refinement file");
  std::string changed = text;
  changed[changed.find("CORRECTION cam") + 11] = 'k';  // "cam" -> "kam": the checksum no longer holds
  refused(changed, "");
  std::string not_unit = text;
  const std::size_t line = not_unit.find("CORRECTION");
  const std::size_t end_of_line = not_unit.find('\n', line);
  not_unit.replace(line, end_of_line - line, "CORRECTION cam 5 0.5 0 0 0");
  refused(not_unit, "");
  EXPECT_FALSE(KeyframeRefiner::ReadCorrections(dir + "/missing.refinement", &read, &error));
  EXPECT_NE(error.find("cannot open"), std::string::npos);
}

TEST(KeyframeRefiner, OptionsAreValidated) {
  std::string error;
  EXPECT_TRUE(KeyframeRefinerOptions().Validate(&error)) << error;
  KeyframeRefinerOptions options;
  options.max_keyframes = 2;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("refinement_max_keyframes"), std::string::npos);
  options = KeyframeRefinerOptions();
  options.max_correction_deg = std::nan("");
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("refinement_max_correction_deg"), std::string::npos);
}

}  // namespace
}  // namespace rotation_averaging
