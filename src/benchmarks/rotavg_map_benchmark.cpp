// rotavg_map_benchmark: the saved map at the sizes a robot reaches (see
// scripts/benchmark_map.sh, which saves the demo's map first).
//
// The keyframes of a saved map (real ones: the demo's, through the node's
// front end) are repeated under new stamps up to each size asked for, with a
// view graph that chains each copy's keyframes like the original. For each
// size it writes that map and measures, through the node's own pipeline
// (KeyframePipeline, with the node's configuration):
//  * the database on disk per keyframe;
//  * loading: the keyframe database alone (read, checked, indexed), and the
//    whole map (graph, first solve, database): the first load, as a node
//    starting up makes it, and the median of --loads more (the process's
//    memory is then mapped already: what a first load spends on that
//    shows as the difference);
//  * saving (as autosave does): the whole save, and how long it held the
//    graph (a solve waits for that) and the front end (a keyframe waits).
// Prints one markdown table row per size.
#include <sys/resource.h>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <map>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/io/keyframe_database.h"
#include "rotation_averaging/ros/bag_replay.h"
#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/util/time_distribution.h"
#include "tools/cli.h"

namespace ra = rotation_averaging;
namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;
using ra::SecondsSince;

double PeakRssMib() {
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.empty() ? 0.0 : v[v.size() / 2];
}

// `size` keyframes: the originals, then copies of them whose stamps follow
// the last original's, each copy its own chains. The graph chains each
// chain's keyframes by their sequential rotations (identity with a wide
// covariance where a keyframe has none), and joins the copies' first
// keyframes to the originals' (so the map is one component).
void MakeMap(const ra::KeyframeDatabase& original, std::size_t size, ra::KeyframeDatabase* database,
             ra::ViewGraph* graph) {
  std::int64_t first = original.keyframes.front().key.stamp_ns, last = first;
  std::uint32_t chains = 0;
  for (const ra::StoredKeyframe& kf : original.keyframes) {
    first = std::min(first, kf.key.stamp_ns);
    last = std::max(last, kf.key.stamp_ns);
    chains = std::max(chains, kf.chain + 1);
  }
  const std::int64_t span = last - first + 1'000'000'000LL;
  database->feature_type = original.feature_type;
  database->num_words = original.num_words;
  database->vocabulary_fingerprint = original.vocabulary_fingerprint;
  database->keyframes.clear();
  std::map<std::uint32_t, ra::ViewId> last_of_chain;
  for (std::size_t i = 0; i < size; ++i) {
    const std::size_t copy = i / original.keyframes.size();
    ra::StoredKeyframe kf = original.keyframes[i % original.keyframes.size()];
    kf.key.stamp_ns += static_cast<std::int64_t>(copy) * span;
    kf.chain += static_cast<std::uint32_t>(copy) * chains;
    const ra::ViewId id = i;
    graph->AddView(id, ra::OnlineAverager::KeyframeName(kf.key));
    ra::RelativeRotation edge;
    edge.has_covariance = true;
    edge.covariance = 1e-2 * Eigen::Matrix3d::Identity();
    const auto previous = last_of_chain.find(kf.chain);
    if (previous != last_of_chain.end()) {
      edge.view1 = previous->second;
      edge.view2 = id;
      edge.source = ra::EdgeSource::kSequential;
      if (kf.has_sequential) {
        edge.rotation = kf.sequential_rotation;
        edge.covariance = kf.sequential_covariance;
      }
      graph->AddEdge(edge);
    } else if (copy > 0) {
      edge.view1 = i % original.keyframes.size();
      edge.view2 = id;
      edge.source = ra::EdgeSource::kLoopClosure;
      graph->AddEdge(edge);
    }
    last_of_chain[kf.chain] = id;
    database->keyframes.push_back(std::move(kf));
  }
  // Cameras of one capture (rig edges would join them; the solve only needs
  // one component).
  for (std::size_t i = 1; i < size; ++i) {
    if (!graph->FindView(i)) continue;
    const auto& a = database->keyframes[i - 1].key;
    const auto& b = database->keyframes[i].key;
    if (a.frame_id != b.frame_id && std::llabs(a.stamp_ns - b.stamp_ns) < 1'000'000LL) {
      ra::RelativeRotation edge;
      edge.view1 = i - 1;
      edge.view2 = i;
      edge.source = ra::EdgeSource::kRig;
      edge.has_covariance = true;
      edge.covariance = 1e-2 * Eigen::Matrix3d::Identity();
      graph->AddEdge(edge);
    }
  }
}

