#include "rotation_averaging/frontend/geometry/camera_model.h"

#include <yaml-cpp/yaml.h>

#include <Eigen/Geometry>
#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <opencv2/calib3d.hpp>
#include <opencv2/imgproc.hpp>

#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {

const char* const kCameraIntrinsicsRule = "finite, positive focal lengths, last row 0 0 1";

bool IsCameraIntrinsics(const Eigen::Matrix3d& k) {
  return k.allFinite() && k(0, 0) > 0.0 && k(1, 1) > 0.0 && k(2, 0) == 0.0 && k(2, 1) == 0.0 &&
         std::abs(k(2, 2) - 1.0) <= 1e-9;
}
namespace {

// A keypoint whose undistortion reprojects further than this from where it
// was detected is one the model does not invert (its iteration diverged far
// outside the calibrated field of view); a converged one is within 1e-6 px.
constexpr double kRoundTripTolerancePx = 0.01;

// OpenCV's fixed-point undistortion stops after 5 iterations by default,
// which leaves errors of a pixel and more near the corners of a strongly
// distorted lens (k1 = -0.28 at 752x480); these criteria run it to
// convergence.
const cv::TermCriteria kUndistortCriteria(cv::TermCriteria::MAX_ITER + cv::TermCriteria::EPS, 100, 1e-8);

// The coefficients as OpenCV takes them (plumb_bob and rational_polynomial
// padded to their full length).
std::vector<double> OpenCvCoefficients(const CameraIntrinsics& camera) {
  std::vector<double> d = camera.coefficients;
  const std::size_t n = camera.distortion == DistortionModel::kPlumbBob            ? 5
                        : camera.distortion == DistortionModel::kRationalPolynomial ? 8
                                                                                    : 4;
  d.resize(n, 0.0);
  return d;
}

// Normalised ideal coordinates -> normalised distorted coordinates.
Eigen::Vector2d Distort(const CameraIntrinsics& camera, const std::vector<double>& d, const Eigen::Vector2d& x) {
  if (camera.distortion == DistortionModel::kEquidistant) {
    const double r = x.norm();
    if (r < 1e-12) return x;
    const double theta = std::atan(r), t2 = theta * theta;
    const double theta_d = theta * (1.0 + t2 * (d[0] + t2 * (d[1] + t2 * (d[2] + t2 * d[3]))));
    return x * (theta_d / r);
  }
  const double r2 = x.squaredNorm(), xy = x.x() * x.y();
  double radial = 1.0 + r2 * (d[0] + r2 * (d[1] + r2 * d[4]));
  if (d.size() >= 8) radial /= 1.0 + r2 * (d[5] + r2 * (d[6] + r2 * d[7]));
  return {x.x() * radial + 2.0 * d[2] * xy + d[3] * (r2 + 2.0 * x.x() * x.x()),
          x.y() * radial + d[2] * (r2 + 2.0 * x.y() * x.y()) + 2.0 * d[3] * xy};
}

bool Fail(std::string* error, const std::string& message) {
  if (error) *error = message;
  return false;
}

bool ReadYamlCamera(const std::string& path, CameraIntrinsics* camera, int* width, int* height,
                    const std::string& which, std::string* error) {
  YAML::Node root;
  try {
    root = YAML::LoadFile(path);
  } catch (const YAML::Exception& e) {
    return Fail(error, path + ": not a YAML camera file: " + e.what());
  }
  if (!root.IsMap()) return Fail(error, path + ": not a YAML camera file (no mapping at the top)");
  YAML::Node node = root;
  if (!which.empty()) {
    node = root[which];
    if (!node || !node.IsMap()) return Fail(error, path + ": has no camera '" + which + "'");
  } else if (!root["camera_matrix"] && !root["intrinsics"]) {
    // A Kalibr camchain: cam0, cam1, ... The first, in name order.
    std::vector<std::string> cams;
    for (const auto& entry : root) {
      const std::string name = entry.first.as<std::string>("");
      if (name.rfind("cam", 0) == 0 && entry.second.IsMap() && entry.second["intrinsics"]) cams.push_back(name);
    }
    if (cams.empty()) {
      return Fail(error, path + ": no camera_matrix (ROS camera_calibration), intrinsics (EuRoC, Kalibr) or camN entry");
    }
    node = root[*std::min_element(cams.begin(), cams.end())];
  }
  auto numbers = [&](const YAML::Node& n, const std::string& key, std::vector<double>* out) {
    YAML::Node seq = n.IsMap() && n["data"] ? n["data"] : n;
    if (!seq.IsSequence()) return Fail(error, path + ": " + key + " is not a list of numbers");
    out->clear();
    for (const YAML::Node& v : seq) {
      double value = 0.0;
      if (!v.IsScalar() || !ParseDouble(v.Scalar(), &value) || !std::isfinite(value)) {
        return Fail(error, path + ": " + key + " holds '" + (v.IsScalar() ? v.Scalar() : "?") +
                               "', not a finite number");
      }
      out->push_back(value);
    }
    return true;
  };
  if (node["camera_model"] && node["camera_model"].IsScalar() && node["camera_model"].Scalar() != "pinhole") {
    return Fail(error, path + ": camera_model '" + node["camera_model"].Scalar() + "' is not supported (pinhole is)");
  }
  std::vector<double> values;
  camera->k.setIdentity();
  if (node["camera_matrix"]) {
    if (!numbers(node["camera_matrix"], "camera_matrix", &values)) return false;
    if (values.size() != 9) return Fail(error, path + ": camera_matrix needs 9 numbers");
    for (int i = 0; i < 9; ++i) camera->k(i / 3, i % 3) = values[i];
  } else if (node["intrinsics"]) {
    if (!numbers(node["intrinsics"], "intrinsics", &values)) return false;
    if (values.size() != 4) return Fail(error, path + ": intrinsics needs 4 numbers (fu fv cu cv)");
    camera->k(0, 0) = values[0];
    camera->k(1, 1) = values[1];
    camera->k(0, 2) = values[2];
    camera->k(1, 2) = values[3];
  } else {
    return Fail(error, path + ": the camera has neither camera_matrix nor intrinsics");
  }
  const std::string model = node["distortion_model"] ? node["distortion_model"].as<std::string>("") : "";
  if (!ParseDistortionModel(model, &camera->distortion)) {
    return Fail(error, path + ": unknown distortion_model '" + model +
                           "' (plumb_bob, radtan, rational_polynomial, equidistant, none)");
  }
  camera->coefficients.clear();
  for (const char* key : {"distortion_coefficients", "distortion_coeffs", "D"}) {
    if (node[key]) {
      if (!numbers(node[key], key, &camera->coefficients)) return false;
      break;
    }
  }
  int w = 0, h = 0;
  if (node["image_width"] && node["image_height"]) {
    w = node["image_width"].as<int>(0);
    h = node["image_height"].as<int>(0);
  } else if (node["resolution"] && node["resolution"].IsSequence() && node["resolution"].size() == 2) {
    w = node["resolution"][0].as<int>(0);
    h = node["resolution"][1].as<int>(0);
  }
  if (width) *width = w;
  if (height) *height = h;
  std::string why;
  if (!camera->Validate(&why)) return Fail(error, path + ": " + why);
  return true;
}

bool ReadColmapCamera(const std::vector<std::string>& t, LineReader& reader, CameraIntrinsics* camera, int* width,
                      int* height, std::string* error) {
  // Parameters after "ID MODEL WIDTH HEIGHT", and which of them are what.
  struct Model {
    const char* name;
    std::size_t parameters;
    bool one_focal;
    DistortionModel distortion;
  };
  static const Model kModels[] = {
      {"SIMPLE_PINHOLE", 3, true, DistortionModel::kNone},
      {"PINHOLE", 4, false, DistortionModel::kNone},
      {"SIMPLE_RADIAL", 4, true, DistortionModel::kPlumbBob},  // f cx cy k
      {"RADIAL", 5, true, DistortionModel::kPlumbBob},         // f cx cy k1 k2
      {"OPENCV", 8, false, DistortionModel::kPlumbBob},        // fx fy cx cy k1 k2 p1 p2
      {"OPENCV_FISHEYE", 8, false, DistortionModel::kEquidistant},  // fx fy cx cy k1 k2 k3 k4
  };
  const Model* model = nullptr;
  for (const Model& m : kModels) {
    if (t[1] == m.name) model = &m;
  }
  if (!model) return Fail(error, reader.Where("COLMAP camera model " + t[1] + " is not supported"));
  std::vector<double> p;
  for (std::size_t i = 4; i < t.size(); ++i) {
    double v;
    if (!ParseDouble(t[i], &v)) return Fail(error, reader.Where("'" + t[i] + "' is not a number"));
    p.push_back(v);
  }
  if (p.size() != model->parameters) {
    return Fail(error, reader.Where(t[1] + " needs " + std::to_string(model->parameters) + " parameters"));
  }
  Eigen::Matrix3d& k = camera->k;
  k.setIdentity();
  const std::size_t c = model->one_focal ? 1 : 2;  // index of cx
  k(0, 0) = p[0];
  k(1, 1) = model->one_focal ? p[0] : p[1];
  // COLMAP puts the centre of the top-left pixel at (0.5, 0.5); OpenCV's
  // keypoints, K.txt and camera_info put it at (0, 0).
  k(0, 2) = p[c] - 0.5;
  k(1, 2) = p[c + 1] - 0.5;
  camera->distortion = model->distortion;
  camera->coefficients.assign(p.begin() + static_cast<std::ptrdiff_t>(c + 2), p.end());
  if (camera->distortion == DistortionModel::kNone) camera->coefficients.clear();
  if (camera->distortion == DistortionModel::kPlumbBob) camera->coefficients.resize(4, 0.0);  // k1 [k2], p1 = p2 = 0
  int w = 0, h = 0;
  ParseInt(t[2], &w);
  ParseInt(t[3], &h);
  if (width) *width = w;
  if (height) *height = h;
  std::string why;
  if (!camera->Validate(&why)) {  // K a camera's, coefficients finite
    return Fail(error, reader.Where(t[1] + " needs finite parameters and a K that is a camera's (" +
                                    kCameraIntrinsicsRule + ")"));
  }
  return true;
}

}  // namespace

