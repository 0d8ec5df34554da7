// Synthetic two-camera rig data shared by the engine and node tests.
#ifndef ROTATION_AVERAGING_TEST_SYNTHETIC_RIG_H_
#define ROTATION_AVERAGING_TEST_SYNTHETIC_RIG_H_

#include <array>
#include <cmath>
#include <map>
#include <random>
#include <vector>

#include "rotation_averaging/core/controllers/online_averager.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

namespace rotation_averaging {

// A two-camera rig driving in a loop: keyframes every 0.1 s, sequential
// edges per camera, rig edges between the cameras of one capture, loop
// closures between the last and first captures, and some outlier edges.
struct RigData {
  std::map<KeyframeKey, Eigen::Matrix3d> truth;  // world-to-camera
  std::vector<KeyframeRelativeRotation> measurements;
};

inline RigData MakeRig(int captures, double outlier_ratio, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> noise(0.0, DegToRad(0.5));
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  RigData d;
  const Eigen::Matrix3d extrinsic = ExpSO3(Eigen::Vector3d(0, kPi / 2, 0));  // camera 2 looks sideways
  std::vector<std::array<KeyframeKey, 2>> keys;
  for (int c = 0; c < captures; ++c) {
    const double yaw = 2.0 * kPi * c / captures;  // one full turn: returns to the start
    const Eigen::Matrix3d body = ExpSO3(Eigen::Vector3d(0.05 * std::sin(3 * yaw), 0, yaw)).transpose();
    const std::int64_t stamp = 1'000'000'000LL + c * 100'000'000LL;
    keys.push_back({KeyframeKey{"cam_front", stamp}, KeyframeKey{"cam_side", stamp}});
    d.truth[keys.back()[0]] = body;
    d.truth[keys.back()[1]] = extrinsic * body;
  }
  const Eigen::Matrix3d cov = Eigen::Matrix3d::Identity() * std::pow(DegToRad(0.5), 2);
  auto add = [&](const KeyframeKey& a, const KeyframeKey& b, EdgeSource source) {
    KeyframeRelativeRotation m;
    m.keyframe1 = a;
    m.keyframe2 = b;
    m.source = source;
    m.has_covariance = true;
    m.covariance = cov;
    m.num_inliers = 100;
    const Eigen::Matrix3d true_rel = d.truth[a] * d.truth[b].transpose();
    if (unit(rng) < outlier_ratio) {
      m.rotation = ExpSO3((DrawVector3(rng, unit) * 2.0 - Eigen::Vector3d::Ones()) * 2.0);
    } else {
      m.rotation = true_rel * ExpSO3(DrawVector3(rng, noise));
    }
    d.measurements.push_back(m);
  };
  for (int c = 0; c < captures; ++c) {
    add(keys[c][0], keys[c][1], EdgeSource::kRig);
    for (int k = 1; k <= 2 && c + k < captures; ++k) {
      add(keys[c][0], keys[c + k][0], EdgeSource::kSequential);
      add(keys[c][1], keys[c + k][1], EdgeSource::kSequential);
    }
  }
  for (int c = captures - 3; c < captures; ++c) {
    for (int f = 0; f < 3; ++f) add(keys[c][0], keys[f][0], EdgeSource::kLoopClosure);
  }
  return d;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_SYNTHETIC_RIG_H_
