// Public header of rotation_averaging::frontend (docs/embedding.md).
// The live map's refinement: the bundle adjustment that `rotavg images` runs
// after the averaging (frontend/estimators/bundle_adjustment.h), run over the
// newest keyframes of a running map, free of ROS.
//
// The averaging sees each pair through its two-view summary; what every pair
// of one view shares (its keypoints' common error, a view tied to the others
// by wrong matches that fit their own pair) it cannot see. The adjustment
// ties each view's points to every view that sees them, and offline it takes
// the averaging's error down on most scenes (results/frontend.md). Here the
// front end hands over each edge's inlier correspondences as it makes the
// edge; a refinement takes one averaging solution, adjusts its newest
// `max_keyframes` keyframes on the edges among them, and keeps, per
// keyframe, the correction it found:
//
//   C_i = R_adjusted_i G R_averaged_i^T
//
// with G one rotation per camera in each group of keyframes the edges
// connect, fitted robustly so that each camera's keyframes keep the
// averaging's frame: the adjustment holds one view of each group where it
// was, which would turn the whole group by that one view's error, and it
// relates two cameras only through the few tracks both see, so how the
// cameras sit relative to each other stays the averaging's (the cameras of
// a rig with known extrinsics turn together in the adjustment, and count as
// one camera here). Later solutions are published with the
// corrections applied, R_i = C_i R_averaged_i: a correction is the
// keyframe's own error, in its camera's frame, which the averaging's later
// changes (a loop closure moving a whole stretch) do not undo. Keyframes
// newer than the last refinement are published as the averaging has them;
// those that left the window keep their last correction, fitted against
// the averaging of its day, until a refinement of a solution already
// refined (the input gone quiet, the end of a bag) sweeps back over them
// (sweep_back).
//
// A window shorter than the map (a long run) is an open arc, its loop
// closures to the places seen before it outside it: adjusted alone it bends
// along its length, and the rotation G fitted to its keyframes turns it, as
// a whole, to an averaging that drifts until its loops close, so that its
// corrections hold that day's error. With `hold_outside` the older
// keyframes its edges reach join the adjustment with their orientations held
// as the averaging has them (held as published, with the corrections of
// earlier windows, the long runs came out less accurate: docs/decisions.md,
// "The keyframes before the window are held"), and hold the frame of each
// camera (each rig) they belong to in place of G.
//
// The published posterior covariances of the corrected keyframes come from
// the adjustment too (KeyframeRefinerOptions::covariances): the averaging's
// describe its own orientations, which the corrections have moved. Each
// keyframe keeps the adjustment's covariance relative to one reference
// keyframe of its window (the one the averaging holds best: its gauge
// keyframe when that is in the window), and Apply adds the reference's own,
// the averaging's of the solution it is applied to:
//
//   C_k = C_adjusted(k | r) + R_kr C_averaged(r) R_kr^T,  R_kr = R_k R_r^T,
//
// so that it is relative to the component's gauge keyframe, as published.
//
// A keyframe that a refinement moves further than `max_correction_deg` (a
// divergence, not a refinement of a good averaging) keeps what it had; a
// refinement that fails, or that moves more than a quarter of its keyframes
// that far, changes nothing: the corrections before it stay, and the
// summary says why.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_REFINER_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_REFINER_H_

#include <Eigen/Core>
#include <atomic>
#include <cstdint>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"
#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {

// The inlier correspondences of one edge between two keyframes (view1 and
// view2 of `points` are not used: the keyframes say which views).
struct KeyframeCorrespondences {
  KeyframeKey keyframe1, keyframe2;
  EdgeCorrespondences points;
};

