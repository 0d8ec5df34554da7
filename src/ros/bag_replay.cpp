#include "rotation_averaging/ros/bag_replay.h"

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

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <iterator>
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
#include "rotation_averaging/frontend/eval/error_plot.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/ros/msg_conversion.h"

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
  bool rectified = false;  // PipelineConfig::image_type for this topic
  std::string image_topic, info_topic;
  sensor_msgs::CameraInfo::ConstPtr info;
  std::deque<rosbag::MessageInstance> waiting;
};

}  // namespace

bool ReadReplayConfig(const std::string& path, PipelineConfig* config, std::vector<std::string>* warnings,
                      std::string* error) {
  YAML::Node root;
  if (!path.empty()) {
    try {
      root = YAML::LoadFile(path);
    } catch (const YAML::Exception& e) {
      *error = "config " + path + ": " + e.what();
      return false;
    }
  }
  YamlParameters params(root);
  std::string config_error;
  if (!ReadPipelineConfig(params, config, warnings, &config_error)) {
    *error = "config " + path + ": " + config_error;
    return false;
  }
  // Solutions that depend on the input only, not on how fast this machine
  // runs: the periodic full solve of large graphs runs in the solve that is
  // due, not in a background thread (OnlineAveragerOptions).
  config->averager.background_full_solves = false;
  for (const std::string& p : params.Problems()) warnings->push_back(p);
  return true;
}

