#include "ros/bag_replay.h"

#include <image_transport/camera_common.h>
#include <ros/serialization.h>
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <rosbag/view.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <tf2_msgs/TFMessage.h>
#include <unistd.h>
#include <yaml-cpp/yaml.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <iomanip>
#include <limits>
#include <cstdio>
#include <deque>
#include <fstream>
#include <memory>
#include <new>
#include <set>
#include <sstream>
#include <stdexcept>

#include "rotation_averaging/RelativePoseArray.h"
#include "frontend/eval/error_plot.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "ros/keyframe_pipeline.h"
#include "ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

// The node's parameters from a YAML file (the same file the launch files
// load into the node's private namespace).
class YamlParameters : public ParameterSource {
 public:
  explicit YamlParameters(YAML::Node root) : root_(std::move(root)) {}
  bool Get(const std::string& name, std::string* value) const override { return As(name, value); }
  bool Get(const std::string& name, double* value) const override { return As(name, value); }
  bool Get(const std::string& name, int* value) const override { return As(name, value); }
  bool Get(const std::string& name, bool* value) const override { return As(name, value); }
  bool Get(const std::string& name, std::vector<std::string>* value) const override { return As(name, value); }
  const std::vector<std::string>& Problems() const { return problems_; }

 private:
  template <typename T>
  bool As(const std::string& name, T* value) const {
    const YAML::Node node = root_[name];
    if (!node.IsDefined() || node.IsNull()) return false;
    try {
      *value = node.as<T>();
      return true;
    } catch (const YAML::Exception&) {
      problems_.push_back("config: parameter '" + name + "' has the wrong type; using its default");
      return false;
    }
  }
  YAML::Node root_;
  mutable std::vector<std::string> problems_;
};

std::string WithSlash(const std::string& topic) { return !topic.empty() && topic[0] == '/' ? topic : "/" + topic; }

double CpuSeconds() {
  struct rusage usage {};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_utime.tv_sec + usage.ru_stime.tv_sec + 1e-6 * (usage.ru_utime.tv_usec + usage.ru_stime.tv_usec);
}

double PeakRssMiB() {
  struct rusage usage {};
  getrusage(RUSAGE_SELF, &usage);
  return usage.ru_maxrss / 1024.0;
}

bool MakeDirectory(const std::string& path, std::string* error) {
  std::string partial;
  std::stringstream parts(path);
  std::string part;
  if (!path.empty() && path[0] == '/') partial = "/";
  while (std::getline(parts, part, '/')) {
    if (part.empty()) continue;
    partial += part + "/";
    if (mkdir(partial.c_str(), 0755) != 0 && errno != EEXIST) {
      *error = "cannot create " + partial;
      return false;
    }
  }
  struct stat st {};
  if (stat(path.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) {
    *error = path + " is not a directory";
    return false;
  }
  return true;
}

class ProgressBar {
 public:
  ProgressBar(bool enabled, std::size_t total) : enabled_(enabled), total_(total), tty_(isatty(STDERR_FILENO)) {}
  void Update(std::size_t done, double bag_time_s, bool final = false) {
    if (!enabled_) return;
    const auto now = std::chrono::steady_clock::now();
    const double elapsed = std::chrono::duration<double>(now - start_).count();
    const double since = std::chrono::duration<double>(now - last_).count();
    const int percent = total_ > 0 ? static_cast<int>(100.0 * done / total_) : 100;
    // A terminal gets a bar redrawn in place; a log gets a line per 10%.
    if (!final && (tty_ ? since < 0.2 : percent / 10 == last_decile_)) return;
    if (final && !tty_ && percent / 10 == last_decile_) return;  // already printed
    last_ = now;
    last_decile_ = percent / 10;
    const double rate = elapsed > 0.0 ? done / elapsed : 0.0;
    const double eta = rate > 0.0 ? (total_ - done) / rate : 0.0;
    const int filled = percent * 30 / 100;
    char line[200];
    std::snprintf(line, sizeof(line), "[%s%s] %3d%% %zu/%zu messages | %.0f msg/s | bag %.1f s | ETA %.0f s",
                  std::string(filled, '#').c_str(), std::string(30 - filled, '.').c_str(), percent, done, total_, rate,
                  bag_time_s, eta);
    std::fprintf(stderr, tty_ ? "\r%s%s" : "%s%s\n", line, tty_ && final ? "\n" : "");
    std::fflush(stderr);
  }

 private:
  bool enabled_;
  std::size_t total_;
  bool tty_;
  int last_decile_ = -1;
  std::chrono::steady_clock::time_point start_ = std::chrono::steady_clock::now(), last_ = start_;
};

// Ground truth: an orientations CSV, or a bag holding an Orientations message
// (camera-to-world quaternions) on `topic`.
bool ReadGroundTruthFile(const std::string& path, const std::string& topic, NamedOrientations* gt, std::string* error) {
  if (path.size() < 4 || path.substr(path.size() - 4) != ".bag") {
    const ReadReport report = ReadGroundTruth(path, GroundTruthFormat::kAuto, gt);
    if (!report.ok()) *error = report.error;
    return report.ok();
  }
  try {
    rosbag::Bag bag(path, rosbag::bagmode::Read);
    rosbag::View view(bag, rosbag::TopicQuery(std::vector<std::string>{topic, topic.substr(1)}));
    for (const rosbag::MessageInstance& m : view) {
      Orientations::ConstPtr msg = m.instantiate<Orientations>();
      if (!msg) continue;
      gt->clear();
      for (const KeyframeOrientation& k : msg->keyframes) {
        const auto& q = k.orientation;
        (*gt)[OnlineAverager::KeyframeName({k.frame_id, ToNanoseconds(k.stamp)})] =
            QuaternionToRotation(q.w, q.x, q.y, q.z).transpose();
      }
    }
  } catch (const rosbag::BagException& e) {
    *error = "cannot read ground truth from " + path + ": " + e.what();
    return false;
  }
  if (gt->empty()) {
    *error = path + " has no rotation_averaging/Orientations message on " + topic;
    return false;
  }
  return true;
}

// Images waiting for their camera_info (bags often record an image just
// before the camera_info of the same stamp).
struct CameraStream {
  bool compressed = false;
  std::string image_topic, info_topic;
  sensor_msgs::CameraInfo::ConstPtr info;
  std::deque<rosbag::MessageInstance> waiting;
};

}  // namespace

