// What the live node and the bag replay tool share: messages turned into
// validated keyframes and relative rotations, keyframe selection, the
// keyframe front end into the averager, focal calibration, the map on disk
// and the output messages. It orchestrates: each of those is a unit of its
// own (pipeline_config, image_conversion, msg_conversion, output_messages
// here; the front end's focal_corrector and map_store), and this class wires
// them to one averager, one rig model and one front end, with the locks
// between the node's threads (docs/architecture.md). The node adds
// subscriptions, threads and publishers around it; the replay tool adds a
// bag reader and a bag-time solve schedule.
#ifndef ROTATION_AVERAGING_ROS_KEYFRAME_PIPELINE_H_
#define ROTATION_AVERAGING_ROS_KEYFRAME_PIPELINE_H_

#include <geometry_msgs/TransformStamped.h>
#include <ros/time.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>
#include <visualization_msgs/MarkerArray.h>

#include <functional>
#include <limits>
#include <map>
#include <memory>
#include <mutex>
#include <opencv2/core.hpp>
#include <set>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/frontend/controllers/focal_corrector.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"
#include "rotation_averaging/frontend/controllers/keyframe_selector.h"
#include "rotation_averaging/frontend/controllers/map_store.h"
#include "rotation_averaging/ros/image_conversion.h"
#include "rotation_averaging/ros/output_messages.h"
#include "rotation_averaging/ros/pipeline_config.h"
#include "rotation_averaging/util/stream_gaps.h"
#include "rotation_averaging/util/time_distribution.h"
#include "rotation_averaging/CameraInfoCheckArray.h"
#include "rotation_averaging/Orientations.h"
#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

// A decoded, validated keyframe image waiting for the front end.
struct PendingKeyframe {
  KeyframeKey key;
  cv::Mat image;  // 8-bit grey, as the camera took it
  CameraIntrinsics camera;  // of that image: K and its lens distortion
  std::vector<TrackedPoint> tracks;  // `tracks`: the camera's KLT tracks in it (keyframe selection's)
  double decode_s = 0.0;    // wall time of its decoding and checks (DecodeImage)
};

// Counters of the inputs the pipeline turned away (the averager counts its own).
struct PipelineStats {
  std::uint64_t frames = 0;             // valid images offered to keyframe selection
  std::uint64_t frames_skipped = 0;     // of them, not keyframes (keyframe_selection: motion)
  // Images that never came, by the gaps in each camera's stamps (StreamGaps):
  // lost by the driver, the recording, or a subscriber queue that overflowed.
  std::uint64_t frames_missing = 0;
  KeyframeSelectionStats selection;     // keyframe_selection: motion (why each keyframe was made)
  double selection_s = 0.0;             // wall time of keyframe selection
  // The time budget: each valid image's decoding, checks and keyframe
  // selection (what its callback costs), and each keyframe's front end
  // (ProcessKeyframe: focal corrections, features, retrieval, pairs, edges).
  TimeDistribution image_times, keyframe_times;
  std::uint64_t rejected_messages = 0;  // relative poses that failed conversion or validation
  std::uint64_t rejected_images = 0;    // do not decode, bad camera_info, stamp not advancing, ...
  std::uint64_t processed_images = 0;   // keyframes through the front end
  std::uint64_t edges_from_images = 0;  // relative rotations the front end produced
  std::uint64_t absorbed_by_rig = 0;    // measurements within one rig capture (extrinsics known)
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
  // their first keyframe arrives (core/controllers/rig_model.h).
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
  // PipelineStats::frames_missing, without copying the rest of the stats.
  std::uint64_t FramesMissing() const;

  // Runs the front end on one keyframe and enqueues its edges. Not
  // thread-safe with itself (one front-end thread). Returns the edges added;
  // `loop_closure` (optional) tells whether one of them closes a loop.
  std::size_t ProcessKeyframe(const PendingKeyframe& keyframe, bool* loop_closure = nullptr,
                              std::vector<std::string>* warnings = nullptr);
  // focal_calibration: apply. The corrections that are due (the
  // refinement's estimates, the focal checks', the loops'), with their
  // pairs estimated again into the graph; ProcessKeyframe runs it before
  // each keyframe, and a caller whose input has ended (the replay, after
  // its final refinement) can run it on the same thread. True if a
  // camera's focal length changed.
  bool ApplyFocalCorrections(std::vector<std::string>* warnings = nullptr);

  // The averager solves one variable per rig capture; this expands a
  // solution into one orientation per camera keyframe. Callers expand once
  // per solve and pass the result to the output messages below.
  // With the background refinement's corrections applied (PipelineConfig::
  // refinement) unless `refined` is false.
  OnlineSolution CameraSolution(const OnlineSolution& solution, bool refined = true) const;

  // The background refinement (KeyframeRefiner), with an image front end
  // and `refinement` on. MaybeRefine starts one on `solution` (the
  // averager's) when refinement_period_s has passed since the last start at
  // `now_s` (the node's wall time, the replay's bag time) or `force`:
  //  - kBackground (the node): on a thread of its own, then `done`; what it
  //    finds is taken when it ends. None starts while one is under way.
  //  - kStaged (the replay): on a thread of its own, what it finds taken
  //    only when the next one is due, or at CommitRefinement. The previous
  //    one is waited for then: the same refinements land at the same bag
  //    times on every run, and the front end goes on meanwhile.
  //  - kHere: in the calling thread.
  // True if one ran or started.
  enum class RefineIn { kBackground, kStaged, kHere };
  bool HasRefiner() const { return refiner_ != nullptr; }
  bool RefinerRunning() const { return refiner_ && refiner_->Running(); }
  bool MaybeRefine(const OnlineSolution& solution, double now_s, bool force, RefineIn where,
                   std::function<void(bool)> done = nullptr);
  // The keyframes a refinement of `solution` would still adjust
  // (KeyframeRefiner::Pending): the node, once its input is quiet, and the
  // replay at the bag's end refine the final solution until none is left.
  std::size_t RefinementPending(const OnlineSolution& solution) const;
  // Waits for a staged refinement and takes what it found.
  void CommitRefinement();
  void WaitForRefinement();
  KeyframeRefinerStats RefinerStats() const;
  // After the averager's Reset(): the corrections and correspondences held go.
  void ResetRefinement();