const char* DistortionModelName(DistortionModel model) {
  switch (model) {
    case DistortionModel::kPlumbBob: return "plumb_bob";
    case DistortionModel::kRationalPolynomial: return "rational_polynomial";
    case DistortionModel::kEquidistant: return "equidistant";
    case DistortionModel::kNone: break;
  }
  return "none";
}

bool ParseDistortionModel(const std::string& name, DistortionModel* model) {
  if (name.empty() || name == "none") *model = DistortionModel::kNone;
  else if (name == "plumb_bob" || name == "radtan" || name == "radial-tangential") *model = DistortionModel::kPlumbBob;
  else if (name == "rational_polynomial") *model = DistortionModel::kRationalPolynomial;
  else if (name == "equidistant" || name == "fisheye") *model = DistortionModel::kEquidistant;
  else return false;
  return true;
}

bool CameraIntrinsics::HasDistortion() const {
  if (distortion == DistortionModel::kNone) return false;
  return std::any_of(coefficients.begin(), coefficients.end(), [](double c) { return c != 0.0; });
}

double FocalScalingError(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k, const cv::Size& size) {
  if (!camera.HasDistortion() || size.width <= 0 || size.height <= 0) return 0.0;
  Eigen::Matrix3d longer = scaled_k;
  longer(0, 0) *= 1.01;
  longer(1, 1) *= 1.01;
  double worst = 0.0;
  for (const Eigen::Vector2d corner : {Eigen::Vector2d(0.0, 0.0), Eigen::Vector2d(size.width - 1.0, 0.0),
                                       Eigen::Vector2d(0.0, size.height - 1.0),
                                       Eigen::Vector2d(size.width - 1.0, size.height - 1.0)}) {
    const Eigen::Vector2d given = (scaled_k.inverse() * camera.Undistort(corner, scaled_k).homogeneous()).head<2>();
    const Eigen::Vector2d moved = (longer.inverse() * camera.Undistort(corner, longer).homogeneous()).head<2>();
    const Eigen::Vector2d scaled = given / 1.01;
    const double step = (given - scaled).norm();
    if (!given.allFinite() || !moved.allFinite() || !(step > 0.0)) return INFINITY;  // the lens does not invert there
    worst = std::max(worst, (moved - scaled).norm() / step);
  }
  return worst;
}