std::string ReplayResult::Summary() const {
  std::ostringstream out;
  out.setf(std::ios::fixed);
  out.precision(2);
  out << "messages: " << messages_read << " of " << messages_total << (truncated ? " (stopped at damage)" : "") << "\n";
  out << "bag time: " << bag_duration_s << " s; wall time: " << wall_s << " s ("
      << (wall_s > 0.0 ? bag_duration_s / wall_s : 0.0) << "x real time); CPU time: " << cpu_s
      << " s; peak memory: " << peak_rss_mib << " MiB\n";
  out << "keyframes: " << keyframes << " (" << keyframe_images << " images through the front end, " << rejected_images
      << " rejected); relative-pose messages rejected: " << rejected_messages << "\n";
  if (keyframe_images > 0) {
    out << "front end per keyframe: features " << 1e3 * frontend_features_s / keyframe_images << " ms, retrieval "
        << 1e3 * frontend_retrieval_s / keyframe_images << " ms, pair verification "
        << 1e3 * frontend_pairs_s / keyframe_images << " ms\n";
    out << "two-view pairs: " << frontend_failed_pairs << " failed";
    if (!frontend_failures.empty()) {
      out << " (";
      bool first = true;
      for (const auto& [why, n] : frontend_failures) {
        out << (first ? "" : ", ") << why << " " << n;
        first = false;
      }
      out << ")";
    }
    out << ", " << frontend_chain_bridged
        << " failed previous pairs bridged by an older keyframe, " << frontend_rotation_model_edges
        << " edges from the rotation-only model\n";
    out << "loop closures: " << loop_closure_edges << " edges from " << loop_candidates
        << " verified candidates; retrieval: " << retrieval << "\n";
    out << "front-end memory: " << frontend_bytes / 1048576.0 << " MiB of features and retrieval data for "
        << keyframe_images << " keyframes";
    if (compacted_keyframes > 0) {
      out << " (" << compacted_keyframes << " compact, " << compact_bytes / 1024.0 / compacted_keyframes
          << " KB each)";
    }
    out << "\n";
    const std::size_t n = frontend_cost.size();
    if (n >= 300) {
      auto mean = [this](std::size_t from, std::size_t to) {
        double sum = 0.0;
        for (std::size_t k = from; k < to; ++k) sum += frontend_cost[k].total_ms;
        return sum / static_cast<double>(to - from);
      };
      const double early = mean(100, 200), late = mean(n - 100, n);
      out << "front-end cost per keyframe: keyframes 100-200 " << early << " ms, last 100 " << late << " ms ("
          << late / early << "x)\n";
    }
  }
  if (damaged_messages > 0) out << "damaged messages dropped: " << damaged_messages << "\n";
  if (!rig_cameras.empty()) {
    out << "rig cameras (one orientation per capture): ";
    for (std::size_t k = 0; k < rig_cameras.size(); ++k) out << (k ? ", " : "") << rig_cameras[k];
    out << "; measurements within a capture absorbed by the extrinsics: " << absorbed_by_rig << "\n";
  }
  out << "solved variables: " << variables << " (keyframes, or rig captures); edges: " << edges;
  if (!edges_by_source.empty()) {
    out << " (";
    bool first = true;
    for (const auto& [source, n] : edges_by_source) {
      out << (first ? "" : ", ") << source << " " << n;
      first = false;
    }
    out << ")";
  }
  out << "\ncomponents: " << components << "; outlier edges: " << outlier_edges << "; solves: " << solves
      << "; final cost: " << std::setprecision(6) << final_cost << "\n";
  if (have_scores) {
    out << "scores against ground truth:\n" << scores.ToText() << "\n";
  }
  out << "outputs:\n  " << orientations_csv << "\n  " << graph_file << "\n  " << output_bag;
  if (!scores_file.empty()) out << "\n  " << scores_file;
  if (!plot_png.empty()) out << "\n  " << plot_png;
  if (!frontend_cost_csv.empty()) out << "\n  " << frontend_cost_csv;
  if (!frontend_cost_png.empty()) out << "\n  " << frontend_cost_png;
  for (const std::string& w : warnings) out << "\nwarning: " << w;
  return out.str();
}

