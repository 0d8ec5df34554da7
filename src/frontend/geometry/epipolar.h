// Internal to the package: may change between versions.
// The Sampson error of a correspondence, shared by the two-view refinement
// (pixels, F) and the refinement on correspondences (normalised
// coordinates, E); templated for Ceres' automatic derivatives.
#ifndef ROTATION_AVERAGING_SRC_FRONTEND_GEOMETRY_EPIPOLAR_H_
#define ROTATION_AVERAGING_SRC_FRONTEND_GEOMETRY_EPIPOLAR_H_

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

// The Sampson error and its derivative with respect to the entries of F
// (d r / d F(a, b) in `gradient`), in closed form: the two-view refinement
// evaluates it for every inlier at every iteration, where automatic
// derivatives through the pose parameters cost several times more.
// With g = F x1, h = F^T x2, e = x2^T g, d = g0^2 + g1^2 + h0^2 + h1^2:
//   r = e / sqrt(d),  dr/dF = (x2 x1^T - (r / sqrt(d)) (g' x1^T + x2 h'^T)) / sqrt(d),
// g' = (g0, g1, 0), h' = (h0, h1, 0).
inline double SampsonErrorAndGradient(const Eigen::Matrix3d& f, const Eigen::Vector3d& x1, const Eigen::Vector3d& x2,
                                      Eigen::Matrix3d* gradient) {
  const Eigen::Vector3d g = f * x1, h = f.transpose() * x2;
  const double inv_sqrt_d = 1.0 / std::sqrt(g[0] * g[0] + g[1] * g[1] + h[0] * h[0] + h[1] * h[1] + 1e-300);
  const double r = x2.dot(g) * inv_sqrt_d;
  const double c = r * inv_sqrt_d;
  const Eigen::Vector3d u = x2 - c * Eigen::Vector3d(g[0], g[1], 0.0);
  *gradient = inv_sqrt_d * (u * x1.transpose() - c * x2 * Eigen::RowVector3d(h[0], h[1], 0.0));
  return r;
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_FRONTEND_GEOMETRY_EPIPOLAR_H_
