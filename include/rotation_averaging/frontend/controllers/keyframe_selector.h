// Keyframe selection for raw camera streams (20-30 Hz), free of ROS: which
// frames of each camera go to the keyframe front end. Decided from the
// images alone, as VINS-Mono and ORB-SLAM decide, so that a live node and a
// replay of the same bag make the same keyframes whatever the timing:
//  * the first frame of a camera is a keyframe;
//  * a later frame is compared with that camera's last keyframe by KLT
//    (pyramidal Lucas-Kanade on a reduced grey image, corners detected once
//    per keyframe) and becomes a keyframe when the tracked corners moved by
//    a median of `min_motion_deg` (the angle they subtend at the camera:
//    rotation and parallax alike, independent of the image size), when the
//    camera turned by `min_rotation_deg` (the rotation the same corners
//    show, placed again at full resolution: a camera circling what it looks
//    at turns while the corners on it hardly move), when fewer than
//    `min_tracked_fraction` of them are still tracked (the view has left the
//    keyframe's), or when `max_interval_s` has passed;
//  * rig cameras of one capture (stamps within `rig_stamp_tolerance_s`)
//    become keyframes together: a keyframe of one camera makes the frame of
//    every other camera at that capture a keyframe too, whichever of them
//    arrived first (the last `held_frames` frames of each camera are held
//    for that).
// With `tracks`, every frame of a camera is tracked at full
// resolution instead (frontend/features/feature_tracker.h), each keyframe
// carries its tracks to the front end (which relates it to the earlier
// keyframes of its window through the tracks they share), and the motion and
// the tracked fraction above are those of the tracks the keyframe shares with
// the camera's last one. Without, a frame that is not a keyframe costs one
// resize and one KLT, and every 0.2 s of its camera's stamps a rotation
// check (one full-resolution KLT pass and an essential matrix).
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_SELECTOR_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_SELECTOR_H_

#include <Eigen/Core>
#include <cstdint>
#include <deque>
#include <map>
#include <opencv2/core.hpp>
#include <string>
#include <utility>
#include <vector>

#include "rotation_averaging/frontend/features/feature_tracker.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging {

struct KeyframeSelectionOptions {
  // Median angle (deg) by which the corners tracked from the camera's last
  // keyframe moved, and the fraction of them still tracked (occlusion,
  // motion blur, a view turning away). Sparser keyframes mean fewer
  // sequential edges whose errors add up along the path, until the pairs
  // overlap too little to verify well (results/keyframe_selection.md: the
  // accuracy and speed of each threshold on a 20 Hz stream).
  double min_motion_deg = 8.0;
  double min_tracked_fraction = 0.4;
  // The camera's rotation from its last keyframe (deg), estimated from the
  // tracked corners (essential matrix, or the rotation-only model where it
  // explains them), at which a frame becomes a keyframe even though its
  // corners moved less than min_motion_deg: a camera circling what it looks
  // at (an object, a facade, a door) turns while the corners on it hardly
  // move. 0: not checked. At 6 every photograph of the Strecha scenes and
  // lund_door that turned 6 deg since its keyframe is one, and the renderer's
  // 20 Hz streams make the keyframes they made without it, or two more
  // (results/keyframe_rotation.md; docs/decisions.md, "Keyframes by
  // rotation").
  double min_rotation_deg = 6.0;
  // A keyframe at least this often (s), even without motion; 0: never.
  double max_interval_s = 0.0;
  double rig_stamp_tolerance_s = 0.005;  // cameras of one capture: stamps within this
  int tracking_width = 320;  // px: frames are reduced to at most this width for tracking
  int corners = 150;         // detected per keyframe (Shi-Tomasi, spread out)
  int held_frames = 4;       // per camera, for a rig capture whose other camera decides later
  // Full-resolution KLT tracks (see above); tracking_width and corners are
  // then not used. False: the reduced images' KLT decides alone, and every
  // pair is matched by descriptors. Tracks are faster per pair and their
  // re-tracked points more precise than SIFT's, but on the renderer's
  // stream at its usual turn rate they make fewer keyframes and less
  // accurate pairs (results/tracks.md; docs/decisions.md, "Tracks on camera
  // streams").
  bool tracks = false;
  FeatureTrackerOptions tracker;

  bool Validate(std::string* error) const;
};