bool CameraIntrinsics::Validate(std::string* error) const {
  if (!IsCameraIntrinsics(k)) return Fail(error, std::string("K is not a camera's (") + kCameraIntrinsicsRule + ")");
  for (double c : coefficients) {
    if (!std::isfinite(c)) return Fail(error, "distortion coefficients must be finite");
  }
  const std::size_t n = coefficients.size();
  const std::string name = DistortionModelName(distortion);
  // Counts as ROS drivers fill D: plumb_bob with 4 or 5, rational_polynomial
  // with 8, equidistant with 4; more coefficients than the model has must be
  // zero (some drivers pad D). No coefficients at all is no distortion, as
  // image_geometry reads it (an uncalibrated camera_info names a model with
  // an empty D).
  std::size_t expected = 0;
  bool ok = true;
  switch (distortion) {
    case DistortionModel::kNone:
      expected = 0;
      break;
    case DistortionModel::kPlumbBob:
      expected = 5;
      ok = n == 0 || n >= 4;
      break;
    case DistortionModel::kRationalPolynomial:
      expected = 8;
      ok = n == 0 || n >= 5;
      break;
    case DistortionModel::kEquidistant:
      expected = 4;
      ok = n == 0 || n >= 4;
      break;
  }
  for (std::size_t i = expected; i < n; ++i) ok = ok && coefficients[i] == 0.0;
  if (!ok) {
    return Fail(error, name + " takes " +
                           (distortion == DistortionModel::kNone ? std::string("no coefficients (or zeros)")
                                                                 : std::to_string(expected) + " coefficients") +
                           ", got " + std::to_string(n) + (n > expected ? " with non-zero extras" : ""));
  }
  return true;
}

