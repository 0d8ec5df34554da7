// The node's parameters: every field of config/rotation_averaging.yaml with
// its default, where they come from (the parameter server or the replay's
// YAML file), and the one reader that turns them into a validated config.
// The node and the replay read them here and nowhere else.
#ifndef ROTATION_AVERAGING_ROS_PIPELINE_CONFIG_H_
#define ROTATION_AVERAGING_ROS_PIPELINE_CONFIG_H_

#include <cstddef>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/frontend/controllers/keyframe_selector.h"
#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

// Where parameters come from: the node's private namespace on the parameter
// server, or a YAML file for the replay tool. Each getter returns false when
// the parameter is absent (the caller keeps its default).
class ParameterSource {
 public:
  virtual ~ParameterSource() = default;
  virtual bool Get(const std::string& name, std::string* value) const = 0;
  virtual bool Get(const std::string& name, double* value) const = 0;
  virtual bool Get(const std::string& name, int* value) const = 0;
  virtual bool Get(const std::string& name, bool* value) const = 0;
  virtual bool Get(const std::string& name, std::vector<std::string>* value) const = 0;
};

// The parameters that name one of a few choices, parsed once into these (as
// the core parses loss and solver names): OptionName gives a value's
// parameter text, ParseOption reads it (false for any other text) and
// OptionChoices lists the texts, "a, b, c".
enum class TfMode { kAllKeyframes, kLatestPerCamera, kNone };  // all_keyframes, latest_per_camera, none
enum class ImageTransportMode { kRaw, kCompressed };           // raw, compressed
enum class ImageType { kAuto, kRaw, kRectified };              // auto, raw, rectified
enum class KeyframeSelectionMode { kMotion, kAll };            // motion, all
enum class FocalCalibrationMode { kWarn, kApply, kOff };       // warn, apply, off

template <typename E>
const char* OptionName(E value);
template <typename E>
bool ParseOption(const std::string& text, E* value);
template <typename E>
std::string OptionChoices();

// Every parameter of config/rotation_averaging.yaml, with its default: the
// node's parameters are the fields they set, under the field's name
// (ReadPipelineConfig lists them).
struct PipelineConfig {
  PipelineConfig();  // the libraries' defaults, and the node's own where they differ

  std::string fixed_frame = "map";
  TfMode tf_mode = TfMode::kAllKeyframes;
  std::string keyframe_frame_format = "{frame_id}_kf_{stamp_ns}";
  std::string latest_frame_format = "{frame_id}_averaged";
  OnlineAveragerOptions averager;
  std::vector<std::string> image_topics;
  ImageTransportMode image_transport = ImageTransportMode::kRaw;
  // How camera_info describes the images (image_proc's convention: one
  // camera_info serves both image_raw and image_rect): "raw" images are
  // undistorted by camera_info's K, distortion_model and D; "rectified"
  // images take the rectified camera, P's left 3x3, and no distortion;
  // "auto" decides by topic: a topic whose last name starts with image_rect
  // is rectified, any other raw.
  ImageType image_type = ImageType::kAuto;
  // Which images become keyframes: "motion", those that moved enough since
  // their camera's last keyframe, or that track too little of it
  // (frontend/controllers/keyframe_selector.h; a raw 20-30 Hz stream);
  // "all", every image (a stack that already publishes keyframes).
  KeyframeSelectionMode keyframe_selection = KeyframeSelectionMode::kMotion;
  // The check of each camera's focal length against its verified image
  // pairs (frontend/controllers/focal_monitor.h): "warn" estimates it as the
  // pairs accumulate, reports it (diagnostics, ~camera_info_checks)
  // and warns when camera_info's focal length disagrees (or when it has no
  // distortion model and the images are distorted); "apply" also
  // corrects it then (frontend/controllers/focal_corrector.h); "off" does
  // neither.
  FocalCalibrationMode focal_calibration = FocalCalibrationMode::kApply;
  // With "apply": once a camera is corrected, its focal length is refined
  // further by the loops of the averaging (FocalCorrector::RefineByLoops),
  // as loop closures arrive.
  bool focal_loop_refinement = true;
  // The background refinement of the newest keyframes by bundle adjustment
  // on their pairs' inliers (frontend/controllers/keyframe_refiner.h), with
  // an image front end: after a solve, once `refinement_period_s` (of wall
  // time in the node, of bag time in the replay) has passed since the last
  // one started; its corrections are published with every later solution.
  bool refinement = true;
  double refinement_period_s = 20.0;
  KeyframeRefinerOptions refiner;  // refinement_max_keyframes, refinement_max_correction_deg
  KeyframeSelectionOptions selection;  // keyframe_min_motion_deg, ...; its rig tolerance is rig_stamp_tolerance_s
  KeyframeFrontendOptions frontend;    // frontend.vocabulary: loaded from `vocabulary`
  // File of `rotavg vocabulary`; "default": DefaultVocabularyPath(); "" or
  // "none": no vocabulary (retrieval by voting, linear in the map).
  std::string vocabulary = "default";
  std::size_t max_image_queue = 8;
  // Images of each topic that ROS holds while the image callback (decoding,
  // keyframe selection) is busy; beyond, ROS drops the oldest, and the gap
  // in the camera's stamps is counted (PipelineStats::frames_missing). A
  // second and a half at 20 Hz: a loaded machine holds that callback up for
  // longer than half a second, and a frame lost changes which keyframes are
  // made.
  std::size_t image_transport_queue = 30;
  RigModelOptions rig;  // use_rig_extrinsics, rig_frame, rig_stamp_tolerance_s
  // rviz markers: orientations carry no positions, so each camera (or rig)
  // gets a lane along y and its keyframes are laid out along x in time order.
  bool markers = true;
  double marker_spacing_m = 0.5;       // between consecutive keyframes of a lane
  int marker_max_keyframes = 2000;     // only the newest are drawn beyond this
  std::string load_graph, save_on_shutdown;
  std::vector<std::string> add_maps;  // added after load_graph (AddMap): other sessions', other robots
  std::string autosave_path;    // graph saved atomically every autosave_period_s s ("" = off)
  double autosave_period_s = 30.0;

  // True if every field (the averager's and the front end's options
  // included) is within its range; otherwise false, with `error` naming the
  // first field that is not.
  bool Validate(std::string* error) const;
};

// Reads every parameter into `config` (which holds the defaults), each under
// the name of the field it sets; a parameter under its former name is read
// too, with a deprecation warning. False, with `error` naming the parameter,
// when a value is out of its range or not one of its choices (Validate);
// then `config` is not to be used. Warnings (deprecated names, a vocabulary
// that does not load) are appended to `warnings`.
bool ReadPipelineConfig(const ParameterSource& params, PipelineConfig* config, std::vector<std::string>* warnings,
                        std::string* error);

// The vocabulary the build trains (target `vocabulary`, run by
// scripts/setup.sh) in the package's share folder of the devel space.
std::string DefaultVocabularyPath();

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_PIPELINE_CONFIG_H_
