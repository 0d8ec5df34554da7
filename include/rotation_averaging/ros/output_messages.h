// The node's outputs built from a solution: ~orientations, the keyframes'
// and cameras' transforms for tf, rviz markers and ~camera_info_checks. The
// node publishes them and the replay writes them to its bag; neither builds
// a message itself.
#ifndef ROTATION_AVERAGING_ROS_OUTPUT_MESSAGES_H_
#define ROTATION_AVERAGING_ROS_OUTPUT_MESSAGES_H_

#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include <map>
#include <mutex>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/frontend/controllers/focal_monitor.h"
#include "rotation_averaging/ros/pipeline_config.h"
#include "rotation_averaging/CameraInfoCheckArray.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

// "{frame_id}" and "{stamp_ns}" in a frame name pattern.
std::string KeyframeFrameName(const std::string& format, const KeyframeKey& key);

// Each camera's latest focal-length check (~camera_info_checks), with the
// correction applied to it (by camera; 1 where none is listed).
CameraInfoCheckArray CameraInfoCheckMsg(const std::map<std::string, CameraFocalCheck>& checks,
                                        const std::map<std::string, double>& corrections, const ros::Time& stamp);

// The messages of solutions expanded to one orientation per camera keyframe
// (RigModel::ToCameraKeyframes), under the frames and formats of the config.
class OutputMessages {
 public:
  explicit OutputMessages(const PipelineConfig& config);

  Orientations OrientationsMsg(const OnlineSolution& cameras, const ros::Time& stamp) const;
  // all_keyframes: one transform per keyframe, stamped with its capture time.
  tf2_msgs::TFMessage KeyframeTransforms(const OnlineSolution& cameras) const;
  // rviz: camera frusta by solved orientation (namespace "keyframes") and the
  // edges coloured by their robust weight (namespace "edges": green = full
  // weight, red = rejected as an outlier). Lanes and edges come from the
  // averager's `variables`, frusta from their expansion `cameras`, placed at
  // their variable (`rig`).
  visualization_msgs::MarkerArray Markers(const OnlineSolution& variables, const OnlineSolution& cameras,
                                          const RigModel& rig, const ros::Time& stamp) const;
  // latest_per_camera: the newest keyframe of each camera, stamped `now`;
  // a frame whose last transform had a stamp >= now is left out (tf refuses
  // a stamp twice).
  std::vector<geometry_msgs::TransformStamped> LatestTransforms(const OnlineSolution& cameras, const ros::Time& now);
  void ForgetLatestStamps();  // after a reset

 private:
  geometry_msgs::TransformStamped Transform(const ros::Time& stamp, const std::string& child,
                                            const geometry_msgs::Quaternion& camera_to_world) const;

  std::string fixed_frame_, keyframe_frame_format_, latest_frame_format_;
  double marker_spacing_m_;
  int marker_max_keyframes_;
  std::mutex mutex_;  // last_latest_stamp_
  std::map<std::string, ros::Time> last_latest_stamp_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_OUTPUT_MESSAGES_H_
