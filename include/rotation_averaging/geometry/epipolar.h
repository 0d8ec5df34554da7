// Internal to the package: may change between versions.
// The Sampson error of a correspondence, shared by the two-view refinement
// (pixels, F) and the refinement on correspondences (normalised
// coordinates, E); templated for Ceres' automatic derivatives.
#ifndef ROTATION_AVERAGING_GEOMETRY_EPIPOLAR_H_
#define ROTATION_AVERAGING_GEOMETRY_EPIPOLAR_H_

#include <Eigen/Core>
#include <cmath>

namespace rotation_averaging {

// [t]x such that [t]x u = t x u.
template <typename T>
Eigen::Matrix<T, 3, 3> CrossMatrix(const T* t) {
  Eigen::Matrix<T, 3, 3> m;
  m << T(0), -t[2], t[1], t[2], T(0), -t[0], -t[1], t[0], T(0);
  return m;
}

// First-order distance of (x1, x2) (homogeneous, last coordinate 1) to the
// epipolar geometry x2^T F x1 = 0:
//   r = x2^T F x1 / sqrt((F x1)_0^2 + (F x1)_1^2 + (F^T x2)_0^2 + (F^T x2)_1^2).
template <typename T>
T SampsonError(const Eigen::Matrix<T, 3, 3>& f, const Eigen::Matrix<T, 3, 1>& x1, const Eigen::Matrix<T, 3, 1>& x2) {
  using std::sqrt;  // and ceres::sqrt for Jets, by argument-dependent lookup
  const Eigen::Matrix<T, 3, 1> fx1 = f * x1;
  const Eigen::Matrix<T, 3, 1> ftx2 = f.transpose() * x2;
  const T denominator = fx1[0] * fx1[0] + fx1[1] * fx1[1] + ftx2[0] * ftx2[0] + ftx2[1] * ftx2[1];
  return x2.dot(fx1) / sqrt(denominator + T(1e-300));
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_GEOMETRY_EPIPOLAR_H_
