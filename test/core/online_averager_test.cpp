#include "rotation_averaging/core/controllers/online_averager.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <functional>
#include <map>
#include <memory>
#include <limits>
#include <random>
#include <thread>
#include <tuple>

#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "common/synthetic_rig.h"

namespace rotation_averaging {
namespace {

double MedianErrorDeg(const OnlineSolution& s, const RigData& d) {
  NamedOrientations est, gt;
  for (const auto& [k, r] : s.orientations) est[OnlineAverager::KeyframeName(k)] = r;
  for (const auto& [k, r] : d.truth) gt[OnlineAverager::KeyframeName(k)] = r;
  const EvaluationResult e = EvaluateOrientations(est, gt);
  EXPECT_EQ(e.views_common, d.truth.size());
  return e.median_error_deg;
}

TEST(OnlineAverager, SolvesARigWithLoopClosuresAndOutliers) {
  const RigData d = MakeRig(60, 0.1, 1);
  OnlineAverager averager(OnlineAveragerOptions{});
  for (const auto& m : d.measurements) averager.AddRelativeRotation(m);
  ASSERT_TRUE(averager.SolveNow());
  const auto solution = averager.Solution();
  EXPECT_EQ(solution->sequence, 1u);
  EXPECT_EQ(solution->orientations.size(), 120u);
  // 0.5 deg edge noise along a mostly sequential rig: drift of about a degree
  // between the loop closures.
  const double magsac_error = MedianErrorDeg(*solution, d);
  EXPECT_LT(magsac_error, 1.0);
  // The squared loss on the same data is pulled by the 10% outliers.
  OnlineAveragerOptions squared;
  squared.averaging.loss = LossType::kSquared;
  OnlineAverager baseline(squared);
  for (const auto& m : d.measurements) baseline.AddRelativeRotation(m);
  ASSERT_TRUE(baseline.SolveNow());
  EXPECT_GT(MedianErrorDeg(*baseline.Solution(), d), 3.0 * magsac_error);
  const OnlineAveragerStats stats = averager.Stats();
  EXPECT_EQ(stats.accepted, d.measurements.size());
  EXPECT_EQ(stats.views, 120u);
  EXPECT_GT(stats.outlier_edges, 0u);
}

// Numerically hostile input on top of a good graph: a new pair of keyframes
// joined only by two contradictory edges with covariances 12 orders of
// magnitude apart, a component whose edges are all outliers, and confident
// outliers (covariance 1e-300 rad^2 .. 1e300) into the good component. Every
// solve ends with a status per component and finite orientations, and the
// good keyframes keep their accuracy.
TEST(OnlineAverager, NumericalFaultsEndFiniteAndKeepTheGoodKeyframes) {
  const RigData d = MakeRig(40, 0.0, 9);
  for (SolverType solver : {SolverType::kIrls, SolverType::kCeres}) {
    for (LossType loss : {LossType::kMagsac, LossType::kCauchy, LossType::kSquared}) {
      OnlineAveragerOptions options;
      options.averaging.loss = loss;
      options.averaging.solver = solver;
      OnlineAverager averager(options);
      for (const auto& m : d.measurements) averager.AddRelativeRotation(m);
      ASSERT_TRUE(averager.SolveNow());
      const double before = MedianErrorDeg(*averager.Solution(), d);
      KeyframeRelativeRotation m;
      m.has_covariance = true;
      m.keyframe1 = {"fault", 1};
      m.keyframe2 = {"fault", 2};
      m.rotation = ExpSO3(Eigen::Vector3d(0, 0, 1.0));
      m.covariance = 1e-12 * Eigen::Matrix3d::Identity();
      m.source = EdgeSource::kSequential;
      EXPECT_TRUE(averager.AddRelativeRotation(m));
      m.rotation = ExpSO3(Eigen::Vector3d(0, 0, -2.0));
      m.covariance = Eigen::Matrix3d::Identity();
      m.source = EdgeSource::kLoopClosure;
      EXPECT_TRUE(averager.AddRelativeRotation(m));
      for (int a = 0; a < 3; ++a) {  // a triangle of random edges
        m.keyframe1 = {"outliers", a};
        m.keyframe2 = {"outliers", (a + 1) % 3};
        m.rotation = ExpSO3(Eigen::Vector3d(2.0 * a - 1.0, -1.0, 0.5 * a));
        m.covariance = std::pow(10.0, -4.0 * a) * Eigen::Matrix3d::Identity();
        m.source = EdgeSource::kOther;
        EXPECT_TRUE(averager.AddRelativeRotation(m));
      }
      auto key = d.truth.begin();
      for (double c : {1e-300, 1e-30, 1e-12, 1e12, 1e300}) {  // confident (and hopeless) outliers
        const KeyframeKey a = (key++)->first, b = (key++)->first;
        m.keyframe1 = a;
        m.keyframe2 = b;
        m.rotation = d.truth.at(a) * d.truth.at(b).transpose() * ExpSO3(Eigen::Vector3d(1.5, 0.0, 0.0));
        m.covariance = c * Eigen::Matrix3d::Identity();
        std::string error;
        EXPECT_TRUE(averager.AddRelativeRotation(m, &error)) << c << ": " << error;
      }
      const std::uint64_t sequence = averager.Solution()->sequence;
      const bool solved = averager.SolveNow();
      const auto solution = averager.Solution();
      const std::string what = std::string(SolverTypeName(solver)) + " " + LossTypeName(loss);
      if (solved) {
        EXPECT_EQ(solution->sequence, sequence + 1) << what;
      } else {  // the previous good solution stays
        EXPECT_EQ(solution->sequence, sequence) << what;
        EXPECT_EQ(averager.Stats().failed_solves, 1u) << what;
      }
      for (const auto& [k, r] : solution->orientations) EXPECT_TRUE(IsRotationMatrix(r, 1e-9)) << what;
      for (const auto& c : solution->summary.components) EXPECT_FALSE(c.status.empty()) << what;
      for (const SolvedEdge& e : solution->edges) {
        EXPECT_TRUE(std::isfinite(e.residual_deg) && std::isfinite(e.robust_weight)) << what;
      }
      // The good keyframes: robust losses ignore the faults; the squared loss
      // is pulled, but stays finite.
      const double after = MedianErrorDeg(*solution, d);
      if (loss != LossType::kSquared) EXPECT_LT(after, std::max(1.0, 2.0 * before)) << what;
      EXPECT_TRUE(std::isfinite(after)) << what;
    }
  }
}

TEST(OnlineAverager, RejectsAndCountsBadInput) {
  OnlineAverager averager(OnlineAveragerOptions{});
  KeyframeRelativeRotation m;
  m.keyframe1 = {"cam", 1};
  m.keyframe2 = {"cam", 2};
  std::string why;
  KeyframeRelativeRotation nan = m;
  nan.rotation(1, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(averager.AddRelativeRotation(nan, &why));
  KeyframeRelativeRotation self = m;
  self.keyframe2 = self.keyframe1;
  EXPECT_FALSE(averager.AddRelativeRotation(self, &why));
  EXPECT_NE(why.find("itself"), std::string::npos);
  KeyframeRelativeRotation bad_cov = m;
  bad_cov.has_covariance = true;
  bad_cov.covariance = -Eigen::Matrix3d::Identity();
  EXPECT_FALSE(averager.AddRelativeRotation(bad_cov, &why));
  KeyframeRelativeRotation no_frame = m;
  no_frame.keyframe1.frame_id.clear();
  EXPECT_FALSE(averager.AddRelativeRotation(no_frame, &why));
  KeyframeRelativeRotation scaled = m;
  scaled.rotation *= 2.0;
  EXPECT_FALSE(averager.AddRelativeRotation(scaled, &why));
  EXPECT_TRUE(averager.AddRelativeRotation(m, &why));
  const OnlineAveragerStats stats = averager.Stats();
  EXPECT_EQ(stats.received, 6u);
  EXPECT_EQ(stats.rejected_invalid, 5u);
  ASSERT_TRUE(averager.SolveNow());
  EXPECT_EQ(averager.Stats().edges, 1u);
}

TEST(OnlineAverager, BoundedQueueDropsAndCounts) {
  OnlineAveragerOptions options;
  options.max_queue = 5;
  OnlineAverager averager(options);
  const RigData d = MakeRig(10, 0.0, 2);
  int accepted = 0;
  for (int k = 0; k < 10; ++k) accepted += averager.AddRelativeRotation(d.measurements[k]);
  EXPECT_EQ(accepted, 5);
  EXPECT_EQ(averager.Stats().dropped_queue_full, 5u);
  averager.SolveNow();  // drains the queue: room again
  EXPECT_TRUE(averager.AddRelativeRotation(d.measurements[10]));
}

TEST(OnlineAverager, ViewAndEdgeCapsDropAndCount) {
  const RigData d = MakeRig(30, 0.0, 4);
  OnlineAveragerOptions options;
  options.max_views = 12;
  OnlineAverager by_views(options);
  for (const auto& m : d.measurements) by_views.AddRelativeRotation(m);
  ASSERT_TRUE(by_views.SolveNow());
  OnlineAveragerStats s = by_views.Stats();
  EXPECT_EQ(s.views, 12u);
  EXPECT_GT(s.dropped_cap, 0u);
  EXPECT_EQ(s.accepted + s.dropped_cap, d.measurements.size());
  EXPECT_EQ(by_views.Solution()->orientations.size(), 12u);
  for (const auto& [k, r] : by_views.Solution()->orientations) EXPECT_TRUE(IsRotationMatrix(r, 1e-9));

  options.max_views = 1000000;
  options.max_edges = 20;
  OnlineAverager by_edges(options);
  for (const auto& m : d.measurements) by_edges.AddRelativeRotation(m);
  ASSERT_TRUE(by_edges.SolveNow());
  s = by_edges.Stats();
  EXPECT_EQ(s.edges, 20u);
  EXPECT_EQ(s.dropped_cap, d.measurements.size() - 20u);
}

TEST(OnlineAverager, WorkerSolvesPeriodicallyAndWarmStarts) {
  OnlineAveragerOptions options;
  options.solve_period_s = 0.05;
  OnlineAverager averager(options);
  std::atomic<int> callbacks{0};
  averager.SetSolutionCallback([&](std::shared_ptr<const OnlineSolution>) { ++callbacks; });
  averager.Start();
  const RigData d = MakeRig(40, 0.0, 3);
  const std::size_t half = d.measurements.size() / 2;
  for (std::size_t k = 0; k < half; ++k) averager.AddRelativeRotation(d.measurements[k]);
  auto wait_for = [&](std::uint64_t sequence) {
    for (int i = 0; i < 200 && averager.Solution()->sequence < sequence; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return averager.Solution()->sequence >= sequence;
  };
  ASSERT_TRUE(wait_for(1));
  const std::uint64_t first = averager.Solution()->sequence;
  for (std::size_t k = half; k < d.measurements.size(); ++k) averager.AddRelativeRotation(d.measurements[k]);
  ASSERT_TRUE(wait_for(first + 1));
  // Wait until every measurement has left the queue for the graph; the solve
  // that took the last ones may still run, and Stop lets it finish. (Stopping
  // with measurements still queued made the restart below solve them: flaky.)
  for (int i = 0; i < 200 && averager.Stats().accepted < d.measurements.size(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  ASSERT_EQ(averager.Stats().accepted, d.measurements.size());
  averager.Stop();
  EXPECT_GE(callbacks.load(), 2);
  EXPECT_EQ(averager.Solution()->orientations.size(), 80u);
  EXPECT_LT(MedianErrorDeg(*averager.Solution(), d), 1.0);
  // Nothing new: the worker does not re-solve for nothing.
  const std::uint64_t solves = averager.Stats().solves;
  averager.Start();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  averager.Stop();
  EXPECT_EQ(averager.Stats().solves, solves);
}

TEST(OnlineAverager, ChangingOptionsSolvesColdButKeepsTheFrame) {
  const RigData d = MakeRig(30, 0.1, 6);
  OnlineAverager a(OnlineAveragerOptions{});
  for (const auto& m : d.measurements) a.AddRelativeRotation(m);
  ASSERT_TRUE(a.SolveNow());
  const auto first = a.Solution();
  RotationAveragingOptions squared;
  squared.loss = LossType::kSquared;
  a.SetAveragingOptions(squared);
  ASSERT_TRUE(a.SolveNow());
  a.SetAveragingOptions(RotationAveragingOptions());
  ASSERT_TRUE(a.SolveNow());
  const auto back = a.Solution();
  // Back to MAGSAC from a cold start: the same solution, in the same frame
  // (no global rotation between them).
  double worst = 0.0;
  for (const auto& [key, r] : first->orientations) worst = std::max(worst, AngularDistanceRad(r, back->orientations.at(key)));
  EXPECT_LT(RadToDeg(worst), 0.05);
}

int CaptureOf(const KeyframeKey& key) { return static_cast<int>((key.stamp_ns - 1'000'000'000LL) / 100'000'000LL); }

// Feeds a rig capture by capture: the first `start` captures at once, then
// one capture (its keyframes and edges to earlier ones) per SolveNow; the
// rig's closing loop closures last.
void FeedCaptures(const RigData& d, int start, OnlineAverager* averager,
                  const std::function<void(int capture, const OnlineSolution& before)>& after_solve = nullptr) {
  std::map<int, std::vector<KeyframeRelativeRotation>> by_capture;
  std::vector<KeyframeRelativeRotation> loops;
  for (const auto& m : d.measurements) {
    if (m.source == EdgeSource::kLoopClosure) loops.push_back(m);
    else by_capture[std::max(CaptureOf(m.keyframe1), CaptureOf(m.keyframe2))].push_back(m);
  }
  for (const auto& [c, ms] : by_capture) {
    for (const auto& m : ms) ASSERT_TRUE(averager->AddRelativeRotation(m));
    if (c < start - 1) continue;
    const std::shared_ptr<const OnlineSolution> before = averager->Solution();
    ASSERT_TRUE(averager->SolveNow());
    if (after_solve) after_solve(c, *before);
  }
  for (const auto& m : loops) ASSERT_TRUE(averager->AddRelativeRotation(m));
  ASSERT_TRUE(averager->SolveNow());
}

// Local re-solves (forced on a small graph): after each new capture only
// keyframes near it move, a full solve comes every full_solve_every + 1
// solves, and the end result is as accurate as solving everything in full.
TEST(OnlineAverager, LocalSolvesMoveOnlyTheNeighbourhoodAndStayAccurate) {
  const RigData d = MakeRig(150, 0.05, 12);
  OnlineAveragerOptions options;
  options.local_solve_min_views = 50;
  options.full_solve_every = 4;
  options.background_full_solves = false;  // deterministic: the due full solve runs in SolveNow
  options.local.hops = 2;
  OnlineAverager averager(options);
  int local = 0, full = 0, far_moved = 0;
  FeedCaptures(d, 60, &averager, [&](int capture, const OnlineSolution& before) {
    const auto after = averager.Solution();
    if (capture == 59) return;  // the first, cold solve
    (after->local ? local : full)++;
    if (!after->local) return;
    // Keyframes more than a few captures back (2 hops = 2 captures along the
    // sequential edges, the rig edge to the other camera, ...) did not move.
    for (const auto& [key, r] : before.orientations) {
      if (CaptureOf(key) < capture - 6 && !(after->orientations.at(key) == r)) ++far_moved;
    }
    EXPECT_EQ(after->orientations.size(), 2u * (capture + 1));
  });
  EXPECT_EQ(far_moved, 0);
  // 90 captures after the cold solve: 4 local, then one full, and so on.
  EXPECT_EQ(local, 72);
  EXPECT_EQ(full, 18);
  // The loop closures (the last solve) make a full solve due at once: the
  // loop's error is spread over the whole loop, not the neighbourhoods of
  // its ends.
  EXPECT_EQ(averager.Stats().local_solves, 72u);
  EXPECT_FALSE(averager.Solution()->local);
  OnlineAveragerOptions all_full = options;
  all_full.local_solve_min_views = 0;
  OnlineAverager reference(all_full);
  for (const auto& m : d.measurements) reference.AddRelativeRotation(m);
  ASSERT_TRUE(reference.SolveNow());
  const double local_error = MedianErrorDeg(*averager.Solution(), d);
  const double full_error = MedianErrorDeg(*reference.Solution(), d);
  EXPECT_LT(local_error, 1.0);
  EXPECT_NEAR(local_error, full_error, 0.05);
  // A full solve on request (nothing new) is the same solution again.
  ASSERT_TRUE(averager.SolveFullNow());
  EXPECT_FALSE(averager.Solution()->local);
  EXPECT_NEAR(MedianErrorDeg(*averager.Solution(), d), local_error, 1e-3);
  // Every edge has a result in the published solution, local or not.
  EXPECT_EQ(averager.Solution()->edges.size(), d.measurements.size());
}

// The periodic full solve in a second thread: taken by a later solve once
// finished; Reset while it runs drops it.
TEST(OnlineAverager, BackgroundFullSolvesAreTakenAndResetDropsThem) {
  const RigData d = MakeRig(100, 0.05, 13);
  OnlineAveragerOptions options;
  options.local_solve_min_views = 50;
  options.full_solve_every = 3;
  OnlineAverager averager(options);
  FeedCaptures(d, 40, &averager);
  for (int i = 0; i < 500 && averager.Stats().background_solves == 0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    ASSERT_TRUE(averager.SolveNow());
  }
  const OnlineAveragerStats stats = averager.Stats();
  EXPECT_GE(stats.background_solves, 1u);
  EXPECT_GE(stats.local_solves, 50u);
  EXPECT_EQ(averager.Solution()->orientations.size(), 200u);
  EXPECT_LT(MedianErrorDeg(*averager.Solution(), d), 1.0);
  // Start a background solve (three local solves), reset at once, then a new graph.
  const RigData other = MakeRig(60, 0.0, 14);
  averager.Reset();
  FeedCaptures(other, 30, &averager);
  averager.Reset();
  for (const auto& m : other.measurements) averager.AddRelativeRotation(m);
  ASSERT_TRUE(averager.SolveNow());
  for (int i = 0; i < 20; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
    averager.SolveNow();
  }
  EXPECT_EQ(averager.Solution()->orientations.size(), 120u);
  EXPECT_LT(MedianErrorDeg(*averager.Solution(), other), 1.0);
}

// Background solves after the first replay on their own copy of the graph
// what was added since the one before: each solve taken has a result for
// every edge added so far, at the orientations it publishes.
TEST(OnlineAverager, BackgroundSolvesSeeEverythingAddedBeforeThem) {
  const RigData d = MakeRig(100, 0.05, 16);
  OnlineAveragerOptions options;
  options.local_solve_min_views = 50;
  options.full_solve_every = 2;
  OnlineAverager averager(options);
  std::map<std::tuple<std::string, std::string, EdgeSource>, Eigen::Matrix3d> measured;
  for (const auto& m : d.measurements) {
    measured[{OnlineAverager::KeyframeName(m.keyframe1), OnlineAverager::KeyframeName(m.keyframe2), m.source}] =
        m.rotation;
  }
  std::uint64_t taken = 0;
  int checked = 0;
  FeedCaptures(d, 40, &averager, [&](int, const OnlineSolution&) {
    const OnlineAveragerStats stats = averager.Stats();
    if (stats.background_solves > taken) {
      taken = stats.background_solves;
      const auto solution = averager.Solution();
      EXPECT_EQ(solution->edges.size(), stats.edges);
      double worst = 0.0;
      for (const SolvedEdge& e : solution->edges) {
        const Eigen::Matrix3d& m = measured.at(
            {OnlineAverager::KeyframeName(e.keyframe1), OnlineAverager::KeyframeName(e.keyframe2), e.source});
        const Eigen::Matrix3d r = m.transpose() * solution->orientations.at(e.keyframe1) *
                                  solution->orientations.at(e.keyframe2).transpose();
        worst = std::max(worst, std::abs(RadToDeg(LogSO3(r).norm()) - e.residual_deg));
      }
      EXPECT_LT(worst, 1e-6) << "background solve " << taken;
      ++checked;
    }
    // Time for the background solve to finish before the next capture.
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  });
  EXPECT_GE(checked, 3);
}

// An edge that joins two components solved apart (each in its own gauge)
// cannot be solved locally: the averager solves in full and the joined
// component ends in one frame.
TEST(OnlineAverager, JoiningComponentsTakesAFullSolve) {
  const RigData d = MakeRig(60, 0.0, 15);
  for (std::size_t min_views : {std::size_t{50}, std::size_t{0}}) {  // local solves on / off
    SCOPED_TRACE("local_solve_min_views " + std::to_string(min_views));
    OnlineAveragerOptions options;
    options.local_solve_min_views = min_views;
    options.background_full_solves = false;
    OnlineAverager averager(options);
    // Captures 0-29 and 30-59 as two components (the edges between them held back).
    std::vector<KeyframeRelativeRotation> bridge;
    for (const auto& m : d.measurements) {
      const bool first = CaptureOf(m.keyframe1) < 30, second = CaptureOf(m.keyframe2) < 30;
      if (first != second) bridge.push_back(m);
      else averager.AddRelativeRotation(m);
    }
    ASSERT_FALSE(bridge.empty());
    ASSERT_TRUE(averager.SolveNow());
    EXPECT_EQ(averager.Stats().components, 2u);
    averager.AddRelativeRotation(bridge.front());
    ASSERT_TRUE(averager.SolveNow());
    EXPECT_FALSE(averager.Solution()->local);
    EXPECT_EQ(averager.Stats().components, 1u);
    EXPECT_LT(MedianErrorDeg(*averager.Solution(), d), 1.0);
    // Within the joined component, local solves again (loop closures would
    // make a full solve due).
    for (std::size_t k = 1; k < bridge.size(); ++k) {
      if (bridge[k].source != EdgeSource::kLoopClosure) averager.AddRelativeRotation(bridge[k]);
    }
    ASSERT_TRUE(averager.SolveNow());
    EXPECT_EQ(averager.Solution()->local, min_views > 0);
    EXPECT_LT(MedianErrorDeg(*averager.Solution(), d), 1.0);
  }
}

double WorstMoveDeg(const OnlineSolution& from, const OnlineSolution& to) {
  double worst = 0.0;
  for (const auto& [key, r] : from.orientations) {
    const auto it = to.orientations.find(key);
    EXPECT_NE(it, to.orientations.end()) << OnlineAverager::KeyframeName(key);
    if (it != to.orientations.end()) worst = std::max(worst, AngularDistanceRad(r, it->second));
  }
  return RadToDeg(worst);
}

// A node restarted on its saved graph publishes the old keyframes where it
// published them before: the orientations saved with the graph are the
// first solve's start and keep its gauge. The map grows capture by capture,
// so its frame is the one of its first solve; a cold solve of the whole
// graph (a file without orientations) picks another gauge.
TEST(OnlineAverager, ALoadedGraphKeepsThePublishedFrames) {
  const RigData d = MakeRig(40, 0.05, 9);
  OnlineAverager a(OnlineAveragerOptions{});
  FeedCaptures(d, 3, &a);
  const std::shared_ptr<const OnlineSolution> saved = a.Solution();
  const std::string path =
      (std::filesystem::temp_directory_path() / ("rotavg_frames_" + std::to_string(::getpid()) + ".txt")).string();
  std::string error;
  ASSERT_TRUE(a.SaveGraph(path, &error)) << error;
  OnlineAverager b(OnlineAveragerOptions{});
  ASSERT_TRUE(b.LoadGraph(path, &error)) << error;
  EXPECT_LT(WorstMoveDeg(*saved, *b.Solution()), 0.01);

  // The same graph without its orientations (format v1).
  ViewGraph graph;
  std::map<ViewId, Eigen::Matrix3d> orientations;
  ASSERT_TRUE(ReadRotavgGraph(path, &graph, &orientations).ok());
  EXPECT_EQ(orientations.size(), saved->orientations.size());
  ASSERT_TRUE(WriteRotavgGraph(path, graph, &error)) << error;
  OnlineAverager cold(OnlineAveragerOptions{});
  ASSERT_TRUE(cold.LoadGraph(path, &error)) << error;
  EXPECT_GT(WorstMoveDeg(*saved, *cold.Solution()), 1.0);
  EXPECT_LT(MedianErrorDeg(*cold.Solution(), d), 1.0);
  std::filesystem::remove(path);
}

// Maps of two sessions added together: each keeps the frames it was
// published in, apart, until edges join them; then the larger keeps its
// frame and the other is placed in it. A map that continued one held (saved
// from the same history) adds only what it has beyond it.
TEST(OnlineAverager, AddedGraphsKeepTheirFramesUntilJoined) {
  const RigData d = MakeRig(40, 0.0, 10);
  auto part = [&](int from, int to) {  // edges among captures [from, to)
    std::vector<KeyframeRelativeRotation> out;
    for (const auto& m : d.measurements) {
      const int a = CaptureOf(m.keyframe1), b = CaptureOf(m.keyframe2);
      if (a >= from && a < to && b >= from && b < to) out.push_back(m);
    }
    return out;
  };
  auto session = [&](const std::vector<KeyframeRelativeRotation>& edges, const std::string& path) {
    auto averager = std::make_unique<OnlineAverager>(OnlineAveragerOptions{});
    for (const auto& m : edges) EXPECT_TRUE(averager->AddRelativeRotation(m));
    EXPECT_TRUE(averager->SolveNow());
    std::string error;
    EXPECT_TRUE(averager->SaveGraph(path, &error)) << error;
    return averager;
  };
  const std::string dir = std::filesystem::temp_directory_path().string();
  const std::string a_path = dir + "/rotavg_add_a_" + std::to_string(::getpid()) + ".txt";
  const std::string b_path = dir + "/rotavg_add_b_" + std::to_string(::getpid()) + ".txt";
  const std::string c_path = dir + "/rotavg_add_c_" + std::to_string(::getpid()) + ".txt";
  const auto a = session(part(0, 25), a_path);
  const auto b = session(part(25, 40), b_path);
  std::vector<KeyframeRelativeRotation> continued = part(0, 25);
  for (const auto& m : part(25, 32)) {
    if (CaptureOf(m.keyframe1) >= 25 || CaptureOf(m.keyframe2) >= 25) continued.push_back(m);
  }
  for (const auto& m : d.measurements) {  // the edges from the first map into the continuation
    const int x = CaptureOf(m.keyframe1), y = CaptureOf(m.keyframe2);
    if (std::min(x, y) < 25 && std::max(x, y) >= 25 && std::max(x, y) < 32) continued.push_back(m);
  }
  const auto c = session(continued, c_path);

  OnlineAverager merged(OnlineAveragerOptions{});
  std::string error;
  ASSERT_TRUE(merged.LoadGraph(a_path, &error)) << error;
  OnlineAverager::AddedGraph added;
  ASSERT_TRUE(merged.AddGraph(b_path, &added, &error)) << error;
  EXPECT_EQ(added.views, 30u);
  EXPECT_EQ(added.views_held, 0u);
  EXPECT_EQ(merged.Stats().components, 2u);
  EXPECT_LT(WorstMoveDeg(*a->Solution(), *merged.Solution()), 0.01);
  EXPECT_LT(WorstMoveDeg(*b->Solution(), *merged.Solution()), 0.01);

  // The edges between the two (a third session passing both places) join
  // them: the larger map keeps its frame, the other is placed in it.
  for (const auto& m : d.measurements) {
    if ((CaptureOf(m.keyframe1) < 25) != (CaptureOf(m.keyframe2) < 25)) ASSERT_TRUE(merged.AddRelativeRotation(m));
  }
  ASSERT_TRUE(merged.SolveNow());
  EXPECT_EQ(merged.Stats().components, 1u);
  EXPECT_LT(WorstMoveDeg(*a->Solution(), *merged.Solution()), 1.0);
  EXPECT_LT(MedianErrorDeg(*merged.Solution(), d), 1.0);

  // The continued map shares the first map's keyframes and edges.
  OnlineAverager shared(OnlineAveragerOptions{});
  ASSERT_TRUE(shared.LoadGraph(a_path, &error)) << error;
  ASSERT_TRUE(shared.AddGraph(c_path, &added, &error)) << error;
  EXPECT_EQ(added.views_held, 50u);
  EXPECT_EQ(added.views, 14u);
  EXPECT_EQ(added.edges_held, part(0, 25).size());
  EXPECT_EQ(shared.Stats().edges, continued.size());
  EXPECT_EQ(shared.Stats().components, 1u);
  EXPECT_LT(WorstMoveDeg(*a->Solution(), *shared.Solution()), 0.5);
  // A file that is not a graph changes nothing.
  EXPECT_FALSE(shared.AddGraph(dir + "/rotavg_no_such_map.txt", &added, &error));
  EXPECT_EQ(shared.Stats().edges, continued.size());
  for (const std::string& p : {a_path, b_path, c_path}) std::filesystem::remove(p);
}

TEST(OnlineAverager, SaveLoadAndReset) {
  const RigData d = MakeRig(30, 0.05, 4);
  OnlineAverager a(OnlineAveragerOptions{});
  for (const auto& m : d.measurements) a.AddRelativeRotation(m);
  ASSERT_TRUE(a.SolveNow());
  const std::string path =
      (std::filesystem::temp_directory_path() / ("rotavg_online_" + std::to_string(::getpid()) + ".txt")).string();
  std::string error;
  ASSERT_TRUE(a.SaveGraph(path, &error)) << error;
  OnlineAverager b(OnlineAveragerOptions{});
  ASSERT_TRUE(b.LoadGraph(path, &error)) << error;
  EXPECT_EQ(b.Stats().edges, a.Stats().edges);
  EXPECT_EQ(b.Solution()->orientations.size(), a.Solution()->orientations.size());
  EXPECT_LT(MedianErrorDeg(*b.Solution(), d), 1.0);
  b.Reset();
  EXPECT_TRUE(b.Solution()->orientations.empty());
  EXPECT_EQ(b.Stats().views, 0u);
  EXPECT_FALSE(b.SolveNow());  // nothing to solve
  std::filesystem::remove(path);
  KeyframeKey key;
  EXPECT_TRUE(OnlineAverager::ParseKeyframeName("cam_left@123456789", &key));
  EXPECT_EQ(key.frame_id, "cam_left");
  EXPECT_EQ(key.stamp_ns, 123456789);
  EXPECT_FALSE(OnlineAverager::ParseKeyframeName("no_stamp", &key));
  EXPECT_FALSE(OnlineAverager::ParseKeyframeName("cam@12x", &key));
}

}  // namespace
}  // namespace rotation_averaging
