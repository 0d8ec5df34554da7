// Keyframe front end for the live node, free of ROS: each keyframe image is
// described once and related to
//  * the previous keyframe of the same camera (sequential edge) or, when that
//    pair fails, the newest of the `covisibility_window` last keyframes that
//    verifies: one failed pair does not cut the chain,
//  * the keyframes of the other cameras captured within a stamp tolerance
//    (rig edges),
//  * up to `max_loop_candidates` older keyframes found by image retrieval
//    (loop-closure edges), each verified by a relative pose.
// Retrieval with a vocabulary (frontend/features/vocabulary.h): the keyframes whose
// tf-idf bag of words scores highest against the new one's in an inverted
// index. Its cost hardly grows with the map, and keyframes that have left the
// recent window keep only their `compact_features` best features (SIFT
// descriptors packed at 4 bits per value, and their words; the memory per
// keyframe is in results/long_run.md), and are matched within
// the vocabulary tree's branches. Without a vocabulary: a fixed sample of
// the new keyframe's descriptors is matched against every older keyframe's
// nearest-neighbour index, whose cost and memory grow with the map (every
// keyframe keeps all its features and an index).
// Pair verification and retrieval run on `num_threads` threads; the edges and
// their order do not depend on the thread count, nor on the order in which
// the cameras' images of one capture arrive.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_H_

#include <map>
#include <set>
#include <memory>
#include <string>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/frontend/features/feature_tracker.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/frontend/features/vocabulary.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"
#include "rotation_averaging/frontend/controllers/focal_monitor.h"
#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"
#include "rotation_averaging/frontend/io/keyframe_database.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {

