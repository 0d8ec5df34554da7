// Bags of camera streams as drivers record them: a EuRoC-layout dataset
// (WriteEurocBag), and a rendered rig scene (sim/rig_scene.h) as a bag: per camera
// /<cam>/image_raw (mono8, or /<cam>/image_raw/compressed PNG) and
// /<cam>/camera_info at every capture, the extrinsics base_link -> cam_* on
// /tf_static (half a second before the first capture), and the ground truth
// as one rotation_averaging/Orientations message on /ground_truth/orientations.
// Captures start at bag time 1000 s.
#ifndef ROTATION_AVERAGING_SIM_DEMO_BAG_H_
#define ROTATION_AVERAGING_SIM_DEMO_BAG_H_

#include <rosbag/bag.h>

#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/frontend/io/euroc_dataset.h"
#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging {

// One keyframe image of `frame` as the node reads it: /<frame>/camera_info
// (K, and the camera's distortion model and D; plumb_bob with D all zero for
// a camera without distortion) and /<frame>/image_raw (mono8) or,
// compressed, /<frame>/image_raw/compressed (PNG).
void WriteKeyframeImage(rosbag::Bag* bag, const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                        const CameraIntrinsics& camera, bool compressed);

// How a driver reads its sensor out (REP 104): a region of it (empty: the
// whole sensor), then binned in binning x binning blocks, each the mean of
// its pixels, as a sensor's binning sums their charges.
struct SensorReadout {
  cv::Rect roi;
  int binning = 1;
  bool Whole() const { return roi.empty() && binning == 1; }
};
// The image a readout gives of a full-sensor image: the region's pixels, its
// width and height cut to whole blocks, then binned.
cv::Mat ReadOut(const cv::Mat& sensor_image, const SensorReadout& readout);
// WriteKeyframeImage for an image read out of a `sensor`-sized sensor whose
// intrinsics `camera` are: camera_info keeps the sensor's K, width and
// height and carries the readout in binning_x, binning_y and roi.
void WriteKeyframeImage(rosbag::Bag* bag, const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                        const CameraIntrinsics& camera, bool compressed, const cv::Size& sensor,
                        const SensorReadout& readout);

// How WriteRigSceneBag writes the camera streams.
struct RigSceneBagOptions {
  bool progress = false;  // a line on stderr per capture
  // With a distortion (its K is ignored: the scene's), every image is what
  // that lens would have seen (DistortImage, from a render of the wider
  // field it sees: no black border) and camera_info carries the model: a
  // raw camera stream.
  CameraIntrinsics lens;
  // The lens's images undistorted again (UndistortImage, as image_proc's
  // image_rect), camera_info without distortion: the same content through
  // both resamplings, for comparing the model with rectification.
  bool rectify = false;
  // camera_info without the lens's distortion, the images distorted: a
  // driver whose calibration describes no lens (a lens the user never
  // calibrated).
  bool info_no_lens = false;
  // camera_info's focal lengths are the scene's times this: a calibration
  // that is a little off.
  double info_focal_scale = 1.0;
  // Not empty: one such factor per camera (in the scene's order), in place
  // of info_focal_scale: a rig whose cameras' calibrations are off by
  // different amounts.
  std::vector<double> info_focal_scales;
  // camera_info's principal point this far (sensor pixels, x and y) from
  // the scene's.
  double info_principal_offset_x = 0.0, info_principal_offset_y = 0.0;
  // Not whole: each camera's images are read out of the rendered sensor
  // (its width x height, the scene's K) by a region of interest and
  // binning, and camera_info says so, as a driver with those settings
  // publishes them.
  SensorReadout readout;
  // Not empty: the same images also as a folder for `rotavg images`:
  // <dir>/<keyframe name>.png (mono8, <frame_id>@<stamp_ns> as in the bag),
  // <dir>/K.txt (the scene's K) and <dir>/ground_truth.csv (world-to-camera
  // orientations keyed by the image files' names). Ideal pinhole images
  // only: refused with a lens, a focal scale other than 1 or a readout of
  // part of the sensor.
  std::string images_dir;
};

// `ground_truth` (optional) receives the world-to-camera orientations keyed
// by keyframe name (<frame_id>@<stamp_ns>).
bool WriteRigSceneBag(const RigScene& scene, const std::string& path, bool compressed, NamedOrientations* ground_truth,
                      std::string* error, const RigSceneBagOptions& options = RigSceneBagOptions());

// The cameras of a EuRoC-layout dataset (frontend/io/euroc_dataset.h) as
// their driver publishes them: /<cam>/image_raw (mono8, or PNG on
// /<cam>/image_raw/compressed) with /<cam>/camera_info (frame <cam>, the
// distortion model and D of sensor.yaml; P = [K 0]) at the dataset's stamps,
// and the extrinsics body -> <cam> from T_BS on /tf_static before the first
// image. With `rectify` the images are rectified and camera_info carries no
// distortion. Returns the images written.
std::size_t WriteEurocBag(const std::vector<EurocCamera>& cameras, const std::string& path, bool compressed,
                          bool rectify, std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SIM_DEMO_BAG_H_
