#include "rotation_averaging/sim/turning_view.h"

#include <Eigen/Geometry>
#include <cmath>
#include <opencv2/imgproc.hpp>

namespace rotation_averaging {

TurningView::TurningView(const cv::Mat& base, const TurningViewOptions& options) : base_(base), options_(options) {
  k_ << options.focal_px, 0, options.width / 2.0, 0, options.focal_px, options.height / 2.0, 0, 0, 1;
}

Eigen::Matrix3d TurningView::Homography(int t) const {
  const double a = t * options_.step_deg * M_PI / 180.0;
  const Eigen::Matrix3d r =
      (Eigen::AngleAxisd(a, Eigen::Vector3d::UnitY()) * Eigen::AngleAxisd(0.4 * a, Eigen::Vector3d::UnitX()))
          .toRotationMatrix();
  return k_ * r * k_.inverse();
}

cv::Mat TurningView::View(int t) const {
  // Pixel of view t -> pixel of the base image, whose middle is view 0.
  Eigen::Matrix3d centre = Eigen::Matrix3d::Identity();
  centre(0, 2) = (base_.cols - options_.width) / 2.0;
  centre(1, 2) = (base_.rows - options_.height) / 2.0;
  const Eigen::Matrix3d m = centre * Homography(t).inverse();
  cv::Mat mc(3, 3, CV_64F);
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j) mc.at<double>(i, j) = m(i, j);
  }
  cv::Mat view, grey, noise(options_.height, options_.width, CV_32F);
  cv::warpPerspective(base_, view, mc, cv::Size(options_.width, options_.height),
                      cv::INTER_LINEAR | cv::WARP_INVERSE_MAP, cv::BORDER_REFLECT);
  cv::RNG rng(1000 + t);
  rng.fill(noise, cv::RNG::NORMAL, 0.0, options_.noise_grey);
  view.convertTo(grey, CV_32F);
  grey += noise;
  grey.convertTo(view, CV_8U);
  return view;
}

double TurningView::Error(int t, const Eigen::Vector2d& p0, const Eigen::Vector2d& pt) const {
  return ((Homography(t) * p0.homogeneous()).hnormalized() - pt).norm();
}

}  // namespace rotation_averaging
