// rosbag play --clock of a rendered rig bag into the live node gives the same
// view graph as rotation_averaging_replay on that bag, and the same
// orientations up to where warm-started solves settle.
#include <gtest/gtest.h>
#include <ros/ros.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <mutex>
#include <string>
#include <tuple>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/bag_replay.h"
#include "rotation_averaging/sim/demo_bag.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rostest/play_bag.h"

namespace rotation_averaging {
namespace {

TEST(NodeReplay, LiveNodeFedByRosbagPlayMatchesTheReplayTool) {
  ros::NodeHandle nh;
  std::string config;
  ASSERT_TRUE(nh.getParam("/demo_config", config));
  char pattern[] = "/tmp/rotavg_node_replay_XXXXXX";
  const std::string dir = mkdtemp(pattern);

  RigSceneOptions scene_options;
  scene_options.num_captures = 12;
  scene_options.WithWidth(320);
  const RigScene scene(scene_options);
  const std::string bag = dir + "/rig.bag";
  std::string error;
  ASSERT_TRUE(WriteRigSceneBag(scene, bag, false, nullptr, &error)) << error;

  ReplayOptions options;
  options.bags = {bag};
  options.config_path = config;
  options.ground_truth_path = bag;
  options.output_dir = dir + "/replay";
  options.progress = false;
  const ReplayResult replay = ReplayBags(options);
  ASSERT_TRUE(replay.ok) << replay.error;
  ASSERT_EQ(replay.keyframes, 24u);
  ASSERT_LT(replay.scores.median_error_deg, 0.5);
  NamedOrientations replayed;
  ASSERT_TRUE(ReadOrientationsCsv(replay.orientations_csv, &replayed).ok());

  const NamedOrientations live = PlayIntoNode("rotation_averaging", bag, replay.keyframes);
  ASSERT_EQ(live.size(), replayed.size());
  // The node refined its solution in the background, as the replay refined
  // its final one: it is nearer the replay's than the replay's without the
  // refinement is.
  ASSERT_TRUE(replay.refinement);
  ASSERT_GE(replay.refinement_stats.applied, 1u);
  {
    const std::string unrefined_config = dir + "/unrefined.yaml";
    std::ofstream(unrefined_config) << std::ifstream(config).rdbuf() << "\nrefinement: false\n";
    ReplayOptions unrefined_options = options;
    unrefined_options.config_path = unrefined_config;
    unrefined_options.output_dir = dir + "/unrefined";
    const ReplayResult unrefined = ReplayBags(unrefined_options);
    ASSERT_TRUE(unrefined.ok) << unrefined.error;
    NamedOrientations averaged;
    ASSERT_TRUE(ReadOrientationsCsv(unrefined.orientations_csv, &averaged).ok());
    const double to_refined = EvaluateOrientations(live, replayed).median_error_deg;
    const double to_averaged = EvaluateOrientations(live, averaged).median_error_deg;
    std::printf("live node: median %.6f deg from the replay, %.6f deg from the replay without refinement\n",
                to_refined, to_averaged);
    EXPECT_LT(to_refined, to_averaged);
  }

  // The front end is deterministic: the node's graph is the replay's, edge
  // for edge (pair, source, inliers, rotation).
  ExpectNodeGraphIsTheReplays("rotation_averaging", dir + "/live_graph.txt", replay.graph_file);

  const EvaluationResult between = EvaluateOrientations(live, replayed);
  EXPECT_EQ(between.views_common, replayed.size());
  // Same graph, solved at other moments: each solve is warm-started from the
  // one before and auto-scales the loss from its own first pass, so where a
  // capture's edges disagree the two can settle it apart. On this scene two
  // captures come out 0.15 deg from the replay's (their error against the
  // ground truth is 0.08-0.35 deg) while a cold solve of the same graph lands
  // within 0.001 deg of the node's: the replay's sequence of warm starts, not
  // the node, put them elsewhere. So the orientations are compared by their
  // median, and every keyframe within a bound on such settling; the graph
  // check above is the exact one.
  double worst = 0.0;
  for (const auto& [name, e] : between.errors_deg) worst = std::max(worst, e);
  EXPECT_LT(between.median_error_deg, 0.01);
  EXPECT_LT(worst, 0.3) << "median " << between.median_error_deg;
  std::printf("live node vs replay tool over %zu keyframes: median %.6f deg, max %.6f deg\n", between.views_common,
              between.median_error_deg, worst);
}

}  // namespace
}  // namespace rotation_averaging