namespace {

// Opens every bag; an unindexed one (truncated while recording) cannot be
// read in time order without `rosbag reindex`, which the error names.
bool OpenBags(const std::vector<std::string>& paths, std::vector<std::unique_ptr<rosbag::Bag>>* bags,
              std::string* error) {
  for (const std::string& path : paths) {
    auto bag = std::make_unique<rosbag::Bag>();
    try {
      bag->open(path, rosbag::bagmode::Read);
    } catch (const rosbag::BagUnindexedException&) {
      *error = path + " is not indexed (recording was interrupted): run `rosbag reindex " + path +
               "` and replay the reindexed bag";
      return false;
    } catch (const rosbag::BagException& e) {
      // A file that starts like a bag but cannot be opened lost its end (the
      // index): reindexing recovers the messages before the cut.
      std::ifstream in(path, std::ios::binary);
      char magic[13] = {0};
      in.read(magic, 12);
      if (in && std::string(magic) == "#ROSBAG V2.0") {
        *error = "cannot open " + path + ": " + e.what() + "; the bag looks truncated (its index is missing): run " +
                 "`rosbag reindex " + path + "` and replay the reindexed bag";
      } else {
        *error = "cannot open " + path + ": " + e.what() + (in ? " (not a ROS bag: no #ROSBAG V2.0 header)" : "");
      }
      return false;
    }
    bags->push_back(std::move(bag));
  }
  return true;
}

// The input topics the bags hold, each of the type the node subscribes with,
// and the camera stream of every configured image topic.
struct InputTopics {
  std::string pose_topic, poses_topic;            // with '/'
  std::set<std::string> present;                  // input topics found, as spelled in the bags
  std::map<std::string, CameraStream> cameras;    // by configured image topic
};

bool FindInputTopics(const ReplayOptions& options, const PipelineConfig& config,
                     const std::vector<std::unique_ptr<rosbag::Bag>>& bags, InputTopics* topics,
                     std::vector<std::string>* warnings, std::string* error) {
  std::map<std::string, std::string> expected;  // topic (with '/') -> datatype
  topics->pose_topic = WithSlash(options.relative_pose_topic);
  topics->poses_topic = WithSlash(options.relative_poses_topic);
  expected[topics->pose_topic] = "rotation_averaging/RelativePose";
  expected["/tf_static"] = "tf2_msgs/TFMessage";
  expected[topics->poses_topic] = "rotation_averaging/RelativePoseArray";
  for (const std::string& topic : config.image_topics) {
    const std::string t = WithSlash(topic);
    expected[t] = "sensor_msgs/Image";
    expected[t + "/compressed"] = "sensor_msgs/CompressedImage";
    expected[WithSlash(image_transport::getCameraInfoTopic(t))] = "sensor_msgs/CameraInfo";
  }
  std::set<std::string> present_normalised;
  std::set<std::string> all_topics;
  for (std::size_t b = 0; b < bags.size(); ++b) {
    rosbag::View whole(*bags[b]);
    for (const rosbag::ConnectionInfo* c : whole.getConnections()) {
      all_topics.insert(c->topic);
      auto it = expected.find(WithSlash(c->topic));
      if (it == expected.end()) continue;
      if (c->datatype != it->second) {
        *error = options.bags[b] + ": topic " + c->topic + " has type " + c->datatype + ", expected " + it->second;
        return false;
      }
      topics->present.insert(c->topic);
      present_normalised.insert(WithSlash(c->topic));
    }
  }
  for (const std::string& topic : config.image_topics) {
    const std::string t = WithSlash(topic);
    CameraStream stream;
    stream.compressed = !present_normalised.count(t) && present_normalised.count(t + "/compressed");
    stream.image_topic = stream.compressed ? t + "/compressed" : t;
    stream.info_topic = WithSlash(image_transport::getCameraInfoTopic(t));
    stream.rectified = IsRectifiedTopic(t, config.image_type);
    if (!present_normalised.count(stream.image_topic)) {
      warnings->push_back("image topic " + t + " (raw or compressed) is not in the bags");
    } else if (!present_normalised.count(stream.info_topic)) {
      warnings->push_back(stream.info_topic + " is not in the bags: images of " + t + " cannot be used");
    }
    topics->cameras.emplace(t, std::move(stream));
  }
  if (all_topics.empty()) {
    *error = "the bags hold no message at all";
    return false;
  }
  const bool only_tf = topics->present.size() == 1 && present_normalised.count("/tf_static");
  if (topics->present.empty() || only_tf) {
    std::string have;
    for (const std::string& t : all_topics) have += (have.empty() ? "" : ", ") + t;
    std::string want;
    for (const auto& [t, type] : expected) want += (want.empty() ? "" : ", ") + t + " (" + type + ")";
    *error = "the bags hold none of the input topics " + want + "; they have: " + (have.empty() ? "nothing" : have) +
             (config.image_topics.empty() ? " (image topics come from image_topics in the config)" : "");
    return false;
  }
  return true;
}

// Static transforms (rig extrinsics) first, whatever their time in the bag:
// the live node receives the latched /tf_static as it subscribes, before the
// first image, while a recorder may write it a little later. Returns the
// other input topics.
std::vector<std::string> ApplyStaticTransforms(const std::vector<std::unique_ptr<rosbag::Bag>>& bags,
                                               const std::set<std::string>& present, KeyframePipeline* pipeline,
                                               std::vector<std::string>* warnings) {
  std::vector<std::string> inputs;
  for (const std::string& t : present) {
    if (WithSlash(t) != "/tf_static") {
      inputs.push_back(t);
      continue;
    }
    rosbag::View statics;
    for (auto& bag : bags) statics.addQuery(*bag, rosbag::TopicQuery(t));
    try {
      for (const rosbag::MessageInstance& m : statics) {
        if (tf2_msgs::TFMessage::ConstPtr tf = m.instantiate<tf2_msgs::TFMessage>()) pipeline->AcceptStaticTransforms(*tf);
      }
    } catch (const rosbag::BagException& e) {
      warnings->push_back(std::string("/tf_static could not be read completely: ") + e.what());
    }
  }
  return inputs;
}

// Feeds the messages through the pipeline in bag time, solving when the live
// node's worker would (every solve_period_s when new input arrived, at once
// after a loop closure), and writes each solution to the output bag.
class Replayer {
 public:
  Replayer(const PipelineConfig& config, KeyframePipeline* pipeline, rosbag::Bag* out, ReplayResult* result)
      : config_(config), pipeline_(*pipeline), out_(*out), result_(*result) {}

  // The first solution after load_graph: the keyframes of the loaded map,
  // followed until a new keyframe joins them (MeasureMerge).
  void FollowLoadedMap(std::shared_ptr<const OnlineSolution> loaded) { loaded_ = std::move(loaded); }

  // A map to save once the replay has passed `after` (the last input
  // message of a bag).
  struct Checkpoint {
    ros::Time after;
    std::string path;
  };
  // In order of time.
  void SaveAt(std::vector<Checkpoint> checkpoints) { checkpoints_ = std::move(checkpoints); }
  const std::string& Error() const { return error_; }

