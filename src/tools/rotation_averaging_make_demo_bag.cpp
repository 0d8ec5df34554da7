// rotation_averaging_make_demo_bag: renders the synthetic rig of
// sim/rig_scene.h into a bag the node and the replay tool can use.
//
//   rotation_averaging_make_demo_bag --output demo.bag [--captures 60] [--cameras 2] [--laps 1]
//       [--width 640] [--height 480] [--noise 2] [--period 1.0] [--seed 1] [--compressed]
//       [--gt-csv ground_truth.csv] [--distortion MODEL:c1,c2,...]
//       [--start-angle 0] [--start-time 0] [--light-gain 1] [--light-gradient 0] [--noise-seed 0]
//       [--info-focal-scale 1 | S1,S2,...] [--rectify] [--info-no-lens] [--images-dir DIR]
//       [--binning 1] [--roi X,Y,W,H] [--info-principal-offset DX,DY]
//
// The bag holds, per camera, <cam>/image_raw (mono8, or <cam>/image_raw/compressed
// PNG with --compressed) and <cam>/camera_info; the rig extrinsics on
// /tf_static (base_link -> cam_*); and the ground truth as one
// rotation_averaging/Orientations message on /ground_truth/orientations.
// With --distortion (e.g. plumb_bob:-0.28,0.07,0,0 or equidistant:0.1,0,0,0)
// the images are what that lens would have seen and camera_info carries the
// model, as a camera driver's image_raw does; with --rectify as well, the
// lens's images undistorted again and camera_info without distortion, as
// image_proc's image_rect (the same content through both resamplings);
// with --info-no-lens, the lens's images and camera_info without the lens (a
// lens nobody calibrated).
// --info-focal-scale writes camera_info's focal lengths that many times the
// scene's (one factor, or one per camera: 0.97,1.01), --info-principal-offset
// its principal point that many sensor pixels off. --images-dir also writes the same images as a folder for `rotavg
// images` (<keyframe name>.png, K.txt, ground_truth.csv keyed by file name;
// ideal pinhole images only). The --start-* and --light-*
// options and --noise-seed make another session in the same room (same
// --seed): starting elsewhere on the loop, later, under other lighting.
// --roi and --binning read each image out of the rendered sensor (--width x
// --height) as a driver with those settings does: the region X,Y,W,H of it
// (sensor pixels), then binned in N x N blocks; camera_info keeps the
// sensor's K and size and carries roi and binning_x/binning_y (REP 104).
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <iostream>
#include <functional>
#include <string>
#include <vector>

#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/sim/demo_bag.h"
#include "rotation_averaging/util/freed_memory.h"

namespace ra = rotation_averaging;

