#include "rotation_averaging/frontend/controllers/keyframe_selector.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "rotation_averaging/util/option_check.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// A keyframe with fewer corners than this cannot be tracked from: the next
// frame with enough of them becomes the keyframe.
constexpr std::size_t kMinCorners = 10;
// KLT's corners must come back to where they started (forward-backward
// check) within this (px of the reduced image): a corner that slid along an
// edge or jumped to a look-alike is not tracked.
constexpr float kForwardBackwardPx = 1.0f;
// Keyframe capture stamps remembered for the rig's other cameras.
constexpr std::size_t kRememberedCaptures = 16;

}  // namespace

bool KeyframeSelectionOptions::Validate(std::string* error) const {
  std::string tracker_error;
  return OptionCheck()
      .AtLeast("keyframe_min_motion_deg", min_motion_deg, 0.0)
      .Within("keyframe_min_tracked_fraction", min_tracked_fraction, 0.0, 1.0)
      .AtLeast("keyframe_max_interval_s", max_interval_s, 0.0)
      .AtLeast("rig_stamp_tolerance_s", rig_stamp_tolerance_s, 0.0)
      .AtLeast("keyframe_tracking_width", tracking_width, 32)
      .AtLeast("keyframe_corners", corners, static_cast<int>(kMinCorners))
      .AtLeast("keyframe_held_frames", held_frames, 0)
      .Require(!tracks || tracker.Validate(&tracker_error), tracker_error)
      .Ok(error);
}

KeyframeSelector::KeyframeSelector(const KeyframeSelectionOptions& options) : options_(options) {}

void KeyframeSelector::Reset() {
  cameras_.clear();
  keyframe_stamps_.clear();
  for (auto& [name, tracker] : trackers_) tracker.Reset();
}

SelectorFrame KeyframeSelector::Track(const SelectorFrame& frame) {
  SelectorFrame tracked = frame;
  if (!options_.tracks) return tracked;
  auto it = trackers_.find(frame.camera);
  if (it == trackers_.end()) it = trackers_.emplace(frame.camera, FeatureTracker(options_.tracker)).first;
  tracked.tracks = it->second.Track(frame.image);
  return tracked;
}

cv::Mat KeyframeSelector::Reduce(const cv::Mat& image) const {
  if (image.cols <= options_.tracking_width) return image;
  const double scale = static_cast<double>(options_.tracking_width) / image.cols;
  cv::Mat small;
  cv::resize(image, small, cv::Size(), scale, scale, cv::INTER_AREA);
  return small;
}

bool KeyframeSelector::SameCapture(std::int64_t a, std::int64_t b) const {
  return std::abs(static_cast<double>(a - b)) <= options_.rig_stamp_tolerance_s * 1e9;
}

void KeyframeSelector::MakeKeyframe(Camera& camera, const SelectorFrame& frame, const cv::Mat& small) {
  camera.keyframe_stamp_ns = frame.stamp_ns;
  camera.has_keyframe = true;
  ++stats_.keyframes;
  if (options_.tracks) {
    camera.keyframe_tracks = frame.tracks;
    camera.keyframe_size = frame.image.size();
    camera.focal_px = 0.5 * (frame.intrinsics.k(0, 0) + frame.intrinsics.k(1, 1));
    return;
  }
  camera.keyframe_small = small;
  camera.scale = static_cast<double>(small.cols) / frame.image.cols;
  camera.focal_px = 0.5 * (frame.intrinsics.k(0, 0) + frame.intrinsics.k(1, 1)) * camera.scale;
  camera.corners.clear();
  cv::goodFeaturesToTrack(small, camera.corners, options_.corners, 0.01, std::max(3.0, small.cols / 40.0));
}

KeyframeSelector::Reason KeyframeSelector::DecideByTracks(const Camera& camera, const SelectorFrame& frame) const {
  if (!camera.has_keyframe || frame.image.size() != camera.keyframe_size) return Reason::kFirst;
  if (options_.max_interval_s > 0.0 &&
      static_cast<double>(frame.stamp_ns - camera.keyframe_stamp_ns) >= options_.max_interval_s * 1e9) {
    return Reason::kInterval;
  }
  // Nothing to track from (a blank view): the next textured frame takes over.
  if (camera.keyframe_tracks.size() < kMinCorners) {
    return frame.tracks.size() >= kMinCorners ? Reason::kTracking : Reason::kNone;
  }
  std::vector<double> moved;
  for (const auto& [from, to] : SharedTracks(camera.keyframe_tracks, frame.tracks)) {
    moved.push_back(RadToDeg(std::atan((to - from).norm() / camera.focal_px)));
  }
  const double tracked = static_cast<double>(moved.size()) / camera.keyframe_tracks.size();
  if (tracked < options_.min_tracked_fraction) return Reason::kTracking;
  std::nth_element(moved.begin(), moved.begin() + moved.size() / 2, moved.end());
  if (!moved.empty() && moved[moved.size() / 2] >= options_.min_motion_deg) return Reason::kMotion;
  return Reason::kNone;
}

