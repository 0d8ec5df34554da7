// libFuzzer target for the message-to-graph path: serialised ROS messages as
// the node receives them (RelativePose, RelativePoseArray, CameraInfo, Image,
// CompressedImage, /tf_static), deserialised, decoded and validated by the
// KeyframePipeline, fed through the rig model and the image front end into the
// averager, solved, and turned back into the output messages. Built and run by
// scripts/fuzz.sh (clang, -fsanitize=fuzzer,address,undefined).
//
// Input: records [kind: 1 byte][length: 2 bytes little endian][payload], each
// payload one serialised message (ROS wire format, as on a topic or in a bag).
// A message may be refused (it does not deserialise, or the pipeline rejects
// it); nothing may crash, and the solution must stay finite and orthonormal.
//
// Seeds: run the binary with ROTAVG_FUZZ_WRITE_SEEDS=DIR to write valid
// message sequences there (test/fuzz/corpus_messages was made that way).
#include <ros/serialization.h>
#include <sensor_msgs/CameraInfo.h>
#include <sensor_msgs/CompressedImage.h>
#include <sensor_msgs/Image.h>
#include <tf2_msgs/TFMessage.h>

#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <new>
#include <stdexcept>
#include <string>
#include <vector>

#include <opencv2/imgcodecs.hpp>

#include "rotation_averaging/RelativePose.h"
#include "rotation_averaging/RelativePoseArray.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/ros/keyframe_pipeline.h"

namespace ra = rotation_averaging;
namespace ser = ros::serialization;

