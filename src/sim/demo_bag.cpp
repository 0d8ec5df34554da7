#include "rotation_averaging/sim/demo_bag.h"

#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <tuple>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

geometry_msgs::Quaternion ToQuaternion(const Eigen::Matrix3d& r) {
  const Eigen::Vector4d q = RotationToQuaternion(r);
  geometry_msgs::Quaternion m;
  m.w = q[0];
  m.x = q[1];
  m.y = q[2];
  m.z = q[3];
  return m;
}

// parent -> child: the child frame's orientation and position in the parent.
geometry_msgs::TransformStamped StaticTransform(const ros::Time& stamp, const std::string& parent,
                                                const std::string& child, const Eigen::Matrix3d& parent_from_child,
                                                const Eigen::Vector3d& child_in_parent) {
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = parent;
  t.child_frame_id = child;
  t.transform.translation.x = child_in_parent.x();
  t.transform.translation.y = child_in_parent.y();
  t.transform.translation.z = child_in_parent.z();
  t.transform.rotation = ToQuaternion(parent_from_child);
  return t;
}

}  // namespace

cv::Mat ReadOut(const cv::Mat& sensor_image, const SensorReadout& readout) {
  cv::Mat region = readout.roi.empty() ? sensor_image : sensor_image(readout.roi);
  const int b = std::max(1, readout.binning);
  if (b == 1) return region.clone();
  region = region(cv::Rect(0, 0, region.cols / b * b, region.rows / b * b));
  // INTER_AREA at a whole factor is the mean of each block.
  cv::Mat binned;
  cv::resize(region, binned, cv::Size(region.cols / b, region.rows / b), 0, 0, cv::INTER_AREA);
  return binned;
}

void WriteKeyframeImage(rosbag::Bag* bag, const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                        const CameraIntrinsics& camera, bool compressed) {
  WriteKeyframeImage(bag, frame, stamp, grey, camera, compressed, grey.size(), SensorReadout());
}

void WriteKeyframeImage(rosbag::Bag* bag, const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                        const CameraIntrinsics& camera, bool compressed, const cv::Size& sensor,
                        const SensorReadout& readout) {
  const Eigen::Matrix3d& k = camera.k;
  sensor_msgs::CameraInfo info;
  info.header.stamp = stamp;
  info.header.frame_id = frame;
  info.width = sensor.width;
  info.height = sensor.height;
  info.binning_x = info.binning_y = static_cast<std::uint32_t>(std::max(1, readout.binning));
  if (!readout.roi.empty()) {
    info.roi.x_offset = readout.roi.x;
    info.roi.y_offset = readout.roi.y;
    info.roi.width = readout.roi.width;
    info.roi.height = readout.roi.height;
  }
  if (camera.distortion == DistortionModel::kNone) {
    info.distortion_model = "plumb_bob";
    info.D.assign(5, 0.0);
  } else {
    info.distortion_model = DistortionModelName(camera.distortion);
    info.D = camera.coefficients;
  }
  for (int i = 0; i < 9; ++i) info.K[i] = k(i / 3, i % 3);
  info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
  info.P = {k(0, 0), k(0, 1), k(0, 2), 0, 0, k(1, 1), k(1, 2), 0, 0, 0, 1, 0};
  bag->write("/" + frame + "/camera_info", stamp, info);
  if (compressed) {
    sensor_msgs::CompressedImage m;
    m.header = info.header;
    m.format = "mono8; png compressed";
    cv::imencode(".png", grey, m.data);
    bag->write("/" + frame + "/image_raw/compressed", stamp, m);
    return;
  }
  sensor_msgs::Image m;
  m.header = info.header;
  m.width = grey.cols;
  m.height = grey.rows;
  m.encoding = "mono8";
  m.step = grey.cols;
  const cv::Mat packed = grey.isContinuous() ? grey : grey.clone();
  m.data.assign(packed.data, packed.data + packed.total());
  bag->write("/" + frame + "/image_raw", stamp, m);
}

