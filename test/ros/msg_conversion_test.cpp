#include "rotation_averaging/ros/msg_conversion.h"

#include <gtest/gtest.h>

#include <limits>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

TEST(MsgConversion, RelativePoseRoundTrip) {
  KeyframeRelativeRotation in;
  in.keyframe1 = {"cam_left", 1'700'000'000'123'456'789LL};
  in.keyframe2 = {"cam_right", 1'700'000'000'223'456'789LL};
  in.rotation = ExpSO3(Eigen::Vector3d(0.1, -0.3, 0.2));
  in.has_covariance = true;
  in.covariance << 4e-6, 1e-7, 0, 1e-7, 2e-6, 0, 0, 0, 9e-6;
  in.num_inliers = 321;
  in.source = EdgeSource::kLoopClosure;
  KeyframeRelativeRotation out;
  std::string error;
  ASSERT_TRUE(FromMsg(ToMsg(in), &out, &error)) << error;
  EXPECT_EQ(out.keyframe1.stamp_ns, in.keyframe1.stamp_ns);
  EXPECT_EQ(out.keyframe2.frame_id, "cam_right");
  EXPECT_LT((out.rotation - in.rotation).norm(), 1e-12);
  EXPECT_TRUE(out.has_covariance);
  EXPECT_EQ(out.covariance, in.covariance);
  EXPECT_EQ(out.num_inliers, 321);
  EXPECT_EQ(out.source, EdgeSource::kLoopClosure);
  // No covariance: all zeros in the message.
  in.has_covariance = false;
  ASSERT_TRUE(FromMsg(ToMsg(in), &out, &error));
  EXPECT_FALSE(out.has_covariance);
}

TEST(MsgConversion, RejectsMalformedMessages) {
  KeyframeRelativeRotation in;
  in.keyframe1 = {"a", 1};
  in.keyframe2 = {"b", 2};
  RelativePose good = ToMsg(in);
  KeyframeRelativeRotation out;
  std::string error;
  RelativePose m = good;
  m.rotation.w = 0.5;  // not unit
  EXPECT_FALSE(FromMsg(m, &out, &error));
  EXPECT_NE(error.find("not unit"), std::string::npos);
  m = good;
  m.rotation.x = std::numeric_limits<double>::quiet_NaN();
  EXPECT_FALSE(FromMsg(m, &out, &error));
  m = good;
  m.rotation_covariance[4] = std::numeric_limits<double>::infinity();
  EXPECT_FALSE(FromMsg(m, &out, &error));
  m = good;
  m.frame_id_2.clear();
  EXPECT_FALSE(FromMsg(m, &out, &error));
  m = good;
  m.source = 9;
  EXPECT_FALSE(FromMsg(m, &out, &error));
  // A stamp with nsec >= 1e9 at the end of the 32-bit range: its nanoseconds
  // do not fit a ros::Time again (found by fuzz_messages: the output threw).
  m = good;
  m.stamp_2.sec = 0xffffffffu;
  m.stamp_2.nsec = 1500000000u;
  EXPECT_FALSE(FromMsg(m, &out, &error));
  EXPECT_NE(error.find("not normalised"), std::string::npos);
}

TEST(MsgConversion, NanosecondsOutsideRosTimeAreClampedNotThrown) {
  EXPECT_NO_THROW(FromNanoseconds(std::numeric_limits<std::int64_t>::max()));
  EXPECT_EQ(FromNanoseconds(std::numeric_limits<std::int64_t>::max()).sec, 0xffffffffu);
  EXPECT_EQ(FromNanoseconds(-5).toNSec(), 0u);
  EXPECT_EQ(FromNanoseconds(1234567890123LL).toNSec(), 1234567890123u);
  KeyframeKey key{"cam", std::numeric_limits<std::int64_t>::max()};
  EXPECT_NO_THROW(ToMsg(key, Eigen::Matrix3d::Identity(), 0, nullptr));
}

TEST(MsgConversion, OrientationIsCameraToWorld) {
  const Eigen::Matrix3d world_to_camera = ExpSO3(Eigen::Vector3d(0.0, 0.0, 0.5));
  const KeyframeOrientation msg = ToMsg(KeyframeKey{"cam", 5}, world_to_camera, 2);
  const Eigen::Matrix3d camera_to_world =
      QuaternionToRotation(msg.orientation.w, msg.orientation.x, msg.orientation.y, msg.orientation.z);
  EXPECT_LT((camera_to_world - world_to_camera.transpose()).norm(), 1e-12);
  EXPECT_EQ(msg.component, 2u);
  EXPECT_EQ(msg.stamp.toNSec(), 5u);
}

}  // namespace
}  // namespace rotation_averaging
