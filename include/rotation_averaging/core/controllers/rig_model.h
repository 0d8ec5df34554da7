// Multi-camera rigs with known extrinsic rotations: rotation averaging then
// solves one orientation per rig capture, and each camera's orientation is
// derived from it. Free of ROS (the node and the replay tool feed it static
// transforms).
//
// Static transforms form a tree (parent -> child, rotation of the child frame
// in the parent). A camera frame whose chain of static transforms reaches the
// rig frame (by default the root of its tree) gets camera_from_rig = E_c.
// Keyframes of such cameras captured within `stamp_tolerance_s` of each other
// belong to one capture, keyed (rig frame, stamp of its first keyframe).
//
// With world-to-camera R_c = E_c R_rig, a camera-level measurement
// M = R_a R_b^T (covariance C of a right perturbation in b's camera frame)
// becomes R_A R_B^T = E_a^T M E_b with covariance E_b^T C E_b in B's rig
// frame. A measurement between two cameras of one capture carries no
// information once the extrinsics are known and is absorbed.
//
// A camera is resolved the first time one of its keyframes is seen: cameras
// without extrinsics then are solved on their own, even if extrinsics arrive
// later (changing them mid-run would move keyframes between variables).
#ifndef ROTATION_AVERAGING_CORE_CONTROLLERS_RIG_MODEL_H_
#define ROTATION_AVERAGING_CORE_CONTROLLERS_RIG_MODEL_H_

#include <map>
#include <mutex>
#include <set>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

struct RigModelOptions {
  bool enabled = true;
  std::string rig_frame;           // "" = the root of each camera's static transform tree
  double stamp_tolerance_s = 0.005;  // keyframes of one capture
};

class RigModel {
 public:
  // A resolved camera: in a rig (its rig frame and camera_from_rig), or
  // solved on its own.
  struct Camera {
    bool in_rig = false;
    std::string rig_frame;
    Eigen::Matrix3d camera_from_rig = Eigen::Matrix3d::Identity();
  };
  // What a rig file holds (Save), read and checked by ReadFile.
  struct Saved {
    std::map<std::string, Camera> cameras;
    std::map<std::string, std::set<std::int64_t>> capture_stamps;  // rig frame -> capture stamps
    std::map<KeyframeKey, std::vector<KeyframeKey>> members;        // capture -> camera keyframes in it
    std::map<KeyframeKey, KeyframeKey> variable_of;                 // camera keyframe -> capture
  };

  explicit RigModel(const RigModelOptions& options);

  // A static transform: `child` is rotated by `child_in_parent` (rotation
  // taking child coordinates to parent coordinates) relative to `parent`.
  void AddStaticTransform(const std::string& parent, const std::string& child, const Eigen::Matrix3d& child_in_parent);

  // Resolves the camera if it is new; true if it belongs to a rig.
  bool IsRigCamera(const std::string& camera_frame);
  // The variable of a keyframe already seen (no registration): the
  // keyframe itself if unknown or not on a rig.
  KeyframeKey VariableOfKnown(const KeyframeKey& keyframe) const;
  // Maps a camera-level measurement to the solved variables. False when it
  // is absorbed (both ends in one capture).
  bool ToVariables(const KeyframeRelativeRotation& in, KeyframeRelativeRotation* out);
  // A right perturbation d of the rotation of a camera-level measurement
  // whose second keyframe is of camera `frame2`, as the right perturbation
  // of the variable edge ToVariables makes of it (E_2^T d, as its
  // covariance moves).
  Eigen::Vector3d PerturbationToVariables(const std::string& frame2, const Eigen::Vector3d& d) const;
  // Expands a solution over variables into one over camera keyframes.
  OnlineSolution ToCameraKeyframes(const OnlineSolution& solution) const;

  std::size_t NumRigCameras() const;
  std::size_t NumAbsorbed() const;
  // Rig cameras and their camera_from_rig rotations (for logs).
  std::map<std::string, std::pair<std::string, Eigen::Matrix3d>> RigCameras() const;
  void Clear();  // forgets captures (after a graph reset); extrinsics stay

  // The resolved cameras (rig frame and camera_from_rig of each, or that it
  // is solved on its own) and every capture's camera keyframes, as a text
  // file with a checksum (written atomically): what a restart needs to put
  // a saved graph's captures back into camera keyframes, and to map new
  // measurements to the same captures, before any static transform arrives.
  bool Save(const std::string& path, std::string* error) const;
  // Reads a rig file; a malformed or corrupted file is refused with the
  // reason.
  static bool ReadFile(const std::string& path, Saved* saved, std::string* error);
  // Replaces the captures, and the cameras the file names, with the file's.
  void Replace(Saved saved);
  // Adds the file's captures to those held (another session's or robot's
  // map); a capture already held, and a camera already resolved, are kept
  // as they are.
  void Merge(Saved saved);
  // ReadFile, then Replace or Merge; a refused file changes nothing.
  bool Load(const std::string& path, std::string* error);
  bool Add(const std::string& path, std::string* error);
  std::size_t NumCaptures() const;

 private:
  bool ResolveLocked(const std::string& camera_frame);
  // camera_from_rig of a resolved rig camera; the identity otherwise.
  Eigen::Matrix3d CameraFromRigLocked(const std::string& camera_frame) const;
  KeyframeKey VariableLocked(const KeyframeKey& keyframe);

  RigModelOptions options_;
  mutable std::mutex mutex_;
  std::map<std::string, std::pair<std::string, Eigen::Matrix3d>> parent_of_;  // child -> (parent, child_in_parent)
  std::map<std::string, Camera> cameras_;  // resolved cameras
  std::map<std::string, std::set<std::int64_t>> capture_stamps_;  // rig frame -> capture stamps
  std::map<KeyframeKey, std::vector<KeyframeKey>> members_;        // capture -> camera keyframes in it
  std::map<KeyframeKey, KeyframeKey> variable_of_;                 // camera keyframe -> capture
  std::size_t absorbed_ = 0;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_CONTROLLERS_RIG_MODEL_H_