namespace {

// What camera_info says of each camera of `scene` (`info_off`: other than
// the scene's camera): the lens, unless the images are rectified or
// info_no_lens leaves it out, and the focal lengths and principal point as
// bag_options puts them off.
bool CameraInfos(const RigScene& scene, const CameraIntrinsics& camera, const RigSceneBagOptions& bag_options,
                 std::vector<CameraIntrinsics>* infos, bool* info_off, std::string* error) {
  CameraIntrinsics info = camera;
  if (bag_options.rectify || bag_options.info_no_lens) {
    info.distortion = DistortionModel::kNone;
    info.coefficients.clear();
  }
  const std::size_t num_cameras = scene.Cameras().size();
  std::vector<double> focal_scales(num_cameras, bag_options.info_focal_scale);
  if (!bag_options.info_focal_scales.empty()) {
    if (bag_options.info_focal_scales.size() != num_cameras) {
      if (error) {
        *error = std::to_string(bag_options.info_focal_scales.size()) + " focal scales for " +
                 std::to_string(num_cameras) + " cameras";
      }
      return false;
    }
    focal_scales = bag_options.info_focal_scales;
  }
  infos->assign(num_cameras, info);
  *info_off = false;
  for (std::size_t c = 0; c < num_cameras; ++c) {
    (*infos)[c].k(0, 0) *= focal_scales[c];
    (*infos)[c].k(1, 1) *= focal_scales[c];
    (*infos)[c].k(0, 2) += bag_options.info_principal_offset_x;
    (*infos)[c].k(1, 2) += bag_options.info_principal_offset_y;
    *info_off = *info_off || bag_options.info_no_lens || focal_scales[c] != 1.0 || bag_options.info_principal_offset_x != 0.0 ||
                bag_options.info_principal_offset_y != 0.0;
  }
  return true;
}

// The readout fits the sensor, and an image folder asks for what it can
// hold (then it is created).
bool CheckRigSceneOutputs(const RigSceneOptions& options, const CameraIntrinsics& camera, bool info_off,
                          const RigSceneBagOptions& bag_options, std::string* error) {
  const SensorReadout& readout = bag_options.readout;
  const cv::Rect sensor_rect(0, 0, options.width, options.height);
  const cv::Rect region = readout.roi.empty() ? sensor_rect : readout.roi;
  if (readout.binning < 1 || (region & sensor_rect) != region || region.width < readout.binning ||
      region.height < readout.binning) {
    if (error) {
      *error = "the readout (binning " + std::to_string(readout.binning) + ", region " +
               std::to_string(readout.roi.width) + " x " + std::to_string(readout.roi.height) + " at (" +
               std::to_string(readout.roi.x) + ", " + std::to_string(readout.roi.y) + ")) does not fit the " +
               std::to_string(options.width) + " x " + std::to_string(options.height) + " sensor";
    }
    return false;
  }
  const std::string& images_dir = bag_options.images_dir;
  if (images_dir.empty()) return true;
  if (camera.HasDistortion() || info_off || !bag_options.readout.Whole()) {
    if (error) {
      *error = "an image folder holds ideal pinhole images with the scene's K: no lens, camera_info as the scene's, "
               "the whole sensor";
    }
    return false;
  }
  std::error_code ec;
  std::filesystem::create_directories(images_dir, ec);
  if (ec) {
    if (error) *error = "cannot create " + images_dir + ": " + ec.message();
    return false;
  }
  return true;
}

// The image folder's K and ground truth, keyed by the images' file names.
bool WriteImageFolderFiles(const std::string& images_dir, const Eigen::Matrix3d& k, const NamedOrientations& truth,
                           std::string* error) {
  std::ofstream k_file(images_dir + "/K.txt");
  char line[256];
  for (int r = 0; r < 3; ++r) {
    std::snprintf(line, sizeof(line), "%.17g %.17g %.17g\n", k(r, 0), k(r, 1), k(r, 2));
    k_file << line;
  }
  if (!k_file.good()) {
    if (error) *error = "cannot write " + images_dir + "/K.txt";
    return false;
  }
  NamedOrientations by_file;
  for (const auto& [name, r] : truth) by_file[name + ".png"] = r;
  return WriteOrientationsCsv(images_dir + "/ground_truth.csv", by_file, error);
}

}  // namespace