namespace {

enum Kind : std::uint8_t { kPose = 0, kPoseArray, kCameraInfo, kImage, kCompressed, kStatic, kKinds };

// ROS's vector deserialiser resizes a vector before it checks that the
// stream holds that many elements, so a damaged length asks for gigabytes:
// roscpp and our replay catch the bad_alloc and drop the message, but under
// ASan operator new aborts instead of throwing. So a message is first
// deserialised into the same message type with an allocator that refuses
// anything larger than a bound (bad_alloc, as without ASan); only when that
// succeeds (every length agreed with the bytes) are the bytes deserialised
// into the real type, which then allocates the same, bounded, sizes.
template <class T>
struct BoundedAllocator {
  using value_type = T;
  template <class U>
  struct rebind {
    using other = BoundedAllocator<U>;
  };
  BoundedAllocator() = default;
  template <class U>
  BoundedAllocator(const BoundedAllocator<U>&) {}
  T* allocate(std::size_t n) {
    if (n > (std::size_t{64} << 20) / sizeof(T)) throw std::bad_alloc();
    return std::allocator<T>().allocate(n);
  }
  void deallocate(T* p, std::size_t n) { std::allocator<T>().deallocate(p, n); }
  template <class U>
  bool operator==(const BoundedAllocator<U>&) const { return true; }
  template <class U>
  bool operator!=(const BoundedAllocator<U>&) const { return false; }
};

template <class M>
bool DeserializeInto(const std::uint8_t* data, std::size_t size, M* msg) {
  try {
    ser::IStream stream(const_cast<std::uint8_t*>(data), static_cast<std::uint32_t>(size));
    ser::deserialize(stream, *msg);
    return true;
  } catch (const ser::StreamOverrunException&) {
  } catch (const std::bad_alloc&) {
  } catch (const std::length_error&) {
  }
  return false;
}

// As roscpp and rosbag do: a message whose bytes do not deserialise is dropped.
template <template <class> class Msg>
bool Deserialize(const std::uint8_t* data, std::size_t size, Msg<std::allocator<void>>* msg) {
  Msg<BoundedAllocator<void>> probe;
  return DeserializeInto(data, size, &probe) && DeserializeInto(data, size, msg);
}

void Check(bool ok, const char* what) {
  if (!ok) {
    std::fprintf(stderr, "fuzz_messages: invariant broken: %s\n", what);
    std::abort();
  }
}

void CheckRotation(const Eigen::Matrix3d& r, const char* what) {
  Check(r.allFinite(), what);
  Check((r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-6, what);
  Check(std::abs(r.determinant() - 1.0) < 1e-6, what);
}

ra::PipelineConfig Config() {
  ra::PipelineConfig config;
  config.averager.solve_period_s = 0.0;  // solved below, in this thread
  config.averager.averaging.posterior_covariance_max_views = 20000;  // as the node
  config.image_topics = {"/cam/image"};  // the image front end exists
  config.frontend.features.max_features = 200;
  return config;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  ra::KeyframePipeline pipeline(Config());
  sensor_msgs::CameraInfo info;
  bool have_info = false;
  std::size_t records = 0;
  std::string error;
  while (size >= 3 && records < 32) {
    const std::uint8_t kind = data[0] % kKinds;
    std::size_t length = data[1] | (static_cast<std::size_t>(data[2]) << 8);
    data += 3;
    size -= 3;
    if (length > size) length = size;
    const std::uint8_t* payload = data;
    data += length;
    size -= length;
    ++records;
    switch (kind) {
      case kPose: {
        ra::RelativePose pose;
        if (Deserialize(payload, length, &pose)) pipeline.AcceptRelativePose(pose, &error);
        break;
      }
      case kPoseArray: {
        ra::RelativePoseArray poses;
        if (Deserialize(payload, length, &poses)) {
          for (const ra::RelativePose& pose : poses.poses) pipeline.AcceptRelativePose(pose, &error);
        }
        break;
      }
      case kCameraInfo:
        have_info = Deserialize(payload, length, &info);
        break;
      case kImage:
      case kCompressed: {
        if (!have_info) break;
        ra::PendingKeyframe keyframe;
        bool decoded = false;
        if (kind == kImage) {
          sensor_msgs::Image image;
          decoded = Deserialize(payload, length, &image) && pipeline.DecodeImage(image, info, &keyframe, &error);
        } else {
          sensor_msgs::CompressedImage image;
          decoded = Deserialize(payload, length, &image) &&
                    pipeline.DecodeCompressedImage(image, info, &keyframe, &error);
        }
        if (decoded) {
          Check(keyframe.image.type() == CV_8UC1 && !keyframe.image.empty(), "decoded keyframe is 8-bit grey");
          // The front end runs on small images only: fuzzing is about input,
          // not about the feature detector's running time on large ones.
          if (keyframe.image.total() <= 160 * 120) pipeline.ProcessKeyframe(keyframe);
        }
        break;
      }
      case kStatic: {
        tf2_msgs::TFMessage statics;
        if (Deserialize(payload, length, &statics)) pipeline.AcceptStaticTransforms(statics);
        break;
      }
      default:
        break;
    }
  }
  ra::OnlineAverager& averager = pipeline.Averager();
  averager.SolveNow();
  const ra::OnlineAveragerStats stats = averager.Stats();
  Check(stats.accepted + stats.rejected_invalid + stats.dropped_queue_full + stats.dropped_cap <= stats.received,
        "every measurement counted once");
  std::shared_ptr<const ra::OnlineSolution> solution = averager.Solution();
  if (!solution) return 0;
  for (const auto& [key, r] : solution->orientations) CheckRotation(r, "solved orientation");
  for (const auto& [key, c] : solution->covariance) {
    Check(c.allFinite(), "posterior covariance is finite");
    Check((c - c.transpose()).norm() <= 1e-9 * (1.0 + c.norm()), "posterior covariance is symmetric");
  }
  for (const ra::SolvedEdge& e : solution->edges) {
    Check(std::isfinite(e.residual_deg) && std::isfinite(e.robust_weight), "edge residual and weight are finite");
  }
  const ra::OnlineSolution cameras = pipeline.CameraSolution(*solution);
  for (const auto& [key, r] : cameras.orientations) CheckRotation(r, "camera orientation");
  const ra::Orientations out = pipeline.OrientationsMsg(cameras, ros::Time(1.0));
  Check(out.keyframes.size() == cameras.orientations.size(), "one Orientations entry per keyframe");
  pipeline.KeyframeTransforms(cameras);
  pipeline.Markers(*solution, cameras, ros::Time(1.0));
  return 0;
}

// ---------------------------------------------------------------------------
// Seeds: valid message sequences for the corpus.
namespace {

template <class M>
void Append(Kind kind, const M& msg, std::vector<std::uint8_t>* out) {
  const std::uint32_t length = ser::serializationLength(msg);
  std::vector<std::uint8_t> bytes(length);
  ser::OStream stream(bytes.data(), length);
  ser::serialize(stream, msg);
  out->push_back(kind);
  out->push_back(length & 0xff);
  out->push_back((length >> 8) & 0xff);
  out->insert(out->end(), bytes.begin(), bytes.end());
}

ra::RelativePose Pose(const std::string& f1, double t1, const std::string& f2, double t2, double angle,
                      std::uint8_t source) {
  ra::RelativePose p;
  p.frame_id_1 = f1;
  p.stamp_1 = ros::Time(t1);
  p.frame_id_2 = f2;
  p.stamp_2 = ros::Time(t2);
  p.rotation.w = std::cos(angle / 2);
  p.rotation.z = std::sin(angle / 2);
  p.rotation_covariance = {1e-4, 0, 0, 0, 1e-4, 0, 0, 0, 2e-4};
  p.num_inliers = 100;
  p.source = source;
  return p;
}

sensor_msgs::CameraInfo Info(int width, int height) {
  sensor_msgs::CameraInfo info;
  info.header.frame_id = "cam";
  info.width = width;
  info.height = height;
  info.K = {40.0, 0, width / 2.0, 0, 40.0, height / 2.0, 0, 0, 1};
  return info;
}

cv::Mat Texture(int width, int height, int shift) {
  cv::Mat grey(height, width, CV_8UC1);
  for (int y = 0; y < height; ++y) {
    for (int x = 0; x < width; ++x) grey.at<std::uint8_t>(y, x) = ((x + shift) / 4 * 37 + y / 4 * 91) % 256;
  }
  return grey;
}

sensor_msgs::Image Image(double t, int shift) {
  sensor_msgs::Image image;
  image.header.frame_id = "cam";
  image.header.stamp = ros::Time(t);
  image.width = 64;
  image.height = 48;
  image.encoding = "mono8";
  image.step = 64;
  const cv::Mat grey = Texture(64, 48, shift);
  image.data.assign(grey.data, grey.data + grey.total());
  return image;
}

void WriteSeed(const std::string& path, const std::vector<std::uint8_t>& bytes) {
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(bytes.data()), bytes.size());
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  const char* dir = std::getenv("ROTAVG_FUZZ_WRITE_SEEDS");
  if (!dir) return 0;
  const std::string d(dir);
  std::vector<std::uint8_t> chain;  // a loop of one camera, with a loop closure
  for (int i = 1; i < 5; ++i) Append(kPose, Pose("cam", i, "cam", i + 1, 0.2, 1), &chain);
  Append(kPose, Pose("cam", 5, "cam", 1, -0.8, 2), &chain);
  WriteSeed(d + "/pose_chain", chain);
  std::vector<std::uint8_t> array;
  ra::RelativePoseArray poses;
  for (int i = 1; i < 4; ++i) poses.poses.push_back(Pose("a", i, "b", i, 0.5, 3));
  poses.poses.push_back(Pose("a", 1, "a", 2, 0.1, 1));
  Append(kPoseArray, poses, &array);
  WriteSeed(d + "/pose_array", array);
  std::vector<std::uint8_t> images;
  Append(kCameraInfo, Info(64, 48), &images);
  for (int i = 1; i < 4; ++i) Append(kImage, Image(i, 2 * i), &images);
  WriteSeed(d + "/images", images);
  std::vector<std::uint8_t> compressed;
  Append(kCameraInfo, Info(64, 48), &compressed);
  sensor_msgs::CompressedImage png;
  png.header.frame_id = "cam";
  png.header.stamp = ros::Time(1.0);
  png.format = "mono8; png compressed";
  cv::imencode(".png", Texture(64, 48, 0), png.data);
  Append(kCompressed, png, &compressed);
  WriteSeed(d + "/compressed", compressed);
  std::vector<std::uint8_t> rig;  // extrinsics first, then measurements between rig cameras
  tf2_msgs::TFMessage statics;
  geometry_msgs::TransformStamped t;
  t.header.frame_id = "base_link";
  t.child_frame_id = "cam_a";
  t.transform.rotation.w = 1.0;
  statics.transforms.push_back(t);
  t.child_frame_id = "cam_b";
  t.transform.rotation.w = std::cos(0.785);
  t.transform.rotation.z = std::sin(0.785);
  statics.transforms.push_back(t);
  Append(kStatic, statics, &rig);
  Append(kPose, Pose("cam_a", 1, "cam_a", 2, 0.1, 1), &rig);
  Append(kPose, Pose("cam_b", 1, "cam_b", 2, 0.1, 1), &rig);
  Append(kPose, Pose("cam_a", 2, "cam_b", 2, 1.57, 0), &rig);
  WriteSeed(d + "/rig", rig);
  std::fprintf(stderr, "fuzz_messages: seeds written to %s\n", dir);
  std::exit(0);
}
