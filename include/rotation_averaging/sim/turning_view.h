// A camera turning on the spot over a still image: view t is view 0 moved
// by the homography K R_t K^-1 (exact for a turning camera), with the
// grey-level noise of a sensor drawn anew for each view. The truth of where
// a point of one view lies in another, for measuring how precisely tracks
// and matches place it (feature_tracker_test, rotavg_track_precision).
#ifndef ROTATION_AVERAGING_SIM_TURNING_VIEW_H_
#define ROTATION_AVERAGING_SIM_TURNING_VIEW_H_

#include <Eigen/Core>
#include <opencv2/core.hpp>

namespace rotation_averaging {

struct TurningViewOptions {
  int width = 640, height = 480;  // of each view
  double focal_px = 420.0;        // principal point at the view's centre
  double step_deg = 0.8;          // about the view's y axis per view, and 0.4 of it about x
  double noise_grey = 2.0;        // standard deviation of the noise, grey levels
};

class TurningView {
 public:
  // `base`: 8-bit grey, at least the view's size; view 0 is its middle.
  TurningView(const cv::Mat& base, const TurningViewOptions& options);

  Eigen::Matrix3d Homography(int t) const;  // pixel of view 0 -> pixel of view t
  cv::Mat View(int t) const;                // the image of view t (borders reflect the base)
  // Distance (px) of `pt` in view t from where `p0` of view 0 lies there.
  double Error(int t, const Eigen::Vector2d& p0, const Eigen::Vector2d& pt) const;

 private:
  cv::Mat base_;
  TurningViewOptions options_;
  Eigen::Matrix3d k_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SIM_TURNING_VIEW_H_
