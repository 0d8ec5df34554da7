// rotation_averaging_make_demo_bag: renders the synthetic rig of
// scene/rig_scene.h into a bag the node and the replay tool can use.
//
//   rotation_averaging_make_demo_bag --output demo.bag [--captures 60] [--cameras 2]
//       [--width 640] [--height 480] [--noise 2] [--period 1.0] [--seed 1] [--compressed]
//       [--gt-csv ground_truth.csv]
//
// The bag holds, per camera, <cam>/image_raw (mono8, or <cam>/image_raw/compressed
// PNG with --compressed) and <cam>/camera_info; the rig extrinsics on
// /tf_static (base_link -> cam_*); and the ground truth as one
// rotation_averaging/Orientations message on /ground_truth/orientations.
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <cstdio>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <string>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/geometry/so3.h"
#include "rotation_averaging/io/orientation_io.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/scene/rig_scene.h"

namespace ra = rotation_averaging;

namespace {

int Usage(const std::string& why) {
  if (!why.empty()) std::cerr << "rotation_averaging_make_demo_bag: " << why << "\n";
  std::cerr << "usage: rotation_averaging_make_demo_bag --output demo.bag [--captures 60] [--cameras 2]\n"
               "           [--width 640] [--height 480] [--noise 2] [--period 1.0] [--seed 1] [--compressed]\n"
               "           [--gt-csv ground_truth.csv]\n";
  return 2;
}

geometry_msgs::Quaternion ToQuaternion(const Eigen::Matrix3d& r) {
  const Eigen::Vector4d q = ra::RotationToQuaternion(r);
  geometry_msgs::Quaternion m;
  m.w = q[0];
  m.x = q[1];
  m.y = q[2];
  m.z = q[3];
  return m;
}

}  // namespace

int main(int argc, char** argv) {
  ra::RigSceneOptions options;
  std::string output, gt_csv;
  bool compressed = false;
  const double start_s = 1000.0;  // bag time of the first capture
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    const bool has_value = k + 1 < argc;
    auto number = [&](double* out) {
      if (!has_value) return false;
      char* end = nullptr;
      *out = std::strtod(argv[++k], &end);
      return end && *end == '\0';
    };
    double v = 0.0;
    if (a == "--output" && has_value) {
      output = argv[++k];
    } else if (a == "--gt-csv" && has_value) {
      gt_csv = argv[++k];
    } else if (a == "--compressed") {
      compressed = true;
    } else if (a == "--captures" && number(&v) && v >= 4) {
      options.num_captures = static_cast<int>(v);
    } else if (a == "--cameras" && number(&v) && v >= 1 && v <= 4) {
      options.num_cameras = static_cast<int>(v);
    } else if (a == "--width" && number(&v) && v >= 64) {
      options.width = static_cast<int>(v);
      options.focal_px = 420.0 * options.width / 640.0;
    } else if (a == "--height" && number(&v) && v >= 48) {
      options.height = static_cast<int>(v);
    } else if (a == "--noise" && number(&v) && v >= 0) {
      options.noise_grey = v;
    } else if (a == "--period" && number(&v) && v > 0) {
      options.capture_period_s = v;
    } else if (a == "--seed" && number(&v) && v >= 0) {
      options.seed = static_cast<std::uint64_t>(v);
    } else {
      return Usage("bad or incomplete option " + a);
    }
  }
  if (output.empty()) return Usage("give --output");

  const ra::RigScene scene(options);
  const Eigen::Matrix3d k = scene.Intrinsics();
  rosbag::Bag bag;
  try {
    bag.open(output, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    std::cerr << "rotation_averaging_make_demo_bag: cannot write " << output << ": " << e.what() << "\n";
    return 1;
  }
  const ros::Time t0(start_s);

  // Rig extrinsics: the orientation of each camera's optical frame in base_link.
  tf2_msgs::TFMessage extrinsics;
  for (const ra::RigCamera& c : scene.Cameras()) {
    geometry_msgs::TransformStamped t;
    t.header.stamp = t0;
    t.header.frame_id = "base_link";
    t.child_frame_id = c.frame_id;
    t.transform.translation.x = c.position_in_rig.x();
    t.transform.translation.y = c.position_in_rig.y();
    t.transform.translation.z = c.position_in_rig.z();
    t.transform.rotation = ToQuaternion(c.camera_from_rig.transpose());
    extrinsics.transforms.push_back(t);
  }
  // Before the first image, as a recorder started with the robot would have it.
  bag.write("/tf_static", t0 - ros::Duration(0.5), extrinsics);

  rotation_averaging::Orientations truth;
  truth.header.frame_id = "map";
  ra::NamedOrientations truth_csv;
  for (int capture = 0; capture < options.num_captures; ++capture) {
    const ros::Time stamp = t0 + ros::Duration(scene.CaptureTime(capture));
    for (std::size_t c = 0; c < scene.Cameras().size(); ++c) {
      const std::string& frame = scene.Cameras()[c].frame_id;
      const cv::Mat image = scene.Render(capture, static_cast<int>(c));
      sensor_msgs::CameraInfo info;
      info.header.stamp = stamp;
      info.header.frame_id = frame;
      info.width = options.width;
      info.height = options.height;
      info.distortion_model = "plumb_bob";
      info.D.assign(5, 0.0);
      for (int i = 0; i < 9; ++i) info.K[i] = k(i / 3, i % 3);
      info.R = {1, 0, 0, 0, 1, 0, 0, 0, 1};
      info.P = {k(0, 0), 0, k(0, 2), 0, 0, k(1, 1), k(1, 2), 0, 0, 0, 1, 0};
      bag.write("/" + frame + "/camera_info", stamp, info);
      if (compressed) {
        sensor_msgs::CompressedImage m;
        m.header = info.header;
        m.format = "mono8; png compressed";
        cv::imencode(".png", image, m.data);
        bag.write("/" + frame + "/image_raw/compressed", stamp, m);
      } else {
        sensor_msgs::Image m;
        m.header = info.header;
        m.width = options.width;
        m.height = options.height;
        m.encoding = "mono8";
        m.step = options.width;
        m.data.assign(image.data, image.data + image.total());
        bag.write("/" + frame + "/image_raw", stamp, m);
      }
      const ra::KeyframeKey key{frame, ra::ToNanoseconds(stamp)};
      const Eigen::Matrix3d world_to_camera = scene.WorldToCamera(capture, static_cast<int>(c));
      truth.keyframes.push_back(ra::ToMsg(key, world_to_camera, 0));
      truth_csv[ra::OnlineAverager::KeyframeName(key)] = world_to_camera;
    }
    std::fprintf(stderr, "\rrendered capture %d/%d", capture + 1, options.num_captures);
  }
  std::fprintf(stderr, "\n");
  const ros::Time end = t0 + ros::Duration(scene.CaptureTime(options.num_captures - 1));
  truth.header.stamp = end;
  bag.write("/ground_truth/orientations", end, truth);
  bag.close();
  if (!gt_csv.empty()) {
    std::string error;
    if (!ra::WriteOrientationsCsv(gt_csv, truth_csv, &error)) {
      std::cerr << "rotation_averaging_make_demo_bag: " << error << "\n";
      return 1;
    }
  }
  std::cout << "wrote " << output << ": " << options.num_captures << " captures x " << scene.Cameras().size()
            << " cameras at " << options.width << "x" << options.height << ", " << options.capture_period_s
            << " s apart (" << scene.CaptureTime(options.num_captures - 1) << " s of bag time), ground truth on "
            << "/ground_truth/orientations" << (gt_csv.empty() ? "" : " and in " + gt_csv) << std::endl;
  return 0;
}
