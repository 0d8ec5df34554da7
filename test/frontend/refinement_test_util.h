// Shared by the tests of the refinements that start from averaged
// orientations (correspondence_refinement.h, bundle_adjustment.h).
#ifndef ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_
#define ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_

#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <random>
#include <vector>

#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {

// Largest angle between the estimate and the truth after removing the gauge
// (both expressed relative to view 0).
inline double MaxErrorDeg(const ViewOrientations& estimate, const ViewOrientations& truth) {
  double worst = 0.0;
  const Eigen::Matrix3d e0 = estimate.at(0), t0 = truth.at(0);
  for (const auto& [id, r] : truth) {
    worst = std::max(worst, RadToDeg(LogSO3((r * t0.transpose()).transpose() * (estimate.at(id) * e0.transpose())).norm()));
  }
  return worst;
}

// Every orientation rotated by a random angle of about `degrees`.
inline ViewOrientations Perturbed(const ViewOrientations& truth, double degrees, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> n(0.0, DegToRad(degrees) / std::sqrt(3.0));
  ViewOrientations out;
  for (const auto& [id, r] : truth) out[id] = ExpSO3(DrawVector3(rng, n)) * r;
  return out;
}

// Six bad copies of the first six of `edges` (over views 0-3): a NaN point,
// no pixel noise, a self-edge, an unknown view (99), uneven point lists and
// too few correspondences.
inline std::vector<EdgeCorrespondences> BadEdgeCorrespondences(const std::vector<EdgeCorrespondences>& edges) {
  EdgeCorrespondences nan_point = edges[0];
  nan_point.points1[3].x() = std::numeric_limits<double>::quiet_NaN();
  EdgeCorrespondences no_sigma = edges[1];
  no_sigma.sigma = 0.0;
  EdgeCorrespondences self = edges[2];
  self.view2 = self.view1;
  EdgeCorrespondences unknown = edges[3];
  unknown.view2 = 99;
  EdgeCorrespondences uneven = edges[4];
  uneven.points2.pop_back();
  EdgeCorrespondences few = edges[5];
  few.points1.resize(3);
  few.points2.resize(3);
  return {nan_point, no_sigma, self, unknown, uneven, few};
}

constexpr double kArcSceneFocal = 1000.0;  // pixels, for the noise level only

// Cameras on an arc around a box of points, every pair an edge. Each view
// sees each point as one keypoint (noise drawn once per view and point), so
// the pairs' matches share keypoints and link into tracks, as a detector's
// keypoints do.
struct ArcScene {
  ViewOrientations truth;
  std::vector<Eigen::Vector3d> centres, points;
  std::vector<std::vector<Eigen::Vector2d>> keypoints;  // [view][point]
  std::vector<EdgeCorrespondences> edges;
};

// Every pair of the scene's views that shares at least `min_shared` points
// as an edge: the keypoints of the points both see (`visible[view][point]`;
// empty: every point), the true translation direction, the noise's sigma.
inline void AddSceneEdges(double noise_px, const std::vector<std::vector<bool>>& visible, std::size_t min_shared,
                          ArcScene* scene) {
  const int views = static_cast<int>(scene->keypoints.size());
  for (int i = 0; i < views; ++i) {
    for (int j = i + 1; j < views; ++j) {
      EdgeCorrespondences e;
      e.view1 = static_cast<ViewId>(i);
      e.view2 = static_cast<ViewId>(j);
      for (std::size_t p = 0; p < scene->points.size(); ++p) {
        if (!visible.empty() && (!visible[i][p] || !visible[j][p])) continue;
        e.points1.push_back(scene->keypoints[i][p]);
        e.points2.push_back(scene->keypoints[j][p]);
      }
      if (e.points1.size() < min_shared) continue;
      e.translation = (scene->truth[e.view2] * (scene->centres[i] - scene->centres[j])).normalized();
      e.sigma = std::max(noise_px, 0.05) / kArcSceneFocal;
      scene->edges.push_back(std::move(e));
    }
  }
}

inline ArcScene MakeArcScene(int views, double noise_px, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px / kArcSceneFocal);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  ArcScene scene;
  for (int k = 0; k < 300; ++k) {
    const Eigen::Vector3d d = DrawVector3(rng, u);
    scene.points.emplace_back(3.0 * d.x(), 2.0 * d.y(), 6.0 + 2.0 * d.z());
  }
  for (int v = 0; v < views; ++v) {
    const double angle = DegToRad(-20.0 + 40.0 * v / (views - 1));
    const Eigen::Vector3d centre(6.0 * std::sin(angle), 0.3 * u(rng), 6.0 - 6.0 * std::cos(angle));
    const Eigen::Vector3d z = (Eigen::Vector3d(0, 0, 6) - centre).normalized();
    const Eigen::Vector3d x = Eigen::Vector3d::UnitY().cross(z).normalized();
    Eigen::Matrix3d camera_to_world;
    camera_to_world << x, z.cross(x), z;
    const Eigen::Matrix3d r =
        (camera_to_world * Eigen::AngleAxisd(0.05 * u(rng), Eigen::Vector3d::UnitZ()).toRotationMatrix()).transpose();
    scene.truth[static_cast<ViewId>(v)] = r;
    scene.centres.push_back(centre);
    std::vector<Eigen::Vector2d> seen;
    for (const Eigen::Vector3d& p : scene.points) {
      seen.push_back((r * (p - centre)).hnormalized() + DrawVector2(rng, noise));
    }
    scene.keypoints.push_back(seen);
  }
  AddSceneEdges(noise_px, {}, 0, &scene);
  return scene;
}

