#include "rotation_averaging/frontend/features/feature_tracker.h"

#include <algorithm>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>
#include <opencv2/video/tracking.hpp>

#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {

bool FeatureTrackerOptions::Validate(std::string* error) const {
  return OptionCheck()
      .AtLeast("max_tracks", max_tracks, 10)
      .AtLeast("track_min_spacing_px", min_spacing_px, 1.0)
      .Within("track_replenish_fraction", replenish_fraction, 0.0, 1.0)
      .Above("track_forward_backward_px", forward_backward_px, 0.0)
      .AtLeast("track_window_px", window_px, 5)
      .Within("track_pyramid_levels", pyramid_levels, 0, 8)
      .Ok(error);
}

std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> SharedTracks(const std::vector<TrackedPoint>& first,
                                                                      const std::vector<TrackedPoint>& second) {
  std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> shared;
  auto a = first.begin();
  auto b = second.begin();
  while (a != first.end() && b != second.end()) {
    if (a->id < b->id) {
      ++a;
    } else if (b->id < a->id) {
      ++b;
    } else {
      shared.emplace_back(a->px, b->px);
      ++a;
      ++b;
    }
  }
  return shared;
}

std::vector<cv::Mat> TrackPyramid(const cv::Mat& grey, const FeatureTrackerOptions& options, bool with_derivatives) {
  std::vector<cv::Mat> pyramid;
  cv::buildOpticalFlowPyramid(grey, pyramid, cv::Size(options.window_px, options.window_px), options.pyramid_levels,
                              with_derivatives);
  return pyramid;
}

void RetrackBetween(const std::vector<cv::Mat>& pyramid1, const std::vector<cv::Mat>& pyramid2,
                    const std::vector<cv::Point2f>& points1, std::vector<cv::Point2f>* points2,
                    std::vector<bool>* kept, const FeatureTrackerOptions& options) {
  kept->assign(points1.size(), false);
  if (points1.empty()) return;
  const cv::Size window(options.window_px, options.window_px);
  const cv::TermCriteria stop(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01);
  // KLT's window moves without deforming: over a keyframe pair's motion the
  // view's perspective changes, and a point drawn from a deformed window is
  // biased. The first image warped by the homography that the tracks fit
  // (exact for a turning camera, close for distant structure) looks like
  // the second, and the points are re-tracked from it.
  std::vector<cv::Point2f> from = points1;
  std::vector<cv::Mat> warped_pyramid;
  const std::vector<cv::Mat>* source = &pyramid1;
  cv::Mat h;
  if (points1.size() >= 8) h = cv::findHomography(points1, *points2, cv::RANSAC, 2.0, cv::noArray(), 200, 0.995);
  if (!h.empty()) {
    cv::Mat warped;
    cv::warpPerspective(pyramid1[0], warped, h, pyramid2[0].size(), cv::INTER_LINEAR, cv::BORDER_REPLICATE);
    warped_pyramid = TrackPyramid(warped, options);
    source = &warped_pyramid;
    cv::perspectiveTransform(points1, from, h);
  }
  std::vector<cv::Point2f> next = *points2, back = from;
  std::vector<unsigned char> status, back_status;
  std::vector<float> err;
  cv::calcOpticalFlowPyrLK(*source, pyramid2, from, next, status, err, window, options.pyramid_levels, stop,
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  cv::calcOpticalFlowPyrLK(pyramid2, *source, next, back, back_status, err, window, options.pyramid_levels, stop,
                           cv::OPTFLOW_USE_INITIAL_FLOW);
  const float limit = static_cast<float>(options.forward_backward_px * options.forward_backward_px);
  const cv::Size size = pyramid2[0].size();
  for (std::size_t i = 0; i < points1.size(); ++i) {
    const cv::Point2f d = back[i] - from[i];
    const cv::Point2f& p = next[i];
    const bool inside = p.x >= 1.0f && p.y >= 1.0f && p.x < size.width - 2.0f && p.y < size.height - 2.0f;
    if (!status[i] || !back_status[i] || !inside || d.x * d.x + d.y * d.y > limit) continue;
    (*points2)[i] = p;
    (*kept)[i] = true;
  }
}

FeatureTracker::FeatureTracker(const FeatureTrackerOptions& options) : options_(options) {}

void FeatureTracker::Reset() {
  pyramid_.clear();
  points_.clear();
  ids_.clear();
}

std::vector<TrackedPoint> FeatureTracker::Track(const cv::Mat& grey) {
  const cv::Size window(options_.window_px, options_.window_px);
  std::vector<cv::Mat> pyramid = TrackPyramid(grey, options_);
  if (!pyramid_.empty() && pyramid_[0].size() != pyramid[0].size()) Reset();
  if (!points_.empty()) {
    std::vector<cv::Point2f> next, back;
    std::vector<unsigned char> status, back_status;
    std::vector<float> err;
    const cv::TermCriteria stop(cv::TermCriteria::COUNT | cv::TermCriteria::EPS, 30, 0.01);
    cv::calcOpticalFlowPyrLK(pyramid_, pyramid, points_, next, status, err, window, options_.pyramid_levels, stop);
    // Backward from where the points landed (the forward result as the start).
    back = points_;
    cv::calcOpticalFlowPyrLK(pyramid, pyramid_, next, back, back_status, err, window, options_.pyramid_levels, stop,
                             cv::OPTFLOW_USE_INITIAL_FLOW);
    const float limit = static_cast<float>(options_.forward_backward_px * options_.forward_backward_px);
    const float border = 1.0f;
    std::size_t kept = 0;
    for (std::size_t i = 0; i < points_.size(); ++i) {
      const cv::Point2f d = back[i] - points_[i];
      const cv::Point2f& p = next[i];
      const bool inside = p.x >= border && p.y >= border && p.x < grey.cols - 1 - border && p.y < grey.rows - 1 - border;
      if (!status[i] || !back_status[i] || !inside || d.x * d.x + d.y * d.y > limit) continue;
      points_[kept] = p;
      ids_[kept] = ids_[i];
      ++kept;
    }
    points_.resize(kept);
    ids_.resize(kept);
  }
  pyramid_ = std::move(pyramid);
  if (static_cast<double>(points_.size()) < options_.replenish_fraction * options_.max_tracks) Replenish(grey);
  std::vector<TrackedPoint> out(points_.size());
  for (std::size_t i = 0; i < points_.size(); ++i) {
    out[i].id = ids_[i];
    out[i].px = Eigen::Vector2d(points_[i].x, points_[i].y);
  }
  // Kept tracks keep their order and new ones come after them with larger
  // ids: the list is already in id order.
  return out;
}

void FeatureTracker::Replenish(const cv::Mat& grey) {
  const int wanted = options_.max_tracks - static_cast<int>(points_.size());
  if (wanted <= 0) return;
  cv::Mat mask(grey.size(), CV_8UC1, cv::Scalar(255));
  const int radius = static_cast<int>(std::lround(options_.min_spacing_px));
  for (const cv::Point2f& p : points_) cv::circle(mask, cv::Point(cvRound(p.x), cvRound(p.y)), radius, 0, -1);
  std::vector<cv::Point2f> corners;
  cv::goodFeaturesToTrack(grey, corners, wanted, 0.01, options_.min_spacing_px, mask);
  for (const cv::Point2f& c : corners) {
    points_.push_back(c);
    ids_.push_back(next_id_++);
  }
}

}  // namespace rotation_averaging
