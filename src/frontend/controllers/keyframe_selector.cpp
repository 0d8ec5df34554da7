#include "rotation_averaging/frontend/controllers/keyframe_selector.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/frontend/features/features.h"
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
// KLT on the reduced images: its window (px) and pyramid levels above the
// image.
constexpr int kSelectionWindowPx = 21;
constexpr int kSelectionLevels = 3;
// Keyframe capture stamps remembered for the rig's other cameras.
constexpr std::size_t kRememberedCaptures = 16;
// The rotation is estimated from at least this many tracked corners.
constexpr std::size_t kMinRotationCorners = 12;
// A corner is explained by a model within this many pixels (of the image
// tracked: KLT's forward-backward tolerance).
constexpr double kRotationInlierPx = 1.0;
constexpr int kRefineIterations = 20;
// A camera's rotation is checked at most this often (s of its stamps): on
// a 20-30 Hz stream every few frames, at a fraction of the check's cost per
// frame, the camera turning a degree or two past the threshold before it is
// seen; photographs a second apart are each checked.
constexpr double kRotationCheckPeriodS = 0.2;

// Corners tracked on the reduced images (`from` in the keyframe, `to` in the
// frame: pixels of the reduced images, `scale` = reduced / full width)
// placed again on the full-resolution images: one Lucas-Kanade pass at full
// resolution, started where the reduced images put them. The reduction
// gives away the precision a rotation needs: on Strecha entry-P10 at 768 px,
// tracked at 320 px, a photograph that turned 10.4 deg since its keyframe was
// estimated at 5.2 deg and let go; placed again, every photograph that
// turned past 6 deg is a keyframe (keyframe_selector_test). Corners that do
// not converge are dropped.
void PlaceAtFullResolution(const cv::Mat& keyframe, const cv::Mat& image, double scale,
                           std::vector<Eigen::Vector2d>* from, std::vector<Eigen::Vector2d>* to) {
  std::vector<cv::Point2f> a, b;
  for (std::size_t i = 0; i < from->size(); ++i) {
    // Pixel centres: reduced x is full (x + 0.5) / scale - 0.5.
    a.emplace_back(static_cast<float>(((*from)[i].x() + 0.5) / scale - 0.5),
                   static_cast<float>(((*from)[i].y() + 0.5) / scale - 0.5));
    b.emplace_back(static_cast<float>(((*to)[i].x() + 0.5) / scale - 0.5),
                   static_cast<float>(((*to)[i].y() + 0.5) / scale - 0.5));
  }
  if (a.empty()) return;
  std::vector<unsigned char> status;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(keyframe, image, a, b, status, err, cv::Size(15, 15), 1,
                           cv::TermCriteria(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 20, 0.01),
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  from->clear();
  to->clear();
  for (std::size_t i = 0; i < a.size(); ++i) {
    if (!status[i]) continue;
    from->emplace_back(a[i].x, a[i].y);
    to->emplace_back(b[i].x, b[i].y);
  }
}

// The camera's rotation (deg) from its keyframe to a frame, from corners
// tracked between them (`from`, `to`: pixels of images with intrinsics
// `scaled_k`). The rotation-only model (the closed-form rotation between the
// corners' bearings) where it explains most of them within
// kRotationInlierPx: a camera turning in place, or hardly moved, where the
// essential matrix is undetermined. Otherwise the essential matrix's
// (RANSAC, then the pose that puts the corners in front of both cameras):
// a camera circling what it looks at turns while the corners on it hardly
// move, so the corners' motion alone misses the rotation. NaN when neither
// is found.
double TrackedRotationDeg(std::vector<Eigen::Vector2d> from, std::vector<Eigen::Vector2d> to,
                          const CameraIntrinsics& intrinsics, const Eigen::Matrix3d& scaled_k) {
  if (intrinsics.HasDistortion()) {
    UndistortPixels(intrinsics, scaled_k, &from);
    UndistortPixels(intrinsics, scaled_k, &to);
  }
  const Eigen::Matrix3d k_inv = scaled_k.inverse();
  const double focal = 0.5 * (scaled_k(0, 0) + scaled_k(1, 1));
  std::vector<Eigen::Vector3d> b1, b2;
  std::vector<cv::Point2d> n1, n2;
  std::vector<Eigen::Vector2d> p1, p2;
  for (std::size_t i = 0; i < from.size() && i < to.size(); ++i) {
    if (!from[i].allFinite() || !to[i].allFinite()) continue;
    p1.push_back(from[i]);
    p2.push_back(to[i]);
    b1.push_back((k_inv * from[i].homogeneous()).normalized());
    b2.push_back((k_inv * to[i].homogeneous()).normalized());
    n1.emplace_back(b1.back().x() / b1.back().z(), b1.back().y() / b1.back().z());
    n2.emplace_back(b2.back().x() / b2.back().z(), b2.back().y() / b2.back().z());
  }
  if (b1.size() < kMinRotationCorners) return std::numeric_limits<double>::quiet_NaN();
  // Rotation-only: R maximising sum b2 . R b1 (Kabsch).
  Eigen::Matrix3d h = Eigen::Matrix3d::Zero();
  for (std::size_t i = 0; i < b1.size(); ++i) h += b2[i] * b1[i].transpose();
  const Eigen::JacobiSVD<Eigen::Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  const Eigen::Matrix3d rotation = svd.matrixU() * d * svd.matrixV().transpose();
  std::size_t explained = 0;
  for (std::size_t i = 0; i < b1.size(); ++i) {
    explained += std::acos(std::clamp((rotation * b1[i]).dot(b2[i]), -1.0, 1.0)) * focal <= kRotationInlierPx;
  }
  if (2 * explained >= b1.size()) return RadToDeg(RotationAngleRad(rotation));
  cv::Mat mask;
  const cv::Mat e = cv::findEssentialMat(n1, n2, 1.0, cv::Point2d(0.0, 0.0), cv::RANSAC, 0.999,
                                         kRotationInlierPx / focal, mask);
  if (e.rows != 3 || e.cols != 3) return std::numeric_limits<double>::quiet_NaN();
  cv::Mat r, t;
  if (cv::recoverPose(e, n1, n2, r, t, 1.0, cv::Point2d(0.0, 0.0), mask) < static_cast<int>(kMinRotationCorners)) {
    return std::numeric_limits<double>::quiet_NaN();
  }
  // RANSAC's model is a minimal sample's: refined on its inliers by the
  // Sampson error, as the two-view estimation refines its poses.
  Eigen::Matrix3d essential_rotation;
  Eigen::Vector3d translation;
  for (int i = 0; i < 3; ++i) {
    translation(i) = t.at<double>(i);
    for (int j = 0; j < 3; ++j) essential_rotation(i, j) = r.at<double>(i, j);
  }
  std::vector<int> inliers;
  for (int i = 0; i < mask.rows; ++i) {
    if (mask.at<unsigned char>(i)) inliers.push_back(i);
  }
  RefinePoseOnInliers(p1, p2, inliers, scaled_k, scaled_k, &essential_rotation, &translation, kRefineIterations);
  return RadToDeg(RotationAngleRad(essential_rotation));
}

}  // namespace

