// rotation_averaging_node: live covariance-weighted robust rotation averaging.
//
// Subscribes to relative poses (single and array), keeps the view graph in an
// OnlineAverager (ROS-free), re-solves it in a worker thread every
// ~solve_period_s seconds, and publishes the keyframe orientations over tf2 and
// as a latched Orientations topic. Callbacks only convert, validate and
// enqueue. See config/rotation_averaging.yaml for every parameter.
#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/camera_common.h>
#include <image_transport/image_transport.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <std_srvs/Trigger.h>
#include <tf2_msgs/TFMessage.h>
#include <tf2_ros/transform_broadcaster.h>

#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <fstream>
#include <map>
#include <memory>
#include <stdexcept>
#include <mutex>
#include <string>
#include <thread>

#include "rotation_averaging/LoadGraph.h"
#include "rotation_averaging/RotationAveragingConfig.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/SaveGraph.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "core/util/option_check.h"
#include "ros/keyframe_pipeline.h"
#include "ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

// Parameters from the node's private namespace.
class NodeParameters : public ParameterSource {
 public:
  explicit NodeParameters(const ros::NodeHandle& pnh) : pnh_(pnh) {}
  bool Get(const std::string& name, std::string* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, double* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, int* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, bool* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, std::vector<std::string>* value) const override {
    if (pnh_.getParam(name, *value)) return true;
    // On the command line (`rosrun ... _image_topics:=[/a/image_raw,/b/image_raw]`)
    // roscpp stores a list as one string: read it as the list it spells.
    std::string text;
    if (!pnh_.getParam(name, text)) return false;
    value->clear();
    std::string item;
    for (char c : text + ",") {
      if (c == ',') {
        if (!item.empty()) value->push_back(item);
        item.clear();
      } else if (c != '[' && c != ']' && c != '"' && c != '\'' && c != ' ' && c != '\t') {
        item += c;
      }
    }
    return true;
  }

 private:
  const ros::NodeHandle& pnh_;
};

