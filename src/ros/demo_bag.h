// Internal to the package: may change between versions.
// Writes a rendered rig scene (src/frontend/scene/rig_scene.h) as a bag: per camera
// /<cam>/image_raw (mono8, or /<cam>/image_raw/compressed PNG) and
// /<cam>/camera_info at every capture, the extrinsics base_link -> cam_* on
// /tf_static (half a second before the first capture), and the ground truth
// as one rotation_averaging/Orientations message on /ground_truth/orientations.
// Captures start at bag time 1000 s.
#ifndef ROTATION_AVERAGING_SRC_ROS_DEMO_BAG_H_
#define ROTATION_AVERAGING_SRC_ROS_DEMO_BAG_H_

#include <rosbag/bag.h>

#include <opencv2/core.hpp>
#include <string>

#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "frontend/scene/rig_scene.h"

namespace rotation_averaging {

// One keyframe image of `frame` as the node reads it: /<frame>/camera_info
// (K, no distortion) and /<frame>/image_raw (mono8) or, compressed,
// /<frame>/image_raw/compressed (PNG).
void WriteKeyframeImage(rosbag::Bag* bag, const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                        const Eigen::Matrix3d& k, bool compressed);

// `ground_truth` (optional) receives the world-to-camera orientations keyed
// by keyframe name (<frame_id>@<stamp_ns>).
bool WriteRigSceneBag(const RigScene& scene, const std::string& path, bool compressed, NamedOrientations* ground_truth,
                      std::string* error, bool progress = false);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_ROS_DEMO_BAG_H_
