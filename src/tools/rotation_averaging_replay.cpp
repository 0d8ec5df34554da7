// rotation_averaging_replay: the node's pipeline over recorded bags, offline.
//
//   rosrun rotation_averaging rotation_averaging_replay --bag A.bag [--bag B.bag ...]
//       [--config config.yaml] [--gt ground_truth.csv|bag] --output-dir DIR
//       [--relative-pose-topic T] [--relative-poses-topic T] [--gt-topic T]
//       [--save-after-each-bag] [--threads N] [--no-progress]
//
// Exit status: 0 on success, 1 when the replay failed (message on stderr), 2
// on a usage error.
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <string>

#include "rotation_averaging/ros/bag_replay.h"
#include "rotation_averaging/util/freed_memory.h"

namespace {

int Usage(const char* why) {
  if (why) std::cerr << "rotation_averaging_replay: " << why << "\n";
  std::cerr << "usage: rotation_averaging_replay --bag A.bag [--bag B.bag ...] [--config config.yaml]\n"
               "           [--gt ground_truth.csv|ground_truth.bag] --output-dir DIR\n"
               "           [--relative-pose-topic relative_pose] [--relative-poses-topic relative_poses]\n"
               "           [--gt-topic /ground_truth/orientations] [--save-after-each-bag] [--threads N]\n"
               "           [--no-progress]\n"
               "Replays the bags (merged in time order) through the node's pipeline as fast as the CPU allows\n"
               "and writes DIR/orientations.csv, DIR/graph.txt, DIR/replay.bag and, with --gt, DIR/scores.txt\n"
               "and DIR/errors.png. The config is the node's parameter file (config/rotation_averaging.yaml).\n"
               "--save-after-each-bag: after each bag's last message, the map is solved and saved to\n"
               "DIR/map_after_bag<N>_<bag name>.txt (+ .rig, .keyframes), loadable with load_graph.\n"
               "--threads N: the front end's threads (num_threads; 0: every core); the output is the same\n"
               "for any N.\n";
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  rotation_averaging::ReplayOptions options;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    auto value = [&](std::string* out) {
      if (k + 1 >= argc) return false;
      *out = argv[++k];
      return true;
    };
    std::string v;
    if (a == "--bag" && value(&v)) {
      options.bags.push_back(v);
    } else if (a == "--config" && value(&v)) {
      options.config_path = v;
    } else if (a == "--gt" && value(&v)) {
      options.ground_truth_path = v;
    } else if (a == "--output-dir" && value(&v)) {
      options.output_dir = v;
    } else if (a == "--relative-pose-topic" && value(&v)) {
      options.relative_pose_topic = v;
    } else if (a == "--relative-poses-topic" && value(&v)) {
      options.relative_poses_topic = v;
    } else if (a == "--gt-topic" && value(&v)) {
      options.ground_truth_topic = v;
    } else if (a == "--save-after-each-bag") {
      options.save_after_each_bag = true;
    } else if (a == "--threads" && value(&v)) {
      char* end = nullptr;
      const long n = std::strtol(v.c_str(), &end, 10);
      if (v.empty() || *end != '\0' || n < 0 || n > 1024) return Usage(("--threads takes 0 to 1024, not '" + v + "'").c_str());
      options.num_threads = static_cast<int>(n);
    } else if (a == "--no-progress") {
      options.progress = false;
    } else if (a == "--help" || a == "-h") {
      return Usage(nullptr);
    } else {
      return Usage(("unknown or incomplete option " + a).c_str());
    }
  }
  if (options.bags.empty()) return Usage("give at least one --bag");
  if (options.output_dir.empty()) return Usage("give --output-dir");
  const rotation_averaging::ReplayResult result = rotation_averaging::ReplayBags(options);
  if (!result.ok) {
    std::cerr << "rotation_averaging_replay: " << result.error << "\n";
    for (const std::string& w : result.warnings) std::cerr << "warning: " << w << "\n";
    return 1;
  }
  std::cout << result.Summary() << std::endl;
  return 0;
}
