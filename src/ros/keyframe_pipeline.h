// Internal to the package: may change between versions.
// What the live node and the bag replay tool share: reading the parameters,
// turning messages into validated keyframes and relative rotations, running
// the keyframe front end into the averager, and building the output messages.
// The node adds subscriptions, threads and publishers around it; the replay
// tool adds a bag reader and a bag-time solve schedule. Neither re-implements
// anything here.
#ifndef ROTATION_AVERAGING_SRC_ROS_KEYFRAME_PIPELINE_H_
#define ROTATION_AVERAGING_SRC_ROS_KEYFRAME_PIPELINE_H_

#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <set>
#include <string>
#include <vector>

#include "rotation_averaging/CameraInfoCheckArray.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePose.h"
#include "frontend/controllers/keyframe_frontend.h"
#include "frontend/controllers/keyframe_selector.h"
#include "rotation_averaging/core/controllers/online_averager.h"
#include "core/controllers/rig_model.h"

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

// Every parameter of config/rotation_averaging.yaml, with its default: the
// node's parameters are the fields they set, under the field's name
// (ReadPipelineConfig lists them).
struct PipelineConfig {
  PipelineConfig();  // the libraries' defaults, and the node's own where they differ

  std::string fixed_frame = "map";
  std::string tf_mode = "all_keyframes";  // all_keyframes, latest_per_camera, none
  std::string keyframe_frame_format = "{frame_id}_kf_{stamp_ns}";
  std::string latest_frame_format = "{frame_id}_averaged";
  OnlineAveragerOptions averager;
  std::vector<std::string> image_topics;
  std::string image_transport = "raw";  // raw or compressed
  // How camera_info describes the images (image_proc's convention: one
  // camera_info serves both image_raw and image_rect): "raw" images are
  // undistorted by camera_info's K, distortion_model and D; "rectified"
  // images take the rectified camera, P's left 3x3, and no distortion;
  // "auto" decides by topic: a topic whose last name starts with image_rect
  // is rectified, any other raw.
  std::string image_type = "auto";
  // Which images become keyframes: "motion", those that moved enough since
  // their camera's last keyframe, or that track too little of it
  // (frontend/controllers/keyframe_selector.h; a raw 20-30 Hz stream);
  // "all", every image (a stack that already publishes keyframes).
  std::string keyframe_selection = "motion";
  // The check of each camera's focal length against its verified image
  // pairs (frontend/controllers/focal_monitor.h): "warn" estimates it as the
  // pairs accumulate, reports it (diagnostics, ~camera_info_checks)
  // and warns when camera_info's focal length disagrees (or when it has no
  // distortion model and the images are distorted); "apply" also
  // corrects it then (KeyframeFrontend::ApplyFocalCorrection: the camera's
  // pairs estimated again, their edges replaced; a camera of a rig only when
  // the rig's other cameras are checked too); "off" does neither.
  std::string focal_calibration = "warn";
  // With "apply": once a camera is corrected, its focal length is refined
  // further by the loops of the averaging (RefineFocalByLoops), as loop
  // closures arrive.
  bool focal_loop_refinement = true;
  KeyframeSelectionOptions selection;  // keyframe_min_motion_deg, ...; its rig tolerance is rig_stamp_tolerance_s
  KeyframeFrontendOptions frontend;    // frontend.vocabulary: loaded from `vocabulary`
  // File of `rotavg vocabulary`; "default": DefaultVocabularyPath(); "" or
  // "none": no vocabulary (retrieval by voting, linear in the map).
  std::string vocabulary = "default";
  std::size_t max_image_queue = 8;
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

// A decoded, validated keyframe image waiting for the front end.
struct PendingKeyframe {
  KeyframeKey key;
  cv::Mat image;  // 8-bit grey, as the camera took it
  CameraIntrinsics camera;  // of that image: K and its lens distortion
};

// Whether images on `topic` are rectified under PipelineConfig::image_type.
bool IsRectifiedTopic(const std::string& topic, const std::string& image_type);

// The camera of an image described by `info`: K, distortion_model and D for
// a raw image; P's left 3x3 and no distortion for a rectified one. K and P
// are the full sensor's (width x height); a driver that reads out a region
// of interest or bins pixels (REP 104: roi in full-resolution pixels, then
// binning_x x binning_y blocks, 0 meaning 1) delivers a smaller image, whose
// camera is that K moved by the region's offset and scaled by the binning,
// with each binned pixel at the centre of its block (see the .cpp). The
// distortion acts on normalised coordinates and carries over unchanged.
// `image_size` (optional) gets the size the image must have: the region's
// (the full sensor's without one) divided by the binning, or 0 x 0 where
// camera_info states no size (width 0). False, with `error`, for a K (or P)
// that is not a camera's, an unknown distortion_model (named), a D that does
// not fit its model, such as non-zero coefficients with no model, or a
// region of interest that does not lie on the sensor or leaves no binned
// pixel.
bool CameraFromInfo(const sensor_msgs::CameraInfo& info, bool rectified, CameraIntrinsics* camera,
                    std::string* error, cv::Size* image_size = nullptr);

// Counters of the inputs the pipeline turned away (the averager counts its own).
struct PipelineStats {
  std::uint64_t frames = 0;             // valid images offered to keyframe selection
  std::uint64_t frames_skipped = 0;     // of them, not keyframes (keyframe_selection: motion)
  double selection_s = 0.0;             // wall time of keyframe selection
  std::uint64_t rejected_messages = 0;  // relative poses that failed conversion or validation
  std::uint64_t rejected_images = 0;    // do not decode, bad camera_info, stamp not advancing, ...
  std::uint64_t processed_images = 0;   // keyframes through the front end
  std::uint64_t edges_from_images = 0;  // relative rotations the front end produced
  std::uint64_t absorbed_by_rig = 0;    // measurements within one rig capture (extrinsics known)
};

// How long a SaveMap held what the node's other threads wait for, and how
// long it took in all (the files written after the copies; seconds).
struct MapSaveTiming {
  double graph_lock_s = 0.0;     // the graph and solution copied: solves wait
  double frontend_lock_s = 0.0;  // the keyframes copied: new keyframes wait
  double total_s = 0.0;
};

class KeyframePipeline {
 public:
  explicit KeyframePipeline(const PipelineConfig& config);
  ~KeyframePipeline();