struct KeyframeSelectionStats {
  std::uint64_t frames = 0;            // every frame offered
  std::uint64_t keyframes = 0;         // of them, made keyframes
  std::uint64_t by_motion = 0, by_rotation = 0, by_tracking = 0, by_interval = 0, first = 0, by_rig = 0;  // why
  std::uint64_t skipped = 0;           // not keyframes
  double tracking_s = 0.0;             // wall time of the checks
  std::uint64_t rotation_checks = 0;   // rotations estimated (min_rotation_deg)
  double rotation_s = 0.0;             // their wall time, part of tracking_s
};

// One frame of a camera as the selector sees it.
struct SelectorFrame {
  std::string camera;
  std::int64_t stamp_ns = 0;
  cv::Mat image;  // 8-bit grey, full resolution
  CameraIntrinsics intrinsics;
  // With KeyframeSelectionOptions::tracks: the camera's tracks in `image`
  // (its pixels as given), in increasing id order.
  std::vector<TrackedPoint> tracks;
};

class KeyframeSelector {
 public:
  explicit KeyframeSelector(const KeyframeSelectionOptions& options);

  // Offers one frame (stamps advancing per camera); returns the frames that
  // become keyframes now, in stamp order, then camera order: none, this one,
  // and/or held frames of other cameras at its capture. Not thread-safe.
  std::vector<SelectorFrame> Offer(const SelectorFrame& frame);
  const KeyframeSelectionStats& Stats() const { return stats_; }
  // Forgets every camera's keyframe and frames (a gap in the streams).
  // Track ids are not reused: a later frame shares no track with a
  // keyframe from before.
  void Reset();

 private:
  struct Camera {
    cv::Mat keyframe_small;             // the last keyframe, reduced
    std::vector<cv::Mat> keyframe_pyramid;  // its Lucas-Kanade pyramid, with derivatives
    cv::Mat keyframe_full;              // and at full resolution, with min_rotation_deg
    std::int64_t rotation_checked_ns = 0;  // stamp of the last rotation check (or keyframe)
    std::vector<cv::Point2f> corners;   // detected in it
    double scale = 1.0;                 // reduced / full resolution
    double focal_px = 1.0;              // of the reduced image
    std::int64_t keyframe_stamp_ns = 0;
    bool has_keyframe = false;
    std::deque<SelectorFrame> held;     // recent frames that were not keyframes
    std::vector<TrackedPoint> keyframe_tracks;  // with `tracks`: the last keyframe's
    cv::Size keyframe_size;
  };
  enum class Reason { kNone, kFirst, kMotion, kRotation, kTracking, kInterval };
  // A rotation check of this frame is due (min_rotation_deg set, and the
  // camera's last one, or its keyframe, long enough ago); notes it as made.
  bool RotationCheckDue(Camera& camera, const SelectorFrame& frame) const;
  // The rotation from the camera's keyframe to the frame that the corners
  // tracked between them show (from, to: pixels of the images tracked) is
  // at least min_rotation_deg. Called when RotationCheckDue.
  bool RotatedEnough(const Camera& camera, const SelectorFrame& frame, std::vector<Eigen::Vector2d>* from,
                     std::vector<Eigen::Vector2d>* to);
  Reason Decide(Camera& camera, const SelectorFrame& frame, cv::Mat* small);
  Reason DecideByTracks(Camera& camera, const SelectorFrame& frame);
  // What both ways of tracking decide from: of the keyframe's `corners`,
  // those tracked into the frame moved by `moved` (deg); `from`, `to` are
  // their pixels in the images tracked, for the rotation check.
  Reason DecideByCorners(Camera& camera, const SelectorFrame& frame, std::size_t corners, std::vector<double> moved,
                         std::vector<Eigen::Vector2d>* from, std::vector<Eigen::Vector2d>* to);
  // With `tracks`: the frame with its camera's tracks in it, tracked from
  // the camera's previous frame.
  SelectorFrame Track(const SelectorFrame& frame);
  void MakeKeyframe(Camera& camera, const SelectorFrame& frame, const cv::Mat& small);
  bool SameCapture(std::int64_t a, std::int64_t b) const;
  cv::Mat Reduce(const cv::Mat& image) const;  // to at most tracking_width

  KeyframeSelectionOptions options_;
  std::map<std::string, Camera> cameras_;
  std::map<std::string, FeatureTracker> trackers_;  // kept by Reset (their ids go on)
  // Recent keyframes (stamp, camera): a frame of another camera within the
  // tolerance of one is a keyframe too.
  std::deque<std::pair<std::int64_t, std::string>> keyframe_stamps_;
  KeyframeSelectionStats stats_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_KEYFRAME_SELECTOR_H_
