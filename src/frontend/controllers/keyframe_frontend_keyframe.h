// Internal to the front end: the keyframe KeyframeFrontend holds, shared by
// its sources (keyframe_frontend.cpp: adding keyframes and loop closures;
// keyframe_frontend_focal.cpp: pairs held for focal calibration;
// keyframe_frontend_database.cpp: the keyframe database).
#ifndef ROTATION_AVERAGING_SRC_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_KEYFRAME_H_
#define ROTATION_AVERAGING_SRC_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_KEYFRAME_H_

#include <cstdint>
#include <memory>
#include <vector>

#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"

namespace rotation_averaging {

struct KeyframeFrontend::Keyframe {
  KeyframeKey key;
  int camera_position = 0;               // index in by_camera_[key.frame_id]
  bool has_sequential = false;           // sequential edge from the previous keyframe of its camera
  Eigen::Matrix3d sequential_rotation;   // R_prev,this
  Eigen::Matrix3d sequential_covariance;
  ImageFeatures features;              // all of them, or the compact set once out of the recent window
  std::unique_ptr<FeatureIndex> index;  // null once compact
  // Its KLT tracks (AddKeyframe's: pixels of the image as given, in
  // increasing id order), the camera they undistort with, and the image's
  // pyramid to re-track them from; none once out of the window.
  std::vector<TrackedPoint> tracks;
  CameraIntrinsics track_camera;
  std::vector<cv::Mat> track_pyramid;
  bool compact = false;
  bool bridged = false;                 // its previous pair failed and an older one of the window verified
  BowVector bow;                        // with a vocabulary
  // Per feature: inliers of the verified pairs it took part in. Features
  // seen again from other views are the ones a later revisit will match.
  std::vector<std::uint16_t> inlier_hits;
  Eigen::Matrix3d k;  // intrinsics of the (resized) image the features come from
  // The lens its keypoints were undistorted with (distortion model and
  // coefficients; `k` is the one above). None for a rectified camera and
  // for a keyframe loaded from a database.
  CameraIntrinsics lens;
  int loaded_chain = -1;  // index into loaded_chains_; -1: a keyframe of this session
  // Loaded, of the chain a new session continues (LoadDatabase): the camera
  // may have moved while no keyframe was made, so a pair with a new keyframe
  // needs a loop closure's evidence.
  bool resumed = false;
};

// A pair's inliers in normalised coordinates (pa's pixels of intrinsics k1,
// pb's of k2), with its translation and pixel noise: what the refinement
// holds of it (KeyframeFrontendOptions::keep_correspondences). The
// rotation-only model's zero translation: its matches join the
// refinement's tracks but give no baseline.
EdgeCorrespondences InlierCorrespondences(const std::vector<Eigen::Vector2d>& pa, const std::vector<Eigen::Vector2d>& pb,
                                          const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                                          const RelativePoseResult& pose);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_KEYFRAME_H_