bool WriteRigSceneBag(const RigScene& scene, const std::string& path, bool compressed, NamedOrientations* ground_truth,
                      std::string* error, const RigSceneBagOptions& bag_options) {
  const RigSceneOptions& options = scene.Options();
  const bool progress = bag_options.progress;
  CameraIntrinsics camera = bag_options.lens;
  camera.k = scene.Intrinsics();
  std::vector<CameraIntrinsics> infos;
  bool info_off = false;
  if (!CameraInfos(scene, camera, bag_options, &infos, &info_off, error)) return false;
  if (!CheckRigSceneOutputs(options, camera, info_off, bag_options, error)) return false;
  const std::string& images_dir = bag_options.images_dir;
  rosbag::Bag bag;
  try {
    bag.open(path, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    if (error) *error = "cannot write " + path + ": " + e.what();
    return false;
  }
  const ros::Time t0(1000.0);

  // Rig extrinsics: the orientation of each camera's optical frame in base_link.
  tf2_msgs::TFMessage extrinsics;
  for (const RigCamera& c : scene.Cameras()) {
    extrinsics.transforms.push_back(
        StaticTransform(t0, "base_link", c.frame_id, c.camera_from_rig.transpose(), c.position_in_rig));
  }
  // Before the first image, as a recorder started with the robot would have it.
  bag.write("/tf_static", t0 - ros::Duration(0.5), extrinsics);

  // A barrel lens sees beyond the pinhole image of its size: the scene is
  // rendered that much wider, so that no raw pixel is black (a real lens
  // has no such border, whose hard edge would give features that stay put).
  const int margin = LensMarginPx(camera, cv::Size(options.width, options.height));
  Orientations truth;
  truth.header.frame_id = "map";
  NamedOrientations truth_csv;
  try {
    for (int capture = 0; capture < options.num_captures; ++capture) {
      const ros::Time stamp = t0 + ros::Duration(scene.CaptureTime(capture));
      for (std::size_t c = 0; c < scene.Cameras().size(); ++c) {
        const std::string& frame = scene.Cameras()[c].frame_id;
        cv::Mat image = DistortImage(scene.Render(capture, static_cast<int>(c), margin), camera, margin);
        if (bag_options.rectify) image = UndistortImage(image, camera);
        const cv::Size sensor = image.size();
        if (!bag_options.readout.Whole()) image = ReadOut(image, bag_options.readout);
        WriteKeyframeImage(&bag, frame, stamp, image, infos[c], compressed, sensor, bag_options.readout);
        const KeyframeKey key{frame, ToNanoseconds(stamp)};
        const std::string name = OnlineAverager::KeyframeName(key);
        const Eigen::Matrix3d world_to_camera = scene.WorldToCamera(capture, static_cast<int>(c));
        if (!images_dir.empty() && !cv::imwrite(images_dir + "/" + name + ".png", image)) {
          if (error) *error = "cannot write " + images_dir + "/" + name + ".png";
          return false;
        }
        truth.keyframes.push_back(ToMsg(key, world_to_camera, 0));
        truth_csv[name] = world_to_camera;
      }
      if (progress) std::fprintf(stderr, "\rrendered capture %d/%d", capture + 1, options.num_captures);
    }
    if (progress) std::fprintf(stderr, "\n");
    const ros::Time end = t0 + ros::Duration(scene.CaptureTime(options.num_captures - 1));
    truth.header.stamp = end;
    bag.write("/ground_truth/orientations", end, truth);
    bag.close();
  } catch (const rosbag::BagException& e) {
    if (error) *error = "writing " + path + ": " + e.what();
    return false;
  }
  if (!images_dir.empty() && !WriteImageFolderFiles(images_dir, camera.k, truth_csv, error)) return false;
  if (ground_truth) *ground_truth = std::move(truth_csv);
  return true;
}

std::size_t WriteEurocBag(const std::vector<EurocCamera>& cameras, const std::string& path, bool compressed,
                          bool rectify, std::string* error) {
  rosbag::Bag bag;
  try {
    bag.open(path, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    if (error) *error = "cannot write " + path + ": " + e.what();
    return 0;
  }
  // Every image of every camera in stamp order (cameras of one capture share it).
  std::vector<std::tuple<std::int64_t, std::size_t, std::string>> images;
  for (std::size_t c = 0; c < cameras.size(); ++c) {
    for (const auto& [stamp, file] : cameras[c].images) images.emplace_back(stamp, c, file);
  }
  std::sort(images.begin(), images.end());
  if (images.empty()) {
    if (error) *error = "the dataset lists no image that exists";
    return 0;
  }
  const ros::Time first = FromNanoseconds(std::get<0>(images.front()));
  tf2_msgs::TFMessage extrinsics;
  for (const EurocCamera& c : cameras) {
    extrinsics.transforms.push_back(StaticTransform(first, "body", c.name, c.body_from_camera, c.camera_in_body));
  }
  bag.write("/tf_static", first - ros::Duration(0.5), extrinsics);
  std::size_t written = 0;
  try {
    for (const auto& [stamp, c, file] : images) {
      cv::Mat grey = cv::imread(file, cv::IMREAD_GRAYSCALE);
      if (grey.empty()) {
        if (error) *error = "cannot read image " + file;
        return 0;
      }
      CameraIntrinsics camera = cameras[c].intrinsics;
      if (rectify) {
        grey = UndistortImage(grey, camera);
        camera.distortion = DistortionModel::kNone;
        camera.coefficients.clear();
      }
      WriteKeyframeImage(&bag, cameras[c].name, FromNanoseconds(stamp), grey, camera, compressed);
      ++written;
    }
    bag.close();
  } catch (const rosbag::BagException& e) {
    if (error) *error = "writing " + path + ": " + e.what();
    return 0;
  }
  return written;
}

}  // namespace rotation_averaging