  // Output messages for a solution expanded by CameraSolution (OutputMessages).
  Orientations OrientationsMsg(const OnlineSolution& cameras, const ros::Time& stamp) const {
    return output_.OrientationsMsg(cameras, stamp);
  }
  tf2_msgs::TFMessage KeyframeTransforms(const OnlineSolution& cameras) const {
    return output_.KeyframeTransforms(cameras);
  }
  visualization_msgs::MarkerArray Markers(const OnlineSolution& variables, const OnlineSolution& cameras,
                                          const ros::Time& stamp) const {
    return output_.Markers(variables, cameras, rig_, stamp);
  }
  std::vector<geometry_msgs::TransformStamped> LatestTransforms(const OnlineSolution& cameras, const ros::Time& now) {
    return output_.LatestTransforms(cameras, now);
  }
  void ForgetLatestStamps() { output_.ForgetLatestStamps(); }  // after a reset
  // Each camera's latest focal-length check (~camera_info_checks).
  CameraInfoCheckArray CameraInfoCheckMsg(const ros::Time& stamp) const;

  // The latest focal-length check of each camera (focal_calibration), by
  // camera; estimates run on a thread of their own.
  std::map<std::string, CameraFocalCheck> FocalChecks() const;
  // Wall time of each focal-length estimate that ran (FocalChecker); empty
  // without the check.
  TimeDistribution FocalCheckTimes() const;
  // Log lines of the checks and corrections since the last call
  // (FocalChecker::TakeNotices, FocalCorrector::TakeNotices), each with
  // whether it is a warning; with refinement_focal, what the refinement's
  // estimate says of each camera's focal length, each time that changes
  // (JudgeFocalEstimate: a warning when it disagrees).
  std::vector<std::pair<std::string, bool>> TakeFocalNotices();
  // Waits for the estimates that are due (the replay, before its summary).
  void WaitForFocalChecks();
  // focal_calibration: apply. The product of the corrections applied to
  // each camera's focal length, by camera (cameras never corrected are not
  // listed).
  std::map<std::string, double> FocalCorrections() const;
  // focal_calibration: apply. The lens given to each camera whose
  // camera_info describes none (its check's division model), by camera.
  std::map<std::string, RadialDistortion> LensCorrections() const;
  // focal_calibration: apply with focal_loop_refinement. Each corrected
  // camera's latest estimate from the loops and what became of it, as its
  // log line says it (cameras the loops have not estimated are not listed).
  std::map<std::string, std::string> FocalLoopRefinements() const;

  PipelineStats Stats() const;
  // The front end's counters as of its latest keyframe; safe to call while
  // another thread runs ProcessKeyframe.
  KeyframeFrontendStats FrontendStats() const;

 private:
  bool Validate(const std::string& frame, const ros::Time& stamp, const cv::Mat& grey,
                const sensor_msgs::CameraInfo& info, bool rectified, PendingKeyframe* out, std::string* error);
  bool Reject(std::uint64_t* counter, const std::string& why, std::string* error);
  // The rig captures of a camera solution, as the refiner takes them.
  KeyframeRefiner::RigCaptures RefinerRig(const OnlineSolution& cameras) const;
  // Into the averager through the rig model (one variable per rig capture).
  bool AddMeasurement(const KeyframeRelativeRotation& m, std::string* error, bool* queue_full = nullptr);

  PipelineConfig config_;
  std::unique_ptr<OnlineAverager> averager_;
  std::unique_ptr<KeyframeFrontend> frontend_;
  std::unique_ptr<FocalChecker> focal_checker_;      // with a front end and focal_calibration: warn or apply
  std::unique_ptr<FocalCorrector> focal_corrector_;  // with a front end and focal_calibration: apply
  std::unique_ptr<MapStore> map_store_;
  std::unique_ptr<KeyframeRefiner> refiner_;  // with a front end and `refinement`
  std::mutex refine_mutex_;  // last_refine_s_
  double last_refine_s_ = std::numeric_limits<double>::quiet_NaN();  // the last start (NaN: before the first solve)
  OutputMessages output_;
  // Held while the front end adds a keyframe, and while its database is
  // saved or loaded (the node saves from a timer thread).
  std::mutex frontend_mutex_;
  RigModel rig_;
  std::mutex selector_mutex_;
  KeyframeSelector selector_;
  StreamGaps stream_gaps_;  // under mutex_
  mutable std::mutex mutex_;  // stats_, frontend_stats_, last_image_stamp_, camera_models_, camera_model_notices_
  PipelineStats stats_;
  KeyframeFrontendStats frontend_stats_;
  std::map<std::string, std::int64_t> last_image_stamp_;
  std::map<std::string, std::string> camera_models_;  // frame -> description of its model
  std::vector<std::string> camera_model_notices_;
  // The refinement's focal verdicts said so far, and the refinement they
  // are of (TakeFocalNotices).
  std::map<std::string, FocalVerdict> refinement_focal_verdicts_;
  std::uint64_t refinement_focal_seen_ = 0;
};
}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_KEYFRAME_PIPELINE_H_