  void Run(rosbag::View& view, InputTopics* topics, bool progress) {
    const ros::Time bag_start = view.getBeginTime();
    const double period = config_.averager.solve_period_s;
    ros::Time next_solve = period > 0.0 ? bag_start + ros::Duration(period) : ros::TIME_MAX;
    ProgressBar bar(progress, result_.messages_total);
    ros::Time last_time = bag_start;
    std::size_t next_checkpoint = 0;
    try {
      for (const rosbag::MessageInstance& m : view) {
        const ros::Time time = m.getTime();
        last_time = time;
        while (next_checkpoint < checkpoints_.size() && time > checkpoints_[next_checkpoint].after) {
          SaveMap(checkpoints_[next_checkpoint++]);
        }
        while (time >= next_solve) {
          Solve(next_solve);
          next_solve += ros::Duration(period);
        }
        try {
          Dispatch(m, time, topics);
        } catch (const ros::serialization::StreamOverrunException& e) {
          DroppedDamaged(m, time, e.what());
        } catch (const std::bad_alloc&) {
          // ROS's deserialiser allocates an array before it checks the bytes.
          DroppedDamaged(m, time, "an array length beyond the memory");
        } catch (const std::length_error&) {
          DroppedDamaged(m, time, "an array length beyond what a vector holds");
        }
        ++result_.messages_read;
        bar.Update(result_.messages_read, (time - bag_start).toSec());
      }
    } catch (const ros::Exception& e) {
      result_.truncated = true;
      result_.warnings.push_back("the bags are damaged after " + std::to_string(result_.messages_read) +
                                 " messages (bag time " + std::to_string((last_time - bag_start).toSec()) +
                                 " s): " + e.what() + "; results cover the messages before the damage");
    }
    bar.Update(result_.messages_read, (last_time - bag_start).toSec(), /*final=*/true);
    result_.bag_duration_s = (last_time - bag_start).toSec();
    Solve(last_time);  // the final solve, at the last message's time
    RefineFinal(last_time);
    // Bags that ended with the last message (or after damage: what was read).
    while (next_checkpoint < checkpoints_.size()) SaveMap(checkpoints_[next_checkpoint++]);
  }

 private:
  // At the first solve where a keyframe that is not in the loaded map shares
  // a component with one that is: how far the loaded keyframes moved from
  // the first solve after loading, in degrees and in that solve's posterior
  // standard deviation along the move (a left perturbation, as the
  // covariance). The gauge keyframe has no covariance: degrees only.
  void MeasureMerge(const OnlineSolution& solution) {
    std::set<int> loaded_components;
    for (const auto& [key, r] : loaded_->orientations) {
      const auto it = solution.component.find(key);
      if (it != solution.component.end()) loaded_components.insert(it->second);
    }
    bool merged = false;
    for (const auto& [key, c] : solution.component) {
      if (loaded_components.count(c) && !loaded_->orientations.count(key)) {
        merged = true;
        break;
      }
    }
    if (!merged) return;
    result_.map_merged = true;
    result_.map_merged_at_solve = result_.solves;
    std::vector<Eigen::Matrix3d> before_all, after_all;
    for (const auto& [key, before] : loaded_->orientations) {
      const auto it = solution.orientations.find(key);
      if (it == solution.orientations.end()) continue;
      before_all.push_back(before);
      after_all.push_back(it->second);
      const Eigen::Vector3d d = LogSO3(it->second * before.transpose());
      result_.map_merge_move_deg = std::max(result_.map_merge_move_deg, RadToDeg(d.norm()));
      const auto cov = loaded_->covariance.find(key);
      if (cov == loaded_->covariance.end() || d.norm() == 0.0) continue;
      const Eigen::Vector3d u = d.normalized();
      const double sigma = std::sqrt(std::max(0.0, u.dot(cov->second * u)));
      if (sigma > 0.0) result_.map_merge_move_sigma = std::max(result_.map_merge_move_sigma, d.norm() / sigma);
    }
    // The frame as a whole: the one rotation that best maps the loaded
    // keyframes' orientations onto their new ones (a gauge jump would show
    // here; a correction the new evidence brings to single keyframes not).
    if (!before_all.empty()) {
      result_.map_merge_frame_deg =
          RadToDeg(AngularDistanceRad(AlignRotations(before_all, after_all), Eigen::Matrix3d::Identity()));
    }
  }