  const PipelineConfig& Config() const { return config_; }
  OnlineAverager& Averager() { return *averager_; }
  bool HasFrontend() const { return frontend_ != nullptr; }
  const KeyframeFrontend* Frontend() const { return frontend_.get(); }

  // The map on disk: the averager's view graph at `graph_path`, beside it
  // the rig model's cameras and captures (RigPath; RigModel::Save) and, with
  // an image front end that has a vocabulary, its keyframe database
  // (KeyframeDatabasePath; KeyframeFrontend::SaveDatabase), each written
  // atomically. `note` (if given) says what was saved or why the database
  // was not.
  bool SaveMap(const std::string& graph_path, std::string* error, std::string* note = nullptr);
  // Of the last SaveMap that succeeded.
  MapSaveTiming LastSaveTiming() const;
  // Loads a map saved by SaveMap: the view graph, the rig model if its file
  // is beside it, and the keyframe database if there is one and the
  // pipeline has an image front end, so that new keyframes relate to the old
  // ones by loop closures. A file that is refused leaves, with the reason in
  // `error`, what is held as it was.
  // `saved_orientations` (if given): the orientations saved with the graph,
  // by keyframe (where the map had them when it was saved).
  bool LoadMap(const std::string& graph_path, std::string* error, std::string* note = nullptr,
               std::map<KeyframeKey, Eigen::Matrix3d>* saved_orientations = nullptr);
  // Adds a map saved by SaveMap (another session's, another robot's) to the
  // one held: its graph (OnlineAverager::AddGraph: keyframes already held
  // are shared history, its others keep its frame until a loop closure
  // joins them to another component), its rig captures and its keyframes,
  // which new keyframes are then retrieved against and verified with. The
  // two maps join where a new keyframe closes loops to both. Keyframes and
  // captures are told apart by frame id and stamp: two robots need distinct
  // camera and rig frame ids. A refused map leaves what is held as it was.
  bool AddMap(const std::string& graph_path, std::string* error, std::string* note = nullptr);

  // Converts, validates and enqueues one relative pose. On failure the
  // message is counted as rejected and `error` says why.
  bool AcceptRelativePose(const RelativePose& msg, std::string* error);

  // Static transforms (rig extrinsics); transforms from the fixed frame (our
  // own keyframe output) are ignored. Cameras are resolved against them when
  // their first keyframe arrives (src/core/controllers/rig_model.h).
  void AcceptStaticTransforms(const tf2_msgs::TFMessage& msg);
  const RigModel& Rig() const { return rig_; }
  // After the averager's Reset().
  void ResetRig() { rig_.Clear(); }