namespace {

int Usage(const std::string& why) {
  if (!why.empty()) std::cerr << "rotation_averaging_make_demo_bag: " << why << "\n";
  std::cerr << "usage: rotation_averaging_make_demo_bag --output demo.bag [--captures 60] [--cameras 2] [--laps 1]\n"
               "           [--width 640] [--height 480] [--noise 2] [--period 1.0] [--seed 1] [--compressed]\n"
               "           [--gt-csv ground_truth.csv] [--distortion MODEL:c1,c2,...]\n"
               "           [--start-angle 0] [--start-time 0] [--light-gain 1] [--light-gradient 0] [--noise-seed 0]\n"
               "           [--info-focal-scale 1 | S1,S2,...] [--rectify] [--info-no-lens] [--images-dir DIR]\n"
               "           [--binning 1] [--roi X,Y,W,H] [--info-principal-offset DX,DY]\n";
  return 2;
}

// What the command line asks for.
struct Request {
  ra::RigSceneOptions options;
  std::string output, gt_csv;
  bool compressed = false;
  ra::RigSceneBagOptions bag_options;
};

// --info-focal-scale: one factor for every camera, or one per camera
// separated by commas. "" or why the text is refused.
std::string ParseFocalScales(const std::string& text, ra::RigSceneBagOptions* bag_options) {
  std::vector<double> scales;
  std::size_t start = 0;
  while (start <= text.size()) {
    const std::size_t comma = std::min(text.find(',', start), text.size());
    const std::string item = text.substr(start, comma - start);
    char* end = nullptr;
    const double v = std::strtod(item.c_str(), &end);
    if (item.empty() || !end || *end != '\0' || !std::isfinite(v) || v < 0.5 || v > 2) {
      return "--info-focal-scale takes a number in [0.5, 2], or one per camera (0.97,1.01), not '" + text + "'";
    }
    scales.push_back(v);
    start = comma + 1;
  }
  if (scales.size() == 1) {
    bag_options->info_focal_scale = scales[0];
  } else {
    bag_options->info_focal_scales = scales;
  }
  return "";
}

// The options that take a number: what each takes, and where its value goes.
struct Numeric {
  const char* name;
  const char* takes;
  std::function<bool(double)> valid;
  std::function<void(double)> set;
};

std::vector<Numeric> NumericOptions(Request* r) {
  return {
      {"--captures", "a number >= 4", [](double v) { return v >= 4; },
       [r](double v) { r->options.num_captures = static_cast<int>(v); }},
      {"--laps", "a number >= 1", [](double v) { return v >= 1; },
       [r](double v) { r->options.laps = static_cast<int>(v); }},
      {"--cameras", "1 to 4", [](double v) { return v >= 1 && v <= 4; },
       [r](double v) { r->options.num_cameras = static_cast<int>(v); }},
      {"--width", "a number >= 64", [](double v) { return v >= 64; },
       [r](double v) { r->options.WithWidth(static_cast<int>(v)); }},  // same field of view, 4:3
      {"--height", "a number >= 48", [](double v) { return v >= 48; },
       [r](double v) { r->options.height = static_cast<int>(v); }},
      {"--noise", "a number >= 0", [](double v) { return v >= 0; }, [r](double v) { r->options.noise_grey = v; }},
      {"--period", "a number > 0", [](double v) { return v > 0; }, [r](double v) { r->options.capture_period_s = v; }},
      {"--seed", "a number >= 0", [](double v) { return v >= 0; },
       [r](double v) { r->options.seed = static_cast<std::uint64_t>(v); }},
      {"--start-angle", "a number", [](double) { return true; }, [r](double v) { r->options.start_angle_deg = v; }},
      {"--start-time", "a number >= 0", [](double v) { return v >= 0; }, [r](double v) { r->options.start_time_s = v; }},
      {"--light-gain", "a number > 0", [](double v) { return v > 0; }, [r](double v) { r->options.light_gain = v; }},
      {"--light-gradient", "a number in [0, 2)", [](double v) { return v >= 0 && v < 2; },
       [r](double v) { r->options.light_gradient = v; }},
      {"--noise-seed", "a number >= 0", [](double v) { return v >= 0; },
       [r](double v) { r->options.noise_seed = static_cast<std::uint64_t>(v); }},
      {"--binning", "a whole number from 1 to 8", [](double v) { return v >= 1 && v <= 8 && v == std::floor(v); },
       [r](double v) { r->bag_options.readout.binning = static_cast<int>(v); }},
  };
}

// Reads the command line into `r`: "" or why it is refused.
std::string ParseArguments(int argc, char** argv, Request* r) {
  ra::RigSceneBagOptions& bag_options = r->bag_options;
  const std::vector<Numeric> numeric = NumericOptions(r);
  std::string error;
  for (int k = 1; k < argc; ++k) {
    const std::string a = argv[k];
    const bool has_value = k + 1 < argc;
    if ((a == "--output" || a == "--gt-csv" || a == "--distortion" || a == "--images-dir") && !has_value) {
      return a + " needs a value";
    } else if (a == "--output") {
      r->output = argv[++k];
    } else if (a == "--gt-csv") {
      r->gt_csv = argv[++k];
    } else if (a == "--images-dir") {
      bag_options.images_dir = argv[++k];
    } else if (a == "--distortion") {
      if (!ra::ParseDistortionSpec(argv[++k], &bag_options.lens, &error)) return "--distortion: " + error;
    } else if (a == "--info-focal-scale") {
      if (!has_value) return a + " needs a value: a number in [0.5, 2], or one per camera (0.97,1.01)";
      const std::string why = ParseFocalScales(argv[++k], &bag_options);
      if (!why.empty()) return why;
    } else if (a == "--info-principal-offset") {
      const std::string text = has_value ? argv[++k] : "";
      double x = 0.0, y = 0.0;
      char extra = 0;
      if (std::sscanf(text.c_str(), "%lf,%lf%c", &x, &y, &extra) != 2 || !std::isfinite(x) || !std::isfinite(y) ||
          std::abs(x) > 100.0 || std::abs(y) > 100.0) {
        return "--info-principal-offset takes DX,DY (pixels, at most 100), not '" + text + "'";
      }
      bag_options.info_principal_offset_x = x;
      bag_options.info_principal_offset_y = y;
    } else if (a == "--roi") {
      // X,Y,W,H: whole numbers, a region of the sensor.
      const std::string text = has_value ? argv[++k] : "";
      int v[4];
      char extra = 0;
      if (std::sscanf(text.c_str(), "%d,%d,%d,%d%c", &v[0], &v[1], &v[2], &v[3], &extra) != 4 || v[0] < 0 ||
          v[1] < 0 || v[2] < 1 || v[3] < 1) {
        return "--roi takes X,Y,W,H (whole numbers, W and H at least 1), not '" + text + "'";
      }
      bag_options.readout.roi = cv::Rect(v[0], v[1], v[2], v[3]);
    } else if (a == "--compressed") {
      r->compressed = true;
    } else if (a == "--rectify") {
      bag_options.rectify = true;
    } else if (a == "--info-no-lens") {
      bag_options.info_no_lens = true;
    } else {
      const auto option = std::find_if(numeric.begin(), numeric.end(), [&](const Numeric& n) { return a == n.name; });
      if (option == numeric.end()) return "unknown option " + a;
      if (!has_value) return a + " needs a value: " + option->takes;
      const std::string text = argv[++k];
      char* end = nullptr;
      const double v = std::strtod(text.c_str(), &end);
      if (text.empty() || !end || *end != '\0' || !std::isfinite(v) || !option->valid(v)) {
        return a + " takes " + option->takes + ", not '" + text + "'";
      }
      option->set(v);
    }
  }
  return "";
}

// Options that do not go together, and a readout that does not fit the
// sensor: "" or why. `image` gets the size of the images written.
std::string CheckRequest(const Request& r, cv::Size* image) {
  const ra::RigSceneOptions& options = r.options;
  const ra::RigSceneBagOptions& bag_options = r.bag_options;
  if (r.output.empty()) return "give --output";
  if (!bag_options.info_focal_scales.empty() &&
      bag_options.info_focal_scales.size() != static_cast<std::size_t>(options.num_cameras)) {
    return "--info-focal-scale: " + std::to_string(bag_options.info_focal_scales.size()) + " factors for " +
           std::to_string(options.num_cameras) + " cameras";
  }
  const bool info_off = bag_options.info_focal_scale != 1.0 ||
                        std::any_of(bag_options.info_focal_scales.begin(), bag_options.info_focal_scales.end(),
                                    [](double v) { return v != 1.0; }) ||
                        bag_options.info_principal_offset_x != 0.0 || bag_options.info_principal_offset_y != 0.0;
  if (bag_options.rectify && !bag_options.lens.HasDistortion()) return "--rectify needs a --distortion";
  if (bag_options.info_no_lens && !bag_options.lens.HasDistortion()) return "--info-no-lens needs a --distortion";
  if (bag_options.info_no_lens && bag_options.rectify) return "--info-no-lens and --rectify: rectified images have no lens";
  if (!bag_options.images_dir.empty() && (bag_options.lens.HasDistortion() || info_off)) {
    return "--images-dir writes ideal pinhole images with the scene's K: not with --distortion, "
           "--info-focal-scale or --info-principal-offset";
  }
  const ra::SensorReadout& readout = bag_options.readout;
  if (!readout.roi.empty() && (readout.roi & cv::Rect(0, 0, options.width, options.height)) != readout.roi) {
    return "--roi: the region does not lie on the " + std::to_string(options.width) + "x" +
           std::to_string(options.height) + " sensor";
  }
  const cv::Size region = readout.roi.empty() ? cv::Size(options.width, options.height) : readout.roi.size();
  *image = cv::Size(region.width / readout.binning, region.height / readout.binning);
  if (image->width < 64 || image->height < 48) {
    return "the readout leaves " + std::to_string(image->width) + "x" + std::to_string(image->height) +
           " pixels (at least 64x48)";
  }
  if (!bag_options.images_dir.empty() && !readout.Whole()) {
    return "--images-dir writes the whole sensor's images: not with --roi or --binning";
  }
  return "";
}

}  // namespace

