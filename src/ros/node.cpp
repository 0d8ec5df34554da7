#include "rotation_averaging/ros/node.h"

#include <image_transport/camera_common.h>
#include <tf2_msgs/TFMessage.h>

#include <stdexcept>
#include <utility>

#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {

std::vector<std::string> ParseListText(const std::string& text) {
  std::vector<std::string> items;
  std::string item;
  for (char c : text + ",") {
    if (c == ',') {
      if (!item.empty()) items.push_back(item);
      item.clear();
    } else if (c != '[' && c != ']' && c != '"' && c != '\'' && c != ' ' && c != '\t') {
      item += c;
    }
  }
  return items;
}

bool NodeParameters::Get(const std::string& name, std::vector<std::string>* value) const {
  if (pnh_.getParam(name, *value)) return true;
  std::string text;
  if (!pnh_.getParam(name, text)) return false;
  *value = ParseListText(text);
  return true;
}

RotationAveragingNode::RotationAveragingNode(ros::NodeHandle& nh, ros::NodeHandle& pnh) : pnh_(pnh) {
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

  SetUpImages(nh);
  SetUpServices(nh, pnh);
  averager_->SetSolutionCallback([this](std::shared_ptr<const OnlineSolution> s) {
    last_solution_wall_s_ = ros::WallTime::now().toSec();
    Publish(*s);
    Refine(*s, false);
  });
  LoadMaps();
  SetUpReconfigure();
  averager_->Start();
  const OnlineAveragerOptions& options = config.averager;
  ROS_INFO("rotation_averaging_node: fixed frame '%s', tf mode %s, solve every %.2f s, loss %s, weighting %s",
           config.fixed_frame.c_str(), OptionName(tf_mode_), options.solve_period_s, LossTypeName(options.averaging.loss),
           EdgeWeightingName(options.averaging.weighting));
}