class RotationAveragingNode {
 public:
  explicit RotationAveragingNode(ros::NodeHandle& nh, ros::NodeHandle& pnh) : pnh_(pnh) {
    std::vector<std::string> warnings;
    PipelineConfig config;
    std::string error;
    const bool valid = ReadPipelineConfig(NodeParameters(pnh), &config, &warnings, &error);
    for (const std::string& w : warnings) ROS_WARN("%s", w.c_str());
    if (!valid) throw std::invalid_argument(error);
    pipeline_ = std::make_unique<KeyframePipeline>(config);
    averager_ = &pipeline_->Averager();
    current_averaging_ = config.averager.averaging;
    tf_mode_ = config.tf_mode;
    const OnlineAveragerOptions& options = config.averager;

    SetUpImages(nh);
    orientations_pub_ = pnh.advertise<Orientations>("orientations", 1, /*latch=*/true);
    if (!config.image_topics.empty() && config.focal_calibration != "off") {
      camera_info_checks_pub_ = pnh.advertise<CameraInfoCheckArray>("camera_info_checks", 1, /*latch=*/true);
    }
    if (config.markers) markers_pub_ = pnh.advertise<visualization_msgs::MarkerArray>("markers", 1, /*latch=*/true);
    // Our own latched /tf_static publisher: the whole keyframe set is rebuilt
    // once per solve (tf2_ros::StaticTransformBroadcaster merges updates by
    // linear search, quadratic in the number of keyframes).
    if (tf_mode_ == "all_keyframes") static_tf_pub_ = nh.advertise<tf2_msgs::TFMessage>("/tf_static", 1, true);
    single_sub_ = nh.subscribe("relative_pose", 1000, &RotationAveragingNode::OnRelativePose, this);
    array_sub_ = nh.subscribe("relative_poses", 100, &RotationAveragingNode::OnRelativePoseArray, this);
    // Rig extrinsics (static transforms from the cameras to the rig frame).
    tf_static_sub_ = nh.subscribe<tf2_msgs::TFMessage>(
        "/tf_static", 100, [this](const tf2_msgs::TFMessage::ConstPtr& m) { pipeline_->AcceptStaticTransforms(*m); });
    solve_srv_ = pnh.advertiseService("solve", &RotationAveragingNode::OnSolve, this);
    reset_srv_ = pnh.advertiseService("reset", &RotationAveragingNode::OnReset, this);
    save_srv_ = pnh.advertiseService("save_graph", &RotationAveragingNode::OnSave, this);
    load_srv_ = pnh.advertiseService("load_graph", &RotationAveragingNode::OnLoad, this);
    add_map_srv_ = pnh.advertiseService("add_map", &RotationAveragingNode::OnAddMap, this);

    diagnostics_.setHardwareID("rotation_averaging");
    diagnostics_.add("rotation averaging", this, &RotationAveragingNode::Diagnose);
    diagnostics_timer_ = pnh.createTimer(ros::Duration(1.0), [this](const ros::TimerEvent&) { diagnostics_.update(); });
    // Periodic atomic save (write, then rename; checksummed): a node killed
    // mid-run restarts from the last save with load_graph.
    if (!config.autosave_path.empty() && config.autosave_period_s > 0.0) {
      autosave_timer_ = pnh.createWallTimer(ros::WallDuration(config.autosave_period_s), [this](const ros::WallTimerEvent&) {
        std::string error;
        if (averager_->Stats().views == 0) return;
        if (!pipeline_->SaveMap(pipeline_->Config().autosave_path, &error)) {
          ROS_WARN_THROTTLE(60.0, "autosave to %s failed: %s", pipeline_->Config().autosave_path.c_str(), error.c_str());
        }
      });
    }

    averager_->SetSolutionCallback([this](std::shared_ptr<const OnlineSolution> s) { Publish(*s); });
    const std::string& load = config.load_graph;
    if (!load.empty()) {
      std::string error, note;
      if (pipeline_->LoadMap(load, &error, &note)) {
        ROS_INFO("%s", note.c_str());
      } else {
        ROS_ERROR("could not load %s: %s; starting empty", load.c_str(), error.c_str());
      }
    }
    for (const std::string& map : config.add_maps) {
      std::string error, note;
      if (pipeline_->AddMap(map, &error, &note)) {
        ROS_INFO("%s", note.c_str());
      } else {
        ROS_ERROR("could not add the map %s: %s; going on without it", map.c_str(), error.c_str());
      }
    }
    // dynamic_reconfigure starts from the values loaded above.
    reconfigure_ = std::make_unique<dynamic_reconfigure::Server<RotationAveragingConfig>>(reconfigure_mutex_, pnh_);
    RotationAveragingConfig initial;
    initial.loss = LossTypeName(options.averaging.loss);
    initial.weighting = EdgeWeightingName(options.averaging.weighting);
    initial.solver = SolverTypeName(options.averaging.solver);
    initial.loss_scale = options.averaging.loss_scale;
    initial.solve_period_s = options.solve_period_s;
    reconfigure_->updateConfig(initial);
    reconfigure_->setCallback([this](RotationAveragingConfig& config, uint32_t) { OnReconfigure(config); });
    averager_->Start();
    ROS_INFO("rotation_averaging_node: fixed frame '%s', tf mode %s, solve every %.2f s, loss %s, weighting %s",
             config.fixed_frame.c_str(), tf_mode_.c_str(), options.solve_period_s, LossTypeName(options.averaging.loss),
             EdgeWeightingName(options.averaging.weighting));
  }

  ~RotationAveragingNode() {
    // Image callbacks run on their own spinner and queue: stop the spinner
    // and unsubscribe before the queue (a member declared after the
    // subscribers, so destroyed before them) goes away; a subscriber torn
    // down after its queue locks a destroyed mutex.
    if (image_spinner_) image_spinner_->stop();
    image_spinner_.reset();
    camera_subs_.clear();
    compressed_subs_.clear();
    info_subs_.clear();
    image_transport_.reset();
    image_callbacks_.disable();
    image_callbacks_.clear();
    {
      std::lock_guard<std::mutex> lock(image_mutex_);
      images_running_ = false;
    }
    image_wake_.notify_all();
    if (image_worker_.joinable()) image_worker_.join();
    averager_->Stop();
    const std::string& save = pipeline_->Config().save_on_shutdown;
    if (!save.empty()) {
      std::string error;
      std::string note;
      if (pipeline_->SaveMap(save, &error, &note)) {
        ROS_INFO("%s", note.c_str());
      } else {
        ROS_ERROR("saving on shutdown failed: %s", error.c_str());
      }
    }
  }