struct KeyframeFrontendOptions {
  FeatureOptions features;              // downsample applies to the incoming images
  MatchOptions matching;
  RelativePoseOptions relative_pose;
  double rig_stamp_tolerance_s = 0.005;  // cameras of one capture: stamps within this
  // Keyframes of the same camera a new one may be related to: the previous
  // one, or when that pair fails, the newest older one in this window that
  // verifies. With 1, every failed pair (motion blur, a view that turned
  // away) splits the graph. Relating every keyframe to all of the window
  // adds pairs whose errors exceed their covariances more the longer they are,
  // and was less accurate (docs/decisions.md, "Covisibility window").
  int covisibility_window = 3;
  // True: the new keyframe is also related to the older keyframes of the
  // window (not only the previous one), each pair kept when its rotation
  // agrees with the one the chain through the previous keyframe predicts
  // (within three standard deviations of both), with the cell jackknife's
  // covariance (loop_jackknife_grid: wider baselines, as loop closures).
  // False: the chain alone, and the older keyframes only when the previous
  // pair fails (docs/decisions.md, "Window pairs").
  bool window_pairs = true;
  // A keyframe given with its KLT tracks (AddKeyframe's `tracks`) is
  // related to the earlier keyframes of its camera's window that share at
  // least this many tracks with it from those correspondences, by the same
  // estimation and checks as from matched descriptors; a pair that shares
  // fewer, or whose tracks do not verify, is matched by descriptors.
  int min_track_matches = 30;
  // The re-tracking of a pair's shared tracks between its two images
  // (RetrackBetween): its window, pyramid and forward-backward check.
  FeatureTrackerOptions tracker;
  int num_threads = 0;                  // pair verification and retrieval; 0: the machine's cores
  int max_loop_candidates = 3;          // verified per keyframe
  int loop_exclude_recent = 5;          // keyframes of the same camera too recent to be loop closures
  // Retrieval by vocabulary (null: by voting, linear in the map; see above).
  std::shared_ptr<const Vocabulary> vocabulary;
  // Features a keyframe keeps beyond the recent window (vocabulary only):
  // first those that were inliers of the most verified pairs (seen from
  // other views, they are what a revisit matches), then the strongest.
  // More features find more loop closures for more memory, but the extra
  // loops err well beyond their covariances and cost accuracy
  // (results/replay.md, "Twice the features per compact keyframe").
  int compact_features = 1000;
  // Pairs with a compact keyframe (loop closures) match features only within
  // the same first-level branch of the vocabulary tree, as ORB-SLAM matches
  // by vocabulary, instead of comparing every feature with every other.
  bool match_compact_by_vocabulary = true;
  // Candidates must score at least this fraction of the new keyframe's score
  // with its previous keyframe (a view it certainly overlaps).
  double min_retrieval_score_ratio = 0.0;
  int retrieval_sample = 300;           // voting: descriptors of the new keyframe used
  int min_retrieval_votes = 15;         // voting: candidates with fewer votes are not verified
  // Loop closures need more evidence than sequential edges: repetitive
  // structure makes wrong but geometrically consistent pairs with few
  // inliers. Lower finds more loops and lets wrong ones in; the weak loops
  // just above it are right but err several times what the pixel model
  // gives, which the cell jackknife's covariance (loop_jackknife_grid)
  // covers: without it the threshold has to be higher and misses loops
  // (results/replay.md, "Loop closures and their covariances";
  // docs/decisions.md, "Loop-closure threshold").
  int min_loop_inliers = 40;
  // A compact keyframe keeps a part of the correspondences a loop pair would
  // have with all of its features (results/replay.md, "inliers kept"), so a
  // loop closure to one needs this fraction of min_loop_inliers: the same
  // evidence.
  double compact_loop_inlier_fraction = 0.75;
  // Loop closures found for one keyframe check each other through the chain
  // of sequential edges between their old ends: R_a1b ~ R_a1a2 R_a2b. Two
  // loops agree when that prediction is within this angle (plus three
  // predicted standard deviations). With three or more, the loops that agree
  // with fewer than half of the others are dropped; of two that disagree,
  // the one with more inliers is kept.
  double loop_consistency_deg = 1.0;
  // Loop closures of one keyframe to neighbouring old keyframes (next to
  // each other on one camera's chain) see one place through near-duplicate
  // images: wrong matches on its repeated structure recur in each of them,
  // so their errors are shared, and as several edges they can outvote the
  // chain. True: a loop is dropped when one with more inliers reaches the
  // keyframe next to its old end, as ORB-SLAM and VINS-Mono keep one loop
  // per keyframe (results/replay.md, "One loop closure per place"). False:
  // every loop that passes the checks above is kept.
  bool one_loop_per_place = true;
  // Loop-closure pairs get the cell jackknife's covariance
  // (RelativePoseOptions::jackknife_grid) with this grid, whatever
  // relative_pose says: they are the wide-baseline pairs, where groups of
  // matches on repeated structure share their error and the pixel model is
  // over-confident (the loops' NEES with and without it: results/replay.md,
  // "Loop closures and their covariances"). Sequential and rig pairs keep
  // relative_pose's setting: where keypoint noise is independent the
  // jackknife only adds sampling noise to their weights
  // (docs/decisions.md, "Cell jackknife"). 0: the pixel model for loops too.
  int loop_jackknife_grid = 4;
  // The check of each camera's focal length against its verified pairs
  // (frontend/controllers/focal_monitor.h). Off here; the node turns it on
  // (focal_calibration: warn). Its memory: KeyframeFrontendStats::focal_bytes.
  FocalMonitorOptions focal_monitor;
  // Keep each edge's inlier correspondences (normalised coordinates, the
  // pose's translation and pixel noise) until TakeCorrespondences, for the
  // background refinement (frontend/controllers/keyframe_refiner.h).
  bool keep_correspondences = false;

  // True if every field (features, relative_pose included) is within its
  // range; otherwise false, with `error` naming the first field that is not.
  bool Validate(std::string* error) const;
};

