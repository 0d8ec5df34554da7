#include "rotation_averaging/ros/msg_conversion.h"

#include <algorithm>
#include <cmath>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

std::int64_t ToNanoseconds(const ros::Time& t) { return static_cast<std::int64_t>(t.toNSec()); }

bool IsNormalizedStamp(const ros::Time& t) { return t.nsec < 1000000000u; }

ros::Time FromNanoseconds(std::int64_t ns) {
  // ros::Time holds 32-bit seconds; fromNSec throws beyond them. Input
  // stamps are checked (IsNormalizedStamp), so this clamp only guards.
  constexpr std::int64_t kMax = static_cast<std::int64_t>(0xffffffffLL) * 1000000000LL + 999999999LL;
  ros::Time t;
  t.fromNSec(static_cast<std::uint64_t>(std::clamp<std::int64_t>(ns, 0, kMax)));
  return t;
}

bool FromMsg(const RelativePose& msg, KeyframeRelativeRotation* out, std::string* error) {
  auto fail = [error](const std::string& why) {
    if (error) *error = why;
    return false;
  };
  if (msg.frame_id_1.empty() || msg.frame_id_2.empty()) return fail("empty camera frame id");
  // A zero stamp is an uninitialised header, not a capture time.
  if (msg.stamp_1.isZero() || msg.stamp_2.isZero()) return fail("keyframe stamp is zero (uninitialised header?)");
  // A deserialised stamp may carry nsec >= 1e9; its nanoseconds would not
  // round-trip into a ros::Time (fuzz_messages found that crash on output).
  if (!IsNormalizedStamp(msg.stamp_1) || !IsNormalizedStamp(msg.stamp_2)) {
    return fail("keyframe stamp has nsec >= 1e9 (not normalised)");
  }
  const auto& q = msg.rotation;
  const double norm = std::sqrt(q.w * q.w + q.x * q.x + q.y * q.y + q.z * q.z);
  if (!std::isfinite(norm)) return fail("rotation quaternion is not finite");
  if (std::abs(norm - 1.0) > 1e-3) return fail("rotation quaternion is not unit (norm " + std::to_string(norm) + ")");
  if (msg.source > RelativePose::SOURCE_OTHER) return fail("unknown source " + std::to_string(msg.source));
  out->keyframe1 = {msg.frame_id_1, ToNanoseconds(msg.stamp_1)};
  out->keyframe2 = {msg.frame_id_2, ToNanoseconds(msg.stamp_2)};
  out->rotation = QuaternionToRotation(q.w, q.x, q.y, q.z);
  bool all_zero = true;
  for (int k = 0; k < 9; ++k) {
    if (!std::isfinite(msg.rotation_covariance[k])) return fail("rotation covariance is not finite");
    out->covariance(k / 3, k % 3) = msg.rotation_covariance[k];
    all_zero = all_zero && msg.rotation_covariance[k] == 0.0;
  }
  out->has_covariance = !all_zero;
  out->num_inliers = static_cast<int>(std::min<std::uint32_t>(msg.num_inliers, 1u << 30));
  out->source = static_cast<EdgeSource>(msg.source);
  return true;
}

RelativePose ToMsg(const KeyframeRelativeRotation& in) {
  RelativePose msg;
  msg.frame_id_1 = in.keyframe1.frame_id;
  msg.stamp_1 = FromNanoseconds(in.keyframe1.stamp_ns);
  msg.frame_id_2 = in.keyframe2.frame_id;
  msg.stamp_2 = FromNanoseconds(in.keyframe2.stamp_ns);
  const Eigen::Vector4d q = RotationToQuaternion(in.rotation);
  msg.rotation.w = q[0];
  msg.rotation.x = q[1];
  msg.rotation.y = q[2];
  msg.rotation.z = q[3];
  for (int k = 0; k < 9; ++k) msg.rotation_covariance[k] = in.has_covariance ? in.covariance(k / 3, k % 3) : 0.0;
  msg.num_inliers = static_cast<std::uint32_t>(std::max(in.num_inliers, 0));
  msg.source = static_cast<std::uint8_t>(in.source);
  return msg;
}

KeyframeOrientation ToMsg(const KeyframeKey& key, const Eigen::Matrix3d& world_to_camera, int component,
                          const Eigen::Matrix3d* covariance) {
  KeyframeOrientation msg;
  msg.frame_id = key.frame_id;
  msg.stamp = FromNanoseconds(key.stamp_ns);
  const Eigen::Vector4d q = RotationToQuaternion(world_to_camera.transpose());
  msg.orientation.w = q[0];
  msg.orientation.x = q[1];
  msg.orientation.y = q[2];
  msg.orientation.z = q[3];
  msg.component = static_cast<std::uint32_t>(std::max(component, 0));
  msg.has_covariance = covariance != nullptr && covariance->allFinite();
  for (int k = 0; k < 9; ++k) msg.covariance[k] = msg.has_covariance ? (*covariance)(k / 3, k % 3) : 0.0;
  return msg;
}

}  // namespace rotation_averaging
