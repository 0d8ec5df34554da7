// Public header of rotation_averaging::frontend (docs/embedding.md).
// Camera models: pinhole intrinsics and the lens distortion models of ROS's
// sensor_msgs/CameraInfo, read from camera files, and the undistortion of
// keypoints (by OpenCV) that every two-view step relies on: the relative
// pose assumes an ideal pinhole camera, and a raw image's keypoints are not
// one's.
#ifndef ROTATION_AVERAGING_FRONTEND_GEOMETRY_CAMERA_MODEL_H_
#define ROTATION_AVERAGING_FRONTEND_GEOMETRY_CAMERA_MODEL_H_

#include <Eigen/Core>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/features/features.h"

namespace rotation_averaging {

// True if k can be a pinhole camera's intrinsics: finite, positive focal
// lengths, last row 0 0 1 (kCameraIntrinsicsRule, for messages).
bool IsCameraIntrinsics(const Eigen::Matrix3d& k);
extern const char* const kCameraIntrinsicsRule;

// The distortion models of sensor_msgs/CameraInfo (image_geometry's names),
// in OpenCV's parametrisation.
enum class DistortionModel {
  kNone,                // pinhole: the image is rectified or the lens is ideal
  kPlumbBob,            // radial-tangential: k1 k2 p1 p2 [k3] (COLMAP's RADIAL is k1 k2 with the rest 0)
  kRationalPolynomial,  // k1 k2 p1 p2 k3 k4 k5 k6
  kEquidistant,         // fisheye (OpenCV's cv::fisheye, Kalibr's equidistant): k1 k2 k3 k4
};

// "none", "plumb_bob", "rational_polynomial", "equidistant".
const char* DistortionModelName(DistortionModel model);
// ROS's names ("plumb_bob", "rational_polynomial", "equidistant"), Kalibr's
// and EuRoC's ("radtan", "radial-tangential", "equidistant"), OpenCV's
// "fisheye", and "none" or "" for no distortion. False for any other name:
// an unknown model is refused by name, never taken for no distortion.
bool ParseDistortionModel(const std::string& name, DistortionModel* model);

// Pinhole intrinsics of the full-resolution images and their lens
// distortion. K is in OpenCV's pixel convention (the centre of the top-left
// pixel at (0, 0)); the distortion acts on normalised coordinates, so it does
// not change when the image is resized.
struct CameraIntrinsics {
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();
  DistortionModel distortion = DistortionModel::kNone;
  std::vector<double> coefficients;  // in the model's order (above); kNone: empty or all zero

