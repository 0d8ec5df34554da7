// rotation_averaging_node: live covariance-weighted robust rotation averaging.
//
// Subscribes to relative poses (single and array), keeps the view graph in an
// OnlineAverager (ROS-free), re-solves it in a worker thread every
// ~solve_period seconds, and publishes the keyframe orientations over tf2 and
// as a latched Orientations topic. Callbacks only convert, validate and
// enqueue. See config/rotation_averaging.yaml for every parameter.
#include <cv_bridge/cv_bridge.h>
#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/camera_common.h>
#include <image_transport/image_transport.h>
#include <ros/ros.h>
#include <opencv2/imgcodecs.hpp>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/image_encodings.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/transform_broadcaster.h>

#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "rotation_averaging/LoadGraph.h"
#include "rotation_averaging/RotationAveragingConfig.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/controllers/keyframe_frontend.h"
#include "rotation_averaging/controllers/online_averager.h"
#include "rotation_averaging/geometry/so3.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

std::string Replace(std::string text, const std::string& key, const std::string& value) {
  for (std::size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + value.size())) {
    text.replace(at, key.size(), value);
  }
  return text;
}

class RotationAveragingNode {
 public:
  explicit RotationAveragingNode(ros::NodeHandle& nh, ros::NodeHandle& pnh) : pnh_(pnh) {
    fixed_frame_ = pnh.param<std::string>("fixed_frame", "map");
    tf_mode_ = pnh.param<std::string>("tf_mode", "all_keyframes");
    if (tf_mode_ != "all_keyframes" && tf_mode_ != "latest_per_camera" && tf_mode_ != "none") {
      ROS_WARN("tf_mode '%s' unknown: using all_keyframes", tf_mode_.c_str());
      tf_mode_ = "all_keyframes";
    }
    keyframe_frame_format_ = pnh.param<std::string>("keyframe_frame_format", "{frame_id}_kf_{stamp_ns}");
    latest_frame_format_ = pnh.param<std::string>("latest_frame_format", "{frame_id}_averaged");
    save_on_shutdown_ = pnh.param<std::string>("save_on_shutdown", "");

    OnlineAveragerOptions options;
    options.solve_period_s = pnh.param("solve_period", 1.0);
    options.solve_early_on_loop_closure = pnh.param("solve_early_on_loop_closure", true);
    options.max_queue = static_cast<std::size_t>(std::max(1, pnh.param("max_queue", 10000)));
    options.max_views = static_cast<std::size_t>(std::max(2, pnh.param("max_views", 1000000)));
    options.max_edges = static_cast<std::size_t>(std::max(1, pnh.param("max_edges", 10000000)));
    options.averaging = AveragingOptionsFromParams();
    current_averaging_ = options.averaging;
    averager_ = std::make_unique<OnlineAverager>(options);

    SetUpImages(nh);
    orientations_pub_ = pnh.advertise<Orientations>("orientations", 1, /*latch=*/true);
    // Our own latched /tf_static publisher: the whole keyframe set is rebuilt
    // once per solve (tf2_ros::StaticTransformBroadcaster merges updates by
    // linear search, quadratic in the number of keyframes).
    if (tf_mode_ == "all_keyframes") static_tf_pub_ = nh.advertise<tf2_msgs::TFMessage>("/tf_static", 1, true);
    single_sub_ = nh.subscribe("relative_pose", 1000, &RotationAveragingNode::OnRelativePose, this);
    array_sub_ = nh.subscribe("relative_poses", 100, &RotationAveragingNode::OnRelativePoseArray, this);
    solve_srv_ = pnh.advertiseService("solve", &RotationAveragingNode::OnSolve, this);
    reset_srv_ = pnh.advertiseService("reset", &RotationAveragingNode::OnReset, this);
    save_srv_ = pnh.advertiseService("save_graph", &RotationAveragingNode::OnSave, this);
    load_srv_ = pnh.advertiseService("load_graph", &RotationAveragingNode::OnLoad, this);

    diagnostics_.setHardwareID("rotation_averaging");
    diagnostics_.add("rotation averaging", this, &RotationAveragingNode::Diagnose);
    diagnostics_timer_ = pnh.createTimer(ros::Duration(1.0), [this](const ros::TimerEvent&) { diagnostics_.update(); });

    averager_->SetSolutionCallback([this](std::shared_ptr<const OnlineSolution> s) { Publish(*s); });
    const std::string load = pnh.param<std::string>("load_graph", "");
    if (!load.empty()) {
      std::string error;
      if (averager_->LoadGraph(load, &error)) {
        ROS_INFO("loaded the view graph from %s", load.c_str());
      } else {
        ROS_ERROR("could not load %s: %s; starting empty", load.c_str(), error.c_str());
      }
    }
    // dynamic_reconfigure starts from the values loaded above.
    reconfigure_ = std::make_unique<dynamic_reconfigure::Server<RotationAveragingConfig>>(reconfigure_mutex_, pnh_);
    RotationAveragingConfig initial;
    initial.loss = LossTypeName(options.averaging.loss);
    initial.weighting = EdgeWeightingName(options.averaging.weighting);
    initial.solver = SolverTypeName(options.averaging.solver);
    initial.sigma_max = options.averaging.loss_scale;
    initial.solve_period = options.solve_period_s;
    reconfigure_->updateConfig(initial);
    reconfigure_->setCallback([this](RotationAveragingConfig& config, uint32_t) { OnReconfigure(config); });
    averager_->Start();
    ROS_INFO("rotation_averaging_node: fixed frame '%s', tf mode %s, solve every %.2f s, loss %s, weighting %s",
             fixed_frame_.c_str(), tf_mode_.c_str(), options.solve_period_s, LossTypeName(options.averaging.loss),
             EdgeWeightingName(options.averaging.weighting));
  }