KeyframeSelector::Reason KeyframeSelector::Decide(Camera& camera, const SelectorFrame& frame, cv::Mat* small) {
  *small = Reduce(frame.image);
  if (!camera.has_keyframe || small->size() != camera.keyframe_small.size()) return Reason::kFirst;
  if (options_.max_interval_s > 0.0 &&
      static_cast<double>(frame.stamp_ns - camera.keyframe_stamp_ns) >= options_.max_interval_s * 1e9) {
    return Reason::kInterval;
  }
  if (camera.corners.size() < kMinCorners) {
    // Nothing to track from (a blank view): the next textured frame takes over.
    std::vector<cv::Point2f> corners;
    cv::goodFeaturesToTrack(*small, corners, options_.corners, 0.01, std::max(3.0, small->cols / 40.0));
    return corners.size() >= kMinCorners ? Reason::kTracking : Reason::kNone;
  }
  std::vector<cv::Point2f> next, back;
  std::vector<unsigned char> status, back_status;
  std::vector<float> err;
  const cv::Size window(21, 21);
  cv::calcOpticalFlowPyrLK(camera.keyframe_small, *small, camera.corners, next, status, err, window, 3);
  cv::calcOpticalFlowPyrLK(*small, camera.keyframe_small, next, back, back_status, err, window, 3);
  std::vector<double> moved;
  for (std::size_t i = 0; i < camera.corners.size(); ++i) {
    if (!status[i] || !back_status[i]) continue;
    const cv::Point2f d = back[i] - camera.corners[i];
    if (d.x * d.x + d.y * d.y > kForwardBackwardPx * kForwardBackwardPx) continue;
    const cv::Point2f m = next[i] - camera.corners[i];
    moved.push_back(RadToDeg(std::atan(std::sqrt(m.x * m.x + m.y * m.y) / camera.focal_px)));
  }
  const double tracked = static_cast<double>(moved.size()) / camera.corners.size();
  if (tracked < options_.min_tracked_fraction) return Reason::kTracking;
  std::nth_element(moved.begin(), moved.begin() + moved.size() / 2, moved.end());
  if (!moved.empty() && moved[moved.size() / 2] >= options_.min_motion_deg) return Reason::kMotion;
  return Reason::kNone;
}

std::vector<SelectorFrame> KeyframeSelector::Offer(const SelectorFrame& offered) {
  const auto start = std::chrono::steady_clock::now();
  // Every frame of a camera is tracked, keyframe or not.
  const SelectorFrame frame = options_.tracks ? Track(offered) : offered;
  ++stats_.frames;
  std::vector<SelectorFrame> keyframes;
  Camera& camera = cameras_[frame.camera];
  cv::Mat small;
  // A keyframe capture of another camera (never this camera's own: a camera
  // faster than the tolerance would make every frame a keyframe).
  const bool rig_capture =
      std::any_of(keyframe_stamps_.begin(), keyframe_stamps_.end(), [&](const std::pair<std::int64_t, std::string>& k) {
        return k.second != frame.camera && SameCapture(k.first, frame.stamp_ns);
      });
  Reason reason = Reason::kNone;
  if (rig_capture) {
    // Another camera made this capture a keyframe: this camera's frame of it
    // is one too (its own tracking is not needed).
    if (!options_.tracks) small = Reduce(frame.image);
    ++stats_.by_rig;
    MakeKeyframe(camera, frame, small);
    keyframes.push_back(frame);
  } else {
    reason = options_.tracks ? DecideByTracks(camera, frame) : Decide(camera, frame, &small);
  }
  if (reason != Reason::kNone) {
    switch (reason) {
      case Reason::kFirst: ++stats_.first; break;
      case Reason::kMotion: ++stats_.by_motion; break;
      case Reason::kTracking: ++stats_.by_tracking; break;
      case Reason::kInterval: ++stats_.by_interval; break;
      case Reason::kNone: break;
    }
    MakeKeyframe(camera, frame, small);
    keyframes.push_back(frame);
    keyframe_stamps_.emplace_back(frame.stamp_ns, frame.camera);
    if (keyframe_stamps_.size() > kRememberedCaptures) keyframe_stamps_.pop_front();
    // The other cameras' frames of this capture that arrived before it.
    for (auto& [name, other] : cameras_) {
      if (name == frame.camera) continue;
      for (auto it = other.held.begin(); it != other.held.end(); ++it) {
        if (!SameCapture(it->stamp_ns, frame.stamp_ns)) continue;
        ++stats_.by_rig;
        --stats_.skipped;
        MakeKeyframe(other, *it, options_.tracks ? cv::Mat() : Reduce(it->image));
        keyframes.push_back(*it);
        // Frames held before it are older than the new keyframe: no longer promotable.
        other.held.erase(other.held.begin(), it + 1);
        break;
      }
    }
  } else if (!rig_capture) {
    ++stats_.skipped;
    camera.held.push_back(frame);
    while (static_cast<int>(camera.held.size()) > options_.held_frames) camera.held.pop_front();
  }
  if (!keyframes.empty()) camera.held.clear();
  std::sort(keyframes.begin(), keyframes.end(), [](const SelectorFrame& a, const SelectorFrame& b) {
    return a.stamp_ns != b.stamp_ns ? a.stamp_ns < b.stamp_ns : a.camera < b.camera;
  });
  stats_.tracking_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return keyframes;
}

}  // namespace rotation_averaging
