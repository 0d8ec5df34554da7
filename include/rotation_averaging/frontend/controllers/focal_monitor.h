// Online check of each camera's focal length against the pairs the keyframe
// front end verifies: the offline estimator (EstimateFocalScale, with its
// principal-point part of the deviation) run on a camera's own verified
// essential-matrix pairs (sequential and loop-closure pairs of one camera;
// rig pairs mix two cameras' intrinsics) as they accumulate; for a camera
// whose intrinsics have no distortion model, also a radial distortion they
// do not describe (EstimateRadialDistortion).
//
// FocalMonitor collects the pairs and says when an estimate is due: when a
// camera's count of pairs reaches first_estimate_pairs, then each time it
// has grown by `growth`. An estimate is a function of the pairs held at
// that count alone, so the live node and the replay of the same bag report
// the same estimates; only when they arrive differs. FocalChecker runs them
// on a thread of its own: an estimate costs seconds (results/frontend.md,
// "Focal self-calibration"), which the keyframe front end must not wait for.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_MONITOR_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_MONITOR_H_

#include <Eigen/Core>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {

struct FocalMonitorOptions {
  bool enabled = false;
  // The estimator's options (its `enabled` is not read): a camera's focal
  // length disagrees with its images when the estimate is further from 1
  // than focal.min_correction and than 3 of its standard deviations, the
  // rule `rotavg images` applies a correction by (ShouldApplyFocalScale).
  FocalCalibrationOptions focal;
  // The first estimate of a camera when it has this many verified pairs
  // (fewer leave its deviation too wide to judge a calibration a few
  // percent off), then each time its count has grown by `growth`: the cost
  // of all estimates stays a few times that of the last one.
  int first_estimate_pairs = 20;
  double growth = 2.0;
  // Pairs held per camera (their matches: tens of KiB each). When a camera
  // has more, every other one is let go: the pairs held stay spread evenly
  // over the whole sequence.
  int max_pairs = 60;
  // Matches kept per pair (every n-th of them, outliers included: the
  // estimator selects the inliers again at each focal length). Its cost
  // grows with the matches, its precision hardly beyond a few hundred per
  // pair, at sub-pixel noise.
  int max_matches_per_pair = 200;
  // focal_calibration: apply. To estimate a camera's pairs again with a
  // corrected focal length, the front end holds every pair of it that gave
  // an edge, with all its matches (tens of KiB each), up to this many per
  // camera. A camera found out after that is reported, not corrected.
  bool hold_for_correction = false;
  int max_correction_pairs = 1000;

  // True if every field is within its range; otherwise false, with `error`
  // naming the first field that is not.
  bool Validate(std::string* error) const;
};

// One verified pair of a camera: its matched keypoints (undistorted pixels
// of the images the features come from) and the pose estimated from them.
struct FocalSample {
  std::vector<Eigen::Vector2d> points1, points2;
  RelativePoseResult pose;
};

// The sample of one verified pair: at most `max_matches` of its matches,
// evenly spread over them, with the pose's inliers among them.
std::shared_ptr<const FocalSample> MakeFocalSample(const std::vector<Eigen::Vector2d>& points1,
                                                   const std::vector<Eigen::Vector2d>& points2,
                                                   const RelativePoseResult& pose, int max_matches);

// What is needed to estimate one camera's focal length: a copy of the pairs
// held when it was due.
struct FocalJob {
  std::string camera;
  // The camera's intrinsics have no lens distortion: the pairs are also
  // checked for a radial distortion they do not describe.
  bool check_distortion = false;
  // The camera's distortion model, which the keypoints were undistorted
  // with (none: they are the raw ones); its own k is not used.
  CameraIntrinsics lens;
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();  // of the features' images
  double given_focal_px = 0.0;                      // fx of the camera's own K (full resolution)
  std::uint64_t pairs_seen = 0;                     // verified pairs of the camera so far
  std::vector<std::shared_ptr<const FocalSample>> samples;
};

