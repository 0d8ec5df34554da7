// rotation_averaging_images_to_bag: an image folder with ground truth (a
// Strecha scene, or images with a COLMAP text model) as a bag of keyframes
// for the node and the replay tool.
//
//   rotation_averaging_images_to_bag --images DIR --intrinsics CAMERA-FILE --output out.bag
//       [--gt Strecha-folder|images.txt|orientations.csv] [--downsample 0.25] [--rate 1.0]
//       [--frame-id camera] [--compressed] [--write-gt-csv ground_truth.csv]
//       [--rectify] [--distortion MODEL:c1,c2,...] [--info-no-lens]
//   rotation_averaging_images_to_bag --euroc mav0 --output out.bag [--compressed] [--rectify] [--info-no-lens]
//
// CAMERA-FILE: K.txt, COLMAP cameras.txt, or a ROS / EuRoC / Kalibr YAML
// (frontend/geometry/camera_model.h). Images are written in file-name order,
// 1/rate seconds apart, as mono8 <frame-id>/image_raw (or PNG
// <frame-id>/image_raw/compressed) with <frame-id>/camera_info carrying the
// camera's distortion model and D, as a camera driver publishes them.
// --rectify writes rectified images instead (camera_info without
// distortion); --distortion warps images of an ideal camera (a file without
// distortion) through that lens and writes its model: real image content
// with a known distortion (with --rectify too: warped, then rectified;
// with --info-no-lens, camera_info leaves that lens out: a lens nobody
// calibrated). --euroc writes every camera of a EuRoC-layout
// dataset (EuRoC MAV, TUM-VI: mav0/camN/{sensor.yaml,data.csv,data/}) at its
// own stamps, camera_info from sensor.yaml, T_BS as /tf_static body -> camN:
// a stereo or multi-camera driver's raw stream (--info-no-lens: camera_info
// without the lens, the images raw). Ground truth
// goes on /ground_truth/orientations, keyed by the keyframes' frame id and stamp,
// and with --write-gt-csv also to a CSV keyed by keyframe name (for
// rotation_averaging_replay --gt). No output may be one of the inputs: the
// program refuses to start rather than overwrite one.
#include <rosbag/bag.h>
#include <rosbag/exceptions.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/sim/demo_bag.h"
#include "rotation_averaging/ros/msg_conversion.h"
#include "rotation_averaging/util/freed_memory.h"

namespace ra = rotation_averaging;