  ~RotationAveragingNode() {
    {
      std::lock_guard<std::mutex> lock(image_mutex_);
      images_running_ = false;
    }
    image_wake_.notify_all();
    if (image_worker_.joinable()) image_worker_.join();
    averager_->Stop();
    if (!save_on_shutdown_.empty()) {
      std::string error;
      if (!averager_->SaveGraph(save_on_shutdown_, &error)) ROS_ERROR("saving on shutdown failed: %s", error.c_str());
    }
  }

 private:
  // Keyframe images: every image on the configured topics is a keyframe.
  void SetUpImages(ros::NodeHandle& nh) {
    std::vector<std::string> topics;
    pnh_.param("image_topics", topics, std::vector<std::string>());
    if (topics.empty()) return;
    KeyframeFrontendOptions options;
    options.features.downsample = pnh_.param("image_downsample", 1.0);
    if (!(options.features.downsample > 0.0 && options.features.downsample <= 1.0)) options.features.downsample = 1.0;
    options.features.max_features = pnh_.param("max_features", 4000);
    const std::string features = pnh_.param<std::string>("features", "sift");
    if (!ParseFeatureType(features, &options.features.type)) ROS_WARN("features '%s' unknown: using sift", features.c_str());
    options.rig_stamp_tolerance_s = pnh_.param("rig_stamp_tolerance", 0.005);
    options.max_loop_candidates = pnh_.param("max_loop_candidates", 3);
    options.min_loop_inliers = pnh_.param("min_loop_inliers", 60);
    max_image_queue_ = static_cast<std::size_t>(std::max(1, pnh_.param("max_image_queue", 8)));
    frontend_ = std::make_unique<KeyframeFrontend>(options);
    image_transport_ = std::make_unique<image_transport::ImageTransport>(nh);
    // Compressed images are decoded here (Debian ships no compressed
    // image_transport plugin); camera_info is then taken from its own topic.
    const bool compressed = pnh_.param<std::string>("image_transport", "raw") == "compressed";
    for (const std::string& topic : topics) {
      if (compressed) {
        const std::string info_topic = image_transport::getCameraInfoTopic(topic);
        info_subs_.push_back(nh.subscribe<sensor_msgs::CameraInfo>(
            info_topic, 10, [this, topic](const sensor_msgs::CameraInfoConstPtr& info) {
              std::lock_guard<std::mutex> lock(mutex_);
              camera_infos_[topic] = info;
            }));
        compressed_subs_.push_back(nh.subscribe<sensor_msgs::CompressedImage>(
            topic + "/compressed", 10,
            [this, topic](const sensor_msgs::CompressedImageConstPtr& m) { OnCompressedImage(topic, m); }));
        ROS_INFO("keyframes from %s/compressed (+ %s)", topic.c_str(), info_topic.c_str());
      } else {
        camera_subs_.push_back(image_transport_->subscribeCamera(topic, 10, &RotationAveragingNode::OnImage, this));
        ROS_INFO("keyframes from %s (+ camera_info)", topic.c_str());
      }
    }
    images_running_ = true;
    image_worker_ = std::thread(&RotationAveragingNode::ImageWorker, this);
  }