bool KeyframeSelectionOptions::Validate(std::string* error) const {
  std::string tracker_error;
  return OptionCheck()
      .AtLeast("keyframe_min_motion_deg", min_motion_deg, 0.0)
      .AtLeast("keyframe_min_rotation_deg", min_rotation_deg, 0.0)
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
  camera.rotation_checked_ns = frame.stamp_ns;
  camera.has_keyframe = true;
  ++stats_.keyframes;
  if (options_.tracks) {
    camera.keyframe_tracks = frame.tracks;
    camera.keyframe_size = frame.image.size();
    camera.focal_px = 0.5 * (frame.intrinsics.k(0, 0) + frame.intrinsics.k(1, 1));
    return;
  }
  camera.keyframe_small = small;
  cv::buildOpticalFlowPyramid(small, camera.keyframe_pyramid, cv::Size(kSelectionWindowPx, kSelectionWindowPx),
                              kSelectionLevels, true);
  if (options_.min_rotation_deg > 0.0) camera.keyframe_full = frame.image;  // shared, not copied
  camera.scale = static_cast<double>(small.cols) / frame.image.cols;
  camera.focal_px = 0.5 * (frame.intrinsics.k(0, 0) + frame.intrinsics.k(1, 1)) * camera.scale;
  camera.corners.clear();
  cv::goodFeaturesToTrack(small, camera.corners, options_.corners, 0.01, std::max(3.0, small.cols / 40.0));
}

