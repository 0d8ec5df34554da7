// rotation_averaging_node: live covariance-weighted robust rotation averaging.
//
// Subscribes to relative poses (single and array), camera images and
// /tf_static, keeps the view graph in the pipeline's OnlineAverager
// (ROS-free), re-solves it in the averager's worker thread every
// ~solve_period_s seconds, and publishes the keyframe orientations over tf2
// and as a latched Orientations topic. Relative-pose callbacks convert,
// validate and enqueue on the main spinner; image callbacks decode and
// select keyframes on a spinner of their own; the front end runs on a
// worker thread fed by a bounded queue (docs/architecture.md: the threads
// and their locks). See config/rotation_averaging.yaml for every parameter.
#ifndef ROTATION_AVERAGING_ROS_NODE_H_
#define ROTATION_AVERAGING_ROS_NODE_H_

#include <diagnostic_updater/diagnostic_updater.h>
#include <dynamic_reconfigure/server.h>
#include <image_transport/image_transport.h>
#include <ros/callback_queue.h>
#include <ros/ros.h>
#include <sensor_msgs/CompressedImage.h>
#include <std_srvs/Trigger.h>
#include <tf2_ros/transform_broadcaster.h>

#include <condition_variable>
#include <deque>
#include <map>
#include <memory>
#include <atomic>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "rotation_averaging/ros/keyframe_pipeline.h"
#include "rotation_averaging/ros/node_diagnostics.h"
#include "rotation_averaging/LoadGraph.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/RotationAveragingConfig.h"
#include "rotation_averaging/SaveGraph.h"

namespace rotation_averaging {

// Parameters from a node's private namespace. A list given on the command
// line (`rosrun ... _image_topics:=[/a/image_raw,/b/image_raw]`) reaches
// roscpp as one string and is read as the list it spells.
class NodeParameters : public ParameterSource {
 public:
  explicit NodeParameters(const ros::NodeHandle& pnh) : pnh_(pnh) {}
  bool Get(const std::string& name, std::string* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, double* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, int* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, bool* value) const override { return pnh_.getParam(name, *value); }
  bool Get(const std::string& name, std::vector<std::string>* value) const override;

 private:
  const ros::NodeHandle& pnh_;
};

// "[/a/image_raw, '/b/image_raw']" as its items; quotes, brackets and blanks dropped.
std::vector<std::string> ParseListText(const std::string& text);

class RotationAveragingNode {
 public:
  // Throws std::invalid_argument, naming the parameter, when a parameter is
  // out of its range or not one of its choices.
  RotationAveragingNode(ros::NodeHandle& nh, ros::NodeHandle& pnh);
  ~RotationAveragingNode();

 private:
  void SetUpImages(const ros::NodeHandle& node);
  void SetUpServices(ros::NodeHandle& nh, ros::NodeHandle& pnh);
  void SetUpReconfigure();
  void LoadMaps();
  void OnImage(const sensor_msgs::ImageConstPtr& image, const sensor_msgs::CameraInfoConstPtr& info, bool rectified);
  void OnCompressedImage(const std::string& topic, const sensor_msgs::CompressedImageConstPtr& image, bool rectified);
  // Keyframe selection, on the image callbacks' thread in arrival order
  // (the same decisions as the replay's for the same images): an image that
  // is not a keyframe costs its decoding and one tracking check.
  void Select(const PendingKeyframe& image);
  // Queues a decoded keyframe for the front-end worker. The queue is bounded:
  // with images faster than the front end, the excess is dropped and counted
  // instead of the node falling ever further behind.
  void Enqueue(PendingKeyframe keyframe);
  void ImageWorker();
  // The focal-length check's verdicts (focal_calibration: warn), as they
  // change: a camera_info whose focal length the images contradict is
  // a warning, since every rotation of that camera is off by a part of it.
  void LogFocalNotices();
  // Applies a dynamic_reconfigure update that validates; one that does not
  // (an unknown name, a value out of range) is refused as a whole with a
  // warning saying why, and the server is set back to the options in use.
  void OnReconfigure(RotationAveragingConfig& config);
  void Accept(const RelativePose& msg);
  void OnRelativePose(const RelativePose::ConstPtr& msg) { Accept(*msg); }
  void OnRelativePoseArray(const RelativePoseArray::ConstPtr& msg);
  bool OnSolve(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res);
  bool OnReset(std_srvs::Trigger::Request&, std_srvs::Trigger::Response& res);
  bool OnSave(SaveGraph::Request& req, SaveGraph::Response& res);
  bool OnLoad(LoadGraph::Request& req, LoadGraph::Response& res);
  bool OnAddMap(LoadGraph::Request& req, LoadGraph::Response& res);
  // Called from the averager's worker thread after each successful solve.
  void Publish(const OnlineSolution& solution);
  // Starts the background refinement of `solution` when it is due, or
  // `now` (unless one runs).
  void Refine(const OnlineSolution& solution, bool now);
  // The input is quiet when no solution came for this long (s).
  static constexpr double kRefineWhenQuietS = 2.0;
  // Measurements dropped at the view or edge caps are counted when the worker
  // applies them to the graph; say so once per burst, with the caps' names.
  void WarnAboutCaps();
  void Diagnose(diagnostic_updater::DiagnosticStatusWrapper& status);
  NodeStatus Snapshot();

  ros::NodeHandle pnh_;
  std::unique_ptr<KeyframePipeline> pipeline_;
  OnlineAverager* averager_ = nullptr;  // owned by pipeline_
  TfMode tf_mode_ = TfMode::kAllKeyframes;
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
  ros::WallTimer refine_timer_;  // refines the latest solution once the input is quiet
  std::atomic<std::uint64_t> refined_sequence_{0};  // the solution the last refinement started from
  std::atomic<double> last_solution_wall_s_{0.0};
  std::mutex publish_mutex_;  // Publish, from the averager's thread and the refinement's
  std::mutex mutex_;  // camera_infos_, the counters and times below
  std::uint64_t dropped_images_ = 0, images_without_info_ = 0;
  ros::WallTime last_rates_time_;  // diagnostics: input rates between updates
  std::uint64_t last_received_ = 0, last_images_ = 0;
  std::unique_ptr<image_transport::ImageTransport> image_transport_;
  std::vector<image_transport::CameraSubscriber> camera_subs_;
  std::vector<ros::Subscriber> compressed_subs_, info_subs_;
  std::map<std::string, sensor_msgs::CameraInfoConstPtr> camera_infos_;  // by image topic (compressed mode)
  RecentTimes latency_, frontend_time_;  // of the last 50 keyframes, under mutex_
  struct QueuedKeyframe {
    PendingKeyframe keyframe;
    ros::WallTime received;
  };
  // Image callbacks run on their own spinner and queue; a member declared
  // after the subscribers, so destroyed before them: the destructor stops
  // the spinner and unsubscribes first.
  ros::CallbackQueue image_callbacks_;
  std::unique_ptr<ros::AsyncSpinner> image_spinner_;
  std::mutex image_mutex_;  // image_queue_, images_running_, refinement_landed_
  std::condition_variable image_wake_;
  std::deque<QueuedKeyframe> image_queue_;
  std::size_t max_image_queue_ = 8;
  std::uint64_t frames_missing_warned_ = 0;  // the image callback's thread only
  std::uint64_t cap_drops_warned_ = 0;  // the averager's worker thread only
  bool images_running_ = false;
  // A refinement landed: its focal estimates are acted on (and its notices
  // logged) by the image thread, at once if no image waits.
  bool refinement_landed_ = false;
  std::thread image_worker_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_NODE_H_