struct KeyframeRefinerOptions {
  // The newest keyframes (by capture stamp) a refinement adjusts, with the
  // edges among them; the correspondences of edges whose keyframes have
  // both left it are let go. Bounds a refinement's time and the memory.
  int max_keyframes = 200;
  // A keyframe the refinement moves further than this from the averaging
  // keeps what it had (the bundle adjustment refines a good averaging and
  // cannot repair a bad one); with more than a quarter of them the
  // refinement changes nothing.
  double max_correction_deg = 1.0;
  // RefineInBackground's thread runs this much nicer than the thread that
  // starts it (Linux; 0: as nice, at most 19): the refinement takes the CPU
  // that the camera-rate work leaves, so that on a loaded machine it is the
  // refinement that waits, not the images (an image callback held up for
  // longer than its subscriber queue holds loses frames).
  int background_niceness = 10;
  // The corrected keyframes' posterior covariances from the adjustment (see
  // above); false: the averaging's stay, though they describe the
  // averaging's orientations.
  bool covariances = true;
  // The covariances of a rig's keyframes (RigCaptures) from the problem the
  // rig makes, every camera's tracks holding each capture
  // (BundleAdjustmentRig::joint_covariance); false: from each camera's own
  // tracks, at the rig's solution, relative to its own camera's view of the
  // reference capture, a capture's cameras that of the camera its tracks
  // hold best. Those of the joint problem describe independent pixel noise
  // (mean NEES 2.9 on a simulated two-camera rig, bundle_adjustment_test),
  // but on the rendered two-camera rig's 20 Hz stream the errors are two to
  // three times their deviations (NEES median 7.0, 57% of keyframes within
  // chi-square's 95% bound; 4.8 and 88% on the demo bag), with each
  // camera's own 3.1 and 2.1 (98% and 100%; results/posterior.md, "A rig's
  // covariances"): an error neither the residuals nor the
  // jackknives show. A filter that trusts a covariance too much
  // diverges; one too wide only weighs it less.
  bool rig_joint_covariance = false;
  // Each camera's focal length estimated in the adjustment with its
  // deviation (BundleAdjustmentFocal; Stats().focal), relative to the focal
  // length in use: what the focal check's pairs alone cannot pin (a
  // camera's tracks over many keyframes, every view tied by its points).
  // The corrected orientations are those of that adjustment.
  bool estimate_focal = true;
  // With estimate_focal: a camera whose focal length a refinement found to
  // agree with the one in use (JudgeFocalEstimate with
  // focal_min_correction: within its deviation, known to that) keeps the
  // one in use in the later refinements, until a correction (ScaleCamera)
  // frees it again. The averaging's pairs are estimated with the focal
  // length in use: an adjustment that takes its own (within its deviation,
  // never exactly it) turns its orientations against theirs by that error
  // times the angle the window turns through. On the rendered rig, whose
  // camera_info is exact, the free adjustments put it at x0.9999-1.0003;
  // held once it agrees, the median error of the four-camera stream went
  // 0.0022 -> 0.0020 deg, the others within 0.0001 deg (results/
  // refinement.md, "A focal length that agrees").
  bool hold_agreed_focal = true;
  // The older keyframes the window's edges reach (the pairs of its first
  // keyframes, its loop closures) take part in each refinement, held as the
  // averaging has them (see above); false: the window alone, turned to the
  // averaging's frame by G. On a 600-keyframe bag (two cameras, every image
  // a keyframe, a window of 200) the median error went 0.0065 -> 0.0036 deg
  // (the averaging alone: 0.0055), on the four-camera 20 Hz stream (316
  // keyframes) 0.0031 -> 0.0020 deg, both swept back (sweep_back); runs
  // within one window are unchanged (results/refinement.md, "The keyframes
  // before the window, and the sweep back").
  bool hold_outside = true;
  // A refinement of a solution that an earlier one has already refined
  // (the input gone quiet, the end of a bag: KeyframeRefiner::Pending)
  // sweeps back over the keyframes the earlier windows had no room for, a
  // window of the newest of them at a time, the keyframes adjusted in this
  // solution held as published; false: it adjusts the newest again. While
  // the input flows each window's corrections are fitted against the
  // averaging of its day, before the loops that close later: a keyframe
  // that leaves the window keeps that day's error plus the averaging's
  // move since. On the 600-keyframe bag the median error went 0.0052 ->
  // 0.0036 deg, on the four-camera 20 Hz stream 0.0026 -> 0.0020 deg,
  // maps within one window unchanged (results/refinement.md, "The keyframes
  // before the window, and the sweep back"). Its edges are held for it
  // (max_correspondence_mib).
  bool sweep_back = true;
  // With sweep_back, the correspondences held (KeyframeRefinerStats::bytes)
  // are let go beyond this many MiB, the edges whose newer keyframe is the
  // oldest first: the keyframes they leave without edges keep their last
  // correction. Without it the edges of keyframes older than the window go
  // after each refinement.
  double max_correspondence_mib = 128.0;
  double focal_min_correction = 0.005;  // FocalCalibrationOptions::min_correction (the node passes its own)
  // The bundle adjustment's options; the refinement's own defaults in the
  // constructor.
  BundleAdjustmentOptions adjustment;
  KeyframeRefinerOptions();