Eigen::Vector2d CameraIntrinsics::Undistort(const Eigen::Vector2d& pixel, const Eigen::Matrix3d& scaled_k) const {
  std::vector<Eigen::Vector2d> one{pixel};
  UndistortPixels(*this, scaled_k, &one);
  return one[0];
}

CameraIntrinsics PlumbBobFromDivision(const Eigen::Matrix3d& k, double lambda, double max_radius) {
  CameraIntrinsics lens;
  lens.k = k;
  if (lambda == 0.0 || !std::isfinite(lambda) || !(max_radius > 0.0) || !std::isfinite(max_radius)) return lens;
  // r_d = r_u (1 + k1 r_u^2 + k2 r_u^4 + k3 r_u^6) at radii up to max_radius,
  // r_u = r_d / (1 + lambda r_d^2): linear in (k1, k2, k3), in the distorted
  // radius's error (pixels, up to the focal length).
  constexpr int kSamples = 64;
  Eigen::Matrix<double, kSamples, 3> a;
  Eigen::Matrix<double, kSamples, 1> b;
  for (int i = 0; i < kSamples; ++i) {
    const double rd = max_radius * (i + 1) / kSamples;
    const double denominator = 1.0 + lambda * rd * rd;
    if (!(denominator > 0.1)) return lens;  // folds over: not a lens
    const double ru = rd / denominator, ru2 = ru * ru;
    a.row(i) << ru * ru2, ru * ru2 * ru2, ru * ru2 * ru2 * ru2;
    b(i) = rd - ru;
  }
  const Eigen::Vector3d c = a.colPivHouseholderQr().solve(b);
  if (!c.allFinite()) return lens;
  lens.distortion = DistortionModel::kPlumbBob;
  lens.coefficients = {c(0), c(1), 0.0, 0.0, c(2)};
  return lens;
}

