// A synthetic multi-camera rig moving through a textured room, rendered by
// ray casting: the project's own demo and test data with exact ground truth.
//
// World frame: z up, the room spans [-half_extent, half_extent]^2 x [0, height]
// with a textured pillar in the middle and two crates near the walls. The rig
// (body frame x forward, y left, z up) drives once around a circle about the
// room's centre (or `laps` times), heading along the path with a small pitch
// and roll wobble, and ends where it started, so a front end can close the loop. Each camera
// (optical frame: z forward, x right, y down) looks along one rig axis:
// front, left, back, right.
#ifndef ROTATION_AVERAGING_SIM_RIG_SCENE_H_
#define ROTATION_AVERAGING_SIM_RIG_SCENE_H_

#include <Eigen/Core>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace rotation_averaging {

struct RigSceneOptions {
  int num_captures = 60;          // keyframe captures along the loop
  double capture_period_s = 1.0;  // time between captures
  int num_cameras = 2;            // 1-4: front, left, back, right
  int width = 640, height = 480;  // pixels
  double focal_px = 420.0;        // pinhole focal length, principal point at the image centre
  double path_radius_m = 1.8;
  // Times the rig drives round the circle over all captures; each lap after
  // the first runs `lap_radius_step_m` farther out, so later laps pass the
  // same places from slightly different positions.
  int laps = 1;
  double lap_radius_step_m = 0.1;
  double camera_height_m = 1.4;
  double wobble_deg = 4.0;        // amplitude of the pitch and roll wobble
  double noise_grey = 2.0;        // standard deviation of the image noise, grey levels
  double half_extent_m = 4.0;     // room half width
  double room_height_m = 3.0;
  std::uint64_t seed = 1;         // textures and noise
  // Another session in the same room: where on the loop the first capture is
  // (degrees counter-clockwise), when it is taken (the bag's stamps follow),
  // its lighting (a gain, and a brightness that changes across the room by
  // `light_gradient` of it from one wall to the opposite one, as a lamp on
  // one side gives), and its image noise (0: from `seed`).
  double start_angle_deg = 0.0;
  double start_time_s = 0.0;
  double light_gain = 1.0;
  double light_gradient = 0.0;
  std::uint64_t noise_seed = 0;

  // The same field of view at another image width (4:3, focal scaled).
  RigSceneOptions& WithWidth(int w) {
    focal_px *= static_cast<double>(w) / width;
    height = w * 3 / 4;
    width = w;
    return *this;
  }
};

struct RigCamera {
  std::string frame_id;                // e.g. "cam_front"
  Eigen::Matrix3d camera_from_rig;     // rotation taking rig coordinates to camera coordinates
  Eigen::Vector3d position_in_rig;     // metres
};

class RigScene {
 public:
  explicit RigScene(const RigSceneOptions& options);
  ~RigScene();
  RigScene(const RigScene&) = delete;
  RigScene& operator=(const RigScene&) = delete;

  const RigSceneOptions& Options() const { return options_; }
  const std::vector<RigCamera>& Cameras() const { return cameras_; }
  Eigen::Matrix3d Intrinsics() const;
  double CaptureTime(int capture) const { return options_.start_time_s + capture * options_.capture_period_s; }
  // World-to-rig rotation and rig position (world frame) at a capture.
  Eigen::Matrix3d WorldToRig(int capture) const;
  Eigen::Vector3d RigPosition(int capture) const;
  // World-to-camera rotation of a camera at a capture (the ground truth).
  Eigen::Matrix3d WorldToCamera(int capture, int camera) const;
  // 8-bit grey image of a camera at a capture, with noise (deterministic
  // for a given seed, capture and camera). With a margin, the image extends
  // that many pixels beyond the camera's on every side (the same focal
  // length and optical axis: its K is Intrinsics() with the principal point
  // moved by the margin), so that a lens with a wider field of view can be
  // simulated from it (DistortImage).
  cv::Mat Render(int capture, int camera, int margin_px = 0) const;
  // Position (world frame) of a camera at a capture.
  Eigen::Vector3d CameraCentre(int capture, int camera) const;
  // The room seen by any pinhole camera with the scene's intrinsics, from
  // `centre` (world frame), with noise drawn from `noise_seed`.
  cv::Mat RenderView(const Eigen::Matrix3d& world_to_camera, const Eigen::Vector3d& centre,
                     std::uint64_t noise_seed, int margin_px = 0) const;

 private:
  struct Surface;
  double Phase(int capture) const;  // angle along the circle, radians (grows by 2 pi per lap)
  RigSceneOptions options_;
  std::vector<RigCamera> cameras_;
  std::vector<Surface> surfaces_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SIM_RIG_SCENE_H_
