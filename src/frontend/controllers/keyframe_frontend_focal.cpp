// KeyframeFrontend: the pairs held for focal calibration (the focal check's
// samples, the pairs estimated again or moved by their derivatives when a
// camera's focal length is corrected).
#include <algorithm>
#include <cmath>

#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "frontend/controllers/keyframe_frontend_keyframe.h"
#include "rotation_averaging/util/parallel_for.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// K with its focal lengths times `scale` (a focal-length correction).
Eigen::Matrix3d FocalScaled(Eigen::Matrix3d k, double scale) {
  k(0, 0) *= scale;
  k(1, 1) *= scale;
  return k;
}

}  // namespace

void KeyframeFrontend::MonitorFocal(const PairOutcome& outcome, const Keyframe& newer, const CameraIntrinsics& camera) {
  if (!outcome.focal_sample) return;
  focal_monitor_.Add(newer.key.frame_id, newer.k, camera.k(0, 0), newer.lens, outcome.focal_sample);
}

void KeyframeFrontend::HoldPair(const PairTask& task, const PairOutcome& outcome, int newer_index, bool chain) {
  if (!outcome.points1 || !outcome.points2) return;
  HeldPair held;
  held.first = outcome.newer_first ? newer_index : task.older;
  held.second = outcome.newer_first ? task.older : newer_index;
  held.source = task.source;
  held.jackknife_grid = outcome.jackknife_grid;
  held.chain = chain;
  held.points1 = outcome.points1;
  held.points2 = outcome.points2;
  held.pose = outcome.pose;
  const std::string& older_camera = keyframes_[task.older]->key.frame_id;
  const std::string& newer_camera = outcome.newer_first ? outcome.edge.keyframe1.frame_id : outcome.edge.keyframe2.frame_id;
  std::set<std::string> cameras{older_camera, newer_camera};
  for (const std::string& camera : cameras) {
    if (held_overflow_.count(camera)) continue;
    std::vector<HeldPair>& list = held_pairs_[camera];
    if (static_cast<int>(list.size()) >= options_.focal_monitor.max_correction_pairs) {
      // Past the cap the camera cannot be corrected: let its pairs go.
      held_overflow_.insert(camera);
      list.clear();
      list.shrink_to_fit();
      continue;
    }
    list.push_back(held);
  }
}

double KeyframeFrontend::FocalCorrection(const std::string& camera) const {
  const auto it = focal_correction_.find(camera);
  return it == focal_correction_.end() ? 1.0 : it->second;
}

double KeyframeFrontend::FocalInUsePx(const std::string& camera) const {
  const auto it = given_focal_px_.find(camera);
  return it == given_focal_px_.end() ? 0.0 : it->second * FocalCorrection(camera);
}

double KeyframeFrontend::LensCorrection(const std::string& camera) const {
  const auto it = lens_correction_px_.find(camera);
  const double f = FocalInUsePx(camera);
  return it == lens_correction_px_.end() ? 0.0 : it->second.first * f * f;
}

CameraIntrinsics KeyframeFrontend::CorrectedLens(const std::pair<double, double>& correction,
                                                 const Eigen::Matrix3d& k, double focal_px) {
  return PlumbBobFromDivision(k, correction.first * focal_px * focal_px, correction.second);
}

CameraIntrinsics KeyframeFrontend::CameraInUse(const std::string& camera, const CameraIntrinsics& given) const {
  CameraIntrinsics out = given;
  out.k = FocalScaled(given.k, FocalCorrection(camera));
  const auto lens = lens_correction_px_.find(camera);
  if (lens != lens_correction_px_.end() && !given.HasDistortion()) {
    const CameraIntrinsics fitted = CorrectedLens(lens->second, out.k, out.k(0, 0));
    out.distortion = fitted.distortion;
    out.coefficients = fitted.coefficients;
  }
  return out;
}

