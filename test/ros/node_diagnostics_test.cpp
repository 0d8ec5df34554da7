// The node's diagnostics (FillDiagnostics), built from a snapshot of its
// state without a master: the summary names the first thing wrong, in the
// order a user must act on it, and every counter is reported under its key.
#include "rotation_averaging/ros/node_diagnostics.h"

#include <gtest/gtest.h>

#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/ros/node.h"

namespace rotation_averaging {
namespace {

std::map<std::string, std::string> Values(const diagnostic_updater::DiagnosticStatusWrapper& status) {
  std::map<std::string, std::string> values;
  for (const diagnostic_msgs::KeyValue& kv : status.values) values[kv.key] = kv.value;
  return values;
}

diagnostic_updater::DiagnosticStatusWrapper Fill(const NodeStatus& s) {
  diagnostic_updater::DiagnosticStatusWrapper status;
  FillDiagnostics(s, &status);
  return status;
}

NodeStatus Healthy() {
  NodeStatus s;
  s.averager.views = 12;
  s.averager.edges = 30;
  s.averager.solves = 4;
  s.averager.last_solve_s = 0.01;
  s.solve_period_s = 1.0;
  return s;
}

TEST(NodeDiagnostics, AHealthyNodeIsOkAndReportsItsCounters) {
  NodeStatus s = Healthy();
  s.pipeline.frames = 40;
  s.pipeline.selection_s = 0.08;
  const diagnostic_updater::DiagnosticStatusWrapper status = Fill(s);
  EXPECT_EQ(status.level, diagnostic_msgs::DiagnosticStatus::OK);
  EXPECT_EQ(status.message, "ok");
  const std::map<std::string, std::string> v = Values(status);
  EXPECT_EQ(v.at("keyframes"), "12");
  EXPECT_EQ(v.at("edges"), "30");
  EXPECT_EQ(v.at("keyframe selection per image (ms)"), "2");
  EXPECT_EQ(v.at("solve period (s)"), "1");
  // Rates and the front end's figures only where there are some.
  EXPECT_EQ(v.count("keyframe images per second"), 0u);
  EXPECT_EQ(v.count("image queue (keyframes waiting)"), 0u);
}

TEST(NodeDiagnostics, TheSummaryNamesTheFirstProblemInOrder) {
  {
    NodeStatus s = Healthy();
    s.averager.failed_solves = s.averager.solves;
    s.averager.dropped_cap = 3;
    EXPECT_EQ(Fill(s).level, diagnostic_msgs::DiagnosticStatus::ERROR);
    EXPECT_EQ(Fill(s).message, "every solve failed");
  }
  {
    NodeStatus s = Healthy();
    s.averager.last_solve_s = 2.0;
    s.averager.dropped_queue_full = 1;
    EXPECT_EQ(Fill(s).level, diagnostic_msgs::DiagnosticStatus::WARN);
    EXPECT_EQ(Fill(s).message, "solve time exceeds the solve period");
  }
  {
    NodeStatus s = Healthy();
    s.averager.dropped_cap = 1;
    s.dropped_images = 5;
    EXPECT_EQ(Fill(s).message, "input dropped (queue full or caps reached)");
  }
  {
    NodeStatus s = Healthy();
    s.focal_checks["cam_b"].disagrees = true;
    s.focal_checks["cam_a"].distortion_unmodelled = true;
    s.focal_checks["cam_c"].distortion_unmodelled = true;
    EXPECT_EQ(Fill(s).message, "images are distorted but camera_info has no distortion model: cam_a, cam_c");
    s.focal_checks.clear();
    s.focal_checks["cam_b"].disagrees = true;
    EXPECT_EQ(Fill(s).message, "camera_info's focal length disagrees with the images of cam_b");
  }
  {
    NodeStatus s = Healthy();
    s.dropped_images = 2;
    EXPECT_EQ(Fill(s).level, diagnostic_msgs::DiagnosticStatus::WARN);
    EXPECT_EQ(Fill(s).message, "keyframe images dropped: they come faster than the front end processes them");
    // Frames that never reached keyframe selection come after it.
    s.pipeline.frames_missing = 3;
    EXPECT_EQ(Fill(s).message, "keyframe images dropped: they come faster than the front end processes them");
    s.dropped_images = 0;
    EXPECT_EQ(Fill(s).level, diagnostic_msgs::DiagnosticStatus::WARN);
    EXPECT_EQ(Fill(s).message,
              "images missing from the camera streams (gaps in their stamps): the driver, the network or "
              "image_transport_queue lost them, and keyframe selection did not see them");
    EXPECT_EQ(Values(Fill(s)).at("images missing by their cameras' stamps (lost before the node)"), "3");
    // A solve period of 0 (solves on request only) never overruns.
    s.pipeline.frames_missing = 0;
    s.solve_period_s = 0.0;
    s.averager.last_solve_s = 5.0;
    EXPECT_EQ(Fill(s).message, "ok");
  }
}

// The background refinement's counters; its latest run that changed
// nothing is a warning (the averaging's orientations are published), after
// every problem with the input.
TEST(NodeDiagnostics, TheRefinementIsReportedAndWarnsWhenItChangedNothing) {
  NodeStatus s = Healthy();
  s.has_frontend = true;
  s.refinement = true;
  s.refinement_stats.runs = 3;
  s.refinement_stats.applied = 3;
  s.refinement_stats.corrected_keyframes = 40;
  s.refinement_stats.covariance_keyframes = 38;
  s.refinement_stats.last_ok = true;
  s.refinement_stats.last_report = "bundle adjustment: 40 views";
  s.refinement_stats.times.Add(0.25);
  diagnostic_updater::DiagnosticStatusWrapper status = Fill(s);
  EXPECT_EQ(status.message, "ok");
  std::map<std::string, std::string> v = Values(status);
  EXPECT_EQ(v.at("refinements run"), "3");
  EXPECT_EQ(v.at("keyframes corrected by the refinement"), "40");
  EXPECT_EQ(v.at("of them, with the refinement's covariance"), "38");
  EXPECT_EQ(v.at("time per refinement, median (ms)"), "250");
  EXPECT_EQ(v.at("refinement, latest"), "bundle adjustment: 40 views");
  s.refinement_stats.runs = 4;
  s.refinement_stats.failed = 1;
  s.refinement_stats.last_ok = false;
  status = Fill(s);
  EXPECT_EQ(status.level, diagnostic_msgs::DiagnosticStatus::WARN);
  EXPECT_EQ(status.message, "the latest refinement changed nothing (the averaging's orientations are published)");
  s.dropped_images = 1;
  EXPECT_EQ(Fill(s).message, "keyframe images dropped: they come faster than the front end processes them");
  // Without the refinement, none of its keys.
  s.refinement = false;
  EXPECT_EQ(Values(Fill(s)).count("refinements run"), 0u);
}

TEST(NodeDiagnostics, TheFrontEndsFiguresAreReportedWithIt) {
  NodeStatus s = Healthy();
  s.has_frontend = true;
  s.has_rates = true;
  s.keyframe_images_per_s = 2.5;
  s.image_queue = 3;
  s.max_image_queue = 8;
  s.latency.Add(0.1);
  s.latency.Add(0.3);
  s.retrieval = "vocabulary";
  s.frontend.loop_closure_edges = 7;
  s.pipeline.rejected_images = 1;
  s.images_without_info = 2;
  s.focal_corrections["cam_b"] = 1.03;
  s.frontend.pair_times.Add(0.006);
  s.frontend.pair_times.Add(0.004);
  s.pipeline.image_times.Add(0.002);
  s.pipeline.keyframe_times.Add(0.030);
  s.focal_check_times.Add(0.250);
  s.focal_check_times.Add(0.150);
  s.focal_check_times.Add(0.200);
  const std::map<std::string, std::string> v = Values(Fill(s));
  EXPECT_EQ(v.at("focal-length check estimates"), "3");
  EXPECT_EQ(v.at("time per focal-length check estimate, median (ms)"), "200");
  EXPECT_EQ(v.at("time per focal-length check estimate, p95 (ms)"), "250");
  EXPECT_EQ(v.at("keyframe images per second"), "2.5");
  EXPECT_EQ(v.at("time per two-view pair, median (ms)"), "4");
  EXPECT_EQ(v.at("time per two-view pair, p95 (ms)"), "6");
  EXPECT_EQ(v.at("time per image (decoding, checks, selection), median (ms)"), "2");
  EXPECT_EQ(v.at("time per keyframe (front end), p95 (ms)"), "30");
  EXPECT_EQ(v.at("image queue (keyframes waiting)"), "3");
  EXPECT_EQ(v.at("image queue capacity"), "8");
  EXPECT_EQ(v.at("front-end latency per keyframe, last (ms)"), "300");
  EXPECT_EQ(v.at("front-end latency per keyframe, mean of the last 50 (ms)"), "200");
  EXPECT_EQ(v.at("loop-closure retrieval"), "vocabulary");
  EXPECT_EQ(v.at("loop-closure edges"), "7");
  EXPECT_EQ(v.at("rejected images"), "3");  // the pipeline's and those before any camera_info
  EXPECT_EQ(v.at("focal length of cam_b corrected (x camera_info's)"), "1.03");
  EXPECT_EQ(v.count("window-pair edges (to older keyframes of the window)"), 0u);
}

TEST(NodeDiagnostics, NoTimeBudgetIsReportedBeforeAnyImage) {
  NodeStatus s = Healthy();
  s.has_frontend = true;
  const std::map<std::string, std::string> v = Values(Fill(s));
  EXPECT_EQ(v.count("time per image (decoding, checks, selection), median (ms)"), 0u);
  EXPECT_EQ(v.count("time per two-view pair, median (ms)"), 0u);
  EXPECT_EQ(v.count("time per focal-length check estimate, median (ms)"), 0u);
}

TEST(NodeDiagnostics, RecentTimesKeepTheLastFifty) {
  RecentTimes t;
  EXPECT_EQ(t.Mean(), 0.0);
  for (int i = 1; i <= 60; ++i) t.Add(i);
  EXPECT_EQ(t.last, 60.0);
  EXPECT_EQ(t.window.size(), 50u);
  EXPECT_DOUBLE_EQ(t.Mean(), 35.5);  // 11 .. 60
}

TEST(NodeParameters, AListOnTheCommandLineIsReadAsTheListItSpells) {
  EXPECT_EQ(ParseListText("[/a/image_raw,/b/image_raw]"), (std::vector<std::string>{"/a/image_raw", "/b/image_raw"}));
  EXPECT_EQ(ParseListText("[ '/a', \"/b\" ,, ]"), (std::vector<std::string>{"/a", "/b"}));
  EXPECT_TRUE(ParseListText("[]").empty());
}

}  // namespace
}  // namespace rotation_averaging
