// A camera dataset in EuRoC's ASL layout (the format of the EuRoC MAV and
// TUM-VI datasets and of Kalibr's bag-to-folder tools): mav0/<cam>/sensor.yaml
// (intrinsics, distortion, T_BS), mav0/<cam>/data.csv ("#timestamp [ns],
// filename") and mav0/<cam>/data/<file>.
#ifndef ROTATION_AVERAGING_FRONTEND_IO_EUROC_DATASET_H_
#define ROTATION_AVERAGING_FRONTEND_IO_EUROC_DATASET_H_

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging {

struct EurocCamera {
  std::string name;  // the folder: cam0, cam1, ...
  CameraIntrinsics intrinsics;
  int width = 0, height = 0;
  // T_BS: the camera's pose in the body frame (camera-to-body).
  Eigen::Matrix3d body_from_camera = Eigen::Matrix3d::Identity();
  Eigen::Vector3d camera_in_body = Eigen::Vector3d::Zero();
  // (stamp in ns, image path), in stamp order.
  std::vector<std::pair<std::int64_t, std::string>> images;
};

// Reads every camera folder of `mav0` (a folder whose sensor.yaml says
// sensor_type: camera), in name order. An image listed in data.csv but not
// on disk is left out and counted in `missing`. False, with `error`, when
// there is no camera or a file is malformed.
bool ReadEurocCameras(const std::string& mav0, std::vector<EurocCamera>* cameras, std::size_t* missing,
                      std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_IO_EUROC_DATASET_H_