int main(int argc, char** argv) {
  rotation_averaging::KeepFreedMemoryForReuse();  // util/freed_memory.h: buffers of each image reused, not faulted in again
  Request request;
  request.bag_options.progress = true;
  std::string why = ParseArguments(argc, argv, &request);
  cv::Size image;
  if (why.empty()) why = CheckRequest(request, &image);
  if (!why.empty()) return Usage(why);
  const ra::RigSceneOptions& options = request.options;
  const ra::RigSceneBagOptions& bag_options = request.bag_options;
  const ra::RigScene scene(options);
  ra::NamedOrientations truth_csv;
  std::string error;
  if (!ra::WriteRigSceneBag(scene, request.output, request.compressed, &truth_csv, &error, bag_options)) {
    std::cerr << "rotation_averaging_make_demo_bag: " << error << "\n";
    return 1;
  }
  if (!request.gt_csv.empty() && !ra::WriteOrientationsCsv(request.gt_csv, truth_csv, &error)) {
    std::cerr << "rotation_averaging_make_demo_bag: " << error << "\n";
    return 1;
  }
  std::cout << "wrote " << request.output << ": " << options.num_captures << " captures x " << scene.Cameras().size()
            << " cameras at " << image.width << "x" << image.height
            << (bag_options.readout.Whole() ? std::string()
                                            : " (read out of a " + std::to_string(options.width) + "x" +
                                                  std::to_string(options.height) + " sensor)")
            << ", " << options.capture_period_s
            << " s apart (" << scene.CaptureTime(options.num_captures - 1) << " s of bag time), ground truth on "
            << "/ground_truth/orientations" << (request.gt_csv.empty() ? "" : " and in " + request.gt_csv)
            << (bag_options.images_dir.empty() ? "" : "; the images also in " + bag_options.images_dir) << std::endl;
  return 0;
}