double CornerRadius(const Eigen::Matrix3d& k) {
  return std::hypot(k(0, 2) / k(0, 0), k(1, 2) / k(1, 1));
}

int UndistortPixels(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k,
                    std::vector<Eigen::Vector2d>* pixels) {
  if (!camera.HasDistortion() || pixels->empty()) return 0;
  const std::vector<double> d = OpenCvCoefficients(camera);
  cv::Mat k_cv(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) k_cv.at<double>(r, c) = scaled_k(r, c);
  cv::Mat src(static_cast<int>(pixels->size()), 1, CV_64FC2), dst;
  for (std::size_t i = 0; i < pixels->size(); ++i) {
    src.at<cv::Vec2d>(static_cast<int>(i)) = cv::Vec2d((*pixels)[i].x(), (*pixels)[i].y());
  }
  // Output in normalised coordinates (P empty); mapped back with K below, so
  // that the round trip is checked in the same terms.
  if (camera.distortion == DistortionModel::kEquidistant) {
    cv::fisheye::undistortPoints(src, dst, k_cv, d, cv::noArray(), cv::noArray(), kUndistortCriteria);
  } else {
    cv::undistortPoints(src, dst, k_cv, d, cv::noArray(), cv::noArray(), kUndistortCriteria);
  }
  int failed = 0;
  const Eigen::Matrix3d& k = scaled_k;
  for (std::size_t i = 0; i < pixels->size(); ++i) {
    const cv::Vec2d u = dst.at<cv::Vec2d>(static_cast<int>(i));
    const Eigen::Vector2d x(u[0], u[1]);
    const Eigen::Vector2d back = (k * Distort(camera, d, x).homogeneous()).hnormalized();
    if (!x.allFinite() || !((back - (*pixels)[i]).norm() <= kRoundTripTolerancePx)) {
      (*pixels)[i].setConstant(std::numeric_limits<double>::quiet_NaN());
      ++failed;
      continue;
    }
    (*pixels)[i] = (k * x.homogeneous()).hnormalized();
  }
  return failed;
}

int RedoUndistortion(const CameraIntrinsics& camera, const Eigen::Matrix3d& from_k, const Eigen::Matrix3d& to_k,
                     std::vector<Eigen::Vector2d>* pixels) {
  if (!camera.HasDistortion() || pixels->empty()) return 0;
  const std::vector<double> d = OpenCvCoefficients(camera);
  const Eigen::Matrix3d from_inverse = from_k.inverse();
  std::vector<Eigen::Vector2d> raw(pixels->size());
  for (std::size_t i = 0; i < pixels->size(); ++i) {
    const Eigen::Vector2d x = (from_inverse * (*pixels)[i].homogeneous()).hnormalized();
    raw[i] = (from_k * Distort(camera, d, x).homogeneous()).hnormalized();
  }
  UndistortPixels(camera, to_k, &raw);
  int kept = 0;
  for (std::size_t i = 0; i < pixels->size(); ++i) {
    if (raw[i].allFinite()) {
      (*pixels)[i] = raw[i];
    } else {
      ++kept;
    }
  }
  return kept;
}

