#include "rotation_averaging/ros/image_conversion.h"

#include <cv_bridge/cv_bridge.h>
#include <sensor_msgs/image_encodings.h>

#include <algorithm>
#include <cstdint>
#include <opencv2/imgcodecs.hpp>
#include <sstream>
#include <string>
#include <vector>

namespace rotation_averaging {
namespace {

// The largest keyframe accepted, whatever camera_info says: above
// any sensor a mapping stack runs at keyframe rate (134 Mpixel), and a bound
// on what one message can make the decoder allocate (a progressive JPEG holds
// every coefficient of the image while it decodes).
constexpr std::uint64_t kMaxKeyframePixels = std::uint64_t{1} << 27;


// The sensor readout of REP 104: which full-resolution pixels the image
// holds (roi, all zero for the whole sensor) and how many of them each of
// its pixels combines (binning, 0 meaning 1). K's convention puts a pixel's
// centre at its integer coordinate, so the binned pixel u' averages the
// full-resolution pixels x_offset + b u' ... x_offset + b u' + b - 1 and
// lies at their centre, u = x_offset + b u' + (b - 1) / 2. image_geometry's
// PinholeCameraModel leaves out the (b - 1) / 2, which puts a 2 x 2 binned
// image's keypoints a quarter of its pixel off K (docs/decisions.md, "A
// binned pixel at the centre of its block": five times the median error on
// the binned demo).
struct Readout {
  unsigned binning_x = 1, binning_y = 1;
  unsigned x_offset = 0, y_offset = 0;
  unsigned width = 0, height = 0;  // of the region, full-resolution pixels; 0: unknown
  bool windowed = false;           // a region of interest or binning other than 1
};

// REP 104: a roi of all zeros is the whole sensor.
bool HasRegionOfInterest(const sensor_msgs::RegionOfInterest& roi) {
  return roi.x_offset != 0 || roi.y_offset != 0 || roi.width != 0 || roi.height != 0;
}

bool ReadoutFromInfo(const sensor_msgs::CameraInfo& info, Readout* readout, std::string* error) {
  // Far beyond any sensor's binning: a value this large is a corrupt message.
  constexpr unsigned kMaxBinning = 64;
  Readout r;
  r.binning_x = std::max(1u, info.binning_x);
  r.binning_y = std::max(1u, info.binning_y);
  if (r.binning_x > kMaxBinning || r.binning_y > kMaxBinning) {
    *error = "binning " + std::to_string(info.binning_x) + " x " + std::to_string(info.binning_y) + " (at most " +
             std::to_string(kMaxBinning) + ")";
    return false;
  }
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  const bool has_roi = HasRegionOfInterest(roi);
  if (has_roi) {
    if (roi.width == 0 || roi.height == 0) {
      *error = "region of interest at (" + std::to_string(roi.x_offset) + ", " + std::to_string(roi.y_offset) +
               ") has no size";
      return false;
    }
    // In 64 bits: offset + width of two 32-bit fields may wrap around.
    const auto beyond = [](std::uint64_t offset, std::uint64_t extent, std::uint64_t limit) {
      return limit > 0 && offset + extent > limit;
    };
    if (beyond(roi.x_offset, roi.width, info.width) || beyond(roi.y_offset, roi.height, info.height)) {
      *error = "region of interest " + std::to_string(roi.width) + " x " + std::to_string(roi.height) + " at (" +
               std::to_string(roi.x_offset) + ", " + std::to_string(roi.y_offset) + ") does not lie on the " +
               std::to_string(info.width) + " x " + std::to_string(info.height) + " sensor";
      return false;
    }
    r.x_offset = roi.x_offset;
    r.y_offset = roi.y_offset;
    r.width = roi.width;
    r.height = roi.height;
  } else {
    r.width = info.width;
    r.height = info.height;
  }
  if (r.width > 0 && (r.width < r.binning_x || r.height < r.binning_y)) {
    *error = "binning " + std::to_string(r.binning_x) + " x " + std::to_string(r.binning_y) + " leaves no pixel of " +
             std::to_string(r.width) + " x " + std::to_string(r.height);
    return false;
  }
  r.windowed = has_roi || r.binning_x > 1 || r.binning_y > 1;
  *readout = r;
  return true;
}

// K (or P's left 3x3) of the full sensor as the camera of the readout's image.
Eigen::Matrix3d ReadoutIntrinsics(const Eigen::Matrix3d& full, const Readout& r) {
  if (!r.windowed) return full;
  Eigen::Matrix3d to_image = Eigen::Matrix3d::Identity();
  to_image(0, 0) = 1.0 / r.binning_x;
  to_image(1, 1) = 1.0 / r.binning_y;
  to_image(0, 2) = -(r.x_offset + 0.5 * (r.binning_x - 1.0)) / r.binning_x;
  to_image(1, 2) = -(r.y_offset + 0.5 * (r.binning_y - 1.0)) / r.binning_y;
  return to_image * full;
}

}  // namespace

// The decoder allocates the whole image from the header before it reads the
// pixels, so a damaged or hostile header of a few bytes asks for gigabytes.
// PNG and JPEG are what image_transport's compressed transport sends; any
// other format is refused.
std::string CompressedImageSize(const std::vector<std::uint8_t>& d, std::uint32_t* width, std::uint32_t* height) {
  auto be16 = [&d](std::size_t at) { return static_cast<std::uint32_t>(d[at] << 8 | d[at + 1]); };
  auto be32 = [&](std::size_t at) { return be16(at) << 16 | be16(at + 2); };
  static const std::uint8_t kPng[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  if (d.size() >= 24 && std::equal(kPng, kPng + 8, d.begin())) {
    if (d[12] != 'I' || d[13] != 'H' || d[14] != 'D' || d[15] != 'R') return "";
    *width = be32(16);
    *height = be32(20);
    return "PNG";
  }
  if (d.size() < 4 || d[0] != 0xFF || d[1] != 0xD8) return "";
  // JPEG: marker segments up to the first start-of-frame, which holds the size.
  std::size_t at = 2;
  while (at + 4 <= d.size()) {
    if (d[at] != 0xFF) return "";
    const std::uint8_t marker = d[at + 1];
    if (marker == 0xFF) {  // fill byte
      ++at;
      continue;
    }
    if (marker == 0xD9 || marker == 0xDA) return "";  // end of image or scan data before any frame
    const std::uint32_t length = be16(at + 2);
    if (length < 2) return "";
    const bool start_of_frame = marker >= 0xC0 && marker <= 0xCF && marker != 0xC4 && marker != 0xC8 &&
                                marker != 0xCC;
    if (start_of_frame) {
      if (at + 9 > d.size() || length < 7) return "";
      *height = be16(at + 5);
      *width = be16(at + 7);
      return "JPEG";
    }
    at += 2 + length;
  }
  return "";
}

bool IsRectifiedTopic(const std::string& topic, ImageType image_type) {
  if (image_type == ImageType::kRaw) return false;
  if (image_type == ImageType::kRectified) return true;
  const std::size_t slash = topic.find_last_of('/');
  const std::string name = slash == std::string::npos ? topic : topic.substr(slash + 1);
  return name.rfind("image_rect", 0) == 0;
}

bool CameraFromInfo(const sensor_msgs::CameraInfo& info, bool rectified, CameraIntrinsics* camera,
                    std::string* error, cv::Size* image_size) {
  *camera = CameraIntrinsics();
  Readout readout;
  if (!ReadoutFromInfo(info, &readout, error)) return false;
  if (image_size) {
    *image_size = readout.width > 0 ? cv::Size(static_cast<int>(readout.width / readout.binning_x),
                                               static_cast<int>(readout.height / readout.binning_y))
                                    : cv::Size(0, 0);
  }
  if (rectified) {
    // image_proc's rectified image is seen by the camera P describes; a
    // camera_info without P (all zero) falls back to K.
    const bool has_p = info.P[0] != 0.0 || info.P[5] != 0.0;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) camera->k(r, c) = has_p ? info.P[4 * r + c] : info.K[3 * r + c];
    if (!IsCameraIntrinsics(camera->k)) {
      *error = std::string("no valid ") + (has_p ? "P" : "K") + " for a rectified image (" + kCameraIntrinsicsRule + ")";
      return false;
    }
    camera->k = ReadoutIntrinsics(camera->k, readout);
    return true;
  }
  for (int i = 0; i < 9; ++i) camera->k(i / 3, i % 3) = info.K[i];
  if (!ParseDistortionModel(info.distortion_model, &camera->distortion)) {
    *error = "unknown distortion_model '" + info.distortion_model +
             "' (plumb_bob, rational_polynomial, equidistant; none or empty with D all zero)";
    return false;
  }
  camera->coefficients = info.D;
  std::string why;
  if (!IsCameraIntrinsics(camera->k)) {
    *error = std::string("no valid K (") + kCameraIntrinsicsRule + ")";
    return false;
  }
  camera->k = ReadoutIntrinsics(camera->k, readout);
  if (!camera->Validate(&why)) {
    *error = "D does not fit distortion_model '" + info.distortion_model + "': " + why;
    return false;
  }
  return true;
}

std::string DescribeCamera(const std::string& frame, const CameraIntrinsics& camera, bool rectified,
                           const sensor_msgs::CameraInfo& info) {
  std::ostringstream out;
  out << frame << ": f " << camera.k(0, 0) << ", " << camera.k(1, 1) << " px, ";
  const sensor_msgs::RegionOfInterest& roi = info.roi;
  if (HasRegionOfInterest(roi)) {
    out << "region " << roi.width << " x " << roi.height << " at (" << roi.x_offset << ", " << roi.y_offset
        << ") of the sensor, ";
  }
  if (info.binning_x > 1 || info.binning_y > 1) {
    out << "binned " << std::max(1u, info.binning_x) << " x " << std::max(1u, info.binning_y) << ", ";
  }
  if (camera.HasDistortion()) {
    out << "keypoints undistorted by " << DistortionModelName(camera.distortion) << " (";
    for (std::size_t i = 0; i < camera.coefficients.size(); ++i) out << (i ? " " : "") << camera.coefficients[i];
    out << ")";
  } else {
    out << (rectified ? "rectified image (camera_info's P)" : "no distortion in camera_info");
  }
  return out.str();
}

bool CameraOfImage(const std::string& frame, const cv::Mat& grey, const sensor_msgs::CameraInfo& info, bool rectified,
                   CameraIntrinsics* camera, std::string* error) {
  std::string why;
  cv::Size size;
  if (!CameraFromInfo(info, rectified, camera, &why, &size)) {
    *error = "camera_info of " + frame + ": " + why;
    return false;
  }
  if (size.width > 0 && (size.width != grey.cols || size.height != grey.rows)) {
    std::string expected = std::to_string(size.width) + " x " + std::to_string(size.height);
    if (size.width != static_cast<int>(info.width) || size.height != static_cast<int>(info.height)) {
      expected += " (camera_info's " + std::to_string(info.width) + " x " + std::to_string(info.height) +
                  " sensor through its roi and binning)";
    }
    *error = "image of " + frame + " is " + std::to_string(grey.cols) + " x " + std::to_string(grey.rows) +
             ", its camera_info says " + expected;
    return false;
  }
  return true;
}

bool DecodeImageMsg(const sensor_msgs::Image& image, cv::Mat* grey, std::string* error) {
  // cv_bridge compares height * step with the data's size, and step with
  // width * bytes per pixel, in 32 bits: a product that wraps around passes,
  // and the copy then reads gigabytes past the data. Checked in 64 bits first.
  // (The description is built only for a rejection, not for every image.)
  auto from = [&image] {
    return "image from " + image.header.frame_id + " (" + image.encoding + ", " + std::to_string(image.width) + "x" +
           std::to_string(image.height) + ", step " + std::to_string(image.step) + ", " +
           std::to_string(image.data.size()) + " bytes)";
  };
  std::uint64_t pixel_bytes = 0;
  try {
    pixel_bytes = static_cast<std::uint64_t>(sensor_msgs::image_encodings::bitDepth(image.encoding) / 8) *
                  sensor_msgs::image_encodings::numChannels(image.encoding);
  } catch (const std::exception&) {
    *error = from() + " has an unknown encoding";
    return false;
  }
  if (image.width == 0 || image.height == 0 || std::uint64_t{image.width} * image.height > kMaxKeyframePixels ||
      std::uint64_t{image.step} < std::uint64_t{image.width} * pixel_bytes ||
      std::uint64_t{image.height} * image.step != image.data.size()) {
    *error = from() + " is malformed: its size, step and data do not agree";
    return false;
  }
  try {
    // toCvCopy: the keyframe outlives the message.
    *grey = cv_bridge::toCvCopy(image, sensor_msgs::image_encodings::MONO8)->image;
  } catch (const std::exception& e) {
    *error = "image from " + image.header.frame_id + " does not decode (" + image.encoding + "): " + e.what();
    return false;
  }
  return true;
}

bool DecodeCompressedImageMsg(const sensor_msgs::CompressedImage& image, const sensor_msgs::CameraInfo& info,
                              bool rectified, cv::Mat* grey, std::string* error) {
  auto from = [&image] { return "compressed image from " + image.header.frame_id + " (" + image.format + ")"; };
  std::uint32_t width = 0, height = 0;
  const std::string format = CompressedImageSize(image.data, &width, &height);
  if (format.empty()) {
    *error = from() + " is neither PNG nor JPEG, or its header is cut short";
    return false;
  }
  // The size camera_info gives the image (its sensor through roi and
  // binning), or its transpose (an EXIF orientation that the decoder
  // applies; CameraOfImage then compares the decoded image).
  CameraIntrinsics camera;
  std::string why;
  cv::Size size;
  if (!CameraFromInfo(info, rectified, &camera, &why, &size)) {
    *error = "camera_info of " + image.header.frame_id + ": " + why;
    return false;
  }
  const std::uint32_t w = static_cast<std::uint32_t>(size.width), h = static_cast<std::uint32_t>(size.height);
  const bool sized = w > 0 && h > 0;
  const bool as_info = (width == w && height == h) || (width == h && height == w);
  const bool plausible = width > 0 && height > 0 && std::uint64_t{width} * height <= kMaxKeyframePixels;
  if (!plausible || (sized && !as_info)) {
    *error = from() + ": its " + format + " header declares " + std::to_string(width) + "x" + std::to_string(height) +
             " pixels, " +
             (plausible ? "not camera_info's " + std::to_string(w) + "x" + std::to_string(h)
                        : "an empty or implausibly large image");
    return false;
  }
  try {
    *grey = cv::imdecode(image.data, cv::IMREAD_GRAYSCALE);
  } catch (const cv::Exception&) {
    grey->release();
  }
  if (grey->empty()) {
    *error = from() + " does not decode";
    return false;
  }
  return true;
}

}  // namespace rotation_averaging