RotationAveragingNode::~RotationAveragingNode() {
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
  refine_timer_.stop();
  pipeline_->WaitForRefinement();  // its end publishes: before the publishers go
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

// Publishers, subscriptions to relative poses and /tf_static, services,
// diagnostics and the autosave timer.
void RotationAveragingNode::SetUpServices(ros::NodeHandle& nh, ros::NodeHandle& pnh) {
  const PipelineConfig& config = pipeline_->Config();
  orientations_pub_ = pnh.advertise<Orientations>("orientations", 1, /*latch=*/true);
  if (!config.image_topics.empty() && config.focal_calibration != FocalCalibrationMode::kOff) {
    camera_info_checks_pub_ = pnh.advertise<CameraInfoCheckArray>("camera_info_checks", 1, /*latch=*/true);
  }
  if (config.markers) markers_pub_ = pnh.advertise<visualization_msgs::MarkerArray>("markers", 1, /*latch=*/true);
  // Our own latched /tf_static publisher: the whole keyframe set is rebuilt
  // once per solve (tf2_ros::StaticTransformBroadcaster merges updates by
  // linear search, quadratic in the number of keyframes).
  if (tf_mode_ == TfMode::kAllKeyframes) static_tf_pub_ = nh.advertise<tf2_msgs::TFMessage>("/tf_static", 1, true);
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
  // Input gone quiet (the robot stopped, the bag ended): the latest solution
  // is refined without waiting for refinement_period_s, as the replay
  // refines its final one, and again while it has keyframes the windows
  // had no room for (refinement_sweep_back).
  if (pipeline_->HasRefiner()) {
    refine_timer_ = pnh.createWallTimer(ros::WallDuration(1.0), [this](const ros::WallTimerEvent&) {
      const std::shared_ptr<const OnlineSolution> latest = averager_->Solution();
      if (!latest || pipeline_->RefinerRunning()) return;
      if (ros::WallTime::now().toSec() - last_solution_wall_s_ < kRefineWhenQuietS) return;
      if (latest->sequence == refined_sequence_ && pipeline_->RefinementPending(*latest) == 0) return;
      Refine(*latest, true);
    });
  }
}

void RotationAveragingNode::LoadMaps() {
  const PipelineConfig& config = pipeline_->Config();
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
}

// dynamic_reconfigure starts from the values in use.
void RotationAveragingNode::SetUpReconfigure() {
  const OnlineAveragerOptions& options = pipeline_->Config().averager;
  reconfigure_ = std::make_unique<dynamic_reconfigure::Server<RotationAveragingConfig>>(reconfigure_mutex_, pnh_);
  RotationAveragingConfig initial;
  initial.loss = LossTypeName(options.averaging.loss);
  initial.weighting = EdgeWeightingName(options.averaging.weighting);
  initial.solver = SolverTypeName(options.averaging.solver);
  initial.loss_scale = options.averaging.loss_scale;
  initial.solve_period_s = options.solve_period_s;
  reconfigure_->updateConfig(initial);
  reconfigure_->setCallback([this](RotationAveragingConfig& config, uint32_t) { OnReconfigure(config); });
}

// Camera images: keyframe selection (keyframe_selection) picks the
// keyframes of each topic's stream. Their callbacks (decoding, validation,
// selection) run on a spinner thread of their own, so that images never
// delay relative poses on the main thread.
void RotationAveragingNode::SetUpImages(const ros::NodeHandle& node) {
  const PipelineConfig& config = pipeline_->Config();
  if (config.image_topics.empty()) return;
  max_image_queue_ = config.max_image_queue;
  ros::NodeHandle nh(node);
  nh.setCallbackQueue(&image_callbacks_);
  image_transport_ = std::make_unique<image_transport::ImageTransport>(nh);
  // Compressed images are decoded here (Debian ships no compressed
  // image_transport plugin); camera_info is then taken from its own topic.
  const bool compressed = config.image_transport == ImageTransportMode::kCompressed;
  for (const std::string& topic : config.image_topics) {
    const bool rectified = IsRectifiedTopic(topic, config.image_type);
    if (compressed) {
      const std::string info_topic = image_transport::getCameraInfoTopic(topic);
      info_subs_.push_back(nh.subscribe<sensor_msgs::CameraInfo>(
          info_topic, config.image_transport_queue, [this, topic](const sensor_msgs::CameraInfoConstPtr& info) {
            std::lock_guard<std::mutex> lock(mutex_);
            camera_infos_[topic] = info;
          }));
      compressed_subs_.push_back(nh.subscribe<sensor_msgs::CompressedImage>(
          topic + "/compressed", config.image_transport_queue, [this, topic, rectified](const sensor_msgs::CompressedImageConstPtr& m) {
            OnCompressedImage(topic, m, rectified);
          }));
      ROS_INFO("keyframes from %s/compressed (+ %s)", topic.c_str(), info_topic.c_str());
    } else {
      camera_subs_.push_back(image_transport_->subscribeCamera(
          topic, config.image_transport_queue,
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

void RotationAveragingNode::OnImage(const sensor_msgs::ImageConstPtr& image,
                                    const sensor_msgs::CameraInfoConstPtr& info, bool rectified) {
  PendingKeyframe keyframe;
  std::string error;
  if (!pipeline_->DecodeImage(*image, *info, &keyframe, &error, rectified)) {
    ROS_WARN_THROTTLE(5.0, "keyframe image dropped: %s", error.c_str());
    return;
  }
  Select(keyframe);
}

void RotationAveragingNode::OnCompressedImage(const std::string& topic,
                                              const sensor_msgs::CompressedImageConstPtr& image, bool rectified) {
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

void RotationAveragingNode::Select(const PendingKeyframe& image) {
  for (const std::string& notice : pipeline_->TakeCameraModelNotices()) ROS_INFO("camera model: %s", notice.c_str());
  for (PendingKeyframe& keyframe : pipeline_->SelectKeyframes(image)) Enqueue(std::move(keyframe));
  const std::uint64_t missing = pipeline_->FramesMissing();
  if (missing > frames_missing_warned_) {
    ROS_WARN_THROTTLE(5.0,
                      "%llu images missing so far by the gaps in their cameras' stamps (the latest before %s at %.3f): "
                      "lost by the driver, the network, or a full image_transport_queue",
                      static_cast<unsigned long long>(missing), image.key.frame_id.c_str(),
                      1e-9 * static_cast<double>(image.key.stamp_ns));
    frames_missing_warned_ = missing;
  }
}

void RotationAveragingNode::Enqueue(PendingKeyframe keyframe) {
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

void RotationAveragingNode::ImageWorker() {
  while (true) {
    QueuedKeyframe next;
    {
      std::unique_lock<std::mutex> lock(image_mutex_);
      image_wake_.wait(lock, [this] { return !images_running_ || !image_queue_.empty() || refinement_landed_; });
      if (!images_running_) return;
      refinement_landed_ = false;
      if (image_queue_.empty()) {
        // Quiet input: a correction the refinement calls for would otherwise
        // wait for the next image (ProcessKeyframe applies them first).
        lock.unlock();
        std::vector<std::string> warnings;
        pipeline_->ApplyFocalCorrections(&warnings);
        for (const std::string& w : warnings) ROS_WARN_THROTTLE(5.0, "%s", w.c_str());
        LogFocalNotices();
        continue;
      }
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

void RotationAveragingNode::LogFocalNotices() {
  for (const auto& [line, disagrees] : pipeline_->TakeFocalNotices()) {
    if (disagrees) {
      ROS_WARN("camera_info check: %s", line.c_str());
    } else {
      ROS_INFO("camera_info check: %s", line.c_str());
    }
  }
}

void RotationAveragingNode::OnReconfigure(RotationAveragingConfig& config) {
  RotationAveragingOptions o = current_averaging_;
  o.loss_scale = config.loss_scale;
  std::string averaging_error, error;
  const bool valid =
      OptionCheck()
          .Require(ParseLossType(config.loss, &o.loss), "loss '" + config.loss + "' is not one of " + LossTypeChoices())
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

void RotationAveragingNode::Accept(const RelativePose& msg) {
  std::string error;
  if (!pipeline_->AcceptRelativePose(msg, &error)) {
    ROS_WARN_THROTTLE(5.0, "relative pose %s@%.9f -> %s@%.9f dropped: %s", msg.frame_id_1.c_str(), msg.stamp_1.toSec(),
                      msg.frame_id_2.c_str(), msg.stamp_2.toSec(), error.c_str());
  }
}

void RotationAveragingNode::OnRelativePoseArray(const RelativePoseArray::ConstPtr& msg) {
  for (const RelativePose& p : msg->poses) Accept(p);
}

bool RotationAveragingNode::OnSolve(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  res.success = averager_->SolveFullNow();  // on request: the whole graph, not a local re-solve
  const OnlineAveragerStats s = averager_->Stats();
  res.message = res.success ? "solved " + std::to_string(s.views) + " keyframes, " + std::to_string(s.edges) +
                                  " edges in " + std::to_string(s.last_solve_s) + " s"
                            : "nothing solved (empty graph or failed solve; the previous solution is kept)";
  return true;
}

bool RotationAveragingNode::OnReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res) {
  averager_->Reset();
  pipeline_->ResetRefinement();
  pipeline_->ResetRig();
  pipeline_->ResetKeyframeSelection();
  pipeline_->ForgetLatestStamps();
  res.success = true;
  res.message = "graph cleared";
  return true;
}

bool RotationAveragingNode::OnSave(SaveGraph::Request& req, SaveGraph::Response& res) {
  std::string error, note;
  res.success = pipeline_->SaveMap(req.path, &error, &note);
  res.message = res.success ? note : error;
  return true;
}

bool RotationAveragingNode::OnLoad(LoadGraph::Request& req, LoadGraph::Response& res) {
  std::string error, note;
  res.success = pipeline_->LoadMap(req.path, &error, &note);
  res.message = res.success ? note : error;
  return true;
}

bool RotationAveragingNode::OnAddMap(LoadGraph::Request& req, LoadGraph::Response& res) {
  std::string error, note;
  res.success = pipeline_->AddMap(req.path, &error, &note);
  res.message = res.success ? note : error;
  return true;
}

void RotationAveragingNode::Refine(const OnlineSolution& solution, bool now) {
  // From the averager's thread, after its solution is out, or from the
  // quiet-input timer: the refinement runs on a thread of its own, and its
  // end publishes the latest solution again with its corrections.
  const bool started = pipeline_->MaybeRefine(
      solution, ros::WallTime::now().toSec(), now, KeyframePipeline::RefineIn::kBackground, [this](bool ok) {
        const KeyframeRefinerStats r = pipeline_->RefinerStats();
        if (!ok) ROS_WARN_THROTTLE(30.0, "refinement changed nothing: %s", r.last_report.c_str());
        {
          std::lock_guard<std::mutex> lock(image_mutex_);
          refinement_landed_ = true;
        }
        image_wake_.notify_one();
        if (const std::shared_ptr<const OnlineSolution> latest = averager_->Solution()) {
          if (ok) Publish(*latest);
        }
      });
  if (started) refined_sequence_ = solution.sequence;
}

void RotationAveragingNode::Publish(const OnlineSolution& solution) {
  // The averager's thread and the refinement's both publish.
  std::lock_guard<std::mutex> lock(publish_mutex_);
  const ros::Time now = ros::Time::now();
  WarnAboutCaps();
  const OnlineSolution cameras = pipeline_->CameraSolution(solution);  // once per solve
  orientations_pub_.publish(pipeline_->OrientationsMsg(cameras, now));
  if (camera_info_checks_pub_) camera_info_checks_pub_.publish(pipeline_->CameraInfoCheckMsg(now));
  if (markers_pub_ && markers_pub_.getNumSubscribers() > 0) {
    markers_pub_.publish(pipeline_->Markers(solution, cameras, now));
  }
  if (tf_mode_ == TfMode::kAllKeyframes && !solution.orientations.empty()) {
    static_tf_pub_.publish(pipeline_->KeyframeTransforms(cameras));
  }
  if (tf_mode_ == TfMode::kLatestPerCamera) {
    // Stamped with the publication time (the estimate of the camera's
    // current orientation); never twice with the same stamp per frame.
    const std::vector<geometry_msgs::TransformStamped> tfs = pipeline_->LatestTransforms(cameras, now);
    if (!tfs.empty()) broadcaster_.sendTransform(tfs);
  }
}

void RotationAveragingNode::WarnAboutCaps() {
  const OnlineAveragerStats s = averager_->Stats();
  if (s.dropped_cap <= cap_drops_warned_) return;
  const OnlineAveragerOptions& o = pipeline_->Config().averager;
  ROS_WARN_THROTTLE(10.0,
                    "graph caps reached (%zu keyframes, max_views %zu; %zu edges, max_edges %zu): %llu "
                    "measurements dropped so far; raise the caps or reset the graph",
                    s.views, o.max_views, s.edges, o.max_edges, static_cast<unsigned long long>(s.dropped_cap));
  cap_drops_warned_ = s.dropped_cap;
}

NodeStatus RotationAveragingNode::Snapshot() {
  NodeStatus s;
  s.averager = averager_->Stats();
  s.solve_period_s = averager_->SolvePeriod();
  s.pipeline = pipeline_->Stats();
  s.rig_cameras = pipeline_->Rig().NumRigCameras();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    s.dropped_images = dropped_images_;
    s.images_without_info = images_without_info_;
    s.latency = latency_;
    s.frontend_time = frontend_time_;
  }
  {
    std::lock_guard<std::mutex> lock(image_mutex_);
    s.image_queue = image_queue_.size();
  }
  s.max_image_queue = max_image_queue_;
  // Input rates since the previous diagnostics update.
  const ros::WallTime now = ros::WallTime::now();
  const double dt = (now - last_rates_time_).toSec();
  if (dt > 0.0 && last_rates_time_.toSec() > 0.0) {
    s.has_rates = true;
    s.measurements_per_s = (s.averager.received - last_received_) / dt;
    s.keyframe_images_per_s = (s.pipeline.processed_images - last_images_) / dt;
  }
  last_rates_time_ = now;
  last_received_ = s.averager.received;
  last_images_ = s.pipeline.processed_images;
  s.focal_checks = pipeline_->FocalChecks();
  s.focal_check_times = pipeline_->FocalCheckTimes();
  s.refinement = pipeline_->HasRefiner();
  s.refinement_stats = pipeline_->RefinerStats();
  if (pipeline_->HasFrontend()) {
    s.has_frontend = true;
    s.frontend = pipeline_->FrontendStats();
    s.retrieval = pipeline_->Frontend()->RetrievalName();
    s.window_pairs = pipeline_->Config().frontend.window_pairs;
    s.focal_corrections = pipeline_->FocalCorrections();
    s.lens_corrections = pipeline_->LensCorrections();
  }
  ReadMemoryMiB(&s.resident_mib, &s.peak_resident_mib);
  return s;
}

void RotationAveragingNode::Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status) {
  LogFocalNotices();
  FillDiagnostics(Snapshot(), &status);
}

}  // namespace rotation_averaging