  // Decode and validate a keyframe image (frame id, camera model, size, a
  // stamp that advances per camera); `rectified` says how to read `info`
  // (CameraFromInfo, IsRectifiedTopic). On failure the image is counted as
  // rejected.
  bool DecodeImage(const sensor_msgs::Image& image, const sensor_msgs::CameraInfo& info, PendingKeyframe* out,
                   std::string* error, bool rectified = false);
  bool DecodeCompressedImage(const sensor_msgs::CompressedImage& image, const sensor_msgs::CameraInfo& info,
                             PendingKeyframe* out, std::string* error, bool rectified = false);
  // "cam0: f 458.654, 457.296 px, keypoints undistorted by plumb_bob (...)":
  // how each camera's keypoints are undistorted, once per camera and
  // whenever its model changes (for the node's and the replay's log), one
  // line per camera; empty when nothing is new.
  std::vector<std::string> TakeCameraModelNotices();

  // Keyframe selection (PipelineConfig::keyframe_selection) of one decoded
  // image: the images that become keyframes now (none, this one, and/or
  // the other rig cameras' images of its capture), in stamp order. Called
  // from one thread (the image callbacks') in arrival order.
  std::vector<PendingKeyframe> SelectKeyframes(const PendingKeyframe& image);
  // After the averager's Reset(): the next image of each camera is a keyframe.
  void ResetKeyframeSelection();

  // Runs the front end on one keyframe and enqueues its edges. Not
  // thread-safe with itself (one front-end thread). Returns the edges added;
  // `loop_closure` (optional) tells whether one of them closes a loop.
  std::size_t ProcessKeyframe(const PendingKeyframe& keyframe, bool* loop_closure = nullptr,
                              std::vector<std::string>* warnings = nullptr);

  // The averager solves one variable per rig capture; this expands a
  // solution into one orientation per camera keyframe. Callers expand once
  // per solve and pass the result to the output messages below.
  OnlineSolution CameraSolution(const OnlineSolution& solution) const { return rig_.ToCameraKeyframes(solution); }

  // Output messages for a solution expanded by CameraSolution.
  Orientations OrientationsMsg(const OnlineSolution& cameras, const ros::Time& stamp) const;
  // Each camera's latest focal-length check (~camera_info_checks).
  CameraInfoCheckArray CameraInfoCheckMsg(const ros::Time& stamp) const;
  // all_keyframes: one transform per keyframe, stamped with its capture time.
  tf2_msgs::TFMessage KeyframeTransforms(const OnlineSolution& cameras) const;
  // rviz: camera frusta by solved orientation (namespace "keyframes") and the
  // edges coloured by their robust weight (namespace "edges": green = full
  // weight, red = rejected as an outlier). Lanes and edges come from the
  // averager's `variables`, frusta from their expansion `cameras`.
  visualization_msgs::MarkerArray Markers(const OnlineSolution& variables, const OnlineSolution& cameras,
                                          const ros::Time& stamp) const;
  // latest_per_camera: the newest keyframe of each camera, stamped `now`;
  // a frame whose last transform had a stamp >= now is left out.
  std::vector<geometry_msgs::TransformStamped> LatestTransforms(const OnlineSolution& cameras, const ros::Time& now);
  void ForgetLatestStamps();  // after a reset

  // The latest focal-length check of each camera (focal_calibration), by
  // camera; estimates run on a thread of their own.
  std::map<std::string, CameraFocalCheck> FocalChecks() const;
  // Log lines of the checks since the last call (FocalChecker::TakeNotices),
  // each with whether the camera's focal length disagrees.
  std::vector<std::pair<std::string, bool>> TakeFocalNotices();
  // Waits for the estimates that are due (the replay, before its summary).
  void WaitForFocalChecks();
  // focal_calibration: apply. The product of the corrections applied to
  // each camera's focal length, by camera (cameras never corrected are not
  // listed).
  std::map<std::string, double> FocalCorrections() const;
  // focal_calibration: apply with focal_loop_refinement. Each corrected
  // camera's latest estimate from the loops and what became of it, as its
  // log line says it (cameras the loops have not estimated are not listed).
  std::map<std::string, std::string> FocalLoopRefinements() const;

  PipelineStats Stats() const;
  // The front end's counters as of its latest keyframe; safe to call while
  // another thread runs ProcessKeyframe.
  KeyframeFrontendStats FrontendStats() const;

