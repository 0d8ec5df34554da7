// Offline replay of recorded bags through the node's pipeline
// (KeyframePipeline: the same validation, front end and averager), as fast
// as the CPU allows, deterministic run after run. Solves happen at the bag
// times at which the live node would solve (every solve_period_s of bag time
// after the first message, when new input arrived, and at once after a loop
// closure if solve_early_on_loop_closure), plus once at the end.
#ifndef ROTATION_AVERAGING_ROS_BAG_REPLAY_H_
#define ROTATION_AVERAGING_ROS_BAG_REPLAY_H_

#include <map>
#include <string>
#include <vector>

#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/ros/replay_report.h"

namespace rotation_averaging {

struct ReplayOptions {
  std::vector<std::string> bags;    // merged in time order
  std::string config_path;          // YAML with the node's parameters; empty: defaults
  std::string ground_truth_path;    // optional: orientations CSV, or a bag with ground_truth_topic
  std::string output_dir;           // created if missing
  std::string relative_pose_topic = "relative_pose";    // matched with or without a leading '/'
  std::string relative_poses_topic = "relative_poses";
  std::string ground_truth_topic = "/ground_truth/orientations";
  bool progress = true;             // progress bar on stderr
  // After the last input message of each bag: a solve, then the map saved
  // (KeyframePipeline::SaveMap) to output_dir/map_after_bag<N>_<bag stem>.txt
  // with its .rig and .keyframes beside it, as a node that ends its session
  // there would have saved it: one replay of a day's bags leaves the map of
  // every session, each loadable with load_graph.
  bool save_after_each_bag = false;
  // The front end's threads (the node's num_threads; 0: the machine's
  // cores), in place of the config's; < 0: the config's. The keyframes, the
  // edges and the solution do not depend on it.
  int num_threads = -1;
};

ReplayResult ReplayBags(const ReplayOptions& options);

// The node's parameters from a YAML file of them, as the replay reads its
// --config (none: the defaults), with the solves made independent of the
// machine's speed (no background full solves).
bool ReadReplayConfig(const std::string& path, PipelineConfig* config, std::vector<std::string>* warnings,
                      std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_BAG_REPLAY_H_