int UndistortFeatures(const CameraIntrinsics& camera, const Eigen::Matrix3d& scaled_k, ImageFeatures* features) {
  if (!camera.HasDistortion()) return 0;
  if (UndistortPixels(camera, scaled_k, &features->keypoints_px) == 0) return 0;
  const int n = static_cast<int>(features->keypoints_px.size());
  std::vector<int> keep;
  for (int i = 0; i < n; ++i) {
    if (features->keypoints_px[i].allFinite()) keep.push_back(i);
  }
  const auto select = [&keep, n](auto* values) {
    if (static_cast<int>(values->size()) != n) return;
    for (std::size_t r = 0; r < keep.size(); ++r) (*values)[r] = (*values)[keep[r]];
    values->resize(keep.size());
  };
  select(&features->keypoints_px);
  select(&features->strength);
  select(&features->words);
  if (features->descriptors.rows == n) {
    cv::Mat kept(static_cast<int>(keep.size()), features->descriptors.cols, features->descriptors.type());
    for (std::size_t r = 0; r < keep.size(); ++r) features->descriptors.row(keep[r]).copyTo(kept.row(static_cast<int>(r)));
    features->descriptors = kept;
  }
  return n - static_cast<int>(keep.size());
}

cv::Mat DistortImage(const cv::Mat& ideal, const CameraIntrinsics& camera, int margin_px) {
  const int margin = std::max(0, margin_px);
  const cv::Size size(ideal.cols - 2 * margin, ideal.rows - 2 * margin);
  if (ideal.empty() || size.width <= 0 || size.height <= 0) return cv::Mat();
  if (!camera.HasDistortion()) return ideal(cv::Rect(margin, margin, size.width, size.height)).clone();
  // For every pixel of the lens's image, where its ray lands in the ideal one.
  std::vector<Eigen::Vector2d> pixels;
  pixels.reserve(static_cast<std::size_t>(size.area()));
  for (int v = 0; v < size.height; ++v)
    for (int u = 0; u < size.width; ++u) pixels.emplace_back(u, v);
  UndistortPixels(camera, camera.k, &pixels);
  cv::Mat map_x(size, CV_32F), map_y(size, CV_32F);
  for (int v = 0, i = 0; v < size.height; ++v) {
    for (int u = 0; u < size.width; ++u, ++i) {
      const Eigen::Vector2d& p = pixels[static_cast<std::size_t>(i)];
      map_x.at<float>(v, u) = p.allFinite() ? static_cast<float>(p.x() + margin) : -1e6f;
      map_y.at<float>(v, u) = p.allFinite() ? static_cast<float>(p.y() + margin) : -1e6f;
    }
  }
  cv::Mat out;
  cv::remap(ideal, out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

int LensMarginPx(const CameraIntrinsics& camera, const cv::Size& size) {
  if (!camera.HasDistortion()) return 0;
  // The border of the raw image, every pixel of it: where the lens looks
  // furthest out.
  std::vector<Eigen::Vector2d> border;
  for (int u = 0; u < size.width; ++u) {
    border.emplace_back(u, 0);
    border.emplace_back(u, size.height - 1);
  }
  for (int v = 0; v < size.height; ++v) {
    border.emplace_back(0, v);
    border.emplace_back(size.width - 1, v);
  }
  UndistortPixels(camera, camera.k, &border);
  double beyond = 0.0;
  for (const Eigen::Vector2d& p : border) {
    if (!p.allFinite()) continue;
    beyond = std::max({beyond, -p.x(), -p.y(), p.x() - (size.width - 1), p.y() - (size.height - 1)});
  }
  // One pixel more for the bilinear sample's neighbour.
  return static_cast<int>(std::ceil(beyond)) + (beyond > 0.0 ? 1 : 0);
}

cv::Mat UndistortImage(const cv::Mat& raw, const CameraIntrinsics& camera) {
  if (!camera.HasDistortion() || raw.empty()) return raw.clone();
  cv::Mat k_cv(3, 3, CV_64F);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) k_cv.at<double>(r, c) = camera.k(r, c);
  const std::vector<double> d = OpenCvCoefficients(camera);
  cv::Mat map_x, map_y;
  if (camera.distortion == DistortionModel::kEquidistant) {
    cv::fisheye::initUndistortRectifyMap(k_cv, d, cv::Mat::eye(3, 3, CV_64F), k_cv, raw.size(), CV_32FC1, map_x,
                                         map_y);
  } else {
    cv::initUndistortRectifyMap(k_cv, d, cv::noArray(), k_cv, raw.size(), CV_32FC1, map_x, map_y);
  }
  cv::Mat out;
  cv::remap(raw, out, map_x, map_y, cv::INTER_LINEAR, cv::BORDER_CONSTANT, cv::Scalar::all(0));
  return out;
}

bool ParseDistortionSpec(const std::string& text, CameraIntrinsics* camera, std::string* error) {
  const std::size_t colon = text.find(':');
  const std::string name = text.substr(0, colon);
  DistortionModel model;
  if (!ParseDistortionModel(name, &model)) {
    return Fail(error, "unknown distortion model '" + name + "' (plumb_bob, rational_polynomial, equidistant)");
  }
  std::vector<double> coefficients;
  if (colon != std::string::npos) {
    for (const std::string& token : SplitTokens(text.substr(colon + 1), true)) {
      double v;
      if (!ParseDouble(token, &v) || !std::isfinite(v)) return Fail(error, "'" + token + "' is not a finite number");
      coefficients.push_back(v);
    }
  }
  CameraIntrinsics parsed = *camera;
  parsed.distortion = model;
  parsed.coefficients = coefficients;
  std::string why;
  if (!parsed.Validate(&why)) return Fail(error, "distortion '" + text + "': " + why);
  *camera = parsed;
  return true;
}

bool ReadIntrinsics(const std::string& path, Eigen::Matrix3d* k, std::string* error) {
  LineReader reader(path);
  if (!reader.IsOpen()) {
    *error = "cannot open " + path;
    return false;
  }
  std::vector<double> values;
  std::string line;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    for (const std::string& t : SplitTokens(line)) {
      double v;
      if (!ParseDouble(t, &v) || !std::isfinite(v)) {
        *error = reader.Where("'" + t + "' is not a finite number");
        return false;
      }
      values.push_back(v);
    }
  }
  if (values.size() != 9) {
    *error = path + ": expected 9 numbers (3x3 K), found " + std::to_string(values.size());
    return false;
  }
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) (*k)(r, c) = values[3 * r + c];
  if (!IsCameraIntrinsics(*k)) {
    *error = path + ": K must be a camera's (" + kCameraIntrinsicsRule + ")";
    return false;
  }
  return true;
}

