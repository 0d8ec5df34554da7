// The one conversion per message type between ROS messages and the core
// library (the only place that knows both). See msg/*.msg for conventions.
#ifndef ROTATION_AVERAGING_ROS_MSG_CONVERSION_H_
#define ROTATION_AVERAGING_ROS_MSG_CONVERSION_H_

#include <ros/time.h>

#include <string>

#include "rotation_averaging/KeyframeOrientation.h"
#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

std::int64_t ToNanoseconds(const ros::Time& t);
// Clamped to what a ros::Time holds (0 .. 2^32 s): never throws.
ros::Time FromNanoseconds(std::int64_t ns);
// nsec < 1e9: input stamps that are not are rejected (their nanoseconds may
// not fit a ros::Time again).
bool IsNormalizedStamp(const ros::Time& t);

// Fails (with `error`) on an empty frame id, a zero stamp, a non-finite or non-unit
// quaternion (|q| off by more than 1e-3), a non-finite or asymmetric
// covariance, or an unknown source. An all-zero covariance means "unknown".
bool FromMsg(const RelativePose& msg, KeyframeRelativeRotation* out, std::string* error);
RelativePose ToMsg(const KeyframeRelativeRotation& in);

// world-to-camera R -> camera-to-world quaternion in the message; with a
// covariance (left perturbation of R, see OnlineSolution::covariance), the
// message's has_covariance and covariance are set.
KeyframeOrientation ToMsg(const KeyframeKey& key, const Eigen::Matrix3d& world_to_camera, int component,
                          const Eigen::Matrix3d* covariance = nullptr);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_MSG_CONVERSION_H_