  void Dispatch(const rosbag::MessageInstance& m, const ros::Time& time, InputTopics* topics) {
    const std::string topic = WithSlash(m.getTopic());
    if (topic == topics->pose_topic || topic == topics->poses_topic) {
      bool loop_closure = false;
      if (topic == topics->pose_topic) {
        if (RelativePose::ConstPtr pose = m.instantiate<RelativePose>()) AcceptPose(*pose, time, &loop_closure);
      } else if (RelativePoseArray::ConstPtr poses = m.instantiate<RelativePoseArray>()) {
        for (const RelativePose& pose : poses->poses) AcceptPose(pose, time, &loop_closure);
      }
      if (loop_closure && config_.averager.solve_early_on_loop_closure) Solve(time);
      return;
    }
    for (auto& [name, stream] : topics->cameras) {
      if (topic == stream.info_topic) {
        stream.info = m.instantiate<sensor_msgs::CameraInfo>();
        while (stream.info && !stream.waiting.empty()) {
          ProcessImage(stream, stream.waiting.front(), time);
          stream.waiting.pop_front();
        }
      } else if (topic == stream.image_topic) {
        if (stream.info) {
          ProcessImage(stream, m, time);
        } else if (stream.waiting.size() < 4) {
          stream.waiting.push_back(m);
        } else {
          Warn("image on " + stream.image_topic + " dropped: no camera_info on " + stream.info_topic);
        }
      }
    }
  }

  void Solve(const ros::Time& when) {
    if (!dirty_) return;
    dirty_ = false;
    OnlineAverager& averager = pipeline_.Averager();
    if (!averager.SolveNow()) return;
    ++result_.solves;
    const std::shared_ptr<const OnlineSolution> solution = averager.Solution();
    if (loaded_ && !result_.map_merged) MeasureMerge(*solution);
    // Refinements by bag time, each on a thread of its own while the bag
    // goes on, taken when the next is due: the same on every run.
    if (pipeline_.MaybeRefine(*solution, when.toSec(), false, KeyframePipeline::RefineIn::kStaged)) {
      refined_sequence_ = solution->sequence;
    }
    const OnlineSolution cameras = pipeline_.CameraSolution(*solution);
    out_.write("/rotation_averaging/orientations", when, pipeline_.OrientationsMsg(cameras, when));
    if (pipeline_.HasFrontend() && config_.focal_calibration != FocalCalibrationMode::kOff) {
      out_.write("/rotation_averaging/camera_info_checks", when, pipeline_.CameraInfoCheckMsg(when));
    }
    if (config_.tf_mode == TfMode::kAllKeyframes) {
      out_.write("/tf_static", when, pipeline_.KeyframeTransforms(cameras));
    } else if (config_.tf_mode == TfMode::kLatestPerCamera) {
      tf2_msgs::TFMessage tf;
      tf.transforms = pipeline_.LatestTransforms(cameras, when);
      if (!tf.transforms.empty()) out_.write("/tf", when, tf);
    }
  }

  // The final solution refined, unless the last refinement was of it: what
  // the node publishes once its refinement has caught up with the input.
  // With focal_calibration: apply, a correction the final refinement's
  // focal estimates call for is applied as the next keyframe would apply
  // it (its pairs estimated again), then solved and refined again: twice
  // at most.
  void RefineFinal(const ros::Time& when) {
    for (int round = 0; round < 3; ++round) {
      pipeline_.CommitRefinement();
      const std::shared_ptr<const OnlineSolution> solution = pipeline_.Averager().Solution();
      if (!solution) return;
      if (solution->sequence != refined_sequence_) {
        if (!pipeline_.MaybeRefine(*solution, when.toSec(), true, KeyframePipeline::RefineIn::kHere)) return;
        refined_sequence_ = solution->sequence;
      }
      // The keyframes the windows had no room for, swept back over
      // (refinement_sweep_back) as the node does once its input is quiet.
      for (std::size_t pending = pipeline_.RefinementPending(*solution); pending > 0;) {
        if (!pipeline_.MaybeRefine(*solution, when.toSec(), true, KeyframePipeline::RefineIn::kHere)) break;
        const std::size_t left = pipeline_.RefinementPending(*solution);
        if (left >= pending) break;
        pending = left;
      }
      out_.write("/rotation_averaging/orientations", when,
                 pipeline_.OrientationsMsg(pipeline_.CameraSolution(*solution), when));
      std::vector<std::string> warnings;
      const bool corrected = round < 2 && pipeline_.ApplyFocalCorrections(&warnings);
      TakeFocalNotices();
      for (const std::string& w : warnings) Warn(w);
      if (!corrected) return;
      dirty_ = true;
      Solve(when);
    }
  }