// One row of the table: a map of `size` keyframes made from `original`,
// written, its database loaded `loads` times into a front end, the whole map
// `loads` times into a pipeline, then saved `saves` times. False with `error`.
bool MeasureMapSize(const ra::PipelineConfig& config, const ra::KeyframeDatabase& original, std::size_t size,
                    const std::string& output_dir, int loads, int saves, std::string* error) {
  ra::KeyframeDatabase database;
  ra::ViewGraph graph;
  MakeMap(original, size, &database, &graph);
  const std::string map = output_dir + "/map_" + std::to_string(size) + ".txt";
  if (!ra::WriteRotavgGraph(map, graph, error) ||
      !ra::WriteKeyframeDatabase(ra::KeyframeDatabasePath(map), database, error)) {
    return false;
  }
  std::error_code ec;
  fs::remove(ra::RigPath(map), ec);
  database = ra::KeyframeDatabase();
  const double bytes = static_cast<double>(fs::file_size(ra::KeyframeDatabasePath(map)));

  // The database alone, into a front end as the node configures it.
  std::vector<double> database_loads;
  for (int k = 0; k < loads; ++k) {
    ra::KeyframeFrontend frontend(config.frontend);
    const auto start = Clock::now();
    if (!frontend.LoadDatabase(ra::KeyframeDatabasePath(map), error)) {
      return false;
    }
    database_loads.push_back(SecondsSince(start));
  }
  const double database_s = database_loads.front();
  const double database_again_s = Median({database_loads.begin() + 1, database_loads.end()});
  // The whole map (the last load's pipeline is kept), then saves of it as
  // autosave makes them.
  std::vector<double> map_loads;
  std::unique_ptr<ra::KeyframePipeline> loaded;
  for (int k = 0; k < loads; ++k) {
    loaded.reset();  // one map in memory at a time
    loaded = std::make_unique<ra::KeyframePipeline>(config);
    const auto start = Clock::now();
    if (!loaded->LoadMap(map, error)) {
      return false;
    }
    map_loads.push_back(SecondsSince(start));
  }
  const double map_s = map_loads.front();
  const double map_again_s = Median({map_loads.begin() + 1, map_loads.end()});
  ra::KeyframePipeline& pipeline = *loaded;
  std::vector<double> total, graph_lock, frontend_lock;
  const std::string saved = output_dir + "/saved_" + std::to_string(size) + ".txt";
  for (int k = 0; k < saves; ++k) {
    if (!pipeline.SaveMap(saved, error)) {
      return false;
    }
    const ra::MapSaveTiming timing = pipeline.LastSaveTiming();
    total.push_back(timing.total_s);
    graph_lock.push_back(timing.graph_lock_s);
    frontend_lock.push_back(timing.frontend_lock_s);
  }
  std::cout << "| " << size << " | " << bytes / 1048576.0 << " | " << bytes / 1024.0 / size << " | "
            << 1e3 * database_s << " / " << 1e3 * database_again_s << " | " << std::setprecision(3)
            << 1e3 * database_s / size << std::setprecision(1) << " | " << 1e3 * map_s << " / " << 1e3 * map_again_s
            << " | " << 1e3 * Median(total) << " | " << 1e3 * Median(graph_lock) << " | "
            << 1e3 * Median(frontend_lock) << " | " << PeakRssMib() << " |\n"
            << std::flush;
  for (const std::string& path : {map, saved}) {
    for (const std::string& file : {path, ra::KeyframeDatabasePath(path), ra::RigPath(path)}) fs::remove(file, ec);
  }
  return true;
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging_cli::Args args;
  std::string error;
  if (!rotation_averaging_cli::ParseArgs(argc, argv, 1, {}, &args, &error) || !args.Has("--map") ||
      !args.Has("--config") || !args.Has("--output-dir")) {
    std::cerr << "usage: rotavg_map_benchmark --map GRAPH --config NODE_YAML --output-dir DIR "
                 "[--sizes 800,10000] [--saves 5] [--loads 2]\n"
                 "  GRAPH: a map saved by the node or the replay (GRAPH.keyframes beside it)\n";
    return 2;
  }
  std::vector<std::string> warnings;
  ra::PipelineConfig config;
  if (!ra::ReadReplayConfig(args.Get("--config"), &config, &warnings, &error)) {
    std::cerr << error << "\n";
    return 1;
  }
  if (!config.frontend.vocabulary) {
    std::cerr << "the configuration has no vocabulary: no keyframe database to measure\n";
    return 1;
  }
  config.image_topics = {"/benchmark/image_raw"};  // the pipeline builds its front end for images
  ra::KeyframeDatabase original;
  if (!ra::ReadKeyframeDatabase(ra::KeyframeDatabasePath(args.Get("--map")),
                                config.frontend.vocabulary->Fingerprint(), &original, &error)) {
    std::cerr << error << "\n";
    return 1;
  }
  if (original.keyframes.empty()) {
    std::cerr << "the map holds no keyframes\n";
    return 1;
  }
  std::vector<std::size_t> sizes;
  std::stringstream list(args.Get("--sizes", "800,10000"));
  for (std::string item; std::getline(list, item, ',');) sizes.push_back(std::stoul(item));
  const int saves = std::max(1, std::stoi(args.Get("--saves", "5")));
  const int loads = 1 + std::max(1, std::stoi(args.Get("--loads", "2")));  // the first, then these
  fs::create_directories(args.Get("--output-dir"));

  std::cout << std::fixed << std::setprecision(1);
  std::cout << "| keyframes | database (MB) | per keyframe (KB) | load the database (ms): first / again |"
               " per keyframe (ms) | load the map (ms): first / again | save the map (ms) | graph held (ms) | front end held (ms) | peak memory (MiB) |\n"
               "|---|---|---|---|---|---|---|---|---|---|\n";
  for (std::size_t size : sizes) {
    if (!MeasureMapSize(config, original, size, args.Get("--output-dir"), loads, saves, &error)) {
      std::cerr << error << "\n";
      return 1;
    }
  }
  return 0;
}
