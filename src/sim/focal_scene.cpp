#include "rotation_averaging/sim/focal_scene.h"

#include <cmath>
#include <random>

#include "rotation_averaging/util/random_draws.h"
#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

std::vector<FocalPair> FocalScene::Pairs() const {
  std::vector<FocalPair> out;
  for (std::size_t p = 0; p < poses.size(); ++p) out.push_back({&points1[p], &points2[p], &poses[p]});
  return out;
}

namespace {

// World-to-camera rotation of a camera at `centre` looking at `target`, its
// x axis level (world up is +z).
Eigen::Matrix3d LookAt(const Eigen::Vector3d& centre, const Eigen::Vector3d& target) {
  const Eigen::Vector3d z = (target - centre).normalized();
  const Eigen::Vector3d x = Eigen::Vector3d::UnitZ().cross(z).normalized();
  Eigen::Matrix3d r;
  r.row(0) = x;
  r.row(1) = z.cross(x);
  r.row(2) = z;
  return r;
}

}  // namespace

FocalScene MakeFocalScene(const Eigen::Matrix3d& k_true, const Eigen::Matrix3d& k_given,
                          const FocalSceneOptions& options) {
  std::mt19937 rng(options.seed);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  std::normal_distribution<double> noise(0.0, options.noise_px), normal(0.0, 1.0);
  const bool ring = options.geometry == FocalSceneGeometry::kRing;
  std::vector<Eigen::Vector3d> cloud(ring ? 800 : 600);
  std::vector<Eigen::Matrix3d> rotations;
  std::vector<Eigen::Vector3d> centres;
  if (ring) {
    // An object of radius 2.5 seen from 8 at a height of 2.
    std::uniform_real_distribution<double> object(-2.5, 2.5);
    for (Eigen::Vector3d& x : cloud) x = DrawVector3(rng, object);
    const int n = 24;
    for (int i = 0; i < n; ++i) {
      const double angle = 2.0 * M_PI * i / n, height = 2.0 + 0.5 * options.ring_jitter * normal(rng);
      const Eigen::Vector3d centre(8.0 * std::cos(angle), 8.0 * std::sin(angle), height);
      const Eigen::Vector3d target = 0.5 * options.ring_jitter * DrawVector3(rng, normal);
      centres.push_back(centre);
      rotations.push_back(LookAt(centre, target));
    }
  } else {
    std::uniform_real_distribution<double> xy(-4.0, 4.0), z(6.0, 12.0);
    for (Eigen::Vector3d& x : cloud) x = DrawVector3(rng, xy, xy, z);
    for (int c = 0; c < 8; ++c) {
      rotations.push_back(ExpSO3(Eigen::Vector3d(0.03 * std::sin(c), -0.06 * (c - 3.5), 0.02 * c)));
      centres.emplace_back(0.5 * (c - 3.5), 0.3 * std::cos(c), 0.2 * c);
    }
  }
  const int n = static_cast<int>(centres.size());
  auto project = [&](int c, const Eigen::Vector3d& x, Eigen::Vector2d* pixel) {
    const Eigen::Vector3d camera = rotations[c] * (x - centres[c]);
    if (options.lens_k1 == 0.0) {
      *pixel = (k_true * camera).hnormalized();
    } else {
      const Eigen::Vector2d normalised = camera.hnormalized();
      const Eigen::Vector2d distorted = normalised * (1.0 + options.lens_k1 * normalised.squaredNorm());
      *pixel = (k_true * distorted.homogeneous()).hnormalized();
    }
    return camera.z() > 0.0 && pixel->x() >= 0 && pixel->x() < 640 && pixel->y() >= 0 && pixel->y() < 480;
  };
  FocalScene scene;
  const RelativePoseOptions pose_options;
  for (int a = 0; a < n; ++a) {
    for (int b = a + 1; b < n; ++b) {
      if (ring && std::min(b - a, n - (b - a)) > 3) continue;
      std::vector<Eigen::Vector2d> p1, p2;
      for (const Eigen::Vector3d& x : cloud) {
        Eigen::Vector2d u1, u2;
        if (!project(a, x, &u1) || !project(b, x, &u2)) continue;
        p1.push_back(u1 + DrawVector2(rng, noise));
        p2.push_back(unit(rng) < options.wrong_match_fraction
                         ? Eigen::Vector2d(Eigen::Vector2d(640.0, 480.0).cwiseProduct(DrawVector2(rng, unit)))
                         : Eigen::Vector2d(u2 + DrawVector2(rng, noise)));
      }
      scene.poses.push_back(EstimateRelativePoseWithCovariance(p1, p2, k_given, k_given, pose_options));
      scene.points1.push_back(std::move(p1));
      scene.points2.push_back(std::move(p2));
    }
  }
  return scene;
}

}  // namespace rotation_averaging