struct KeyframeFrontendStats {
  std::uint64_t keyframes = 0;
  std::uint64_t duplicate_keyframes = 0;  // refused: a keyframe with that key is held
  std::uint64_t loaded_keyframes = 0;     // from the database (LoadDatabase)
  std::uint64_t resumed_chains = 0;       // cameras whose loaded chain new keyframes continue
  std::uint64_t sequential_edges = 0, rig_edges = 0, loop_closure_edges = 0;
  std::uint64_t rig_pairs_skipped = 0;   // same capture, both cameras with known extrinsics
  std::uint64_t chain_bridged = 0;         // previous pair failed, an older keyframe of the window verified
  std::uint64_t window_edges = 0;          // window_pairs: edges to the window beyond the previous keyframe
  std::uint64_t window_rejected_inconsistent = 0;  // window_pairs: verified, but off the chain's prediction
  std::uint64_t rotation_model_edges = 0;  // edges from the rotation-only two-view model (no parallax)
  // Pairs of one camera's keyframes estimated from their shared tracks, and
  // of them those that did not verify and were matched by descriptors.
  std::uint64_t track_pairs = 0, track_pairs_matched_instead = 0;
  std::uint64_t loop_candidates_tried = 0;
  std::uint64_t loops_rejected_inconsistent = 0;
  std::uint64_t loops_same_place = 0;  // dropped by one_loop_per_place
  // Loop closures between an added database's keyframes and those held
  // (AddDatabase with links; also counted in loop_closure_edges and
  // loop_candidates_tried), and the wall time of that matching (apart from
  // features_s, retrieval_s and pairs_s, which are per new keyframe).
  std::uint64_t map_links = 0;
  double map_link_s = 0.0;
  std::uint64_t failed_pairs = 0;
  // Keypoints dropped because the camera's distortion model does not invert
  // there (far outside its calibrated field of view).
  std::uint64_t keypoints_outside_model = 0;
  std::map<std::string, std::uint64_t> failures;  // two-view failure reason -> count
  double features_s = 0.0, retrieval_s = 0.0, pairs_s = 0.0;  // wall time
  double last_features_s = 0.0, last_retrieval_s = 0.0, last_pairs_s = 0.0;  // of the latest keyframe
  // Each two-view pair of a new keyframe: its matching and estimation, wall
  // time on the thread that ran it (pairs_s is their span across threads).
  TimeDistribution pair_times;
  std::uint64_t compacted_keyframes = 0;
  // Features and retrieval data held (bag of words and its postings, and
  // the recent window's tracks and their image pyramids; not the
  // nearest-neighbour indices of the recent window), and of that, by the
  // compact keyframes.
  std::size_t keyframe_bytes = 0, compact_bytes = 0;
  std::size_t focal_bytes = 0;  // the pairs the focal-length check holds
};

// How one held pair's edge rotation moves with its camera's focal length
// (KeyframeFrontend::FocalSensitivities).
struct FocalSensitivity {
  KeyframeKey keyframe1, keyframe2;  // the edge, in ApplyFocalCorrection's order
  EdgeSource source = EdgeSource::kSequential;
  // d Log(R_12(1)^T R_12(s)) / ds at s = 1, with the camera's focal length
  // times s: the right perturbation of the edge rotation per unit of
  // relative focal-length change.
  Eigen::Vector3d derivative = Eigen::Vector3d::Zero();
};

class KeyframeFrontend {
 public:
  explicit KeyframeFrontend(const KeyframeFrontendOptions& options);
  ~KeyframeFrontend();