  // A model with a non-zero coefficient: keypoints need undistorting. A
  // rectified camera (no model, or every coefficient zero) leaves keypoints
  // exactly as detected.
  bool HasDistortion() const;
  // True if K is a camera's (IsCameraIntrinsics) and the coefficients are
  // finite and as many as the model takes (plumb_bob: 4 or 5; rational
  // polynomial: 8, or 5 with the rest zero; equidistant: 4; none at all: no
  // distortion, whatever the model); otherwise false with `error` saying
  // which.
  bool Validate(std::string* error) const;
  // The ideal pinhole pixel of a pixel of an image whose intrinsics are
  // `scaled_k` (K, or K scaled for a resized image). Returns the pixel
  // unchanged without distortion; NaN where the model does not invert (far
  // outside the calibrated field of view).
  Eigen::Vector2d Undistort(const Eigen::Vector2d& pixel, const Eigen::Matrix3d& scaled_k) const;
};

// How far a lens keeps its undistorted keypoints from scaling with the
// focal length: at the corners of an image of `size` with intrinsics
// `scaled_k`, the largest distance between the keypoint undistorted with a
// focal length 1% longer and the one undistorted with K divided by 1.01 (in
// normalised coordinates), over what the 1% moves it. 0 without
// distortion; a bundle adjustment that models a focal length error as a
// scale of the normalised keypoints (BundleAdjustmentFocal) is biased by
// about this fraction of the error.
double FocalScalingError(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k, const cv::Size& size);

// The plumb_bob lens (k1 k2 0 0 k3) of intrinsics `k` that undistorts as the
// one-parameter division model x_u = x_d / (1 + lambda |x_d|^2) does (x in
// normalised coordinates of `k`), fitted by least squares in the distorted
// radius over radii up to `max_radius` (normalised: an image's corner). The
// camera_info check estimates the division model (EstimateRadialDistortion);
// the front end undistorts by camera_info's models. kNone when lambda is 0 or
// not finite, or the division model folds over within max_radius.
CameraIntrinsics PlumbBobFromDivision(const Eigen::Matrix3d& k, double lambda, double max_radius);
// The normalised radius of the corner of an image of intrinsics `k` that is
// furthest from its principal point, the image being twice the principal
// point in size.
double CornerRadius(const Eigen::Matrix3d& k);

// Undistorts pixels of an image whose intrinsics are `scaled_k` in place (one
// OpenCV call for all of them). A pixel whose undistortion does not
// reproject onto it within a hundredth of a pixel (the iteration diverged:
// the model is not invertible there) becomes NaN. Returns how many did.
int UndistortPixels(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k,
                    std::vector<Eigen::Vector2d>* pixels);

// Pixels undistorted with intrinsics `from_k` (as UndistortPixels took
// them) moved to where undistorting the same raw pixels with `to_k` puts
// them: back through the lens with `from_k`, then undistorted with `to_k`.
// For a focal length corrected after keypoints were undistorted with the
// old one: the distortion acts on normalised coordinates, so a new K moves
// every keypoint, not only by the scale. A pixel that does not undistort
// with `to_k` stays where it was; returns how many did. Without distortion
// the pixels are the raw ones and are left as they are.
int RedoUndistortion(const CameraIntrinsics& camera, const Eigen::Matrix3d& from_k, const Eigen::Matrix3d& to_k,
                     std::vector<Eigen::Vector2d>* pixels);

// Undistorts the keypoints of features detected in an image with intrinsics
// `scaled_k`, dropping the features whose keypoint does not undistort (with
// their descriptors, strengths and words). Returns the number dropped.
// Without distortion the features are left as they are.
int UndistortFeatures(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k, ImageFeatures* features);

// Images through a lens (same size, same K): DistortImage resamples an
// ideal pinhole image as `camera`'s lens would have seen it (pixels whose
// ray the ideal image does not hold are black), UndistortImage the reverse
// (a raw image rectified, as image_proc does). Bilinear; `camera.k` is the
// images' own K. Without distortion both return the image unchanged.
// With a margin, the ideal image extends `margin_px` pixels beyond the lens's
// on every side (principal point moved by the margin) and the lens's image
// is that much smaller: a barrel lens sees further out than the pinhole
// image of its size, and a margin of LensMarginPx leaves no black pixel.
cv::Mat DistortImage(const cv::Mat& ideal, const CameraIntrinsics& camera, int margin_px = 0);
// How far beyond an image of `size` the rays of `camera`'s raw pixels land
// in its ideal pinhole image, in whole pixels (0 for a lens that only
// looks inside it).
int LensMarginPx(const CameraIntrinsics& camera, const cv::Size& size);
cv::Mat UndistortImage(const cv::Mat& raw, const CameraIntrinsics& camera);

// "plumb_bob:k1,k2,p1,p2,k3" (any model name ParseDistortionModel takes and
// its coefficients, comma separated) into `camera`'s distortion; K is kept.
bool ParseDistortionSpec(const std::string& text, CameraIntrinsics* camera, std::string* error);

// Reads a camera file:
//  * a K.txt (nine numbers, row-major), no distortion;
//  * a COLMAP cameras.txt (first camera: SIMPLE_PINHOLE, PINHOLE,
//    SIMPLE_RADIAL, RADIAL, OPENCV or OPENCV_FISHEYE), its principal point
//    moved by half a pixel into OpenCV's convention;
//  * YAML: ROS camera_calibration's file (camera_matrix, distortion_model,
//    distortion_coefficients), a EuRoC sensor.yaml or a Kalibr camchain
//    (intrinsics [fu fv cu cv], distortion_model, distortion_coefficients or
//    distortion_coeffs; a camchain's first camera, or `camera` such as
//    "cam1").
// `width` and `height` (optional) get the image size the file states (0 if
// none). False, with `error` naming the file and what is wrong (an unknown
// distortion model by its name), if the file does not describe a camera.
bool ReadCameraIntrinsics(const std::string& path, CameraIntrinsics* intrinsics, std::string* error,
                          int* width = nullptr, int* height = nullptr, const std::string& camera = "");
// Reads a 3x3 intrinsics matrix (nine numbers, row-major, whitespace separated).
bool ReadIntrinsics(const std::string& path, Eigen::Matrix3d* k, std::string* error);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_GEOMETRY_CAMERA_MODEL_H_
