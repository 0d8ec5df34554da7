// Shared by the tests of the refinements that start from averaged
// orientations (correspondence_refinement.h, bundle_adjustment.h).
#ifndef ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_
#define ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_

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

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_TEST_REFINEMENT_TEST_UTIL_H_