  bool Validate(std::string* error) const;
};

struct KeyframeRefinerStats {
  // applied: also the sequence number of the latest applied refinement
  // (OnlineSolution::refinement_sequence; 0: none).
  std::uint64_t runs = 0, applied = 0, failed = 0;
  std::uint64_t solution_sequence = 0;   // the averaging solution it refined
  std::size_t corrected_keyframes = 0;   // keyframes with a correction
  std::size_t covariance_keyframes = 0;  // of them, with the adjustment's covariance
  std::size_t edges_held = 0;            // edges whose correspondences are held
  std::size_t bytes = 0;                 // their memory
  double median_correction_deg = 0.0;    // of the latest applied refinement
  double max_correction_deg = 0.0;
  std::size_t held_back = 0;             // of its keyframes, moved beyond max_correction_deg: not corrected
  // The focal length estimates of the latest refinement whose adjustment
  // succeeded (its corrections may have been held back), by camera,
  // relative to the focal length in use now (ScaleCamera since divides
  // them), and that refinement's number (`runs` then).
  std::map<std::string, BundleAdjustmentFocal::Estimate> focal;
  std::uint64_t focal_refinement = 0;
  // hold_agreed_focal: the cameras whose focal length later refinements
  // hold, their estimate having agreed with the one in use.
  std::set<std::string> focal_agreed;
  TimeDistribution times;                // wall time of each refinement
  std::string last_report;               // the adjustment's summary, or why it changed nothing
  int last_iterations = 0;               // the latest adjustment's Ceres iterations, all stages
  bool last_ok = false;
};

class KeyframeRefiner {
 public:
  explicit KeyframeRefiner(const KeyframeRefinerOptions& options);
  ~KeyframeRefiner();  // waits for a refinement under way
  KeyframeRefiner(const KeyframeRefiner&) = delete;
  KeyframeRefiner& operator=(const KeyframeRefiner&) = delete;

  // The correspondences of new edges; an edge between the same two
  // keyframes replaces the one held. Edges with too few correspondences or
  // numbers that are not finite are not held.
  void Add(std::vector<KeyframeCorrespondences> edges);
  // A camera's focal length was multiplied by `scale`: its keyframes'
  // normalised points are divided by it (the principal point stays), and so
  // is its focal estimate (Stats().focal), also that of a refinement under
  // way when it lands.
  void ScaleCamera(const std::string& frame_id, double scale);
  // The camera's focal length is held in the adjustment (estimate_focal):
  // a camera whose lens keeps its points from scaling with the focal
  // length (FocalScalingError). Its points were undistorted with the focal
  // length in use and the distortion acts on the coordinates K gives, so
  // the adjustment's model of a focal length error, a scale of the points,
  // would bias the estimate (the rendered rig through a plumb_bob lens,
  // camera_info 3% short: x1.0049 and x1.0001 against a true x1.0309;
  // docs/decisions.md). The focal check, which undistorts its pairs again
  // for every focal length it tries, estimates such a camera's.
  void HoldFocal(const std::string& frame_id);