  // Adds a keyframe (8-bit image as the camera took it, and that camera's
  // intrinsics and lens distortion) and returns the verified relative
  // rotations it produced. Keypoints are undistorted before any two-view
  // step. Images that yield too few features give no edges.
  std::vector<KeyframeRelativeRotation> AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                    const CameraIntrinsics& camera);
  // The same with the keyframe's KLT tracks (FeatureTracker on every image
  // of its camera; pixels of `image`, in increasing id order): its pairs
  // with earlier keyframes of the camera's window come from the tracks
  // they share (min_track_matches).
  std::vector<KeyframeRelativeRotation> AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                    const CameraIntrinsics& camera,
                                                    const std::vector<TrackedPoint>& tracks);
  // A pinhole camera without distortion (a rectified image).
  std::vector<KeyframeRelativeRotation> AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                    const Eigen::Matrix3d& k);
  const KeyframeFrontendStats& Stats() const { return stats_; }
  // A camera whose rotation within the rig is known (extrinsics): pairs of
  // such cameras in one capture are not matched (the rig model relates them).
  void SetRigCalibrated(const std::string& camera_frame) { rig_calibrated_.insert(camera_frame); }
  std::size_t NumKeyframes() const { return keyframes_.size(); }

  // The keyframe database: what loop-closure retrieval and verification need
  // of every keyframe (the compact features with their words, the bag of
  // words, the intrinsics, the chain of sequential rotations loop closures
  // are checked along), in one binary file (magic "ROTAVG-KEYFRAMES",
  // version, the vocabulary's fingerprint, a checksum of the contents),
  // written atomically (a temporary file renamed over the old one: a crash
  // mid-write leaves the previous database). Needs a vocabulary: retrieval
  // by voting keeps every feature of every keyframe, too much to save.
  // Keyframes are saved as their compact form whether or not they have left
  // the recent window yet.
  bool SaveDatabase(const std::string& path, std::string* error) const;
  // What SaveDatabase writes, copied out (descriptors of compact keyframes
  // are shared, not copied), so that a caller can write it
  // (WriteKeyframeDatabase) without holding the front end.
  bool SnapshotDatabase(KeyframeDatabase* database, std::string* error) const;
  // Replaces every keyframe with those of a database (file of SaveDatabase).
  // They take part in retrieval and loop-closure verification like any old
  // keyframe, and each camera's newest chain is resumed: its next keyframe
  // is related to the last keyframes of that chain as it would have been
  // without the restart (previous keyframe and window), except that those
  // pairs need a loop closure's inliers (the camera may have moved while
  // the node was down), and `failures` counts the others as
  // "resumed_too_few_inliers". A file of another
  // version, another vocabulary, a truncated or corrupted one is refused
  // with the reason, and the keyframes held are left as they were.
  bool LoadDatabase(const std::string& path, std::string* error);
  // Adds the keyframes of a database (another session's or another robot's
  // map) to those held, as LoadDatabase loads them. A keyframe already held
  // is the same keyframe (maps saved from one history share it): skipped,
  // and counted in `already_held`. Refusals as LoadDatabase, leaving what is
  // held as it was.
  // With `links`, a database that shares no keyframe with those held (two
  // maps that never met) is matched against them: each added keyframe's
  // loop-closure candidates among the keyframes held before are retrieved
  // and verified as a new keyframe's are (same evidence, same consistency
  // check), and the loop closures found are returned there, so that maps
  // loaded together join where they saw the same place without waiting for
  // a new keyframe there. A database that shares keyframes is joined through
  // them, and its own loop closures to them are in its graph already:
  // matching it again would count those pairs twice.
  bool AddDatabase(const std::string& path, std::size_t* already_held, std::string* error,
                   std::vector<KeyframeRelativeRotation>* links = nullptr);
  // keep_correspondences: the inlier correspondences of the edges made
  // since the last call, in the order of the edges.
  std::vector<KeyframeCorrespondences> TakeCorrespondences();
  bool UsesVocabulary() const { return options_.vocabulary != nullptr; }
  // "vocabulary of N words (inverted index)" or "voting over every keyframe (no vocabulary)".
  std::string RetrievalName() const;
  // The focal-length estimates that fell due since the last call
  // (FocalMonitor), for a FocalChecker to run.
  std::vector<FocalJob> TakeFocalJobs() { return focal_monitor_.TakeDue(); }
  // focal_calibration: apply. Multiplies the focal length of `camera` by
  // `scale`: for its keyframes from now on (their camera's K corrected before
  // anything), for those held (later pairs with them), and for the pairs of
  // it held (FocalMonitorOptions::hold_for_correction), which are estimated
  // again from their matches; their edges are returned, to replace the old
  // ones. Keypoints of a distorted camera, undistorted with the former K,
  // are undistorted again with the corrected one first (RedoUndistortion),
  // the held pairs' and the keyframes': the lens's distortion acts on the
  // normalised coordinates K gives, so scaling them would not do. Keyframes
  // loaded from a database keep theirs (it holds no lens). False, with
  // `why`, and nothing changed, when the camera's pairs outgrew
  // max_correction_pairs.
  // With `linearised`, the held pairs are not estimated again: each edge
  // moves by its derivative (FocalSensitivities, which must have run),
  // R_12 Exp((scale - 1) d), for a correction of a fraction of a percent
  // (RefineFocalByLoops in the node); its covariance stays, and the check
  // goes on with the camera's next pairs.
  bool ApplyFocalCorrection(const std::string& camera, double scale, std::vector<KeyframeRelativeRotation>* edges,
                            std::string* why, bool linearised = false);
  // The product of the corrections applied to `camera` (1: none).
  double FocalCorrection(const std::string& camera) const;
  // The focal length in use for `camera`, px: its latest camera_info's
  // times FocalCorrection (0: no keyframe of it yet).
  double FocalInUsePx(const std::string& camera) const;
  // focal_calibration: apply, for a camera whose camera_info describes no
  // lens while its images show a radial distortion: lambda of the one-
  // parameter division model in the normalised coordinates of the focal
  // length in use (the camera_info check's RadialDistortion). From now on
  // the camera's keypoints are undistorted by that lens (PlumbBobFromDivision
  // out to the image's corner), those of its keyframes and held pairs too;
  // the held pairs are estimated again and their edges returned, to replace
  // the old ones, as ApplyFocalCorrection does; the focal check starts again
  // with the lens. Once per camera; keyframes loaded from a database keep
  // theirs. False, with `why`, and nothing changed, when the camera has a
  // lens already, lambda gives none, or its pairs outgrew
  // max_correction_pairs.
  bool ApplyLensCorrection(const std::string& camera, double lambda, std::vector<KeyframeRelativeRotation>* edges,
                           std::string* why);
  // The lens correction of `camera` (ApplyLensCorrection's lambda, in the
  // normalised coordinates of the focal length in use then); 0: none.
  double LensCorrection(const std::string& camera) const;
  // `given` (a camera_info of `camera`) as the front end uses it: its focal
  // length times FocalCorrection and, when it describes no lens, the lens
  // of LensCorrection.
  CameraIntrinsics CameraInUse(const std::string& camera, const CameraIntrinsics& given) const;
  // focal_calibration: apply. The held pairs of `camera` (those that
  // ApplyFocalCorrection would estimate again), each pose refined on its
  // inliers with the camera's focal length times 1 +- step (its keypoints
  // undistorted again for each): the central difference of its edge
  // rotation. Computed once per pair and camera (a correction of a few
  // percent changes it by as little). Pairs whose refinement fails are left
  // out. Empty when the camera's pairs are not held (overflowed, or never).
  std::vector<FocalSensitivity> FocalSensitivities(const std::string& camera, double step = 1e-3);

 private:
  struct Keyframe;
  bool TakeDatabase(const std::string& path, bool add, std::size_t* already_held, std::string* error);
  // The sequential chain a keyframe belongs to: its camera's in this
  // session, or one loaded from a database.
  const std::vector<int>& ChainOf(const Keyframe& keyframe) const;
  // R_ab composed along the sequential edges of one camera (a before b);
  // false if the chain between them is broken. `covariance` (optional) gets
  // the sequential edges' covariances added, in chain order.
  bool ChainRotation(int a, int b, Eigen::Matrix3d* r_ab, Eigen::Matrix3d* covariance = nullptr) const;
  // Inliers a loop closure to `older` needs (fewer to a compact keyframe);
  // also a pair across a restart (LoadDatabase's resumed chains).
  double LoopInliersNeeded(const Keyframe& older) const;
  // Both drop loops and their old ends (index into keyframes_) together.
  void FilterInconsistentLoops(std::vector<KeyframeRelativeRotation>* loops, std::vector<int>* old_ends);
  void KeepOneLoopPerPlace(std::vector<KeyframeRelativeRotation>* loops, std::vector<int>* old_ends);
  // Keeps the loops (and old ends) whose `keep` is true, counting the others in `dropped`.
  static void DropLoops(const std::vector<bool>& keep, std::vector<KeyframeRelativeRotation>* loops,
                        std::vector<int>* old_ends, std::uint64_t* dropped);
  struct PairTask {
    int older = 0;  // index into keyframes_ (the edge's first keyframe)
    EdgeSource source = EdgeSource::kSequential;
    // The new keyframe is the edge's first: two cameras of one capture are
    // related in the order of their frame ids, not of their arrival.
    bool newer_first = false;
    int newer = 0;  // index into VerifyPairs' `newers`
    bool wide = false;  // estimated with loop_jackknife_grid, as loop closures
  };
  // Keeps only what loop-closure verification needs of a keyframe that left
  // the recent window.
  void Compact(Keyframe* keyframe);
  // Lets go of the tracks and their pyramid of a keyframe that left its
  // camera's window.
  void ReleaseTracks(Keyframe* keyframe);
  // Compacts the keyframes that left their window in a capture older than
  // `stamp_ns` (beyond the rig tolerance).
  void CompactDue(std::int64_t stamp_ns);
  // Loop-closure candidates of `kf` among keyframes outside `excluded`.
  std::vector<int> RetrieveByVocabulary(const Keyframe& kf, const std::set<int>& excluded, int previous);
  std::vector<int> RetrieveByVoting(const Keyframe& kf, const std::set<int>& excluded);
  std::size_t KeyframeBytes(const Keyframe& keyframe) const;
  struct PairOutcome {
    bool success = false;
    KeyframeRelativeRotation edge;
    bool rotation_model = false;
    bool from_tracks = false;       // estimated from shared tracks
    bool tracks_failed = false;     // the shared tracks did not verify; descriptors were matched
    std::string failure;
    std::vector<std::pair<int, int>> inlier_features;  // (older's feature, newer's feature)
    // A pair of two keyframes of one camera with the essential-matrix model,
    // for the focal-length check (options_.focal_monitor).
    std::shared_ptr<const FocalSample> focal_sample;
    // Every match, for focal_calibration: apply (hold_for_correction), and
    // the pose they gave (its inliers, for the focal length's derivative).
    std::shared_ptr<std::vector<Eigen::Vector2d>> points1, points2;
    std::shared_ptr<RelativePoseResult> pose;
    // Its inliers for the refinement (options_.keep_correspondences).
    std::shared_ptr<const EdgeCorrespondences> correspondences;
    bool newer_first = false;  // the edge's first keyframe is the new one
    int jackknife_grid = 0;    // that the pair was estimated with
    double seconds = 0.0;      // wall time of its matching and estimation, on its thread
  };
  // A pair that gave an edge, held for focal_calibration: apply.
  struct HeldPair {
    int first = 0, second = 0;  // indices into keyframes_, in the edge's order
    EdgeSource source = EdgeSource::kSequential;
    int jackknife_grid = 0;
    bool chain = false;  // the sequential edge of `second` from its previous keyframe
    std::shared_ptr<std::vector<Eigen::Vector2d>> points1, points2;
    // The pair's latest pose (shared by the lists of both cameras of a
    // pair of two), and its edge's derivative with respect to this list's
    // camera's focal length once FocalSensitivities has computed it.
    std::shared_ptr<RelativePoseResult> pose;
    bool has_derivative = false;
    Eigen::Vector3d derivative = Eigen::Vector3d::Zero();
  };
  void HoldPair(const PairTask& task, const PairOutcome& outcome, int newer_index, bool chain);
  // The lens of a lens correction (lens_correction_px_'s entry) for
  // intrinsics `k` of a camera whose focal length in use is `focal_px`.
  static CameraIntrinsics CorrectedLens(const std::pair<double, double>& correction, const Eigen::Matrix3d& k,
                                        double focal_px);
  // A held pair's new edge, replacing its old one (and the newer
  // keyframe's sequential edge, for the chain's predictions).
  void ReplaceHeldEdge(const HeldPair& pair, const RelativePoseResult& pose,
                       std::vector<KeyframeRelativeRotation>* edges);
  // The held pairs of `camera` estimated again from their (corrected)
  // points: the edges of those that succeed, and the focal check fed with
  // them, its camera's focal length `given_px` and lens `lens`. With
  // `keep_correspondences` (and options_.keep_correspondences), their
  // inliers for TakeCorrespondences too: the refinement's held ones are of
  // the old camera.
  void ReestimateHeldPairs(const std::string& camera, double given_px, const CameraIntrinsics& lens,
                           bool keep_correspondences, std::vector<KeyframeRelativeRotation>* edges);
  std::size_t FocalBytes() const;  // what the focal-length check and correction hold
  // Gives the focal-length check the pair of a used outcome.
  void MonitorFocal(const PairOutcome& outcome, const Keyframe& newer, const CameraIntrinsics& camera);
  // Counts the inliers of a pair whose edge is used on both keyframes' features.
  void CountInliers(const PairTask& task, const PairOutcome& outcome, Keyframe* newer);
  // Verifies every task against `newer` (on the thread pool); the outcomes
  // are in task order, their wall time is added to stats_.pairs_s. Count
  // adds an outcome whose result is used to the statistics (speculative
  // ones are not counted when not needed).
  std::vector<PairOutcome> VerifyPairs(const std::vector<PairTask>& tasks, const Keyframe& newer);
  // The same for tasks of several new keyframes (PairTask::newer), timed by
  // the caller (an added map's links count in stats_.map_link_s).
  std::vector<PairOutcome> VerifyPairs(const std::vector<PairTask>& tasks, const std::vector<const Keyframe*>& newers);
  // The outcome of one verified pair (`a` the task's older keyframe; the
  // pose maps `first` to `second`, swapped from (a, new) when `swap`): its
  // edge and inliers, its focal sample, the matches held for correction.
  // `k1` and `k2`: the intrinsics of pa's and pb's pixels.
  void FillOutcome(const PairTask& task, const Keyframe& a, const Keyframe& first, const Keyframe& second, bool swap,
                   int jackknife_grid, const std::vector<std::pair<int, int>>& matches,
                   std::vector<Eigen::Vector2d> pa, std::vector<Eigen::Vector2d> pb, const Eigen::Matrix3d& k1,
                   const Eigen::Matrix3d& k2, const RelativePoseResult& pose, PairOutcome* outcome) const;
  // The inliers of a used outcome into correspondences_ (keep_correspondences).
  void KeepCorrespondences(const PairOutcome& outcome);
  // The loop closures of one new keyframe (`verified` of `candidates`) that
  // have enough inliers and agree with each other, with the candidates they
  // came from; counts them and the rejected ones.
  std::vector<KeyframeRelativeRotation> AcceptLoops(const std::vector<PairTask>& candidates,
                                                    const std::vector<PairOutcome>& verified,
                                                    std::vector<std::size_t>* accepted);
  // The steps of AddKeyframe, in order. The keyframe of `image`: its
  // features, undistorted to `camera`'s ideal pinhole, their index and words.
  std::unique_ptr<Keyframe> DescribeKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                             const CameraIntrinsics& camera, const std::vector<TrackedPoint>& tracks);
  // The correspondences of a pair of one camera's keyframes from the tracks
  // they share; false if they share fewer than min_track_matches.
  bool TrackCorrespondences(const PairTask& task, const Keyframe& a, const Keyframe& newer,
                            std::vector<Eigen::Vector2d>* pa, std::vector<Eigen::Vector2d>* pb) const;
  // The pair with the previous keyframe of the camera (`same`: its
  // keyframes so far) and those with the other cameras' keyframes of the
  // same capture; `related` gets them and the camera's last `window`.
  std::vector<PairTask> ChainAndRigTasks(const KeyframeKey& key, const std::vector<int>& same, int window,
                                         std::set<int>* related);
  // Loop-closure candidates of `kf`: retrieved outside `related` and the
  // camera's loop_exclude_recent last keyframes.
  std::vector<PairTask> LoopCandidates(const Keyframe& kf, const std::set<int>& related, const std::vector<int>& same);
  // Verifies `tasks`, the loop `candidates` and the window's older pairs in
  // one batch: `outcomes` of `tasks`, to which an older pair that bridges a
  // failed previous pair, or with window_pairs each one that agrees with
  // the chain, is added; `verified_loops` of `candidates`.
  void VerifyKeyframePairs(const std::vector<int>& same, int window, const std::vector<PairTask>& candidates,
                           Keyframe* kf, std::vector<PairTask>* tasks, std::vector<PairOutcome>* outcomes,
                           std::vector<PairOutcome>* verified_loops);
  // window_pairs, the previous pair verified (outcomes[0]): adds each of the
  // `verified` older pairs that agrees with the chain through the previous
  // keyframe (`previous_index`).
  void KeepConsistentWindowPairs(int previous_index, const std::vector<PairTask>& window_tasks,
                                 const std::vector<PairOutcome>& verified, std::vector<PairTask>* tasks,
                                 std::vector<PairOutcome>* outcomes);
  // A verified sequential or rig pair of the new keyframe `kf`: its edge, its
  // inliers counted, held and given to the focal check.
  void UseChainOrRigEdge(const PairTask& task, const PairOutcome& outcome, const CameraIntrinsics& camera,
                         const std::vector<int>& same, Keyframe* kf, std::vector<KeyframeRelativeRotation>* edges);
  // Appends the keyframe to its camera's chain, the retrieval index and
  // the compaction schedule.
  void StoreKeyframe(std::unique_ptr<Keyframe> kf);
  // Loop closures from the keyframes at [first_added, end) to those before.
  std::vector<KeyframeRelativeRotation> LinkAddedKeyframes(int first_added);
  void Count(const PairOutcome& outcome);

  KeyframeFrontendOptions options_;
  std::vector<std::unique_ptr<Keyframe>> keyframes_;
  std::map<std::string, std::vector<int>> by_camera_;  // indices into keyframes_, in arrival order
  // Chains of the keyframes loaded from a database, per camera (indices into
  // keyframes_), apart from this session's in by_camera_.
  std::vector<std::vector<int>> loaded_chains_;
  void ResumeChains();  // LoadDatabase: each camera's newest loaded chain back into by_camera_
  std::set<KeyframeKey> keys_;  // of every keyframe held: a key added twice is refused
  KeyframeFrontendStats stats_;
  std::set<std::string> rig_calibrated_;
  std::unique_ptr<InvertedIndex> inverted_index_;  // with a vocabulary
  // (keyframe, stamp of the capture that pushed it out of its window)
  std::vector<std::pair<int, std::int64_t>> due_compaction_;
  FocalMonitor focal_monitor_;
  std::vector<KeyframeCorrespondences> correspondences_;  // keep_correspondences, until taken
  std::map<std::string, std::vector<HeldPair>> held_pairs_;  // by camera (a rig pair under both)
  std::set<std::string> held_overflow_;  // cameras whose pairs outgrew max_correction_pairs
  std::map<std::string, double> focal_correction_;  // ApplyFocalCorrection
  // ApplyLensCorrection's lambda over the focal length in use then, squared
  // (px^-2): the same lens in pixels whatever the focal length becomes.
  // and the normalised radius it is fitted out to (the image's corner then),
  // so that every keyframe's lens is the same to the bit.
  std::map<std::string, std::pair<double, double>> lens_correction_px_;
  std::map<std::string, double> given_focal_px_;     // the latest camera_info's, by camera
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_FRONTEND_H_
