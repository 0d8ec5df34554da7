#include "rotation_averaging/core/controllers/rig_model.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <functional>
#include <iterator>
#include <sstream>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/text_lines.h"

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
  if (std::find(members.begin(), members.end(), keyframe) == members.end()) {
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
  const bool a = cameras_[in.keyframe1.frame_id].in_rig;
  const bool b = cameras_[in.keyframe2.frame_id].in_rig;
  if (a && b && out->keyframe1.frame_id == out->keyframe2.frame_id &&
      out->keyframe1.stamp_ns == out->keyframe2.stamp_ns) {
    ++absorbed_;
    return false;
  }
  // Camera pairs measure a pair of captures independently: keep each.
  const std::string& f1 = in.keyframe1.frame_id;
  const std::string& f2 = in.keyframe2.frame_id;
  out->channel = static_cast<std::uint32_t>(std::hash<std::string>()(std::min(f1, f2) + '\n' + std::max(f1, f2)));
  const Eigen::Matrix3d ea = CameraFromRigLocked(f1);
  const Eigen::Matrix3d eb = CameraFromRigLocked(f2);
  out->rotation = ea.transpose() * in.rotation * eb;
  if (in.has_covariance) out->covariance = eb.transpose() * in.covariance * eb;
  return true;
}

Eigen::Matrix3d RigModel::CameraFromRigLocked(const std::string& camera_frame) const {
  const auto it = cameras_.find(camera_frame);
  return it != cameras_.end() && it->second.in_rig ? it->second.camera_from_rig : Eigen::Matrix3d::Identity();
}

Eigen::Vector3d RigModel::PerturbationToVariables(const std::string& frame2, const Eigen::Vector3d& d) const {
  std::lock_guard<std::mutex> lock(mutex_);
  // R_var = E_1^T R E_2, so R Exp(d) gives R_var E_2^T Exp(d) E_2 = R_var Exp(E_2^T d).
  return CameraFromRigLocked(frame2).transpose() * d;
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

std::size_t RigModel::NumCaptures() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return members_.size();
}

namespace {

constexpr char kRigHeader[] = "# rotation_averaging rig v1";

bool IsName(const std::string& s) { return !s.empty() && s.find_first_of(" \t\r\n") == std::string::npos; }

}  // namespace

bool RigModel::Save(const std::string& path, std::string* error) const {
  std::ostringstream body;
  body.precision(17);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    body << kRigHeader << "\n"
         << "# CAMERA frame in_rig rig_frame qw qx qy qz (camera_from_rig) | CAPTURE rig_frame stamp_ns |"
            " MEMBER camera_frame stamp_ns (a camera keyframe of the CAPTURE above)\n";
    for (const auto& [frame, c] : cameras_) {
      if (!IsName(frame) || (c.in_rig && !IsName(c.rig_frame))) {
        if (error) *error = "frame name '" + frame + "' is empty or contains whitespace";
        return false;
      }
      const Eigen::Vector4d q = RotationToQuaternion(c.camera_from_rig);
      body << "CAMERA " << frame << ' ' << (c.in_rig ? 1 : 0) << ' ' << (c.in_rig ? c.rig_frame : "-") << ' ' << q[0]
           << ' ' << q[1] << ' ' << q[2] << ' ' << q[3] << '\n';
    }
    for (const auto& [capture, members] : members_) {
      body << "CAPTURE " << capture.frame_id << ' ' << capture.stamp_ns << '\n';
      for (const KeyframeKey& m : members) body << "MEMBER " << m.frame_id << ' ' << m.stamp_ns << '\n';
    }
  }
  const std::string text = body.str();
  return WriteFileAtomically(path, [&](std::ostream& out) -> std::string {
    out << text << EndRecord(text);
    return "";
  }, error);
}

bool RigModel::Load(const std::string& path, std::string* error) {
  Saved saved;
  if (!ReadFile(path, &saved, error)) return false;
  Replace(std::move(saved));
  return true;
}

bool RigModel::Add(const std::string& path, std::string* error) {
  Saved saved;
  if (!ReadFile(path, &saved, error)) return false;
  Merge(std::move(saved));
  return true;
}

