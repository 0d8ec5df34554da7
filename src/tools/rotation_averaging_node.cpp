// rotation_averaging_node: live covariance-weighted robust rotation averaging
// (rotation_averaging/ros/node.h; config/rotation_averaging.yaml lists every parameter).
#include <ros/ros.h>

#include <memory>
#include <stdexcept>

#include "rotation_averaging/ros/node.h"
#include "rotation_averaging/util/freed_memory.h"

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
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
