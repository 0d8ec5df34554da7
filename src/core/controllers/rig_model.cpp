#include "core/controllers/rig_model.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <iterator>

namespace rotation_averaging {

RigModel::RigModel(const RigModelOptions& options) : options_(options) {}

void RigModel::AddStaticTransform(const std::string& parent, const std::string& child,
                                  const Eigen::Matrix3d& child_in_parent) {
  if (parent.empty() || child.empty() || parent == child || !child_in_parent.allFinite()) return;
  std::lock_guard<std::mutex> lock(mutex_);
  parent_of_[child] = {parent, child_in_parent};
}

bool RigModel::ResolveLocked(const std::string& camera_frame) {
  auto known = cameras_.find(camera_frame);
  if (known != cameras_.end()) return known->second.in_rig;
  Camera camera;
  if (options_.enabled) {
    // Walk up the static tree: frame_in_root = parent_in_root * frame_in_parent.
    Eigen::Matrix3d camera_in_frame = Eigen::Matrix3d::Identity();  // camera rotation in `frame`
    std::string frame = camera_frame;
    for (int depth = 0; depth < 64; ++depth) {
      auto up = parent_of_.find(frame);
      if (up == parent_of_.end()) break;
      camera_in_frame = up->second.second * camera_in_frame;
      frame = up->second.first;
      if (!options_.rig_frame.empty() && frame == options_.rig_frame) break;
    }
    const bool reached = frame != camera_frame && (options_.rig_frame.empty() || frame == options_.rig_frame);
    if (reached) {
      camera.in_rig = true;
      camera.rig_frame = frame;
      camera.camera_from_rig = camera_in_frame.transpose();
    }
  }
  cameras_[camera_frame] = camera;
  return camera.in_rig;
}

bool RigModel::IsRigCamera(const std::string& camera_frame) {
  std::lock_guard<std::mutex> lock(mutex_);
  return ResolveLocked(camera_frame);
}

KeyframeKey RigModel::VariableLocked(const KeyframeKey& keyframe) {
  if (!ResolveLocked(keyframe.frame_id)) return keyframe;
  const Camera& camera = cameras_[keyframe.frame_id];
  std::set<std::int64_t>& stamps = capture_stamps_[camera.rig_frame];
  const std::int64_t tolerance = static_cast<std::int64_t>(options_.stamp_tolerance_s * 1e9);
  // The nearest existing capture within the tolerance, else a new one.
  std::int64_t capture = keyframe.stamp_ns;
  bool found = false;
  auto it = stamps.lower_bound(keyframe.stamp_ns - tolerance);
  for (; it != stamps.end() && *it <= keyframe.stamp_ns + tolerance; ++it) {
    if (!found || std::llabs(*it - keyframe.stamp_ns) < std::llabs(capture - keyframe.stamp_ns)) capture = *it;
    found = true;
  }
  if (!found) stamps.insert(capture);
  const KeyframeKey variable{camera.rig_frame, capture};
  std::vector<KeyframeKey>& members = members_[variable];
  if (std::find_if(members.begin(), members.end(), [&](const KeyframeKey& m) {
        return m.frame_id == keyframe.frame_id && m.stamp_ns == keyframe.stamp_ns;
      }) == members.end()) {
    members.push_back(keyframe);
    variable_of_[keyframe] = variable;
  }
  return variable;
}

KeyframeKey RigModel::VariableOfKnown(const KeyframeKey& keyframe) const {
  std::lock_guard<std::mutex> lock(mutex_);
  auto it = variable_of_.find(keyframe);
  return it == variable_of_.end() ? keyframe : it->second;
}

bool RigModel::ToVariables(const KeyframeRelativeRotation& in, KeyframeRelativeRotation* out) {
  std::lock_guard<std::mutex> lock(mutex_);
  *out = in;
  out->keyframe1 = VariableLocked(in.keyframe1);
  out->keyframe2 = VariableLocked(in.keyframe2);
  const Camera* a = cameras_[in.keyframe1.frame_id].in_rig ? &cameras_[in.keyframe1.frame_id] : nullptr;
  const Camera* b = cameras_[in.keyframe2.frame_id].in_rig ? &cameras_[in.keyframe2.frame_id] : nullptr;
  if (a && b && out->keyframe1.frame_id == out->keyframe2.frame_id &&
      out->keyframe1.stamp_ns == out->keyframe2.stamp_ns) {
    ++absorbed_;
    return false;
  }
  // Camera pairs measure a pair of captures independently: keep each.
  const std::string& f1 = in.keyframe1.frame_id;
  const std::string& f2 = in.keyframe2.frame_id;
  out->channel = static_cast<std::uint32_t>(std::hash<std::string>()(std::min(f1, f2) + '\n' + std::max(f1, f2)));
  const Eigen::Matrix3d ea = a ? a->camera_from_rig : Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d eb = b ? b->camera_from_rig : Eigen::Matrix3d::Identity();
  out->rotation = ea.transpose() * in.rotation * eb;
  if (in.has_covariance) out->covariance = eb.transpose() * in.covariance * eb;
  return true;
}

OnlineSolution RigModel::ToCameraKeyframes(const OnlineSolution& solution) const {
  std::lock_guard<std::mutex> lock(mutex_);
  OnlineSolution out;
  out.sequence = solution.sequence;
  out.summary = solution.summary;
  out.edges = solution.edges;
  for (const auto& [variable, r] : solution.orientations) {
    auto c = solution.component.find(variable);
    auto cov = solution.covariance.find(variable);
    auto members = members_.find(variable);
    if (members == members_.end()) {
      out.orientations[variable] = r;
      if (c != solution.component.end()) out.component[variable] = c->second;
      if (cov != solution.covariance.end()) out.covariance[variable] = cov->second;
      continue;
    }
    for (const KeyframeKey& key : members->second) {
      // R_c = E_c R_rig: a left perturbation d of the rig is E_c d of the camera.
      const Eigen::Matrix3d& e = cameras_.at(key.frame_id).camera_from_rig;
      out.orientations[key] = e * r;
      if (c != solution.component.end()) out.component[key] = c->second;
      if (cov != solution.covariance.end()) out.covariance[key] = e * cov->second * e.transpose();
    }
  }
  return out;
}

std::size_t RigModel::NumRigCameras() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<std::size_t>(
      std::count_if(cameras_.begin(), cameras_.end(), [](const auto& c) { return c.second.in_rig; }));
}

std::size_t RigModel::NumAbsorbed() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return absorbed_;
}

std::map<std::string, std::pair<std::string, Eigen::Matrix3d>> RigModel::RigCameras() const {
  std::lock_guard<std::mutex> lock(mutex_);
  std::map<std::string, std::pair<std::string, Eigen::Matrix3d>> out;
  for (const auto& [frame, c] : cameras_) {
    if (c.in_rig) out[frame] = {c.rig_frame, c.camera_from_rig};
  }
  return out;
}

void RigModel::Clear() {
  std::lock_guard<std::mutex> lock(mutex_);
  capture_stamps_.clear();
  members_.clear();
  variable_of_.clear();
}

}  // namespace rotation_averaging