// Adds a view of every point of `scene` from `centre`, turned by `r`, its
// keypoints normalised by a focal length `focal_scale` times too short and
// drawn with `noise`; `visible` gains which points are in front of it and
// within `half_width` of its image's centre (normalised).
inline void ObservePoints(const Eigen::Matrix3d& r, const Eigen::Vector3d& centre, double focal_scale,
                          double half_width, std::normal_distribution<double>* noise, std::mt19937* rng,
                          ArcScene* scene, std::vector<std::vector<bool>>* visible) {
  scene->truth[static_cast<ViewId>(scene->keypoints.size())] = r;
  scene->centres.push_back(centre);
  std::vector<Eigen::Vector2d> seen;
  std::vector<bool> in_view;
  for (const Eigen::Vector3d& p : scene->points) {
    const Eigen::Vector3d y = r * (p - centre);
    const Eigen::Vector2d x = focal_scale * y.hnormalized() + DrawVector2(*rng, *noise);
    in_view.push_back(y.z() > 0.5 && x.cwiseAbs().maxCoeff() < half_width);
    seen.push_back(x);
  }
  scene->keypoints.push_back(std::move(seen));
  visible->push_back(std::move(in_view));
}

// Cameras on a path past a deep box of points, turned about every axis
// (general motion for focal self-calibration): each sees the points in its
// field of view with the keypoints normalised by a focal length
// `focal_scale` times too short (x = focal_scale proj: camera_info's focal
// length over focal_scale). Every pair that shares 30 points is an edge.
// (ArcScene's fields; `keypoints` holds every point, seen or not.)
inline ArcScene MakePathScene(int views, double noise_px, double focal_scale, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px / kArcSceneFocal);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  ArcScene scene;
  for (int k = 0; k < 600; ++k) {
    const Eigen::Vector3d d = DrawVector3(rng, u);
    scene.points.emplace_back(6.0 * d.x(), 3.0 * d.y(), 8.0 + 4.0 * d.z());
  }
  std::vector<std::vector<bool>> visible;
  for (int v = 0; v < views; ++v) {
    const Eigen::Vector3d centre(-2.0 + 4.0 * v / (views - 1), 0.3 * u(rng), 0.5 * u(rng));
    const Eigen::Matrix3d r =
        ExpSO3(Eigen::Vector3d(DegToRad(8.0) * u(rng), DegToRad(15.0) * u(rng), DegToRad(15.0) * u(rng)));
    ObservePoints(r, centre, focal_scale, 0.6, &noise, &rng, &scene, &visible);
  }
  AddSceneEdges(noise_px, visible, 30, &scene);
  return scene;
}

// A rig of two cameras looking 90 degrees apart (camera 1 turned about the
// rig's y axis: R_1 = E R_0, E = RigCameraFromRig()), carried along a path
// through a room of points, turning about every axis: view 2c + k is
// camera k of capture c. Each camera's captures that share 30 points make an
// edge; the two cameras share no edge (they look apart), as a rig's
// cameras whose extrinsics are known. (ArcScene's fields; `keypoints`
// holds every point, seen or not.)
inline Eigen::Matrix3d RigCameraFromRig() {
  return Eigen::AngleAxisd(DegToRad(90.0), Eigen::Vector3d::UnitY()).toRotationMatrix();
}

inline ArcScene MakeRigScene(int captures, double noise_px, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, noise_px / kArcSceneFocal);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  ArcScene scene;
  while (scene.points.size() < 2500) {
    const Eigen::Vector3d p = 10.0 * DrawVector3(rng, u);
    if (p.head<2>().norm() > 5.0 || std::abs(p.z()) > 5.0) scene.points.push_back(p);
  }
  const Eigen::Matrix3d from_rig[2] = {Eigen::Matrix3d::Identity(), RigCameraFromRig()};
  std::vector<std::vector<bool>> visible;
  for (int c = 0; c < captures; ++c) {
    const Eigen::Vector3d centre(-2.0 + 4.0 * c / (captures - 1), 0.3 * u(rng), 0.3 * u(rng));
    const Eigen::Matrix3d rig =
        ExpSO3(Eigen::Vector3d(DegToRad(8.0) * u(rng), DegToRad(10.0) * u(rng), DegToRad(8.0) * u(rng)));
    for (int k = 0; k < 2; ++k) ObservePoints(from_rig[k] * rig, centre, 1.0, 0.6, &noise, &rng, &scene, &visible);
  }
  AddSceneEdges(noise_px, visible, 30, &scene);
  scene.edges.erase(std::remove_if(scene.edges.begin(), scene.edges.end(),
                                   [](const EdgeCorrespondences& e) { return (e.view1 - e.view2) % 2 != 0; }),
                    scene.edges.end());
  return scene;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_
