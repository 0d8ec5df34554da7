#include "rotation_averaging/ros/output_messages.h"

#include <algorithm>
#include <utility>

#include "rotation_averaging/ros/msg_conversion.h"

namespace rotation_averaging {
namespace {

std::string Replace(std::string text, const std::string& key, const std::string& value) {
  for (std::size_t at = text.find(key); at != std::string::npos; at = text.find(key, at + value.size())) {
    text.replace(at, key.size(), value);
  }
  return text;
}

}  // namespace

std::string KeyframeFrameName(const std::string& format, const KeyframeKey& key) {
  return Replace(Replace(format, "{frame_id}", key.frame_id), "{stamp_ns}", std::to_string(key.stamp_ns));
}

CameraInfoCheckArray CameraInfoCheckMsg(const std::map<std::string, CameraFocalCheck>& checks,
                                        const std::map<std::string, double>& corrections, const ros::Time& stamp) {
  CameraInfoCheckArray msg;
  msg.header.stamp = stamp;
  for (const auto& [camera, check] : checks) {
    CameraInfoCheck m;
    m.frame_id = camera;
    m.pairs_seen = static_cast<std::uint32_t>(check.pairs_seen);
    m.pairs_used = static_cast<std::uint32_t>(check.calibration.pairs);
    m.estimated = check.calibration.estimated;
    m.given_focal_px = check.given_focal_px;
    m.scale = check.calibration.scale;
    m.scale_stddev = check.calibration.standard_deviation;
    m.disagrees = check.disagrees;
    const auto correction = corrections.find(camera);
    m.applied_scale = correction == corrections.end() ? 1.0 : correction->second;
    m.distortion_checked = check.distortion_checked && check.distortion.estimated;
    m.distortion_lambda = check.distortion.lambda;
    m.distortion_lambda_stddev = check.distortion.standard_deviation;
    m.distortion_corner_px = check.distortion.corner_shift_px;
    m.distortion_unmodelled = check.distortion_unmodelled;
    msg.cameras.push_back(m);
  }
  return msg;
}

OutputMessages::OutputMessages(const PipelineConfig& config)
    : fixed_frame_(config.fixed_frame),
      keyframe_frame_format_(config.keyframe_frame_format),
      latest_frame_format_(config.latest_frame_format),
      marker_spacing_m_(config.marker_spacing_m),
      marker_max_keyframes_(config.marker_max_keyframes) {}

Orientations OutputMessages::OrientationsMsg(const OnlineSolution& solution, const ros::Time& stamp) const {
  Orientations msg;
  msg.header.stamp = stamp;
  msg.header.frame_id = fixed_frame_;
  msg.solve_sequence = solution.sequence;
  msg.keyframes.reserve(solution.orientations.size());
  for (const auto& [key, r] : solution.orientations) {
    auto c = solution.component.find(key);
    auto cov = solution.covariance.find(key);
    msg.keyframes.push_back(ToMsg(key, r, c == solution.component.end() ? 0 : c->second,
                                  cov == solution.covariance.end() ? nullptr : &cov->second));
  }
  return msg;
}

geometry_msgs::TransformStamped OutputMessages::Transform(const ros::Time& stamp, const std::string& child,
                                                            const geometry_msgs::Quaternion& camera_to_world) const {
  geometry_msgs::TransformStamped t;
  t.header.stamp = stamp;
  t.header.frame_id = fixed_frame_;
  t.child_frame_id = child;
  t.transform.rotation = camera_to_world;
  return t;
}

tf2_msgs::TFMessage OutputMessages::KeyframeTransforms(const OnlineSolution& solution) const {
  tf2_msgs::TFMessage msg;
  msg.transforms.reserve(solution.orientations.size());
  for (const auto& [key, r] : solution.orientations) {
    msg.transforms.push_back(Transform(FromNanoseconds(key.stamp_ns),
                                       KeyframeFrameName(keyframe_frame_format_, key),
                                       ToMsg(key, r, 0).orientation));
  }
  return msg;
}

visualization_msgs::MarkerArray OutputMessages::Markers(const OnlineSolution& variables, const OnlineSolution& cameras,
                                                        const RigModel& rig, const ros::Time& stamp) const {
  // Lanes: one per solved frame id (a camera, or a rig frame), keyframes in
  // time order along x.
  std::vector<KeyframeKey> drawn;
  for (const auto& [key, r] : variables.orientations) drawn.push_back(key);
  std::sort(drawn.begin(), drawn.end(),
            [](const KeyframeKey& a, const KeyframeKey& b) { return a.stamp_ns < b.stamp_ns || (a.stamp_ns == b.stamp_ns && a < b); });
  if (drawn.size() > static_cast<std::size_t>(marker_max_keyframes_)) {
    drawn.erase(drawn.begin(), drawn.end() - marker_max_keyframes_);
  }
  std::map<std::string, int> lane;
  std::map<std::string, int> next_in_lane;
  std::map<KeyframeKey, Eigen::Vector3d> position;
  for (const KeyframeKey& key : drawn) {
    const int l = lane.emplace(key.frame_id, static_cast<int>(lane.size())).first->second;
    const int i = next_in_lane[key.frame_id]++;
    position[key] = Eigen::Vector3d(i * marker_spacing_m_, -2.0 * l * marker_spacing_m_, 0.0);
  }
  auto point = [](const Eigen::Vector3d& p) {
    geometry_msgs::Point m;
    m.x = p.x();
    m.y = p.y();
    m.z = p.z();
    return m;
  };
  auto base = [&](const std::string& ns, double width) {
    visualization_msgs::Marker m;
    m.header.frame_id = fixed_frame_;
    m.header.stamp = stamp;
    m.ns = ns;
    m.id = 0;
    m.type = visualization_msgs::Marker::LINE_LIST;
    m.action = visualization_msgs::Marker::ADD;
    m.pose.orientation.w = 1.0;
    m.scale.x = width;
    m.color.a = 1.0;
    return m;
  };
  // Frusta of every camera keyframe, at the position of the variable it
  // belongs to (the cameras of one rig capture share it).
  visualization_msgs::Marker frusta = base("keyframes", 0.01 * marker_spacing_m_);
  frusta.color.r = 0.2;
  frusta.color.g = 0.4;
  frusta.color.b = 1.0;
  const double size = 0.35 * marker_spacing_m_;
  const Eigen::Vector3d corners[4] = {{-0.6, -0.45, 1.0}, {0.6, -0.45, 1.0}, {0.6, 0.45, 1.0}, {-0.6, 0.45, 1.0}};
  for (const auto& [key, r] : cameras.orientations) {
    auto at = position.find(rig.VariableOfKnown(key));
    if (at == position.end()) continue;
    const Eigen::Vector3d apex = at->second;
    Eigen::Vector3d c[4];
    for (int k = 0; k < 4; ++k) c[k] = apex + size * (r.transpose() * corners[k]);  // camera-to-world
    for (int k = 0; k < 4; ++k) {
      frusta.points.push_back(point(apex));
      frusta.points.push_back(point(c[k]));
      frusta.points.push_back(point(c[k]));
      frusta.points.push_back(point(c[(k + 1) % 4]));
    }
  }
  visualization_msgs::Marker edges = base("edges", 0.005 * marker_spacing_m_);
  for (const SolvedEdge& e : variables.edges) {
    auto a = position.find(e.keyframe1), b = position.find(e.keyframe2);
    if (a == position.end() || b == position.end()) continue;
    std_msgs::ColorRGBA colour;
    colour.r = static_cast<float>(1.0 - std::clamp(e.robust_weight, 0.0, 1.0));
    colour.g = static_cast<float>(std::clamp(e.robust_weight, 0.0, 1.0));
    colour.b = 0.0f;
    colour.a = 1.0f;
    edges.points.push_back(point(a->second));
    edges.points.push_back(point(b->second));
    edges.colors.push_back(colour);
    edges.colors.push_back(colour);
  }
  visualization_msgs::MarkerArray out;
  out.markers.push_back(frusta);
  out.markers.push_back(edges);
  return out;
}

std::vector<geometry_msgs::TransformStamped> OutputMessages::LatestTransforms(const OnlineSolution& solution,
                                                                                 const ros::Time& now) {
  std::map<std::string, std::pair<KeyframeKey, Eigen::Matrix3d>> latest;
  for (const auto& [key, r] : solution.orientations) {
    auto it = latest.find(key.frame_id);
    if (it == latest.end() || it->second.first.stamp_ns < key.stamp_ns) latest[key.frame_id] = {key, r};
  }
  std::vector<geometry_msgs::TransformStamped> tfs;
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [frame_id, kr] : latest) {
    const std::string child = KeyframeFrameName(latest_frame_format_, kr.first);
    auto last = last_latest_stamp_.find(child);
    if (last != last_latest_stamp_.end() && now <= last->second) continue;
    last_latest_stamp_[child] = now;
    tfs.push_back(Transform(now, child, ToMsg(kr.first, kr.second, 0).orientation));
  }
  return tfs;
}

void OutputMessages::ForgetLatestStamps() {
  std::lock_guard<std::mutex> lock(mutex_);
  last_latest_stamp_.clear();
}

}  // namespace rotation_averaging