namespace {

int Usage(const std::string& why) {
  if (!why.empty()) std::cerr << "rotation_averaging_images_to_bag: " << why << "\n";
  std::cerr << "usage: rotation_averaging_images_to_bag --images DIR --intrinsics CAMERA-FILE --output out.bag\n"
               "           [--gt Strecha-folder|images.txt|orientations.csv] [--downsample 0.25] [--rate 1.0]\n"
               "           [--frame-id camera] [--compressed] [--write-gt-csv ground_truth.csv]\n"
               "           [--rectify] [--distortion MODEL:c1,c2,...] [--info-no-lens]\n"
               "       rotation_averaging_images_to_bag --euroc mav0 --output out.bag [--compressed] [--rectify]\n"
               "           [--info-no-lens]\n"
               "CAMERA-FILE: K.txt, COLMAP cameras.txt, or a ROS camera_calibration / EuRoC / Kalibr YAML\n";
  return 2;
}

// True if both name the same file (an existing one, through links), or the
// same path once made absolute.
bool SameFile(const std::string& a, const std::string& b) {
  std::error_code ec;
  if (std::filesystem::exists(a, ec) && std::filesystem::exists(b, ec)) {
    const bool same = std::filesystem::equivalent(a, b, ec);
    if (!ec) return same;
  }
  return std::filesystem::weakly_canonical(a, ec) == std::filesystem::weakly_canonical(b, ec);
}

std::string BaseName(const std::string& path) {
  const std::size_t slash = path.find_last_of('/');
  return slash == std::string::npos ? path : path.substr(slash + 1);
}

int EurocToBag(const std::string& mav0, const std::string& output, bool compressed, bool rectify, bool no_lens) {
  if (output.empty()) return Usage("give --output");
  std::vector<ra::EurocCamera> cameras;
  std::size_t missing = 0;
  std::string error;
  if (!ra::ReadEurocCameras(mav0, &cameras, &missing, &error)) {
    std::cerr << "rotation_averaging_images_to_bag: " << error << "\n";
    return 1;
  }
  if (no_lens) {
    // The raw images, camera_info without their lens.
    for (ra::EurocCamera& c : cameras) {
      c.intrinsics.distortion = ra::DistortionModel::kNone;
      c.intrinsics.coefficients.clear();
    }
  }
  for (const ra::EurocCamera& c : cameras) {
    for (const auto& [stamp, image] : c.images) {
      if (SameFile(output, image)) return Usage("--output " + output + " is an image of --euroc: refusing to overwrite it");
    }
  }
  const std::size_t written = ra::WriteEurocBag(cameras, output, compressed, rectify, &error);
  if (written == 0) {
    std::cerr << "rotation_averaging_images_to_bag: " << error << "\n";
    return 1;
  }
  std::cout << "wrote " << output << ": " << written << " images of";
  for (const ra::EurocCamera& c : cameras) {
    std::cout << " " << c.name << " (" << c.images.size() << ", "
              << (rectify ? "rectified" : ra::DistortionModelName(c.intrinsics.distortion)) << ")";
  }
  if (missing > 0) std::cout << "; " << missing << " images listed in data.csv are not on disk";
  std::cout << "; extrinsics body -> camN on /tf_static" << std::endl;
  return 0;
}

// The command line of the folder mode (and of --euroc).
struct Args {
  std::string images_dir, intrinsics_path, output, gt_path, gt_csv, frame_id = "camera", distortion, euroc;
  double downsample = 1.0, rate = 1.0;
  bool compressed = false, rectify = false, no_lens = false;
};

// Returns an empty string, or why the command line is refused.
std::string ParseArgs(int argc, char** argv, Args* args) {
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    const bool has_value = k + 1 < argc;
    if (a == "--images" && has_value) {
      args->images_dir = argv[++k];
    } else if (a == "--intrinsics" && has_value) {
      args->intrinsics_path = argv[++k];
    } else if (a == "--output" && has_value) {
      args->output = argv[++k];
    } else if (a == "--gt" && has_value) {
      args->gt_path = argv[++k];
    } else if (a == "--write-gt-csv" && has_value) {
      args->gt_csv = argv[++k];
    } else if (a == "--gt-csv") {
      return "--gt-csv is ambiguous: the ground truth to read is --gt, the CSV to write is --write-gt-csv";
    } else if (a == "--frame-id" && has_value) {
      args->frame_id = argv[++k];
    } else if (a == "--downsample" && has_value) {
      args->downsample = std::atof(argv[++k]);
    } else if (a == "--rate" && has_value) {
      args->rate = std::atof(argv[++k]);
    } else if (a == "--compressed") {
      args->compressed = true;
    } else if (a == "--euroc" && has_value) {
      args->euroc = argv[++k];
    } else if (a == "--rectify") {
      args->rectify = true;
    } else if (a == "--distortion" && has_value) {
      args->distortion = argv[++k];
    } else if (a == "--info-no-lens") {
      args->no_lens = true;
    } else {
      return "bad or incomplete option " + a;
    }
  }
  if (args->no_lens && args->rectify) return "--info-no-lens and --rectify: rectified images have no lens";
  if (!args->euroc.empty()) return "";
  if (args->no_lens && args->distortion.empty()) return "--info-no-lens needs a --distortion (or --euroc)";
  if (args->images_dir.empty() || args->intrinsics_path.empty() || args->output.empty()) {
    return "give --images, --intrinsics and --output";
  }
  if (!(args->downsample > 0.0 && args->downsample <= 1.0)) return "--downsample must be in (0, 1]";
  if (!(args->rate > 0.0)) return "--rate must be positive";
  if (args->frame_id.empty()) return "--frame-id must not be empty";
  return "";
}

// Refuses an output that is one of the inputs (empty string: none is).
std::string OverwrittenInput(const Args& args, const std::vector<std::string>& images) {
  if (!args.gt_csv.empty() && SameFile(args.gt_csv, args.output)) return "--output and --write-gt-csv name the same file";
  std::vector<std::pair<std::string, std::string>> inputs = {{"--intrinsics", args.intrinsics_path}};
  if (!args.gt_path.empty()) inputs.emplace_back("--gt", args.gt_path);
  for (const std::string& image : images) inputs.emplace_back("an image of --images", image);
  for (const auto& [what, input] : inputs) {
    for (const auto& [flag, out] :
         {std::make_pair("--output", args.output), std::make_pair("--write-gt-csv", args.gt_csv)}) {
      if (!out.empty() && SameFile(out, input)) {
        return std::string(flag) + " " + out + " is " + what + " (" + input + "): refusing to overwrite an input";
      }
    }
  }
  return "";
}

// One image as the bag carries it, with the camera its camera_info
// describes: rectified (--rectify of a distorted camera), downsampled (the
// distortion acts on normalised coordinates: resizing scales K only), then
// through --distortion's lens (`lens`'s K is the downsampled image's), and
// with --rectify back again.
cv::Mat PrepareImage(cv::Mat grey, const Args& args, const ra::CameraIntrinsics& intrinsics, ra::CameraIntrinsics lens,
                     ra::CameraIntrinsics* camera) {
  *camera = intrinsics;
  if (args.rectify && args.distortion.empty()) {
    grey = ra::UndistortImage(grey, intrinsics);
    *camera = ra::CameraIntrinsics();
    camera->k = intrinsics.k;
  }
  if (args.downsample < 1.0) {
    cv::Mat small;
    cv::resize(grey, small, cv::Size(), args.downsample, args.downsample, cv::INTER_AREA);
    grey = small;
    camera->k = ra::ScaleIntrinsics(camera->k, args.downsample);
  }
  if (!args.distortion.empty()) {
    lens.k = camera->k;
    grey = ra::DistortImage(grey, lens);
    *camera = lens;
    if (args.no_lens) {  // a lens nobody calibrated
      camera->distortion = ra::DistortionModel::kNone;
      camera->coefficients.clear();
    }
    if (args.rectify) {  // through the lens and back: what the lens's resampling loses
      grey = ra::UndistortImage(grey, lens);
      camera->distortion = ra::DistortionModel::kNone;
      camera->coefficients.clear();
    }
  }
  return grey;
}