bool KeyframeFrontend::ApplyLensCorrection(const std::string& camera, double lambda,
                                           std::vector<KeyframeRelativeRotation>* edges, std::string* why) {
  edges->clear();
  const auto refuse = [why](const std::string& reason) {
    if (why) *why = reason;
    return false;
  };
  if (lens_correction_px_.count(camera)) return refuse("its lens is corrected already");
  const double f = FocalInUsePx(camera);
  if (!(f > 0.0)) return refuse("no keyframe of it yet");
  if (held_overflow_.count(camera)) {
    return refuse("its pairs outgrew focal_max_correction_pairs (" +
                  std::to_string(options_.focal_monitor.max_correction_pairs) +
                  ") before the check found it out, so they cannot be estimated again: give camera_info its lens");
  }
  const auto chain = by_camera_.find(camera);
  if (chain == by_camera_.end() || chain->second.empty()) return refuse("no keyframe of it yet");
  // As CameraInUse gives it to later keyframes, each keyframe's lens of its
  // own K (the features' scale): lambda is in normalised coordinates, which
  // that scale leaves as they are.
  const std::pair<double, double> correction(lambda / (f * f), CornerRadius(keyframes_[chain->second.back()]->k));
  const auto lens_of = [&](const Eigen::Matrix3d& k) { return CorrectedLens(correction, k, f); };
  if (!lens_of(keyframes_[chain->second.back()]->k).HasDistortion()) return refuse("lambda gives no lens");
  for (int i : chain->second) {
    const Keyframe& kf = *keyframes_[i];
    if (!kf.resumed && kf.lens.HasDistortion()) return refuse("camera_info gives its keyframes a lens already");
  }
  lens_correction_px_[camera] = correction;
  // Raw pixels undistorted; one that does not undistort (beyond the image)
  // stays where it was, as RedoUndistortion leaves it: the features and
  // the held pairs keep their indices.
  const auto undistort = [](const CameraIntrinsics& lens, const Eigen::Matrix3d& k, std::vector<Eigen::Vector2d>* px) {
    std::vector<Eigen::Vector2d> out = *px;
    UndistortPixels(lens, k, &out);
    for (std::size_t i = 0; i < out.size(); ++i) {
      if (out[i].allFinite()) (*px)[i] = out[i];
    }
  };
  std::vector<HeldPair>& held = held_pairs_[camera];
  for (HeldPair& p : held) {
    for (const auto& [index, points] : {std::make_pair(p.first, p.points1), std::make_pair(p.second, p.points2)}) {
      const Keyframe& kf = *keyframes_[index];
      if (kf.key.frame_id == camera && !kf.resumed) undistort(lens_of(kf.k), kf.k, points.get());
    }
  }
  CameraIntrinsics lens;
  for (int i : chain->second) {
    Keyframe& kf = *keyframes_[i];
    if (kf.resumed) continue;
    lens = lens_of(kf.k);
    undistort(lens, kf.k, &kf.features.keypoints_px);
    kf.lens = lens;
    if (!kf.tracks.empty()) {
      kf.track_camera.distortion = lens.distortion;
      kf.track_camera.coefficients = lens.coefficients;
    }
  }
  ReestimateHeldPairs(camera, focal_monitor_.GivenFocal(camera), lens, true, edges);
  return true;
}