  void DropImage(const std::string& why, std::uint64_t* counter) {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      ++*counter;
    }
    ROS_WARN_THROTTLE(5.0, "keyframe image dropped: %s", why.c_str());
  }

  void OnImage(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info) {
    cv::Mat grey;
    try {
      grey = cv_bridge::toCvShare(image, sensor_msgs::image_encodings::MONO8)->image.clone();
    } catch (const std::exception& e) {
      return DropImage("image from " + image->header.frame_id + " does not decode: " + e.what(), &rejected_images_);
    }
    EnqueueKeyframe(image->header, grey, *info);
  }

  void OnCompressedImage(const std::string& topic, const sensor_msgs::CompressedImageConstPtr& image) {
    sensor_msgs::CameraInfoConstPtr info;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = camera_infos_.find(topic);
      if (it != camera_infos_.end()) info = it->second;
    }
    if (!info) return DropImage("no camera_info yet for " + topic, &rejected_images_);
    cv::Mat grey;
    try {
      grey = cv::imdecode(image->data, cv::IMREAD_GRAYSCALE);
    } catch (const cv::Exception& e) {
      grey.release();
    }
    if (grey.empty()) {
      return DropImage("compressed image from " + image->header.frame_id + " (" + image->format + ") does not decode",
                       &rejected_images_);
    }
    EnqueueKeyframe(image->header, grey, *info);
  }

  // Validates and queues a decoded keyframe image for the front-end worker.
  void EnqueueKeyframe(const std_msgs::Header& header, const cv::Mat& grey, const sensor_msgs::CameraInfo& info) {
    const std::string& frame = header.frame_id;
    if (frame.empty()) return DropImage("empty frame_id", &rejected_images_);
    if (grey.empty()) return DropImage("empty image from " + frame, &rejected_images_);
    Eigen::Matrix3d k;
    for (int i = 0; i < 9; ++i) k(i / 3, i % 3) = info.K[i];
    if (!k.allFinite() || !(k(0, 0) > 0.0) || !(k(1, 1) > 0.0) || std::abs(k(2, 2) - 1.0) > 1e-9) {
      return DropImage("camera_info of " + frame + " has no valid K", &rejected_images_);
    }
    if (info.width > 0 && (static_cast<int>(info.width) != grey.cols || static_cast<int>(info.height) != grey.rows)) {
      return DropImage("image of " + frame + " does not match its camera_info size", &rejected_images_);
    }
    const std::int64_t stamp = ToNanoseconds(header.stamp);
    if (!StampAdvances(frame, stamp)) {
      return DropImage("stamp of " + frame + " did not advance (" + std::to_string(header.stamp.toSec()) + ")",
                       &rejected_images_);
    }
    bool queued = false;
    {
      std::lock_guard<std::mutex> lock(image_mutex_);
      if (image_queue_.size() < max_image_queue_) {
        image_queue_.push_back(PendingImage{KeyframeKey{frame, stamp}, grey, k});
        queued = true;
      }
    }
    if (!queued) return DropImage("image queue full (" + std::to_string(max_image_queue_) + ")", &dropped_images_);
    image_wake_.notify_one();
  }

  bool StampAdvances(const std::string& frame, std::int64_t stamp) {
    std::lock_guard<std::mutex> lock(mutex_);
    auto last = last_image_stamp_.find(frame);
    if (last != last_image_stamp_.end() && stamp <= last->second) return false;
    last_image_stamp_[frame] = stamp;
    return true;
  }

  void ImageWorker() {
    while (true) {
      PendingImage next;
      {
        std::unique_lock<std::mutex> lock(image_mutex_);
        image_wake_.wait(lock, [this] { return !images_running_ || !image_queue_.empty(); });
        if (!images_running_) return;
        next = std::move(image_queue_.front());
        image_queue_.pop_front();
      }
      for (const KeyframeRelativeRotation& e : frontend_->AddKeyframe(next.key, next.image, next.k)) {
        std::string error;
        if (!averager_->AddRelativeRotation(e, &error)) ROS_WARN_THROTTLE(5.0, "front-end edge dropped: %s", error.c_str());
      }
      std::lock_guard<std::mutex> lock(mutex_);
      ++processed_images_;
    }
  }

  // Applied at the next solve (which runs at once). Unknown names are
  // refused and the field is reset to the value in use.
  void OnReconfigure(RotationAveragingConfig& config) {
    RotationAveragingOptions o = current_averaging_;
    if (!ParseLossType(config.loss, &o.loss)) {
      ROS_WARN("reconfigure: loss '%s' unknown, kept %s", config.loss.c_str(), LossTypeName(o.loss));
      config.loss = LossTypeName(o.loss);
    }
    if (!ParseEdgeWeighting(config.weighting, &o.weighting)) {
      ROS_WARN("reconfigure: weighting '%s' unknown, kept %s", config.weighting.c_str(), EdgeWeightingName(o.weighting));
      config.weighting = EdgeWeightingName(o.weighting);
    }
    if (!ParseSolverType(config.solver, &o.solver)) {
      ROS_WARN("reconfigure: solver '%s' unknown, kept %s", config.solver.c_str(), SolverTypeName(o.solver));
      config.solver = SolverTypeName(o.solver);
    }
    o.loss_scale = config.sigma_max;
    current_averaging_ = o;
    averager_->SetAveragingOptions(o);
    averager_->SetSolvePeriod(config.solve_period);
    ROS_INFO("reconfigured: loss %s, weighting %s, solver %s, sigma_max %g, solve period %g s", config.loss.c_str(),
             config.weighting.c_str(), config.solver.c_str(), config.sigma_max, config.solve_period);
  }

  RotationAveragingOptions AveragingOptionsFromParams() {
    RotationAveragingOptions o;
    const std::string loss = pnh_.param<std::string>("loss", "magsac");
    if (!ParseLossType(loss, &o.loss)) ROS_WARN("loss '%s' unknown: using magsac", loss.c_str());
    const std::string weighting = pnh_.param<std::string>("weighting", "covariance");
    if (!ParseEdgeWeighting(weighting, &o.weighting)) ROS_WARN("weighting '%s' unknown: using covariance", weighting.c_str());
    const std::string solver = pnh_.param<std::string>("solver", "irls");
    if (!ParseSolverType(solver, &o.solver)) ROS_WARN("solver '%s' unknown: using irls", solver.c_str());
    o.loss_scale = pnh_.param("sigma_max", 0.0);
    o.max_iterations = pnh_.param("max_iterations", 100);
    return o;
  }

  void Accept(const RelativePose& msg) {
    KeyframeRelativeRotation m;
    std::string error;
    if (!FromMsg(msg, &m, &error) || !averager_->AddRelativeRotation(m, &error)) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        ++rejected_messages_;
      }
      ROS_WARN_THROTTLE(5.0, "relative pose %s@%.9f -> %s@%.9f dropped: %s", msg.frame_id_1.c_str(), msg.stamp_1.toSec(),
                        msg.frame_id_2.c_str(), msg.stamp_2.toSec(), error.c_str());
    }
  }

  void OnRelativePose(const RelativePose::ConstPtr& msg) { Accept(*msg); }
  void OnRelativePoseArray(const RelativePoseArray::ConstPtr& msg) {
    for (const RelativePose& p : msg->poses) Accept(p);
  }

  bool OnSolve(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    res.success = averager_->SolveNow();
    const OnlineAveragerStats s = averager_->Stats();
    res.message = res.success ? "solved " + std::to_string(s.views) + " keyframes, " + std::to_string(s.edges) +
                                    " edges in " + std::to_string(s.last_solve_s) + " s"
                              : "nothing solved (empty graph or failed solve; the previous solution is kept)";
    return true;
  }

  bool OnReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    averager_->Reset();
    {
      std::lock_guard<std::mutex> lock(mutex_);
      last_latest_stamp_.clear();
    }
    res.success = true;
    res.message = "graph cleared";
    return true;
  }

  bool OnSave(SaveGraph::Request& req, SaveGraph::Response& res) {
    std::string error;
    res.success = averager_->SaveGraph(req.path, &error);
    res.message = res.success ? "saved to " + req.path : error;
    return true;
  }

  bool OnLoad(LoadGraph::Request& req, LoadGraph::Response& res) {
    std::string error;
    res.success = averager_->LoadGraph(req.path, &error);
    res.message = res.success ? "loaded " + req.path + (error.empty() ? "" : " (" + error + ")") : error;
    return true;
  }

  // Called from the averager's worker thread after each successful solve.
  void Publish(const OnlineSolution& solution) {
    const ros::Time now = ros::Time::now();
    Orientations msg;
    msg.header.stamp = now;
    msg.header.frame_id = fixed_frame_;
    msg.solve_sequence = solution.sequence;
    std::vector<geometry_msgs::TransformStamped> keyframe_tfs;
    std::map<std::string, std::pair<KeyframeKey, Eigen::Matrix3d>> latest;
    for (const auto& [key, r] : solution.orientations) {
      auto c = solution.component.find(key);
      msg.keyframes.push_back(ToMsg(key, r, c == solution.component.end() ? 0 : c->second));
      const KeyframeOrientation& k = msg.keyframes.back();
      if (tf_mode_ == "all_keyframes") {
        keyframe_tfs.push_back(Transform(FromNanoseconds(key.stamp_ns),
                                         Replace(Replace(keyframe_frame_format_, "{frame_id}", key.frame_id),
                                                 "{stamp_ns}", std::to_string(key.stamp_ns)),
                                         k.orientation));
      }
      auto it = latest.find(key.frame_id);
      if (it == latest.end() || it->second.first.stamp_ns < key.stamp_ns) latest[key.frame_id] = {key, r};
    }
    orientations_pub_.publish(msg);
    if (tf_mode_ == "all_keyframes" && !keyframe_tfs.empty()) {
      tf2_msgs::TFMessage tf_static;
      tf_static.transforms = std::move(keyframe_tfs);
      static_tf_pub_.publish(tf_static);
    }
    if (tf_mode_ == "latest_per_camera") {
      // Stamped with the publication time (the estimate of the camera's
      // current orientation); never twice with the same stamp per frame.
      std::vector<geometry_msgs::TransformStamped> tfs;
      std::lock_guard<std::mutex> lock(mutex_);
      for (const auto& [frame_id, kr] : latest) {
        const std::string child = Replace(latest_frame_format_, "{frame_id}", frame_id);
        auto last = last_latest_stamp_.find(child);
        if (last != last_latest_stamp_.end() && now <= last->second) continue;
        last_latest_stamp_[child] = now;
        tfs.push_back(Transform(now, child, ToMsg(kr.first, kr.second, 0).orientation));
      }
      if (!tfs.empty()) broadcaster_.sendTransform(tfs);
    }
  }

  geometry_msgs::TransformStamped Transform(const ros::Time& stamp, const std::string& child,
                                            const geometry_msgs::Quaternion& camera_to_world) const {
    geometry_msgs::TransformStamped t;
    t.header.stamp = stamp;
    t.header.frame_id = fixed_frame_;
    t.child_frame_id = child;
    t.transform.rotation = camera_to_world;
    return t;
  }

  void Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    const OnlineAveragerStats s = averager_->Stats();
    std::uint64_t rejected = 0, rejected_images = 0, dropped_images = 0, processed_images = 0;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      rejected = rejected_messages_;
      rejected_images = rejected_images_;
      dropped_images = dropped_images_;
      processed_images = processed_images_;
    }
    const double period = averager_->SolvePeriod();
    if (s.failed_solves > 0 && s.solves == s.failed_solves) {
      status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "every solve failed");
    } else if (period > 0 && s.last_solve_s > period) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "solve time exceeds the solve period");
    } else if (s.dropped_queue_full + s.dropped_cap > 0) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "input dropped (queue full or caps reached)");
    } else {
      status.summary(diagnostic_msgs::DiagnosticStatus::OK, "ok");
    }
    status.add("keyframes", s.views);
    status.add("edges", s.edges);
    status.add("components", s.components);
    status.add("outlier edges", s.outlier_edges);
    status.add("messages received", s.received);
    status.add("rejected messages", rejected);
    status.add("keyframe images processed", processed_images);
    status.add("rejected images", rejected_images);
    status.add("dropped images (queue full)", dropped_images);
    status.add("dropped (queue full)", s.dropped_queue_full);
    status.add("dropped (caps)", s.dropped_cap);
    status.add("solves", s.solves);
    status.add("failed solves", s.failed_solves);
    status.add("overruns", s.overruns);
    status.add("last solve time (s)", s.last_solve_s);
    status.add("solve period (s)", period);
  }

  ros::NodeHandle pnh_;
  std::string fixed_frame_, tf_mode_, keyframe_frame_format_, latest_frame_format_, save_on_shutdown_;
  std::unique_ptr<OnlineAverager> averager_;
  RotationAveragingOptions current_averaging_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<RotationAveragingConfig>> reconfigure_;
  ros::Publisher orientations_pub_;
  ros::Subscriber single_sub_, array_sub_;
  ros::ServiceServer solve_srv_, reset_srv_, save_srv_, load_srv_;
  tf2_ros::TransformBroadcaster broadcaster_;
  ros::Publisher static_tf_pub_;
  diagnostic_updater::Updater diagnostics_;
  ros::Timer diagnostics_timer_;
  std::mutex mutex_;
  std::uint64_t rejected_messages_ = 0, rejected_images_ = 0, dropped_images_ = 0, processed_images_ = 0;
  std::map<std::string, std::int64_t> last_image_stamp_;
  struct PendingImage {
    KeyframeKey key;
    cv::Mat image;
    Eigen::Matrix3d k;
  };
  std::unique_ptr<KeyframeFrontend> frontend_;
  std::unique_ptr<image_transport::ImageTransport> image_transport_;
  std::vector<image_transport::CameraSubscriber> camera_subs_;
  std::vector<ros::Subscriber> compressed_subs_, info_subs_;
  std::map<std::string, sensor_msgs::CameraInfoConstPtr> camera_infos_;  // by image topic (compressed mode)
  std::mutex image_mutex_;
  std::condition_variable image_wake_;
  std::deque<PendingImage> image_queue_;
  std::size_t max_image_queue_ = 8;
  bool images_running_ = false;
  std::thread image_worker_;
  std::map<std::string, ros::Time> last_latest_stamp_;
};

}  // namespace
}  // namespace rotation_averaging

int main(int argc, char** argv) {
  ros::init(argc, argv, "rotation_averaging_node");
  ros::NodeHandle nh, pnh("~");
  rotation_averaging::RotationAveragingNode node(nh, pnh);
  ros::spin();
  return 0;
}