  // Camera keyframes of a rig with known extrinsics: the capture (the
  // averaging's variable) each belongs to and its camera_from_rig rotation
  // E (R_camera = E R_rig).
  using RigCaptures = std::map<KeyframeKey, std::pair<KeyframeKey, Eigen::Matrix3d>>;
  // Refines `cameras` (an averaging solution, one orientation per camera
  // keyframe) in the calling thread; true if its corrections were taken.
  // The cameras of one capture of `rig` turn together in the adjustment
  // (BundleAdjustmentRig), as the averaging holds them: one orientation,
  // seen by every camera's tracks; they get one correction.
  bool Refine(const OnlineSolution& cameras, const RigCaptures& rig = {});
  // The same on a thread of its own, then `done` (from that thread). False,
  // and nothing started, while one is under way. With `staged`, what it
  // finds (corrections, counters, the edges let go) waits for Commit:
  // a caller that must publish the same on every run (the replay) decides
  // when it lands, and not the clock when the thread ends.
  bool RefineInBackground(std::shared_ptr<const OnlineSolution> cameras, RigCaptures rig,
                          std::function<void(bool)> done, bool staged = false);
  bool Running() const { return running_; }
  // With sweep_back: the keyframes with edges that no window has adjusted
  // in this averaging solution with the edges they have now, which a
  // refinement of it would sweep back over (the node refines the solution
  // it publishes, once its input is quiet, until none is left; 0 without
  // sweep_back).
  std::size_t Pending(const OnlineSolution& cameras, const RigCaptures& rig = {}) const;
  // Waits for a background refinement under way; from the thread that
  // starts them.
  void Wait();
  // Waits for a staged refinement and takes what it found; true if it
  // changed the corrections. Nothing staged: false.
  bool Commit();

  // Lets go of the correspondences and corrections held (the counters stay).
  void Reset();

  // The corrections held, by keyframe: what a saved map keeps of the
  // refinement (the correspondences are not saved: keyframes of an earlier
  // session keep their corrections, and are not adjusted again).
  std::map<KeyframeKey, Eigen::Matrix3d> Corrections() const;
  // Takes corrections (a saved map's): in place of those held with
  // `replace`, else beside them (a keyframe held keeps its own).
  void SetCorrections(const std::map<KeyframeKey, Eigen::Matrix3d>& corrections, bool replace);
  // The corrections in a text file of the package's kind (a header, one
  // line per keyframe "CORRECTION frame_id stamp_ns qw qx qy qz", an END
  // record with the line count and a checksum), written atomically.
  bool SaveCorrections(const std::string& path, std::string* error) const;
  // Reads such a file; a file of another kind, cut short, changed, with a
  // quaternion that is not a unit one or a keyframe twice is refused with
  // the reason ("path:line: ...").
  static bool ReadCorrections(const std::string& path, std::map<KeyframeKey, Eigen::Matrix3d>* corrections,
                              std::string* error);
  // `cameras` with the corrections held applied; its refinement_sequence
  // set to the latest applied refinement's; the corrected keyframes'
  // covariances from the adjustment where `cameras` has a covariance for
  // their reference keyframe in their component.
  void Apply(OnlineSolution* cameras) const;
  KeyframeRefinerStats Stats() const;