  // The map as the session that ends here leaves it: solved with every
  // input so far, then saved.
  void SaveMap(const Checkpoint& checkpoint) {
    Solve(checkpoint.after);
    pipeline_.CommitRefinement();  // a refinement under way is saved with the map
    std::string note, error;
    if (pipeline_.SaveMap(checkpoint.path, &error, &note)) {
      result_.maps_saved_after_bags.push_back(note);
    } else if (error_.empty()) {
      error_ = "saving the map after a bag: " + error;
    }
  }

  void TakeFocalNotices() {
    for (auto& [line, disagrees] : pipeline_.TakeFocalNotices()) {
      if (disagrees) Warn("camera_info check: " + line);
      if (result_.focal_notices.size() < 50) result_.focal_notices.push_back(std::move(line));
    }
  }

  void Warn(const std::string& w) {
    if (result_.warnings.size() < 50) result_.warnings.push_back(w);
    if (result_.warnings.size() == 50) result_.warnings.push_back("(further warnings not shown)");
  }

  void ProcessImage(CameraStream& stream, const rosbag::MessageInstance& m, const ros::Time& time) {
    PendingKeyframe keyframe;
    std::string why;
    bool ok = false;
    if (stream.compressed) {
      sensor_msgs::CompressedImage::ConstPtr image = m.instantiate<sensor_msgs::CompressedImage>();
      ok = image && pipeline_.DecodeCompressedImage(*image, *stream.info, &keyframe, &why, stream.rectified);
    } else {
      sensor_msgs::Image::ConstPtr image = m.instantiate<sensor_msgs::Image>();
      ok = image && pipeline_.DecodeImage(*image, *stream.info, &keyframe, &why, stream.rectified);
    }
    for (std::string& notice : pipeline_.TakeCameraModelNotices()) {
      if (result_.camera_models.size() < 50) result_.camera_models.push_back(std::move(notice));
    }
    if (!ok) return Warn("image on " + stream.image_topic + " at " + std::to_string(time.toSec()) + " dropped: " + why);
    offered_.insert(OnlineAverager::KeyframeName(keyframe.key));
    for (const PendingKeyframe& k : pipeline_.SelectKeyframes(keyframe)) {
      made_.insert(OnlineAverager::KeyframeName(k.key));
      RunFrontend(k, time);
    }
  }


 public:
  // Images that keyframe selection passed over: their ground truth is not
  // scored (a missing keyframe, one rejected or lost, still is).
  std::set<std::string> NotKeyframes() const {
    std::set<std::string> out;
    std::set_difference(offered_.begin(), offered_.end(), made_.begin(), made_.end(), std::inserter(out, out.end()));
    return out;
  }

 private:

  void RunFrontend(const PendingKeyframe& keyframe, const ros::Time& time) {
    bool loop_closure = false;
    std::vector<std::string> warnings;
    const auto frontend_start = std::chrono::steady_clock::now();
    if (pipeline_.ProcessKeyframe(keyframe, &loop_closure, &warnings) > 0) dirty_ = true;
    if (const KeyframeFrontend* f = pipeline_.Frontend()) {
      const KeyframeFrontendStats& fs = f->Stats();
      ReplayResult::KeyframeCost cost;
      cost.features_ms = 1e3 * fs.last_features_s;
      cost.retrieval_ms = 1e3 * fs.last_retrieval_s;
      cost.pairs_ms = 1e3 * fs.last_pairs_s;
      cost.total_ms = 1e3 * std::chrono::duration<double>(std::chrono::steady_clock::now() - frontend_start).count();
      result_.frontend_cost.push_back(cost);
    }
    // The focal-length estimates that fell due, before anything is published:
    // the output bag then holds the same checks on every replay (the node
    // runs them beside its front end instead).
    pipeline_.WaitForFocalChecks();
    TakeFocalNotices();
    for (const std::string& w : warnings) Warn(w);
    if (loop_closure && config_.averager.solve_early_on_loop_closure) Solve(time);
  }