 private:
  // Reads the graph of a saved map and its rig file, if any (views named as
  // keyframes, a rig file that reads), before any part is used: `rig` is
  // what the rig file holds, applied once the rest has loaded.
  bool CheckMap(const std::string& graph_path, SavedKeyframeGraph* graph, bool* have_rig, RigModel::Saved* rig,
                std::string* error) const;
  bool Validate(const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                const sensor_msgs::CameraInfo& info, bool rectified, PendingKeyframe* out, std::string* error);
  bool Reject(std::uint64_t* counter, const std::string& why, std::string* error);
  bool AddMeasurement(const KeyframeRelativeRotation& m, std::string* error, bool* queue_full = nullptr);
  geometry_msgs::TransformStamped Transform(const ros::Time& stamp, const std::string& child,
                                            const geometry_msgs::Quaternion& camera_to_world) const;

  PipelineConfig config_;
  std::unique_ptr<OnlineAverager> averager_;
  std::unique_ptr<KeyframeFrontend> frontend_;
  std::unique_ptr<FocalChecker> focal_checker_;  // with a front end and focal_calibration: warn or apply
  // focal_calibration: apply. Corrects the cameras whose latest check
  // disagrees; the re-estimated edges replace the old ones in the graph.
  // Called by ProcessKeyframe before its keyframe, on the front end's thread.
  void ApplyFocalCorrections(std::vector<std::string>* warnings);
  // A notice that the camera's correction is held back, unless the last one
  // gave the same reason.
  void HoldBackCorrection(const std::string& camera, const std::string& reason);
  // focal_calibration: apply with focal_loop_refinement. The corrected
  // cameras' focal lengths estimated together from the loops of the graph
  // (core/estimators/loop_calibration.h), each pair's derivative from the
  // front end (KeyframeFrontend::FocalSensitivities), the focal check's
  // estimate as the prior; applied as a correction when the loops know the
  // focal length at least twice as precisely as the check, agree with it
  // (within 3 of its standard deviations) and move it by more than their
  // own deviation; the pairs' edges then move by their derivatives
  // (ApplyFocalCorrection, linearised). Runs when the front end's loop
  // closures have grown by a tenth since it last ran (or since a
  // correction): at a cost that grows with the log of their number, and
  // for as long as the camera's pairs are held (max_correction_pairs).
  // Called by ProcessKeyframe after ApplyFocalCorrections.
  void RefineFocalByLoops();
  std::uint64_t loops_at_refinement_ = 0;
  // Per corrected camera: the focal length in use, px, and the latest focal
  // check's estimate of it with its deviation, px (the loops' prior).
  std::map<std::string, double> focal_in_use_px_;
  std::map<std::string, std::pair<double, double>> focal_prior_px_;
  std::map<std::string, std::pair<double, std::uint64_t>> applied_checks_;  // camera -> (given px, pairs) applied
  std::set<std::string> corrections_refused_;
  // The reason a camera's correction was last held back: each new estimate
  // that is held back for the same reason says nothing new.
  std::map<std::string, std::string> held_back_;
  std::vector<std::pair<std::string, bool>> correction_notices_;  // under mutex_
  std::map<std::string, double> focal_corrections_;  // under mutex_
  std::map<std::string, std::string> focal_loop_refinements_;  // under mutex_
  // Held while the front end adds a keyframe, and while its database is
  // saved or loaded (the node saves from a timer thread).
  std::mutex frontend_mutex_;
  // One save at a time: the autosave timer and ~save_graph may both save to
  // the same path, and its files are written through the same temporaries.
  std::mutex save_mutex_;
  RigModel rig_;
  std::mutex selector_mutex_;
  KeyframeSelector selector_;
  mutable std::mutex mutex_;  // stats_, frontend_stats_, last_save_timing_, last_image_stamp_, last_latest_stamp_
  PipelineStats stats_;
  KeyframeFrontendStats frontend_stats_;
  MapSaveTiming last_save_timing_;  // under mutex_
  std::map<std::string, std::int64_t> last_image_stamp_;
  std::map<std::string, ros::Time> last_latest_stamp_;
  std::map<std::string, std::string> camera_models_;  // frame -> description of its model
  std::vector<std::string> camera_model_notices_;
};

// The vocabulary the build trains (target `vocabulary`, run by
// scripts/setup.sh) in the package's share folder of the devel space.
std::string DefaultVocabularyPath();

// Where SaveMap puts the keyframe database of the graph at `graph_path`:
// beside it, with ".keyframes" appended.
std::string KeyframeDatabasePath(const std::string& graph_path);
// Where SaveMap puts the rig model (RigModel::Save): ".rig" appended.
std::string RigPath(const std::string& graph_path);

// "{frame_id}" and "{stamp_ns}" in a frame name pattern.
std::string KeyframeFrameName(const std::string& format, const KeyframeKey& key);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_ROS_KEYFRAME_PIPELINE_H_
