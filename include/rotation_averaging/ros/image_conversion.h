// From image messages to what the front end takes: camera_info to the
// image's camera (its readout and lens included), and an image message
// (raw or compressed) to 8-bit grey, each checked against the other. Beside
// msg_conversion: the one crossing of images and their cameras from ROS into
// the libraries.
#ifndef ROTATION_AVERAGING_ROS_IMAGE_CONVERSION_H_
#define ROTATION_AVERAGING_ROS_IMAGE_CONVERSION_H_

#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>

#include <cstdint>
#include <opencv2/core.hpp>
#include <string>
#include <vector>

#include "rotation_averaging/ros/pipeline_config.h"
#include "rotation_averaging/frontend/geometry/camera_model.h"

namespace rotation_averaging {

// Whether images on `topic` are rectified under PipelineConfig::image_type.
bool IsRectifiedTopic(const std::string& topic, ImageType image_type);

// The camera of an image described by `info`: K, distortion_model and D for
// a raw image; P's left 3x3 and no distortion for a rectified one. K and P
// are the full sensor's (width x height); a driver that reads out a region
// of interest or bins pixels (REP 104: roi in full-resolution pixels, then
// binning_x x binning_y blocks, 0 meaning 1) delivers a smaller image, whose
// camera is that K moved by the region's offset and scaled by the binning,
// with each binned pixel at the centre of its block (see the .cpp). The
// distortion acts on normalised coordinates and carries over unchanged.
// `image_size` (optional) gets the size the image must have: the region's
// (the full sensor's without one) divided by the binning, or 0 x 0 where
// camera_info states no size (width 0). False, with `error`, for a K (or P)
// that is not a camera's, an unknown distortion_model (named), a D that does
// not fit its model, such as non-zero coefficients with no model, or a
// region of interest that does not lie on the sensor or leaves no binned
// pixel.
bool CameraFromInfo(const sensor_msgs::CameraInfo& info, bool rectified, CameraIntrinsics* camera,
                    std::string* error, cv::Size* image_size = nullptr);

// The camera of the decoded image `grey` of `frame` (CameraFromInfo), whose
// size must be the one camera_info gives it. False, with `error` naming the
// frame and the sizes, otherwise.
bool CameraOfImage(const std::string& frame, const cv::Mat& grey, const sensor_msgs::CameraInfo& info, bool rectified,
                   CameraIntrinsics* camera, std::string* error);

// "cam0: f 458.654, 457.296 px, keypoints undistorted by plumb_bob (...)":
// how the keypoints of `frame`'s images are undistorted, for the logs.
std::string DescribeCamera(const std::string& frame, const CameraIntrinsics& camera, bool rectified,
                           const sensor_msgs::CameraInfo& info);

// A raw image as 8-bit grey (a copy: it outlives the message). False, with
// `error`, for an unknown encoding, a size, step and data that do not agree
// (checked in 64 bits before cv_bridge, which checks in 32), an image larger
// than any keyframe, or one that does not convert.
bool DecodeImageMsg(const sensor_msgs::Image& image, cv::Mat* grey, std::string* error);

// A PNG or JPEG image as 8-bit grey. Its header's size is read first and
// must be camera_info's (or its transpose, an EXIF orientation) and
// plausible: the decoder allocates what the header declares. False, with
// `error`, otherwise, or when it does not decode.
bool DecodeCompressedImageMsg(const sensor_msgs::CompressedImage& image, const sensor_msgs::CameraInfo& info,
                              bool rectified, cv::Mat* grey, std::string* error);

// The size a PNG or JPEG declares in its header, read before decoding.
// Returns the format's name, or "" when the bytes are neither (or their
// header is cut short).
std::string CompressedImageSize(const std::vector<std::uint8_t>& data, std::uint32_t* width, std::uint32_t* height);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_ROS_IMAGE_CONVERSION_H_