bool RigModel::ReadFile(const std::string& path, Saved* saved, std::string* error) {
  std::map<std::string, Camera> cameras;
  std::map<std::string, std::set<std::int64_t>> capture_stamps;
  std::map<KeyframeKey, std::vector<KeyframeKey>> members;
  std::map<KeyframeKey, KeyframeKey> variable_of;
  const KeyframeKey* capture = nullptr;
  auto record = [&](const std::vector<std::string_view>& tokens, std::string* why) {
    auto refuse = [&](const std::string& reason) {
      *why = reason;
      return false;
    };
    std::uint64_t stamp = 0;
    if (tokens[0] == "CAMERA") {
      double q[4];
      int in_rig = 0;
      if (tokens.size() != 8 || !ParseInt(tokens[2], &in_rig) || (in_rig != 0 && in_rig != 1) ||
          !ParseQuaternion(&tokens[4], q)) {
        return refuse("expected 'CAMERA frame in_rig rig_frame qw qx qy qz'");
      }
      if (!IsUnitQuaternion(q)) return refuse("not a unit quaternion");
      Camera c;
      c.in_rig = in_rig == 1;
      if (c.in_rig) c.rig_frame = std::string(tokens[3]);
      c.camera_from_rig = QuaternionToRotation(q[0], q[1], q[2], q[3]);
      cameras[std::string(tokens[1])] = c;
    } else if (tokens[0] == "CAPTURE") {
      if (tokens.size() != 3 || !ParseUint64(tokens[2], &stamp)) return refuse("expected 'CAPTURE rig_frame stamp_ns'");
      const KeyframeKey key{std::string(tokens[1]), static_cast<std::int64_t>(stamp)};
      if (members.count(key)) return refuse("capture listed twice");
      capture = &members.emplace(key, std::vector<KeyframeKey>()).first->first;
      capture_stamps[key.frame_id].insert(key.stamp_ns);
    } else if (tokens[0] == "MEMBER") {
      if (tokens.size() != 3 || !ParseUint64(tokens[2], &stamp)) return refuse("expected 'MEMBER camera_frame stamp_ns'");
      if (!capture) return refuse("MEMBER before any CAPTURE");
      const KeyframeKey key{std::string(tokens[1]), static_cast<std::int64_t>(stamp)};
      auto c = cameras.find(key.frame_id);
      if (c == cameras.end() || !c->second.in_rig || c->second.rig_frame != capture->frame_id) {
        return refuse("camera '" + key.frame_id + "' is not a camera of rig '" + capture->frame_id + "'");
      }
      if (!variable_of.emplace(key, *capture).second) return refuse("a keyframe in two captures");
      members[*capture].push_back(key);
    } else {
      return refuse("unknown record '" + std::string(tokens[0]) + "' (CAMERA, CAPTURE or MEMBER)");
    }
    return true;
  };
  if (!ReadEndRecordedFile(path, kRigHeader, "rig", record, error)) return false;
  saved->cameras = std::move(cameras);
  saved->capture_stamps = std::move(capture_stamps);
  saved->members = std::move(members);
  saved->variable_of = std::move(variable_of);
  return true;
}

void RigModel::Replace(Saved saved) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [frame, c] : saved.cameras) cameras_[frame] = c;
  capture_stamps_ = std::move(saved.capture_stamps);
  members_ = std::move(saved.members);
  variable_of_ = std::move(saved.variable_of);
}

void RigModel::Merge(Saved saved) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (const auto& [frame, c] : saved.cameras) cameras_.emplace(frame, c);  // a camera held keeps what it resolved
  for (const auto& [capture, keyframes] : saved.members) {
    if (members_.count(capture)) continue;
    std::vector<KeyframeKey> kept;
    for (const KeyframeKey& k : keyframes) {
      if (variable_of_.emplace(k, capture).second) kept.push_back(k);  // else in a capture held already
    }
    capture_stamps_[capture.frame_id].insert(capture.stamp_ns);
    members_.emplace(capture, std::move(kept));
  }
}

}  // namespace rotation_averaging