// The latest estimate of one camera.
struct CameraFocalCheck {
  std::string camera;
  double given_focal_px = 0.0;
  std::uint64_t pairs_seen = 0;
  FocalCalibration calibration;  // scale: estimated / given focal length
  bool disagrees = false;        // see FocalMonitorOptions::focal
  // A camera without a distortion model (FocalJob::check_distortion): the
  // radial distortion its pairs show, and whether it is beyond what the
  // pixels' noise explains (DistortionIsUnmodelled): raw images whose
  // camera_info gives no distortion model, or rectified images that are not.
  bool distortion_checked = false;
  RadialDistortion distortion;
  bool distortion_unmodelled = false;
  // Beyond the noise, but explained as well by the focal length alone
  // (RadialDistortion::FocalExplainsAsWell): not flagged.
  bool distortion_explained_by_focal = false;
  bool Flagged() const { return disagrees || distortion_unmodelled; }
  // "cam0: focal length x1.031 +- 0.004 of camera_info's 458.7 px (62 of
  // 80 pairs): disagrees, check the calibration".
  std::string Report() const;
};

CameraFocalCheck RunFocalJob(const FocalJob& job, const FocalCalibrationOptions& options);

class FocalMonitor {
 public:
  explicit FocalMonitor(const FocalMonitorOptions& options) : options_(options) {}
  // A verified pair of `camera` whose features' images have the pinhole
  // matrix k, their keypoints undistorted by `lens`'s distortion model (or
  // none; its k is not used). A camera whose k or model changes (a new
  // camera_info) starts again.
  void Add(const std::string& camera, const Eigen::Matrix3d& k, double given_focal_px, CameraIntrinsics lens,
           std::shared_ptr<const FocalSample> sample);
  // The estimates that fell due since the last call, in the order they did.
  std::vector<FocalJob> TakeDue();
  std::size_t HeldPairs(const std::string& camera) const;
  std::size_t HeldBytes() const;  // of every camera's pairs
  double GivenFocal(const std::string& camera) const;  // 0 before its first pair
  // The distortion model of the camera's pairs (none before its first).
  CameraIntrinsics Lens(const std::string& camera) const;

 private:
  struct Camera {
    Eigen::Matrix3d k = Eigen::Matrix3d::Identity();
    double given_focal_px = 0.0;
    CameraIntrinsics lens;
    std::uint64_t seen = 0, next_estimate = 0;
    std::vector<std::shared_ptr<const FocalSample>> held;
  };
  FocalMonitorOptions options_;
  std::map<std::string, Camera> cameras_;
  std::vector<FocalJob> due_;
};

// Runs FocalJobs on a thread of its own, one at a time in the order given.
// A camera's job still waiting when a newer one of it arrives is replaced:
// a node whose cameras outrun the estimates skips estimates, never the
// newest.
class FocalChecker {
 public:
  explicit FocalChecker(const FocalCalibrationOptions& options);
  ~FocalChecker();
  void Submit(std::vector<FocalJob> jobs);
  // The latest estimate of each camera, by camera.
  std::map<std::string, CameraFocalCheck> Checks() const;
  // For the log, since the last call: one line per camera whose focal
  // length was determined for the first time or whose verdict changed (its
  // focal length came to disagree or no longer does; a distortion came to be
  // seen or no longer is), with its Flagged().
  std::vector<std::pair<std::string, bool>> TakeNotices();
  // Waits until every job submitted so far has run (the replay, at its end).
  void Wait();
  // The camera's focal length is now `given_focal_px` (a correction was
  // applied): its check from the former one is dropped, and so are results
  // of jobs still running on it.
  void ExpectFocal(const std::string& camera, double given_focal_px);
  // Wall time of each estimate that ran (one camera's focal length and lens
  // check, on the checker's thread): part of the node's time budget.
  TimeDistribution EstimateTimes() const;

 private:
  void Run();
  FocalCalibrationOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable wake_, idle_;
  std::deque<FocalJob> queue_;
  bool running_job_ = false, stopping_ = false;
  std::map<std::string, CameraFocalCheck> checks_;
  std::map<std::string, double> expected_focal_px_;  // ExpectFocal
  std::vector<std::pair<std::string, bool>> notices_;
  TimeDistribution estimate_times_;
  std::thread worker_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_FOCAL_MONITOR_H_
