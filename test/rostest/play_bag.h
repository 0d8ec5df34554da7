// Shared by the rostests that play a bag into a live node: rosbag play in
// real time with the bag's clock (the launch file sets use_sim_time), then
// the node's ~orientations once they have settled.
#ifndef ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_
#define ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_

#include <gtest/gtest.h>
#include <ros/ros.h>

#include <cstdlib>
#include <mutex>
#include <string>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "ros/msg_conversion.h"

namespace rotation_averaging {

// Plays `bag` into the node `node` and returns its orientations (world to
// camera, by keyframe name) once a solution holds at least `keyframes` of
// them and no new solve came for three seconds (the node has the last images
// queued or in its front end when the bag ends), or after 90 s.
inline NamedOrientations PlayIntoNode(const std::string& node, const std::string& bag, std::size_t keyframes) {
  ros::NodeHandle nh;
  std::mutex mutex;
  Orientations::ConstPtr latest;
  ros::Subscriber sub = nh.subscribe<Orientations>("/" + node + "/orientations", 10,
                                                   [&](const Orientations::ConstPtr& m) {
                                                     std::lock_guard<std::mutex> lock(mutex);
                                                     latest = m;
                                                   });
  EXPECT_TRUE(ros::service::waitForService("/" + node + "/solve", ros::Duration(30.0)));
  const std::string play = "PATH=/usr/bin:$PATH rosbag play --clock --quiet --delay=1 " + bag + " > /dev/null 2>&1";
  EXPECT_EQ(std::system(play.c_str()), 0) << play;
  std::uint64_t last_sequence = 0;
  ros::WallTime settled_since = ros::WallTime::now();
  const ros::WallTime deadline = ros::WallTime::now() + ros::WallDuration(90.0);
  while (ros::WallTime::now() < deadline) {
    ros::WallDuration(0.2).sleep();
    std::lock_guard<std::mutex> lock(mutex);
    if (!latest || latest->keyframes.size() < keyframes) continue;
    if (latest->solve_sequence != last_sequence) {
      last_sequence = latest->solve_sequence;
      settled_since = ros::WallTime::now();
      continue;
    }
    if ((ros::WallTime::now() - settled_since).toSec() > 3.0) break;
  }
  NamedOrientations live;
  std::lock_guard<std::mutex> lock(mutex);
  if (!latest) return live;
  for (const KeyframeOrientation& k : latest->keyframes) {
    live[OnlineAverager::KeyframeName({k.frame_id, ToNanoseconds(k.stamp)})] =
        QuaternionToRotation(k.orientation.w, k.orientation.x, k.orientation.y, k.orientation.z).transpose();
  }
  return live;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_ROSTEST_PLAY_BAG_H_