// Writes the folder's images as keyframes 1/rate apart, with the ground
// truth of those that have one; returns the process's exit code.
int WriteFolderBag(const Args& args, const std::vector<std::string>& images, const ra::CameraIntrinsics& intrinsics,
                   const ra::CameraIntrinsics& lens, const ra::NamedOrientations& truth_by_image) {
  rosbag::Bag bag;
  try {
    bag.open(args.output, rosbag::bagmode::Write);
  } catch (const rosbag::BagException& e) {
    std::cerr << "rotation_averaging_images_to_bag: cannot write " << args.output << ": " << e.what() << "\n";
    return 1;
  }
  const ros::Time t0(1000.0);
  rotation_averaging::Orientations truth;
  truth.header.frame_id = "map";
  ra::NamedOrientations truth_csv;
  std::size_t written = 0, without_truth = 0;
  for (const std::string& path : images) {
    const cv::Mat read = cv::imread(path, cv::IMREAD_GRAYSCALE);
    if (read.empty()) {
      std::cerr << "warning: cannot read " << path << ", skipped\n";
      continue;
    }
    ra::CameraIntrinsics camera;
    const cv::Mat grey = PrepareImage(read, args, intrinsics, lens, &camera);
    const ros::Time stamp = t0 + ros::Duration(written / args.rate);
    ra::WriteKeyframeImage(&bag, args.frame_id, stamp, grey, camera, args.compressed);
    ++written;
    auto gt = truth_by_image.find(BaseName(path));
    if (gt != truth_by_image.end()) {
      const ra::KeyframeKey key{args.frame_id, ra::ToNanoseconds(stamp)};
      truth.keyframes.push_back(ra::ToMsg(key, gt->second, 0));
      truth_csv[ra::OnlineAverager::KeyframeName(key)] = gt->second;
    } else if (!truth_by_image.empty()) {
      ++without_truth;
    }
    std::fprintf(stderr, "\rwrote %zu/%zu images", written, images.size());
  }
  std::fprintf(stderr, "\n");
  if (!truth.keyframes.empty()) {
    const ros::Time end = t0 + ros::Duration((written > 0 ? written - 1 : 0) / args.rate);
    truth.header.stamp = end;
    bag.write("/ground_truth/orientations", end, truth);
  }
  bag.close();
  std::string error;
  if (!args.gt_csv.empty() && !ra::WriteOrientationsCsv(args.gt_csv, truth_csv, &error)) {
    std::cerr << "rotation_averaging_images_to_bag: " << error << "\n";
    return 1;
  }
  std::cout << "wrote " << args.output << ": " << written << " keyframes of " << args.frame_id << ", " << 1.0 / args.rate
            << " s apart; ground truth for " << truth.keyframes.size() << " of them";
  if (without_truth) std::cout << " (" << without_truth << " images have none)";
  std::cout << std::endl;
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  Args args;
  const std::string refused = ParseArgs(argc, argv, &args);
  if (!refused.empty()) return Usage(refused);
  if (!args.euroc.empty()) return EurocToBag(args.euroc, args.output, args.compressed, args.rectify, args.no_lens);
  const std::vector<std::string> images = ra::ListImages(args.images_dir);
  const std::string overwritten = OverwrittenInput(args, images);
  if (!overwritten.empty()) return Usage(overwritten);

  ra::CameraIntrinsics intrinsics;
  std::string error;
  if (!ra::ReadCameraIntrinsics(args.intrinsics_path, &intrinsics, &error)) {
    std::cerr << "rotation_averaging_images_to_bag: " << error << "\n";
    return 1;
  }
  ra::CameraIntrinsics lens;  // the distortion --distortion adds
  if (!args.distortion.empty()) {
    if (intrinsics.HasDistortion()) {
      return Usage("--distortion needs images of an ideal camera; " + args.intrinsics_path + " has a " +
                   ra::DistortionModelName(intrinsics.distortion) + " distortion");
    }
    lens = intrinsics;
    if (!ra::ParseDistortionSpec(args.distortion, &lens, &error)) return Usage("--distortion: " + error);
  }
  if (images.empty()) {
    std::cerr << "rotation_averaging_images_to_bag: no images in " << args.images_dir << "\n";
    return 1;
  }
  ra::NamedOrientations truth_by_image;
  if (!args.gt_path.empty()) {
    const ra::ReadReport report = ra::ReadGroundTruth(args.gt_path, ra::GroundTruthFormat::kAuto, &truth_by_image);
    if (!report.ok()) {
      std::cerr << "rotation_averaging_images_to_bag: ground truth: " << report.error << "\n";
      return 1;
    }
  }
  return WriteFolderBag(args, images, intrinsics, lens, truth_by_image);
}