std::vector<FocalSensitivity> KeyframeFrontend::FocalSensitivities(const std::string& camera, double step) {
  std::vector<FocalSensitivity> out;
  const auto held = held_pairs_.find(camera);
  if (held == held_pairs_.end() || held_overflow_.count(camera) || !(step > 0.0)) return out;
  std::vector<HeldPair>& pairs = held->second;
  ParallelFor(static_cast<int>(pairs.size()), ResolveThreadCount(options_.num_threads), [&](int h) {
    HeldPair& p = pairs[h];
    if (p.has_derivative || !p.pose) return;
    const Keyframe& first = *keyframes_[p.first];
    const Keyframe& second = *keyframes_[p.second];
    const RelativePoseResult& pose = *p.pose;
    // Only the camera's own keyframes change focal length, and of those not
    // the resumed ones, as in ApplyFocalCorrection.
    auto moves = [&camera](const Keyframe& kf) { return kf.key.frame_id == camera && !kf.resumed; };
    Eigen::Matrix3d edge[2];
    for (int side = 0; side < 2; ++side) {
      const double s = side == 0 ? 1.0 + step : 1.0 - step;
      std::vector<Eigen::Vector2d> points[2] = {*p.points1, *p.points2};
      Eigen::Matrix3d k[2] = {first.k, second.k};
      const Keyframe* ends[2] = {&first, &second};
      for (int e = 0; e < 2; ++e) {
        if (!moves(*ends[e])) continue;
        const Eigen::Matrix3d scaled = FocalScaled(k[e], s);
        RedoUndistortion(ends[e]->lens, k[e], scaled, &points[e]);
        k[e] = scaled;
      }
      Eigen::Matrix3d rotation = pose.rotation;
      if (pose.model == TwoViewModel::kEssential) {
        Eigen::Vector3d translation = pose.translation;
        RefinePoseOnInliers(points[0], points[1], pose.inliers, k[0], k[1], &rotation, &translation,
                            options_.relative_pose.refine_max_iterations);
      } else if (RefineRotationOnInliers(points[0], points[1], pose.inliers, k[0], k[1], &rotation) < 0) {
        return;
      }
      edge[side] = rotation.transpose();
    }
    const Eigen::Vector3d derivative = LogSO3(edge[1].transpose() * edge[0]) / (2.0 * step);
    if (!derivative.allFinite()) return;
    p.derivative = derivative;
    p.has_derivative = true;
  });
  for (const HeldPair& p : pairs) {
    if (!p.has_derivative) continue;
    out.push_back(FocalSensitivity{keyframes_[p.first]->key, keyframes_[p.second]->key, p.source, p.derivative});
  }
  return out;
}

bool KeyframeFrontend::ApplyFocalCorrection(const std::string& camera, double scale,
                                            std::vector<KeyframeRelativeRotation>* edges, std::string* why,
                                            bool linearised) {
  edges->clear();
  if (!(scale > 0.0) || !std::isfinite(scale)) {
    if (why) *why = "the correction is not a positive number";
    return false;
  }
  if (held_overflow_.count(camera)) {
    if (why) {
      *why = "its pairs outgrew focal_max_correction_pairs (" +
             std::to_string(options_.focal_monitor.max_correction_pairs) +
             ") before the check found it out, so they cannot be estimated again: fix camera_info";
    }
    return false;
  }
  focal_correction_[camera] = FocalCorrection(camera) * scale;
  const auto corrected = [scale](const Eigen::Matrix3d& k) { return FocalScaled(k, scale); };
  // A raw image's keypoints were undistorted with the old focal length:
  // they are undistorted again with the new one, those of the held pairs
  // (while the keyframes still have the old K) and the keyframes' own, which
  // later pairs match.
  std::vector<HeldPair>& held = held_pairs_[camera];
  for (HeldPair& p : held) {
    for (const auto& [index, points] : {std::make_pair(p.first, p.points1), std::make_pair(p.second, p.points2)}) {
      const Keyframe& kf = *keyframes_[index];
      if (kf.key.frame_id == camera) RedoUndistortion(kf.lens, kf.k, corrected(kf.k), points.get());
    }
  }
  const auto chain = by_camera_.find(camera);
  if (chain != by_camera_.end()) {
    for (int i : chain->second) {
      Keyframe& kf = *keyframes_[i];
      // A loaded keyframe keeps the K it was saved with, as a loop
      // closure's old end does: the session that made it may have
      // corrected it already.
      if (kf.resumed) continue;
      RedoUndistortion(kf.lens, kf.k, corrected(kf.k), &kf.features.keypoints_px);
      kf.k = corrected(kf.k);
    }
  }
  if (linearised) {
    for (HeldPair& p : held) {
      if (!p.has_derivative || !p.pose) continue;  // the old edge stays
      RelativePoseResult& pose = *p.pose;
      pose.rotation = (pose.EdgeRotation() * ExpSO3((scale - 1.0) * p.derivative)).transpose();
      ReplaceHeldEdge(p, pose, edges);
    }
    return true;
  }
  ReestimateHeldPairs(camera, focal_monitor_.GivenFocal(camera) * scale, focal_monitor_.Lens(camera), false, edges);
  return true;
}

