#include "rotation_averaging/frontend/io/euroc_dataset.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>

#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

bool ReadTransform(const std::string& path, EurocCamera* camera, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    *error = path + ": " + e.what();
    return false;
  }
  const YAML::Node data = root["T_BS"] ? root["T_BS"]["data"] : YAML::Node();
  std::vector<double> t;
  if (data && data.IsSequence()) {
    for (const YAML::Node& v : data) {
      double value = 0.0;
      if (!v.IsScalar() || !ParseDouble(v.Scalar(), &value) || !std::isfinite(value)) break;
      t.push_back(value);
    }
  }
  if (t.size() != 16) {
    *error = path + ": T_BS needs 16 finite numbers (4x4, row-major)";
    return false;
  }
  Eigen::Matrix3d r;
  for (int i = 0; i < 9; ++i) r(i / 3, i % 3) = t[4 * (i / 3) + i % 3];
  // Calibrations print a rotation to about 1e-9: re-orthonormalised, and
  // refused if it is not one.
  if (!((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-4) || !(r.determinant() > 0.0)) {
    *error = path + ": T_BS's rotation is not a rotation";
    return false;
  }
  camera->body_from_camera = Eigen::Quaterniond(r).normalized().toRotationMatrix();
  camera->camera_in_body = Eigen::Vector3d(t[3], t[7], t[11]);
  return true;
}

}  // namespace

bool ReadEurocCameras(const std::string& mav0, std::vector<EurocCamera>* cameras, std::size_t* missing,
                      std::string* error) {
  cameras->clear();
  *missing = 0;
  std::error_code ec;
  if (!fs::is_directory(mav0, ec)) {
    *error = mav0 + " is not a folder";
    return false;
  }
  std::vector<std::string> folders;
  for (const auto& entry : fs::directory_iterator(mav0, ec)) {
    const fs::path sensor = entry.path() / "sensor.yaml";
    if (!entry.is_directory() || !fs::exists(sensor)) continue;
    try {
      const YAML::Node root = YAML::LoadFile(sensor.string());
      if (root["sensor_type"] && root["sensor_type"].as<std::string>("") == "camera") {
        folders.push_back(entry.path().filename().string());
      }
    } catch (const YAML::Exception& e) {
      *error = sensor.string() + ": " + e.what();
      return false;
    }
  }
  std::sort(folders.begin(), folders.end());
  if (folders.empty()) {
    *error = mav0 + " has no camera folder (a folder with a sensor.yaml of sensor_type: camera)";
    return false;
  }
  for (const std::string& name : folders) {
    EurocCamera camera;
    camera.name = name;
    const std::string dir = mav0 + "/" + name;
    if (!ReadCameraIntrinsics(dir + "/sensor.yaml", &camera.intrinsics, error, &camera.width, &camera.height) ||
        !ReadTransform(dir + "/sensor.yaml", &camera, error)) {
      return false;
    }
    LineReader reader(dir + "/data.csv");
    if (!reader.IsOpen()) {
      *error = "cannot open " + dir + "/data.csv";
      return false;
    }
    std::string line;
    while (reader.Next(&line)) {
      if (IsBlankOrComment(line)) continue;
      const std::vector<std::string> t = SplitTokens(line, /*comma=*/true);
      std::uint64_t stamp = 0;
      if (t.size() != 2 || !ParseUint64(t[0], &stamp) || stamp > static_cast<std::uint64_t>(std::numeric_limits<std::int64_t>::max())) {
        *error = reader.Where("expected 'timestamp [ns],filename'");
        return false;
      }
      const std::string path = dir + "/data/" + t[1];
      if (!fs::exists(path, ec)) {
        ++*missing;
        continue;
      }
      camera.images.emplace_back(static_cast<std::int64_t>(stamp), path);
    }
    std::sort(camera.images.begin(), camera.images.end());
    cameras->push_back(std::move(camera));
  }
  return true;
}

}  // namespace rotation_averaging