 private:
  struct HeldEdge {
    KeyframeKey keyframe1, keyframe2;
    // Never changed once held (ScaleCamera replaces it): a refinement's
    // input shares it, and the refinement's thread copies it.
    std::shared_ptr<const EdgeCorrespondences> points;
  };
  // A corrected keyframe's covariance relative to its reference keyframe.
  struct RelativeCovariance {
    KeyframeKey reference;
    Eigen::Matrix3d covariance;
  };
  // What one refinement starts from, taken under mutex_ in the thread that
  // starts it: a focal correction, a pair estimated again or a camera held
  // after that belong to the next refinement, whenever this one's thread
  // gets to run.
  struct Input {
    std::vector<std::shared_ptr<const EdgeCorrespondences>> points;
    std::vector<std::pair<ViewId, ViewId>> views;  // of each of `points`
    std::vector<KeyframeKey> keys;                 // of each view id
    std::optional<KeyframeKey> oldest_kept;  // the window's oldest, when `cameras` has more than the window
    std::map<std::string, double> camera_scales;  // camera_scales_
    std::set<std::string> focal_held;             // focal_held_
    // Where the last refinement left the views it shares with this one:
    // their corrections (the orientations published) and centres, which
    // this one starts from (RefineRotationsWithBundleAdjustment's
    // start_centres); by view id.
    std::map<ViewId, Eigen::Matrix3d> start_corrections;
    std::unordered_map<ViewId, Eigen::Vector3d> start_centres;
    std::set<ViewId> held;  // keyframes outside the window that its edges reach (hold_outside)
    std::map<KeyframeKey, int> edges;  // sweep_back: the edges each keyframe has
    std::vector<KeyframeKey> window;   // sweep_back: the keyframes chosen
  };
  // The edges among the max_keyframes keyframes of `cameras` the window
  // takes (the newest, or with sweep_back the newest of those Pending), and
  // what else the refinement needs of this one's state (takes mutex_).
  Input SelectWindow(const OnlineSolution& cameras, const RigCaptures& rig) const;
  // Under mutex_ (sweep_back): lets go of the edges whose newer keyframe
  // is the oldest until the bytes held are within max_correspondence_mib.
  void LetGoBeyondBudget();
  static std::size_t EdgeBytes(const EdgeCorrespondences& e);
  // A focal estimate relative to a focal length `factor` times shorter.
  static void ScaleEstimate(double factor, BundleAdjustmentFocal::Estimate* e);
  // What a keyframe's latest window adjusted it in (sweep_back): the
  // averaging solution's sequence and the edges the keyframe had.
  struct Tried {
    std::uint64_t sequence = 0;
    int edges = 0;
  };
  // The keyframes with edges in `cameras`, each true if a window has
  // adjusted it in this solution with the edges it has now (under mutex_).
  // A rig capture's cameras are one variable of the averaging and get one
  // correction: the capture is current when all of them are. `edges`: each
  // keyframe's count.
  std::map<KeyframeKey, bool> Current(const OnlineSolution& cameras, const RigCaptures& rig,
                                      std::map<KeyframeKey, int>* edges) const;
  // What one refinement found, before it is taken.
  struct Outcome {
    double seconds = 0.0;
    std::uint64_t sequence = 0;  // of the solution refined
    bool ok = false;
    std::string report;
    std::map<KeyframeKey, Eigen::Matrix3d> corrections;
    std::map<KeyframeKey, Tried> tried;  // sweep_back: the window's keyframes
    double median_deg = 0.0, largest_deg = 0.0;  // of the corrections
    std::size_t held_back = 0;
    std::optional<KeyframeKey> oldest_kept;  // the window's oldest, when keyframes are older
    std::map<KeyframeKey, RelativeCovariance> covariances;
    std::map<std::string, BundleAdjustmentFocal::Estimate> focal;
    std::map<std::string, double> camera_scales;  // camera_scales_ as it started
    std::map<KeyframeKey, Eigen::Vector3d> centres;  // the adjusted camera centres
    int iterations = 0;
  };
  // The adjustment's covariances of the corrected keyframes (view ids of
  // `keys`) relative to the reference keyframe; rig captures as their
  // corrections: one for the capture.
  static std::map<KeyframeKey, RelativeCovariance> Covariances(const BundleAdjustmentCovariance& adjusted,
                                                               const OnlineSolution& cameras,
                                                               const std::vector<KeyframeKey>& keys,
                                                               const std::map<ViewId, Eigen::Matrix3d>& corrections,
                                                               const RigCaptures& rig);
  // Refine's work on `input`, under run_mutex_; with `staged`, what it
  // found is left in staged_ for Commit, else taken at once.
  bool Run(const OnlineSolution& cameras, const RigCaptures& rig, const Input& input, bool staged);
  // Under mutex_: the corrections, the counters, the edges let go. True if
  // the corrections were taken.
  bool Take(const Outcome& found);

  const KeyframeRefinerOptions options_;
  mutable std::mutex mutex_;  // edges_, corrections_, stats_
  std::map<std::pair<KeyframeKey, KeyframeKey>, HeldEdge> edges_;
  std::map<KeyframeKey, Eigen::Matrix3d> corrections_;
  std::map<KeyframeKey, Tried> tried_;  // sweep_back
  std::map<KeyframeKey, RelativeCovariance> covariances_;
  std::map<KeyframeKey, Eigen::Vector3d> centres_;  // the last refinement taken's
  std::map<std::string, double> camera_scales_;  // the product of ScaleCamera's, by camera
  std::set<std::string> focal_held_;              // HoldFocal
  std::set<std::string> focal_agreed_;            // hold_agreed_focal: agreed since the last ScaleCamera
  KeyframeRefinerStats stats_;
  std::mutex run_mutex_;  // one refinement at a time
  std::atomic<bool> running_{false};
  std::future<void> background_;  // of the thread that starts them
  std::optional<Outcome> staged_;  // under mutex_; taken by Commit
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_REFINER_H_