bool ReadCameraIntrinsics(const std::string& path, CameraIntrinsics* intrinsics, std::string* error, int* width,
                          int* height, const std::string& camera) {
  if (width) *width = 0;
  if (height) *height = 0;
  *intrinsics = CameraIntrinsics();
  std::string ext = std::filesystem::path(path).extension().string();
  std::transform(ext.begin(), ext.end(), ext.begin(), [](unsigned char c) { return std::tolower(c); });
  if (ext == ".yaml" || ext == ".yml") return ReadYamlCamera(path, intrinsics, width, height, camera, error);
  LineReader reader(path);
  if (!reader.IsOpen()) return Fail(error, "cannot open " + path);
  std::string line;
  while (reader.Next(&line)) {
    if (IsBlankOrComment(line)) continue;
    const std::vector<std::string> t = SplitTokens(line);
    double first = 0.0;
    // "ID MODEL WIDTH HEIGHT PARAMS...": a COLMAP camera line (its model is a
    // word; a K.txt line is all numbers).
    if (t.size() >= 4 && !ParseDouble(t[1], &first)) {
      return ReadColmapCamera(t, reader, intrinsics, width, height, error);
    }
    break;  // not a COLMAP camera line: try K.txt
  }
  return ReadIntrinsics(path, &intrinsics->k, error);
}

}  // namespace rotation_averaging