bool KeyframeSelector::RotationCheckDue(Camera& camera, const SelectorFrame& frame) const {
  if (!(options_.min_rotation_deg > 0.0) ||
      static_cast<double>(frame.stamp_ns - camera.rotation_checked_ns) < kRotationCheckPeriodS * 1e9) {
    return false;
  }
  camera.rotation_checked_ns = frame.stamp_ns;
  return true;
}

bool KeyframeSelector::RotatedEnough(const Camera& camera, const SelectorFrame& frame,
                                     std::vector<Eigen::Vector2d>* from, std::vector<Eigen::Vector2d>* to) {
  const auto start = std::chrono::steady_clock::now();
  // Tracks are full-resolution pixels already; the reduced images' corners
  // are placed again on the full images. Two sizes can reduce to one: a
  // frame of another size than its keyframe's is not compared.
  if (!options_.tracks &&
      (camera.keyframe_full.size() != frame.image.size() || camera.keyframe_full.type() != frame.image.type())) {
    return false;
  }
  double rotation = std::numeric_limits<double>::quiet_NaN();
  try {
    if (!options_.tracks) PlaceAtFullResolution(camera.keyframe_full, frame.image, camera.scale, from, to);
    rotation = TrackedRotationDeg(*from, *to, frame.intrinsics, frame.intrinsics.k);
  } catch (const cv::Exception&) {
    // Degenerate corners OpenCV refuses: no rotation to decide by.
  }
  ++stats_.rotation_checks;
  stats_.rotation_s += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return std::isfinite(rotation) && rotation >= options_.min_rotation_deg;
}

KeyframeSelector::Reason KeyframeSelector::DecideByCorners(Camera& camera, const SelectorFrame& frame,
                                                           std::size_t corners, std::vector<double> moved,
                                                           std::vector<Eigen::Vector2d>* from,
                                                           std::vector<Eigen::Vector2d>* to) {
  const double tracked = static_cast<double>(moved.size()) / corners;
  if (tracked < options_.min_tracked_fraction) return Reason::kTracking;
  std::nth_element(moved.begin(), moved.begin() + moved.size() / 2, moved.end());
  if (!moved.empty() && moved[moved.size() / 2] >= options_.min_motion_deg) return Reason::kMotion;
  if (RotationCheckDue(camera, frame) && RotatedEnough(camera, frame, from, to)) return Reason::kRotation;
  return Reason::kNone;
}

KeyframeSelector::Reason KeyframeSelector::DecideByTracks(Camera& camera, const SelectorFrame& frame) {
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
  std::vector<Eigen::Vector2d> from_points, to_points;
  for (const auto& [from, to] : SharedTracks(camera.keyframe_tracks, frame.tracks)) {
    moved.push_back(RadToDeg(std::atan((to - from).norm() / camera.focal_px)));
    from_points.push_back(from);
    to_points.push_back(to);
  }
  return DecideByCorners(camera, frame, camera.keyframe_tracks.size(), std::move(moved), &from_points, &to_points);
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
  // The keyframe's pyramid is kept and the frame's built once for both
  // directions: given images, each call would build both pyramids and the
  // first one's derivatives again (the same values).
  const cv::Size window(kSelectionWindowPx, kSelectionWindowPx);
  std::vector<cv::Mat> pyramid;
  cv::buildOpticalFlowPyramid(*small, pyramid, window, kSelectionLevels, true);
  cv::calcOpticalFlowPyrLK(camera.keyframe_pyramid, pyramid, camera.corners, next, status, err, window,
                           kSelectionLevels);
  cv::calcOpticalFlowPyrLK(pyramid, camera.keyframe_pyramid, next, back, back_status, err, window, kSelectionLevels);
  std::vector<double> moved;
  std::vector<Eigen::Vector2d> from_points, to_points;
  for (std::size_t i = 0; i < camera.corners.size(); ++i) {
    if (!status[i] || !back_status[i]) continue;
    const cv::Point2f d = back[i] - camera.corners[i];
    if (d.x * d.x + d.y * d.y > kForwardBackwardPx * kForwardBackwardPx) continue;
    const cv::Point2f m = next[i] - camera.corners[i];
    moved.push_back(RadToDeg(std::atan(std::sqrt(m.x * m.x + m.y * m.y) / camera.focal_px)));
    from_points.emplace_back(camera.corners[i].x, camera.corners[i].y);
    to_points.emplace_back(next[i].x, next[i].y);
  }
  return DecideByCorners(camera, frame, camera.corners.size(), std::move(moved), &from_points, &to_points);
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
      case Reason::kRotation: ++stats_.by_rotation; break;
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
