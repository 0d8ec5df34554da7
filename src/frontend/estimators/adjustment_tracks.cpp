#include "frontend/estimators/adjustment_tracks.h"

#include <Eigen/Cholesky>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>

namespace rotation_averaging {
namespace adjustment {
namespace {

// The point's depth along the view's optical axis (negative: behind it).
double Depth(const AdjustedView& v, const Eigen::Vector3d& point) { return (v.rotation * (point - v.centre)).z(); }

}  // namespace

Eigen::Vector3d Ray(const AdjustedView& v, const Eigen::Vector2d& x) {
  return (v.rotation.transpose() * (x / v.focal_scale).homogeneous()).normalized();
}

bool Triangulate(const std::vector<AdjustedView>& views, double min_parallax_rad, Track* track) {
  Eigen::Matrix3d a = Eigen::Matrix3d::Zero();
  Eigen::Vector3d b = Eigen::Vector3d::Zero();
  double max_angle = 0.0;
  std::vector<Eigen::Vector3d> rays;
  for (const Observation& o : track->observations) {
    const AdjustedView& v = views[o.view];
    const Eigen::Vector3d r = Ray(v, o.x);
    const Eigen::Matrix3d p = Eigen::Matrix3d::Identity() - r * r.transpose();
    a += p;
    b += p * v.centre;
    for (const Eigen::Vector3d& earlier : rays) {
      max_angle = std::max(max_angle, std::acos(std::clamp(r.dot(earlier), -1.0, 1.0)));
    }
    rays.push_back(r);
  }
  if (max_angle < min_parallax_rad) return false;
  const Eigen::Vector3d point = a.ldlt().solve(b);
  if (!point.allFinite()) return false;
  for (const Observation& o : track->observations) {
    if (Depth(views[o.view], point) <= 0.0) return false;
  }
  track->point = point;
  return true;
}

// Why the adjustment needs it: a point reflected through a camera's centre
// projects to the same pixel in that camera, so the first stage
// (orientations held, their errors in every residual) carries some across:
// a few hundred of 124,000 observations on the rendered four-camera rig. From
// there the next stage's reduced system has entries of 1e11 where the rest
// are near 1 (one point came to rest 1e-7 of the median depth from a
// centre), its Cholesky factorisation fails on step after step and the
// stage runs to its iteration limit (docs/decisions.md).
int RetriangulateStrayPoints(const std::vector<AdjustedView>& views, double min_parallax_rad,
                             std::vector<Track>* tracks) {
  std::vector<double> depths;
  for (const Track& t : *tracks) {
    for (const Observation& o : t.observations) depths.push_back(Depth(views[o.view], t.point));
  }
  if (depths.empty()) return 0;
  std::nth_element(depths.begin(), depths.begin() + depths.size() / 2, depths.end());
  const double min_depth = kStrayDepthFraction * depths[depths.size() / 2];
  int left_out = 0;
  std::vector<Track> kept;
  kept.reserve(tracks->size());
  for (Track& t : *tracks) {
    // (Not greater: a NaN depth counts as stray too.)
    const bool stray = std::any_of(t.observations.begin(), t.observations.end(),
                                   [&](const Observation& o) { return !(Depth(views[o.view], t.point) > min_depth); });
    if (!stray || Triangulate(views, min_parallax_rad, &t)) {
      kept.push_back(std::move(t));
    } else {
      ++left_out;
    }
  }
  *tracks = std::move(kept);
  return left_out;
}

}  // namespace adjustment
}  // namespace rotation_averaging