ReplayResult ReplayBags(const ReplayOptions& options) {
  ReplayResult result;
  const auto wall_start = std::chrono::steady_clock::now();
  const double cpu_start = CpuSeconds();
  auto fail = [&result](const std::string& why) {
    result.ok = false;
    result.error = why;
    return result;
  };
  if (options.bags.empty()) return fail("no bag given");
  if (options.output_dir.empty()) return fail("no output directory given");

  // Parameters: the node's YAML file.
  YAML::Node root;
  if (!options.config_path.empty()) {
    try {
      root = YAML::LoadFile(options.config_path);
    } catch (const YAML::Exception& e) {
      return fail("config " + options.config_path + ": " + e.what());
    }
  }
  YamlParameters params(root);
  PipelineConfig config;
  std::string config_error;
  if (!ReadPipelineConfig(params, &config, &result.warnings, &config_error)) {
    return fail("config " + options.config_path + ": " + config_error);
  }
  // Solutions that depend on the input only, not on how fast this machine
  // runs: the periodic full solve of large graphs runs in the solve that is
  // due, not in a background thread (OnlineAveragerOptions).
  config.averager.background_full_solves = false;
  for (const std::string& p : params.Problems()) result.warnings.push_back(p);
  KeyframePipeline pipeline(config);
  OnlineAverager& averager = pipeline.Averager();

  NamedOrientations ground_truth;
  if (!options.ground_truth_path.empty()) {
    std::string error;
    if (!ReadGroundTruthFile(options.ground_truth_path, options.ground_truth_topic, &ground_truth, &error)) {
      return fail("ground truth: " + error);
    }
  }
  std::string error;
  if (!MakeDirectory(options.output_dir, &error)) return fail(error);

  // Open every bag; an unindexed one (truncated while recording) cannot be
  // read in time order without `rosbag reindex`.
  std::vector<std::unique_ptr<rosbag::Bag>> bags;
  for (const std::string& path : options.bags) {
    auto bag = std::make_unique<rosbag::Bag>();
    try {
      bag->open(path, rosbag::bagmode::Read);
    } catch (const rosbag::BagUnindexedException&) {
      return fail(path + " is not indexed (recording was interrupted): run `rosbag reindex " + path +
                  "` and replay the reindexed bag");
    } catch (const rosbag::BagException& e) {
      // A file that starts like a bag but cannot be opened lost its end (the
      // index): reindexing recovers the messages before the cut.
      std::ifstream in(path, std::ios::binary);
      char magic[13] = {0};
      in.read(magic, 12);
      if (in && std::string(magic) == "#ROSBAG V2.0") {
        return fail("cannot open " + path + ": " + e.what() + "; the bag looks truncated (its index is missing): run " +
                    "`rosbag reindex " + path + "` and replay the reindexed bag");
      }
      return fail("cannot open " + path + ": " + e.what() + (in ? " (not a ROS bag: no #ROSBAG V2.0 header)" : ""));
    }
    bags.push_back(std::move(bag));
  }

  // The topics we read and the types they must have.
  std::map<std::string, std::string> expected;  // topic (with '/') -> datatype
  const std::string pose_topic = WithSlash(options.relative_pose_topic);
  const std::string poses_topic = WithSlash(options.relative_poses_topic);
  expected[pose_topic] = "rotation_averaging/RelativePose";
  expected["/tf_static"] = "tf2_msgs/TFMessage";
  expected[poses_topic] = "rotation_averaging/RelativePoseArray";
  std::map<std::string, CameraStream> cameras;  // by configured image topic
  for (const std::string& topic : config.image_topics) {
    const std::string t = WithSlash(topic);
    expected[t] = "sensor_msgs/Image";
    expected[t + "/compressed"] = "sensor_msgs/CompressedImage";
    expected[WithSlash(image_transport::getCameraInfoTopic(t))] = "sensor_msgs/CameraInfo";
  }
  std::set<std::string> present;  // expected topics found, as spelled in the bags
  std::set<std::string> present_normalised;
  std::set<std::string> all_topics;
  for (std::size_t b = 0; b < bags.size(); ++b) {
    rosbag::View whole(*bags[b]);
    for (const rosbag::ConnectionInfo* c : whole.getConnections()) {
      all_topics.insert(c->topic);
      auto it = expected.find(WithSlash(c->topic));
      if (it == expected.end()) continue;
      if (c->datatype != it->second) {
        return fail(options.bags[b] + ": topic " + c->topic + " has type " + c->datatype + ", expected " + it->second);
      }
      present.insert(c->topic);
      present_normalised.insert(WithSlash(c->topic));
    }
  }
  for (const std::string& topic : config.image_topics) {
    const std::string t = WithSlash(topic);
    CameraStream stream;
    stream.compressed = !present_normalised.count(t) && present_normalised.count(t + "/compressed");
    stream.image_topic = stream.compressed ? t + "/compressed" : t;
    stream.info_topic = WithSlash(image_transport::getCameraInfoTopic(t));
    if (!present_normalised.count(stream.image_topic)) {
      result.warnings.push_back("image topic " + t + " (raw or compressed) is not in the bags");
    } else if (!present_normalised.count(stream.info_topic)) {
      result.warnings.push_back(stream.info_topic + " is not in the bags: images of " + t + " cannot be used");
    }
    cameras.emplace(t, std::move(stream));
  }
  if (all_topics.empty()) return fail("the bags hold no message at all");
  const bool only_tf = present.size() == 1 && present_normalised.count("/tf_static");
  if (present.empty() || only_tf) {
    std::string have;
    for (const std::string& t : all_topics) have += (have.empty() ? "" : ", ") + t;
    std::string want;
    for (const auto& [t, type] : expected) want += (want.empty() ? "" : ", ") + t + " (" + type + ")";
    return fail("the bags hold none of the input topics " + want + "; they have: " + (have.empty() ? "nothing" : have) +
                (config.image_topics.empty() ? " (image topics come from image_topics in the config)" : ""));
  }

  // Static transforms (rig extrinsics) first, whatever their time in the
  // bag: the live node receives the latched /tf_static as it subscribes,
  // before the first image, while a recorder may write it a little later.
  std::vector<std::string> inputs;
  for (const std::string& t : present) {
    if (WithSlash(t) == "/tf_static") {
      rosbag::View statics;
      for (auto& bag : bags) statics.addQuery(*bag, rosbag::TopicQuery(t));
      try {
        for (const rosbag::MessageInstance& m : statics) {
          if (tf2_msgs::TFMessage::ConstPtr tf = m.instantiate<tf2_msgs::TFMessage>()) pipeline.AcceptStaticTransforms(*tf);
        }
      } catch (const rosbag::BagException& e) {
        result.warnings.push_back(std::string("/tf_static could not be read completely: ") + e.what());
      }
    } else {
      inputs.push_back(t);
    }
  }
  rosbag::View view;
  const std::vector<std::string>& topics = inputs;
  for (auto& bag : bags) view.addQuery(*bag, rosbag::TopicQuery(topics));
  result.messages_total = view.size();
  if (result.messages_total == 0) return fail("the input topics of the bags hold no message");
  result.bag_start_s = view.getBeginTime().toSec();
  const ros::Time bag_start = view.getBeginTime();

  result.output_bag = options.output_dir + "/replay.bag";
  rosbag::Bag out;
  try {
    out.open(result.output_bag, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    return fail("cannot write " + result.output_bag + ": " + e.what());
  }

  // Solve schedule in bag time, as the live node's worker would run it.
  const double period = config.averager.solve_period_s;
  ros::Time next_solve = period > 0.0 ? bag_start + ros::Duration(period) : ros::TIME_MAX;
  bool dirty = false;
  auto solve = [&](const ros::Time& when) {
    if (!dirty) return;
    dirty = false;
    if (!averager.SolveNow()) return;
    ++result.solves;
    const std::shared_ptr<const OnlineSolution> solution = averager.Solution();
    const OnlineSolution cameras = pipeline.CameraSolution(*solution);
    out.write("/rotation_averaging/orientations", when, pipeline.OrientationsMsg(cameras, when));
    if (config.tf_mode == "all_keyframes") {
      out.write("/tf_static", when, pipeline.KeyframeTransforms(cameras));
    } else if (config.tf_mode == "latest_per_camera") {
      tf2_msgs::TFMessage tf;
      tf.transforms = pipeline.LatestTransforms(cameras, when);
      if (!tf.transforms.empty()) out.write("/tf", when, tf);
    }
  };
  auto warn = [&result](const std::string& w) {
    if (result.warnings.size() < 50) result.warnings.push_back(w);
    if (result.warnings.size() == 50) result.warnings.push_back("(further warnings not shown)");
  };
  auto process_image = [&](CameraStream& stream, const rosbag::MessageInstance& m, const ros::Time& time) {
    PendingKeyframe keyframe;
    std::string why;
    bool ok = false;
    if (stream.compressed) {
      sensor_msgs::CompressedImage::ConstPtr image = m.instantiate<sensor_msgs::CompressedImage>();
      ok = image && pipeline.DecodeCompressedImage(*image, *stream.info, &keyframe, &why);
    } else {
      sensor_msgs::Image::ConstPtr image = m.instantiate<sensor_msgs::Image>();
      ok = image && pipeline.DecodeImage(*image, *stream.info, &keyframe, &why);
    }
    if (!ok) return warn("image on " + stream.image_topic + " at " + std::to_string(time.toSec()) + " dropped: " + why);
    bool loop_closure = false;
    std::vector<std::string> warnings;
    const auto frontend_start = std::chrono::steady_clock::now();
    if (pipeline.ProcessKeyframe(keyframe, &loop_closure, &warnings) > 0) dirty = true;
    if (const KeyframeFrontend* f = pipeline.Frontend()) {
      const KeyframeFrontendStats& fs = f->Stats();
      ReplayResult::KeyframeCost cost;
      cost.features_ms = 1e3 * fs.last_features_s;
      cost.retrieval_ms = 1e3 * fs.last_retrieval_s;
      cost.pairs_ms = 1e3 * fs.last_pairs_s;
      cost.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - frontend_start).count();
      result.frontend_cost.push_back(cost);
    }
    for (const std::string& w : warnings) warn(w);
    if (loop_closure && config.averager.solve_early_on_loop_closure) solve(time);
  };
  auto accept_pose = [&](const RelativePose& pose, const ros::Time& time, bool* loop_closure) {
    std::string why;
    if (pipeline.AcceptRelativePose(pose, &why)) {
      dirty = true;
      if (pose.source == RelativePose::SOURCE_LOOP_CLOSURE) *loop_closure = true;
    } else {
      warn("relative pose at " + std::to_string(time.toSec()) + " dropped: " + why);
    }
  };

  // A message whose bytes are damaged: dropped and counted, the rest goes on.
  auto dropped_damaged = [&](const rosbag::MessageInstance& m, const ros::Time& time, const std::string& why) {
    ++result.damaged_messages;
    warn("message on " + m.getTopic() + " at " + std::to_string(time.toSec()) + " does not deserialise (" + why +
         "): dropped");
  };
  ProgressBar bar(options.progress, result.messages_total);
  ros::Time last_time = bag_start;
  try {
    for (const rosbag::MessageInstance& m : view) {
      const ros::Time time = m.getTime();
      last_time = time;
      while (time >= next_solve) {
        solve(next_solve);
        next_solve += ros::Duration(period);
      }
      const std::string topic = WithSlash(m.getTopic());
      try {
      if (topic == pose_topic || topic == poses_topic) {
        bool loop_closure = false;
        if (topic == pose_topic) {
          if (RelativePose::ConstPtr pose = m.instantiate<RelativePose>()) accept_pose(*pose, time, &loop_closure);
        } else if (RelativePoseArray::ConstPtr poses = m.instantiate<RelativePoseArray>()) {
          for (const RelativePose& pose : poses->poses) accept_pose(pose, time, &loop_closure);
        }
        if (loop_closure && config.averager.solve_early_on_loop_closure) solve(time);
      } else {
        for (auto& [name, stream] : cameras) {
          if (topic == stream.info_topic) {
            stream.info = m.instantiate<sensor_msgs::CameraInfo>();
            while (stream.info && !stream.waiting.empty()) {
              process_image(stream, stream.waiting.front(), time);
              stream.waiting.pop_front();
            }
          } else if (topic == stream.image_topic) {
            if (stream.info) {
              process_image(stream, m, time);
            } else if (stream.waiting.size() < 4) {
              stream.waiting.push_back(m);
            } else {
              warn("image on " + stream.image_topic + " dropped: no camera_info on " + stream.info_topic);
            }
          }
        }
      }
      } catch (const ros::serialization::StreamOverrunException& e) {
        dropped_damaged(m, time, e.what());
      } catch (const std::bad_alloc&) {
        // ROS's deserialiser allocates an array before it checks the bytes.
        dropped_damaged(m, time, "an array length beyond the memory");
      } catch (const std::length_error&) {
        dropped_damaged(m, time, "an array length beyond what a vector holds");
      }
      ++result.messages_read;
      bar.Update(result.messages_read, (time - bag_start).toSec());
    }
  } catch (const ros::Exception& e) {
    result.truncated = true;
    result.warnings.push_back("the bags are damaged after " + std::to_string(result.messages_read) +
                              " messages (bag time " + std::to_string((last_time - bag_start).toSec()) +
                              " s): " + e.what() + "; results cover the messages before the damage");
  }
  bar.Update(result.messages_read, (last_time - bag_start).toSec(), /*final=*/true);
  result.bag_duration_s = (last_time - bag_start).toSec();
  solve(last_time);  // the final solve, at the last message's time
  out.close();

  // Outputs.
  const std::shared_ptr<const OnlineSolution> solution =
      std::make_shared<const OnlineSolution>(pipeline.CameraSolution(*averager.Solution()));
  NamedOrientations named;
  for (const auto& [key, r] : solution->orientations) named[OnlineAverager::KeyframeName(key)] = r;
  result.orientations_csv = options.output_dir + "/orientations.csv";
  if (!WriteOrientationsCsv(result.orientations_csv, named, &error)) return fail(error);
  result.graph_file = options.output_dir + "/graph.txt";
  if (!averager.SaveGraph(result.graph_file, &error)) return fail(error);

  const OnlineAveragerStats stats = averager.Stats();
  const PipelineStats pipeline_stats = pipeline.Stats();
  result.variables = stats.views;
  result.keyframes = solution->orientations.size();
  result.edges = stats.edges;
  result.components = solution->summary.components.size();
  result.outlier_edges = solution->summary.num_outlier_edges;
  for (const ComponentSummary& c : solution->summary.components) result.final_cost += c.final_cost;
  for (const auto& [source, n] : averager.EdgesBySource()) result.edges_by_source[EdgeSourceName(source)] = n;
  result.keyframe_images = pipeline_stats.processed_images;
  result.rejected_images = pipeline_stats.rejected_images;
  result.rejected_messages = pipeline_stats.rejected_messages;
  if (const KeyframeFrontend* f = pipeline.Frontend()) {
    result.frontend_features_s = f->Stats().features_s;
    result.frontend_retrieval_s = f->Stats().retrieval_s;
    result.frontend_pairs_s = f->Stats().pairs_s;
    result.frontend_failed_pairs = f->Stats().failed_pairs;
    result.frontend_rotation_model_edges = f->Stats().rotation_model_edges;
    result.frontend_chain_bridged = f->Stats().chain_bridged;
    result.loop_candidates = f->Stats().loop_candidates_tried;
    result.loop_closure_edges = f->Stats().loop_closure_edges;
    result.frontend_bytes = f->Stats().keyframe_bytes;
    result.compacted_keyframes = f->Stats().compacted_keyframes;
    result.compact_bytes = f->Stats().compact_bytes;
    result.frontend_failures = f->Stats().failures;
    result.retrieval = f->RetrievalName();
  }
  if (!result.frontend_cost.empty()) {
    result.frontend_cost_csv = options.output_dir + "/frontend_cost.csv";
    std::ofstream csv(result.frontend_cost_csv);
    csv << "keyframe,features_ms,retrieval_ms,pairs_ms,total_ms\n";
    LineSeries total{"front end, all (mean of 20)", {}, {}}, retrieval{"retrieval (mean of 20)", {}, {}};
    double sum_total = 0.0, sum_retrieval = 0.0;
    for (std::size_t k = 0; k < result.frontend_cost.size(); ++k) {
      const ReplayResult::KeyframeCost& c = result.frontend_cost[k];
      csv << k + 1 << "," << c.features_ms << "," << c.retrieval_ms << "," << c.pairs_ms << "," << c.total_ms << "\n";
      // Means over 20 keyframes: single keyframes with a loop closure to
      // verify are several times the others.
      sum_total += c.total_ms;
      sum_retrieval += c.retrieval_ms;
      if ((k + 1) % 20 == 0) {
        total.x.push_back(static_cast<double>(k + 1));
        total.y.push_back(sum_total / 20);
        retrieval.x.push_back(static_cast<double>(k + 1));
        retrieval.y.push_back(sum_retrieval / 20);
        sum_total = sum_retrieval = 0.0;
      }
    }
    if (!csv) return fail("cannot write " + result.frontend_cost_csv);
    result.frontend_cost_png = options.output_dir + "/frontend_cost.png";
    if (!WriteLinePlot(result.frontend_cost_png, "front-end wall time per keyframe against the keyframe count",
                       "keyframes", "ms per keyframe", {total, retrieval}, &error)) {
      result.frontend_cost_png.clear();  // fewer than 20 keyframes: nothing to draw
    }
  }
  result.absorbed_by_rig = pipeline_stats.absorbed_by_rig;
  for (const auto& [camera, rig] : pipeline.Rig().RigCameras()) result.rig_cameras.push_back(camera + " in " + rig.first);

  if (!ground_truth.empty()) {
    result.scores = EvaluateOrientations(named, ground_truth);
    result.have_scores = true;
    result.scores_file = options.output_dir + "/scores.txt";
    std::ofstream scores(result.scores_file);
    scores << result.scores.ToText() << "\n";
    if (!scores) return fail("cannot write " + result.scores_file);
    // Errors per keyframe over capture time, one series per camera.
    std::map<std::string, ErrorSeries> series;
    std::int64_t first_stamp = std::numeric_limits<std::int64_t>::max();
    for (const auto& [key, r] : solution->orientations) first_stamp = std::min(first_stamp, key.stamp_ns);
    for (const auto& [name, e] : result.scores.errors_deg) {
      KeyframeKey key;
      if (!OnlineAverager::ParseKeyframeName(name, &key)) continue;
      ErrorSeries& s = series[key.frame_id];
      s.label = key.frame_id;
      s.time_s.push_back(1e-9 * static_cast<double>(key.stamp_ns - first_stamp));
      s.error_deg.push_back(e);
    }
    std::vector<ErrorSeries> list;
    for (auto& [frame, s] : series) list.push_back(std::move(s));
    char title[160];
    std::snprintf(title, sizeof(title), "%zu keyframes: median %.3f deg, AUC@2/5/10 %.1f / %.1f / %.1f",
                  result.scores.views_common, result.scores.median_error_deg, 100 * result.scores.auc[0].second,
                  100 * result.scores.auc[1].second, 100 * result.scores.auc[2].second);
    result.plot_png = options.output_dir + "/errors.png";
    if (!WriteErrorPlot(result.plot_png, title, list, &error)) {
      result.warnings.push_back("no plot: " + error);
      result.plot_png.clear();
    }
  }
  result.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  result.cpu_s = CpuSeconds() - cpu_start;
  result.peak_rss_mib = PeakRssMiB();
  result.ok = true;
  return result;
}

}  // namespace rotation_averaging