void KeyframeFrontend::ReplaceHeldEdge(const HeldPair& p, const RelativePoseResult& pose,
                                       std::vector<KeyframeRelativeRotation>* edges) {
  Keyframe& second = *keyframes_[p.second];
  KeyframeRelativeRotation e;
  e.keyframe1 = keyframes_[p.first]->key;
  e.keyframe2 = second.key;
  e.rotation = pose.EdgeRotation();
  e.has_covariance = true;
  e.covariance = pose.covariance;
  e.num_inliers = static_cast<int>(pose.inliers.size());
  e.source = p.source;
  edges->push_back(e);
  if (p.chain) {
    second.sequential_rotation = e.rotation;
    second.sequential_covariance = e.covariance;
  }
}

void KeyframeFrontend::ReestimateHeldPairs(const std::string& camera, double given_px, const CameraIntrinsics& lens,
                                           bool keep_correspondences, std::vector<KeyframeRelativeRotation>* edges) {
  std::vector<HeldPair>& held = held_pairs_[camera];
  std::vector<RelativePoseResult> poses(held.size());
  ParallelFor(static_cast<int>(held.size()), ResolveThreadCount(options_.num_threads), [&](int h) {
    const HeldPair& p = held[h];
    RelativePoseOptions relative_pose = options_.relative_pose;
    relative_pose.jackknife_grid = p.jackknife_grid;
    poses[h] = EstimateRelativePoseWithCovariance(*p.points1, *p.points2, keyframes_[p.first]->k,
                                                  keyframes_[p.second]->k, relative_pose);
  });
  const FocalMonitorOptions& focal = options_.focal_monitor;
  for (std::size_t h = 0; h < held.size(); ++h) {
    const HeldPair& p = held[h];
    const RelativePoseResult& pose = poses[h];
    if (!pose.success) continue;  // the old edge stays
    if (held[h].pose) *held[h].pose = pose;
    held[h].has_derivative = false;  // at the new focal length, when next needed
    ReplaceHeldEdge(p, pose, edges);
    const Keyframe& first = *keyframes_[p.first];
    const Keyframe& second = *keyframes_[p.second];
    if (keep_correspondences && options_.keep_correspondences) {
      correspondences_.push_back(
          {first.key, second.key, InlierCorrespondences(*p.points1, *p.points2, first.k, second.k, pose)});
    }
    // The check starts again on the corrected camera, with these pairs.
    if (focal.enabled && first.key.frame_id == camera && second.key.frame_id == camera && first.k == second.k &&
        pose.model == TwoViewModel::kEssential && static_cast<int>(pose.inliers.size()) >= focal.focal.min_inliers) {
      focal_monitor_.Add(camera, first.k, given_px, lens,
                         MakeFocalSample(*p.points1, *p.points2, pose, focal.max_matches_per_pair));
    }
  }
  stats_.focal_bytes = FocalBytes();
}

std::size_t KeyframeFrontend::FocalBytes() const {
  std::set<const std::vector<Eigen::Vector2d>*> counted;  // a rig pair is held under both cameras
  std::size_t bytes = focal_monitor_.HeldBytes();
  for (const auto& [camera, list] : held_pairs_) {
    for (const HeldPair& p : list) {
      if (counted.insert(p.points1.get()).second) {
        bytes += sizeof(HeldPair) + (p.points1->size() + p.points2->size()) * sizeof(Eigen::Vector2d);
        if (p.pose) bytes += sizeof(RelativePoseResult) + p.pose->inliers.size() * sizeof(int);
      }
    }
  }
  return bytes;
}

}  // namespace rotation_averaging