  void AcceptPose(const RelativePose& pose, const ros::Time& time, bool* loop_closure) {
    std::string why;
    if (pipeline_.AcceptRelativePose(pose, &why)) {
      dirty_ = true;
      if (pose.source == RelativePose::SOURCE_LOOP_CLOSURE) *loop_closure = true;
    } else {
      Warn("relative pose at " + std::to_string(time.toSec()) + " dropped: " + why);
    }
  }

  // A message whose bytes are damaged: dropped and counted, the rest goes on.
  void DroppedDamaged(const rosbag::MessageInstance& m, const ros::Time& time, const std::string& why) {
    ++result_.damaged_messages;
    Warn("message on " + m.getTopic() + " at " + std::to_string(time.toSec()) + " does not deserialise (" + why +
         "): dropped");
  }

  const PipelineConfig& config_;
  KeyframePipeline& pipeline_;
  rosbag::Bag& out_;
  ReplayResult& result_;
  bool dirty_ = false;  // input arrived since the last solve
  std::uint64_t refined_sequence_ = 0;  // the solution the last refinement started from
  std::shared_ptr<const OnlineSolution> loaded_;  // see FollowLoadedMap
  std::vector<Checkpoint> checkpoints_;  // see SaveAt
  std::string error_;  // the first failed save
  std::set<std::string> offered_, made_;  // names of the images offered to keyframe selection, of the keyframes
};

// Where and when save_after_each_bag saves: after each bag's last message on
// the input topics, to output_dir/map_after_bag<N>_<stem>.txt; in order of
// time (bags replayed together may overlap).
std::vector<Replayer::Checkpoint> BagCheckpoints(const ReplayOptions& options,
                                                 const std::vector<std::unique_ptr<rosbag::Bag>>& bags,
                                                 const std::vector<std::string>& inputs,
                                                 std::vector<std::string>* warnings) {
  std::vector<Replayer::Checkpoint> checkpoints;
  for (std::size_t b = 0; b < bags.size(); ++b) {
    rosbag::View own(*bags[b], rosbag::TopicQuery(inputs));
    const std::string path = options.output_dir + "/map_after_bag" + std::to_string(b + 1) + "_" +
                             std::filesystem::path(options.bags[b]).stem().string() + ".txt";
    if (own.size() == 0) {
      warnings->push_back(options.bags[b] + " holds no input message: no map saved after it");
      continue;
    }
    checkpoints.push_back({own.getEndTime(), path});
  }
  std::stable_sort(checkpoints.begin(), checkpoints.end(),
                   [](const Replayer::Checkpoint& a, const Replayer::Checkpoint& b) { return a.after < b.after; });
  return checkpoints;
}

// The largest angle between an orientation saved with the map and the same
// keyframe in `solution`, the first solve after loading it; -1 when the map
// holds no orientations.
double MapLoadShift(const std::map<KeyframeKey, Eigen::Matrix3d>& saved, const OnlineSolution& solution) {
  double shift_deg = saved.empty() ? -1.0 : 0.0;
  for (const auto& [key, r] : saved) {
    const auto it = solution.orientations.find(key);
    if (it != solution.orientations.end()) shift_deg = std::max(shift_deg, RadToDeg(AngularDistanceRad(r, it->second)));
  }
  return shift_deg;
}

}  // namespace

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

  PipelineConfig config;
  std::string error;
  if (!ReadReplayConfig(options.config_path, &config, &result.warnings, &error)) return fail(error);
  if (options.num_threads >= 0) config.frontend.num_threads = options.num_threads;
  KeyframePipeline pipeline(config);
  OnlineAverager& averager = pipeline.Averager();
  // As the node: a map saved before (a restart, an earlier session) is what
  // the bags add to. The node starts empty when it cannot load one; a
  // replay, whose purpose is to test exactly that, stops.
  if (!config.load_graph.empty()) {
    const auto load_start = std::chrono::steady_clock::now();
    std::map<KeyframeKey, Eigen::Matrix3d> saved;
    if (!pipeline.LoadMap(config.load_graph, &error, &result.map_loaded, &saved)) return fail("load_graph: " + error);
    result.map_load_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - load_start).count();
    result.map_load_shift_deg = MapLoadShift(saved, *averager.Solution());
  }
  // The keyframes followed to the merge are the loaded map's: an added map
  // joining it is placed in its frame (the larger of the two keeps its own).
  const std::shared_ptr<const OnlineSolution> loaded_map = averager.Solution();
  for (const std::string& map : config.add_maps) {
    std::string note;
    if (!pipeline.AddMap(map, &error, &note)) return fail("add_maps: " + error);
    result.maps_added.push_back(note);
  }

  NamedOrientations ground_truth;
  if (!options.ground_truth_path.empty() &&
      !ReadGroundTruthFile(options.ground_truth_path, options.ground_truth_topic, &ground_truth, &error)) {
    return fail("ground truth: " + error);
  }
  if (!MakeDirectory(options.output_dir, &error)) return fail(error);

  std::vector<std::unique_ptr<rosbag::Bag>> bags;
  if (!OpenBags(options.bags, &bags, &error)) return fail(error);
  InputTopics topics;
  if (!FindInputTopics(options, config, bags, &topics, &result.warnings, &error)) return fail(error);
  const std::vector<std::string> inputs = ApplyStaticTransforms(bags, topics.present, &pipeline, &result.warnings);
  rosbag::View view;
  for (auto& bag : bags) view.addQuery(*bag, rosbag::TopicQuery(inputs));
  result.messages_total = view.size();
  if (result.messages_total == 0) return fail("the input topics of the bags hold no message");
  result.bag_start_s = view.getBeginTime().toSec();

  result.output_bag = options.output_dir + "/replay.bag";
  rosbag::Bag out;
  try {
    out.open(result.output_bag, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    return fail("cannot write " + result.output_bag + ": " + e.what());
  }
  Replayer replayer(config, &pipeline, &out, &result);
  if (!config.load_graph.empty()) replayer.FollowLoadedMap(loaded_map);
  if (options.save_after_each_bag) replayer.SaveAt(BagCheckpoints(options, bags, inputs, &result.warnings));
  replayer.Run(view, &topics, options.progress);
  out.close();
  if (!replayer.Error().empty()) return fail(replayer.Error());
  std::size_t unscored = 0;
  for (const std::string& name : replayer.NotKeyframes()) unscored += ground_truth.erase(name);
  if (unscored > 0) {
    result.warnings.push_back("ground truth of " + std::to_string(unscored) +
                              " images that keyframe selection passed over is not scored");
  }

  // Outputs.
  const OnlineSolution solution = pipeline.CameraSolution(*averager.Solution());
  NamedOrientations named;
  for (const auto& [key, r] : solution.orientations) named[OnlineAverager::KeyframeName(key)] = r;
  result.orientations_csv = options.output_dir + "/orientations.csv";
  if (!WriteOrientationsCsv(result.orientations_csv, named, &error)) return fail(error);
  result.graph_file = options.output_dir + "/graph.txt";
  if (!averager.SaveGraph(result.graph_file, &error)) return fail(error);
  if (!config.save_on_shutdown.empty()) {
    const auto save_start = std::chrono::steady_clock::now();
    if (!pipeline.SaveMap(config.save_on_shutdown, &error, &result.map_saved)) return fail("save_on_shutdown: " + error);
    result.map_save_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - save_start).count();
    const MapSaveTiming timing = pipeline.LastSaveTiming();
    result.map_save_graph_lock_s = timing.graph_lock_s;
    result.map_save_frontend_lock_s = timing.frontend_lock_s;
  }
  CollectStatistics(pipeline, averager, solution, &result);
  if (!WriteFrontendCost(options.output_dir, &result, &error)) return fail(error);
  if (!ground_truth.empty() &&
      !ScoreAgainstGroundTruth(named, ground_truth, solution, options.output_dir, &result, &error)) {
    return fail(error);
  }
  result.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
  result.cpu_s = CpuSeconds() - cpu_start;
  result.peak_rss_mib = PeakRssMiB();
  result.ok = true;
  return result;
}

}  // namespace rotation_averaging
