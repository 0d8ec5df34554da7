// KLT feature tracks across the images of one camera, free of ROS: corners
// (Shi-Tomasi) followed from each image to the next by pyramidal
// Lucas-Kanade at full resolution, as VINS-Mono's front end tracks them.
//  * A track is kept when the point tracked back into the previous image
//    lands within `forward_backward_px` of where it started: a point that
//    slid along an edge or jumped to a look-alike ends there.
//  * When fewer than `replenish_fraction` of `max_tracks` are left, new
//    corners are detected at least `min_spacing_px` from every live track
//    and from each other, so that the tracks stay spread over the image.
//  * Every track has an id no other track of this tracker had (ids are not
//    reused after Reset): two images share a track when both hold its id,
//    and their points are then correspondences.
// The result of an image depends on the images before it alone (no
// timing, no thread count).
#ifndef ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURE_TRACKER_H_
#define ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURE_TRACKER_H_

#include <Eigen/Core>
#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

namespace rotation_averaging {

struct FeatureTrackerOptions {
  int max_tracks = 300;
  double min_spacing_px = 12.0;       // between detected corners and live tracks
  double replenish_fraction = 0.8;    // detect when fewer than this fraction of max_tracks are live
  double forward_backward_px = 0.5;   // largest round-trip error of a kept track
  int window_px = 21;                 // KLT window
  int pyramid_levels = 3;             // beyond the full-resolution image

  bool Validate(std::string* error) const;
};

// One track's point in one image (pixels of that image as given: raw,
// distorted pixels of a raw camera).
struct TrackedPoint {
  std::uint64_t id = 0;
  Eigen::Vector2d px = Eigen::Vector2d::Zero();
};

// The points of two images' shared tracks, in id order: (first's, second's).
// Both lists must be in increasing id order (as Track returns them).
std::vector<std::pair<Eigen::Vector2d, Eigen::Vector2d>> SharedTracks(const std::vector<TrackedPoint>& first,
                                                                      const std::vector<TrackedPoint>& second);

// The image pyramid KLT tracks on (full resolution and `pyramid_levels`
// halvings), as Track builds it; without the derivatives (a quarter of the
// memory, for a pyramid that is held), KLT computes them as it goes.
std::vector<cv::Mat> TrackPyramid(const cv::Mat& grey, const FeatureTrackerOptions& options,
                                  bool with_derivatives = true);

// Points of tracks two images share, re-tracked from the first image to
// the second directly (KLT from `points1`, starting at `points2`, then back
// from there): tracking from image to image adds each step's error to a
// track's point, re-tracking between the two keeps only that pair's. The
// points that come back within forward_backward_px get their new position
// in `points2`; `kept` says which did.
void RetrackBetween(const std::vector<cv::Mat>& pyramid1, const std::vector<cv::Mat>& pyramid2,
                    const std::vector<cv::Point2f>& points1, std::vector<cv::Point2f>* points2,
                    std::vector<bool>* kept, const FeatureTrackerOptions& options);

class FeatureTracker {
 public:
  explicit FeatureTracker(const FeatureTrackerOptions& options);

  // Tracks the live tracks into `grey` (8-bit, one channel) and replenishes
  // them; returns every live track's point in `grey`, in increasing id
  // order. An image of another size than the previous one starts anew.
  std::vector<TrackedPoint> Track(const cv::Mat& grey);
  // Forgets the previous image and its tracks (a gap in the stream).
  void Reset();
  std::size_t NumTracks() const { return ids_.size(); }

 private:
  void Replenish(const cv::Mat& grey);

  FeatureTrackerOptions options_;
  std::vector<cv::Mat> pyramid_;  // of the previous image
  std::vector<cv::Point2f> points_;
  std::vector<std::uint64_t> ids_;
  std::uint64_t next_id_ = 1;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_FEATURES_FEATURE_TRACKER_H_