 private:
  // Camera images: keyframe selection (keyframe_selection) picks the
  // keyframes of each topic's stream. Their callbacks (decoding, validation,
  // selection) run on a spinner thread of their own, so that images never
  // delay relative poses on the main thread.
  void SetUpImages(const ros::NodeHandle& node) {
    const PipelineConfig& config = pipeline_->Config();
    if (config.image_topics.empty()) return;
    max_image_queue_ = config.max_image_queue;
    ros::NodeHandle nh(node);
    nh.setCallbackQueue(&image_callbacks_);
    image_transport_ = std::make_unique<image_transport::ImageTransport>(nh);
    // Compressed images are decoded here (Debian ships no compressed
    // image_transport plugin); camera_info is then taken from its own topic.
    const bool compressed = config.image_transport == "compressed";
    for (const std::string& topic : config.image_topics) {
      if (compressed) {
        const std::string info_topic = image_transport::getCameraInfoTopic(topic);
        info_subs_.push_back(nh.subscribe<sensor_msgs::CameraInfo>(
            info_topic, 10, [this, topic](const sensor_msgs::CameraInfoConstPtr& info) {
              std::lock_guard<std::mutex> lock(mutex_);
              camera_infos_[topic] = info;
            }));
        compressed_subs_.push_back(nh.subscribe<sensor_msgs::CompressedImage>(
            topic + "/compressed", 10,
            [this, topic, rectified = IsRectifiedTopic(topic, config.image_type)](
                const sensor_msgs::CompressedImageConstPtr& m) { OnCompressedImage(topic, m, rectified); }));
        ROS_INFO("keyframes from %s/compressed (+ %s)", topic.c_str(), info_topic.c_str());
      } else {
        const bool rectified = IsRectifiedTopic(topic, config.image_type);
        camera_subs_.push_back(image_transport_->subscribeCamera(
            topic, 10,
            [this, rectified](const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info) {
              OnImage(image, info, rectified);
            }));
        ROS_INFO("keyframes from %s (+ camera_info)", topic.c_str());
      }
    }
    images_running_ = true;
    image_worker_ = std::thread(&RotationAveragingNode::ImageWorker, this);
    image_spinner_ = std::make_unique<ros::AsyncSpinner>(1, &image_callbacks_);
    image_spinner_->start();
  }

  void OnImage(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info, bool rectified) {
    PendingKeyframe keyframe;
    std::string error;
    if (!pipeline_->DecodeImage(*image, *info, &keyframe, &error, rectified)) {
      ROS_WARN_THROTTLE(5.0, "keyframe image dropped: %s", error.c_str());
      return;
    }
    Select(keyframe);
  }

  void OnCompressedImage(const std::string& topic, const sensor_msgs::CompressedImageConstPtr& image,
                         bool rectified) {
    sensor_msgs::CameraInfoConstPtr info;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      auto it = camera_infos_.find(topic);
      if (it != camera_infos_.end()) info = it->second;
    }
    PendingKeyframe keyframe;
    std::string error;
    if (!info) {
      std::lock_guard<std::mutex> lock(mutex_);
      ++images_without_info_;
      ROS_WARN_THROTTLE(5.0, "keyframe image dropped: no camera_info yet for %s", topic.c_str());
      return;
    }
    if (!pipeline_->DecodeCompressedImage(*image, *info, &keyframe, &error, rectified)) {
      ROS_WARN_THROTTLE(5.0, "keyframe image dropped: %s", error.c_str());
      return;
    }
    Select(keyframe);
  }

  // Keyframe selection, here on the image callbacks' thread in arrival order
  // (the same decisions as the replay's for the same images): an image that
  // is not a keyframe costs its decoding and one tracking check.
  void Select(const PendingKeyframe& image) {
    for (const std::string& notice : pipeline_->TakeCameraModelNotices()) ROS_INFO("camera model: %s", notice.c_str());
    for (PendingKeyframe& keyframe : pipeline_->SelectKeyframes(image)) Enqueue(std::move(keyframe));
  }

  // Queues a decoded keyframe for the front-end worker. The queue is bounded:
  // with images faster than the front end, the excess is dropped and counted
  // instead of the node falling ever further behind.
  void Enqueue(PendingKeyframe keyframe) {
    bool queued = false;
    {
      std::lock_guard<std::mutex> lock(image_mutex_);
      if (image_queue_.size() < max_image_queue_) {
        image_queue_.push_back({std::move(keyframe), ros::WallTime::now()});
        queued = true;
      }
    }
    if (!queued) {
      {
        std::lock_guard<std::mutex> lock(mutex_);
        ++dropped_images_;
      }
      ROS_WARN_THROTTLE(5.0, "keyframe image dropped: image queue full (%zu)", max_image_queue_);
      return;
    }
    image_wake_.notify_one();
  }

  void ImageWorker() {
    while (true) {
      QueuedKeyframe next;
      {
        std::unique_lock<std::mutex> lock(image_mutex_);
        image_wake_.wait(lock, [this] { return !images_running_ || !image_queue_.empty(); });
        if (!images_running_) return;
        next = std::move(image_queue_.front());
        image_queue_.pop_front();
      }
      const ros::WallTime start = ros::WallTime::now();
      std::vector<std::string> warnings;
      pipeline_->ProcessKeyframe(next.keyframe, nullptr, &warnings);
      for (const std::string& w : warnings) ROS_WARN_THROTTLE(5.0, "%s", w.c_str());
      LogFocalNotices();
      const ros::WallTime end = ros::WallTime::now();
      std::lock_guard<std::mutex> lock(mutex_);
      latency_.Add((end - next.received).toSec());
      frontend_time_.Add((end - start).toSec());
    }
  }

  // The focal-length check's verdicts (focal_calibration: warn), as they
  // change: a camera_info whose focal length the images contradict is
  // a warning, since every rotation of that camera is off by a part of it.
  void LogFocalNotices() {
    for (const auto& [line, disagrees] : pipeline_->TakeFocalNotices()) {
      if (disagrees) {
        ROS_WARN("camera_info check: %s", line.c_str());
      } else {
        ROS_INFO("camera_info check: %s", line.c_str());
      }
    }
  }

  // Applied at the next solve (which runs at once). Unknown names are
  // refused and the field is reset to the value in use.
  // Applies a dynamic_reconfigure update that validates; one that does not
  // (an unknown name, a value out of range) is refused as a whole with a
  // warning saying why, and the server is set back to the options in use.
  void OnReconfigure(RotationAveragingConfig& config) {
    RotationAveragingOptions o = current_averaging_;
    o.loss_scale = config.loss_scale;
    std::string averaging_error, error;
    const bool valid =
        OptionCheck()
            .Require(ParseLossType(config.loss, &o.loss),
                     "loss '" + config.loss + "' is not one of " + LossTypeChoices())
            .Require(ParseEdgeWeighting(config.weighting, &o.weighting),
                     "weighting '" + config.weighting + "' is not one of " + EdgeWeightingChoices())
            .Require(ParseSolverType(config.solver, &o.solver),
                     "solver '" + config.solver + "' is not one of " + SolverTypeChoices())
            .NotNan("solve_period_s", config.solve_period_s)
            .Require(o.Validate(&averaging_error), averaging_error)
            .Ok(&error);
    if (!valid) {
      ROS_WARN("reconfigure refused: %s; the options in use are kept", error.c_str());
      config.loss = LossTypeName(current_averaging_.loss);
      config.weighting = EdgeWeightingName(current_averaging_.weighting);
      config.solver = SolverTypeName(current_averaging_.solver);
      config.loss_scale = current_averaging_.loss_scale;
      config.solve_period_s = averager_->SolvePeriod();
      return;
    }
    current_averaging_ = o;
    averager_->SetAveragingOptions(o);
    averager_->SetSolvePeriod(config.solve_period_s);
    ROS_INFO("reconfigured: loss %s, weighting %s, solver %s, loss_scale %g, solve period %g s", config.loss.c_str(),
             config.weighting.c_str(), config.solver.c_str(), config.loss_scale, config.solve_period_s);
  }


  void Accept(const RelativePose& msg) {
    std::string error;
    if (!pipeline_->AcceptRelativePose(msg, &error)) {
      ROS_WARN_THROTTLE(5.0, "relative pose %s@%.9f -> %s@%.9f dropped: %s", msg.frame_id_1.c_str(), msg.stamp_1.toSec(),
                        msg.frame_id_2.c_str(), msg.stamp_2.toSec(), error.c_str());
    }
  }

  void OnRelativePose(const RelativePose::ConstPtr& msg) { Accept(*msg); }
  void OnRelativePoseArray(const RelativePoseArray::ConstPtr& msg) {
    for (const RelativePose& p : msg->poses) Accept(p);
  }

  bool OnSolve(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    res.success = averager_->SolveFullNow();  // on request: the whole graph, not a local re-solve
    const OnlineAveragerStats s = averager_->Stats();
    res.message = res.success ? "solved " + std::to_string(s.views) + " keyframes, " + std::to_string(s.edges) +
                                    " edges in " + std::to_string(s.last_solve_s) + " s"
                              : "nothing solved (empty graph or failed solve; the previous solution is kept)";
    return true;
  }

  bool OnReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
    averager_->Reset();
    pipeline_->ResetRig();
    pipeline_->ResetKeyframeSelection();
    pipeline_->ForgetLatestStamps();
    res.success = true;
    res.message = "graph cleared";
    return true;
  }

  bool OnSave(SaveGraph::Request& req, SaveGraph::Response& res) {
    std::string error, note;
    res.success = pipeline_->SaveMap(req.path, &error, &note);
    res.message = res.success ? note : error;
    return true;
  }

  bool OnLoad(LoadGraph::Request& req, LoadGraph::Response& res) {
    std::string error, note;
    res.success = pipeline_->LoadMap(req.path, &error, &note);
    res.message = res.success ? note : error;
    return true;
  }

  bool OnAddMap(LoadGraph::Request& req, LoadGraph::Response& res) {
    std::string error, note;
    res.success = pipeline_->AddMap(req.path, &error, &note);
    res.message = res.success ? note : error;
    return true;
  }

  // Called from the averager's worker thread after each successful solve.
  void Publish(const OnlineSolution& solution) {
    const ros::Time now = ros::Time::now();
    WarnAboutCaps();
    const OnlineSolution cameras = pipeline_->CameraSolution(solution);  // once per solve
    orientations_pub_.publish(pipeline_->OrientationsMsg(cameras, now));
    if (camera_info_checks_pub_) camera_info_checks_pub_.publish(pipeline_->CameraInfoCheckMsg(now));
    if (markers_pub_ && markers_pub_.getNumSubscribers() > 0) {
      markers_pub_.publish(pipeline_->Markers(solution, cameras, now));
    }
    if (tf_mode_ == "all_keyframes" && !solution.orientations.empty()) {
      static_tf_pub_.publish(pipeline_->KeyframeTransforms(cameras));
    }
    if (tf_mode_ == "latest_per_camera") {
      // Stamped with the publication time (the estimate of the camera's
      // current orientation); never twice with the same stamp per frame.
      const std::vector<geometry_msgs::TransformStamped> tfs = pipeline_->LatestTransforms(cameras, now);
      if (!tfs.empty()) broadcaster_.sendTransform(tfs);
    }
  }

  // Measurements dropped at the view or edge caps are counted when the worker
  // applies them to the graph; say so once per burst, with the caps' names.
  void WarnAboutCaps() {
    const OnlineAveragerStats s = averager_->Stats();
    if (s.dropped_cap <= cap_drops_warned_) return;
    const OnlineAveragerOptions& o = pipeline_->Config().averager;
    ROS_WARN_THROTTLE(10.0,
                      "graph caps reached (%zu keyframes, max_views %zu; %zu edges, max_edges %zu): %llu "
                      "measurements dropped so far; raise the caps or reset the graph",
                      s.views, o.max_views, s.edges, o.max_edges, static_cast<unsigned long long>(s.dropped_cap));
    cap_drops_warned_ = s.dropped_cap;
  }

  // Resident and peak resident memory of this process (MiB), from /proc.
  static void ReadMemoryMiB(double* resident, double* peak) {
    *resident = *peak = 0.0;
    std::ifstream status("/proc/self/status");
    std::string line;
    while (std::getline(status, line)) {
      const bool rss = line.rfind("VmRSS:", 0) == 0, hwm = line.rfind("VmHWM:", 0) == 0;
      if (!rss && !hwm) continue;
      const double kib = std::atof(line.c_str() + 6);
      (rss ? *resident : *peak) = kib / 1024.0;
    }
  }

  void Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
    const OnlineAveragerStats s = averager_->Stats();
    const PipelineStats p = pipeline_->Stats();
    std::uint64_t dropped_images = 0, images_without_info = 0;
    RecentTimes latency, frontend_time;
    {
      std::lock_guard<std::mutex> lock(mutex_);
      dropped_images = dropped_images_;
      images_without_info = images_without_info_;
      latency = latency_;
      frontend_time = frontend_time_;
    }
    std::size_t image_queue = 0;
    {
      std::lock_guard<std::mutex> lock(image_mutex_);
      image_queue = image_queue_.size();
    }
    LogFocalNotices();
    const std::map<std::string, CameraFocalCheck> focal = pipeline_->FocalChecks();
    std::string focal_disagrees, undescribed_lens;
    for (const auto& [camera, check] : focal) {
      if (check.disagrees) focal_disagrees += (focal_disagrees.empty() ? "" : ", ") + camera;
      if (check.distortion_unmodelled) undescribed_lens += (undescribed_lens.empty() ? "" : ", ") + camera;
    }
    const double period = averager_->SolvePeriod();
    if (s.failed_solves > 0 && s.solves == s.failed_solves) {
      status.summary(diagnostic_msgs::DiagnosticStatus::ERROR, "every solve failed");
    } else if (period > 0 && s.last_solve_s > period) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "solve time exceeds the solve period");
    } else if (s.dropped_queue_full + s.dropped_cap > 0) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN, "input dropped (queue full or caps reached)");
    } else if (!undescribed_lens.empty()) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                     "images are distorted but camera_info has no distortion model: " + undescribed_lens);
    } else if (!focal_disagrees.empty()) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                     "camera_info's focal length disagrees with the images of " + focal_disagrees);
    } else if (dropped_images > 0) {
      status.summary(diagnostic_msgs::DiagnosticStatus::WARN,
                     "keyframe images dropped: they come faster than the front end processes them");
    } else {
      status.summary(diagnostic_msgs::DiagnosticStatus::OK, "ok");
    }
    status.add("keyframes", s.views);
    status.add("edges", s.edges);
    status.add("components", s.components);
    status.add("outlier edges", s.outlier_edges);
    status.add("messages received", s.received);
    // Input rates since the previous diagnostics update.
    const ros::WallTime now = ros::WallTime::now();
    const double dt = (now - last_rates_time_).toSec();
    if (dt > 0.0 && last_rates_time_.toSec() > 0.0) {
      status.add("measurements per second (relative poses + front-end edges)", (s.received - last_received_) / dt);
      status.add("keyframe images per second", (p.processed_images - last_images_) / dt);
    }
    last_rates_time_ = now;
    last_received_ = s.received;
    last_images_ = p.processed_images;
    status.add("rejected messages", p.rejected_messages);
    status.add("images seen", p.frames);
    status.add("images that were not keyframes (keyframe_selection)", p.frames_skipped);
    if (p.frames > 0) status.add("keyframe selection per image (ms)", 1e3 * p.selection_s / p.frames);
    status.add("keyframe images processed", p.processed_images);
    status.add("edges from images", p.edges_from_images);
    status.add("rig cameras (extrinsics known)", pipeline_->Rig().NumRigCameras());
    status.add("measurements absorbed by rig extrinsics", p.absorbed_by_rig);
    status.add("rejected images", p.rejected_images + images_without_info);
    status.add("dropped images (queue full)", dropped_images);
    if (pipeline_->HasFrontend()) {
      // Latency: from an image's arrival to its edges entering the graph.
      status.add("image queue (keyframes waiting)", image_queue);
      status.add("image queue capacity", max_image_queue_);
      status.add("front-end latency per keyframe, last (ms)", 1e3 * latency.last);
      status.add("front-end latency per keyframe, mean of the last 50 (ms)", 1e3 * latency.Mean());
      status.add("front-end time per keyframe, mean of the last 50 (ms)", 1e3 * frontend_time.Mean());
      const KeyframeFrontendStats f = pipeline_->FrontendStats();
      status.add("loop-closure retrieval", pipeline_->Frontend()->RetrievalName());
      status.add("front-end memory of keyframes (MiB)", f.keyframe_bytes / 1048576.0);
      status.add("loop-closure edges", f.loop_closure_edges);
      status.add("of them, between added maps and the map held", f.map_links);
      status.add("failed two-view pairs", f.failed_pairs);
      if (pipeline_->Config().frontend.window_pairs) {
        status.add("window-pair edges (to older keyframes of the window)", f.window_edges);
        status.add("window pairs off the chain (dropped)", f.window_rejected_inconsistent);
      }
      // Each camera's focal-length check: its line, and the figures alone.
      for (const auto& [camera, check] : focal) {
        status.add("focal length check of " + camera, check.Report());
        if (!check.calibration.estimated) continue;
        status.add("focal length scale of " + camera + " (estimated / camera_info)", check.calibration.scale);
        status.add("focal length scale of " + camera + ", standard deviation", check.calibration.standard_deviation);
      }
      for (const auto& [camera, correction] : pipeline_->FocalCorrections()) {
        status.add("focal length of " + camera + " corrected (x camera_info's)", correction);
      }
      status.add("front-end memory of the focal-length check (MiB)", f.focal_bytes / 1048576.0);
    }
    status.add("dropped (queue full)", s.dropped_queue_full);
    status.add("dropped (caps)", s.dropped_cap);
    status.add("queued measurements", s.queued);
    double resident = 0.0, peak = 0.0;
    ReadMemoryMiB(&resident, &peak);
    status.add("resident memory (MiB)", resident);
    status.add("peak resident memory (MiB)", peak);
    status.add("solves", s.solves);
    status.add("local solves (of all solves)", s.local_solves);
    status.add("background full solves taken", s.background_solves);
    status.add("failed solves", s.failed_solves);
    status.add("overruns", s.overruns);
    status.add("last solve time (s)", s.last_solve_s);
    status.add("solve period (s)", period);
  }

  ros::NodeHandle pnh_;
  std::unique_ptr<KeyframePipeline> pipeline_;
  OnlineAverager* averager_ = nullptr;  // owned by pipeline_
  std::string tf_mode_;
  RotationAveragingOptions current_averaging_;
  boost::recursive_mutex reconfigure_mutex_;
  std::unique_ptr<dynamic_reconfigure::Server<RotationAveragingConfig>> reconfigure_;
  ros::Publisher orientations_pub_, markers_pub_, camera_info_checks_pub_;
  ros::Subscriber single_sub_, array_sub_, tf_static_sub_;
  ros::ServiceServer solve_srv_, reset_srv_, save_srv_, load_srv_, add_map_srv_;
  tf2_ros::TransformBroadcaster broadcaster_;
  ros::Publisher static_tf_pub_;
  diagnostic_updater::Updater diagnostics_;
  ros::Timer diagnostics_timer_;
  ros::WallTimer autosave_timer_;
  std::mutex mutex_;  // camera_infos_ and the counters below
  std::uint64_t dropped_images_ = 0, images_without_info_ = 0;
  ros::WallTime last_rates_time_;  // diagnostics: input rates between updates
  std::uint64_t last_received_ = 0, last_images_ = 0;
  std::unique_ptr<image_transport::ImageTransport> image_transport_;
  std::vector<image_transport::CameraSubscriber> camera_subs_;
  std::vector<ros::Subscriber> compressed_subs_, info_subs_;
  std::map<std::string, sensor_msgs::CameraInfoConstPtr> camera_infos_;  // by image topic (compressed mode)
  // Means of the last 50 keyframes (diagnostics), under mutex_.
  struct RecentTimes {
    double last = 0.0;
    std::deque<double> window;
    void Add(double t) {
      last = t;
      window.push_back(t);
      if (window.size() > 50) window.pop_front();
    }
    double Mean() const {
      double sum = 0.0;
      for (double t : window) sum += t;
      return window.empty() ? 0.0 : sum / static_cast<double>(window.size());
    }
  };
  RecentTimes latency_, frontend_time_;
  struct QueuedKeyframe {
    PendingKeyframe keyframe;
    ros::WallTime received;
  };
  ros::CallbackQueue image_callbacks_;
  std::unique_ptr<ros::AsyncSpinner> image_spinner_;
  std::mutex image_mutex_;
  std::condition_variable image_wake_;
  std::deque<QueuedKeyframe> image_queue_;
  std::size_t max_image_queue_ = 8;
  std::uint64_t cap_drops_warned_ = 0;  // worker thread only
  bool images_running_ = false;
  std::thread image_worker_;
};

}  // namespace
}  // namespace rotation_averaging

int main(int argc, char** argv) {
  ros::init(argc, argv, "rotation_averaging_node");
  ros::NodeHandle nh, pnh("~");
  std::unique_ptr<rotation_averaging::RotationAveragingNode> node;
  try {
    node = std::make_unique<rotation_averaging::RotationAveragingNode>(nh, pnh);
  } catch (const std::invalid_argument& e) {
    ROS_FATAL("%s: the node does not start (config/rotation_averaging.yaml lists every parameter)", e.what());
    return 1;
  }
  ros::spin();
  return 0;
}
