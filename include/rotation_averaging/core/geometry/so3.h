// Public header of rotation_averaging::core (docs/embedding.md).
// SO(3) helpers: the one place where rotation conventions are defined.
//
// Conventions used throughout rotation_averaging (convert at file and message
// boundaries only):
//
//  * Absolute orientation R_i is WORLD-TO-CAMERA: x_cam_i = R_i * x_world.
//  * An edge (i, j) measures R_ij = R_i * R_j^T (the 1DSfM convention). R_ij
//    maps coordinates in camera j to coordinates in camera i.
//  * Rotation vectors are axis-angle (radians), Exp/Log are the SO(3)
//    exponential and logarithm.
//  * Edge noise is a RIGHT perturbation: measured R_ij = true R_ij * Exp(eta),
//    eta ~ N(0, C_ij), so eta and the covariance C_ij (rad^2) are expressed in
//    camera j's frame. The residual of an edge is r_ij = Log(M_ij^T R_i R_j^T),
//    which is -eta (to first order) at the true orientations.
//  * Solver updates are LEFT perturbations of the absolute orientations,
//    R_i <- Exp(delta_i) * R_i, i.e. delta_i is expressed in camera i's frame.
//  * Quaternions are Hamilton, (w, x, y, z); a quaternion and its negation are
//    the same rotation.
#ifndef ROTATION_AVERAGING_CORE_GEOMETRY_SO3_H_
#define ROTATION_AVERAGING_CORE_GEOMETRY_SO3_H_

#include <Eigen/Core>
#include <cmath>
#include <Eigen/Geometry>

namespace rotation_averaging {

// Skew-symmetric matrix [v]_x such that [v]_x * u = v x u.
Eigen::Matrix3d Hat(const Eigen::Vector3d& v);

// Exp(omega) by Rodrigues' formula, with a Taylor expansion near zero.
Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& omega_rad);

// Log(R) through the quaternion, whose vector part does not vanish at pi.
Eigen::Vector3d LogSO3ViaQuaternion(const Eigen::Matrix3d& rotation);

// atan(t) / t for t^2 = t2 <= 0.01 by its series to t^16 (first omitted
// term t^18 / 19 < 1e-19).
inline double AtanRatioSeries(double t2) {
  double p = 1.0 / 17.0;
  for (const double k : {-1.0 / 15.0, 1.0 / 13.0, -1.0 / 11.0, 1.0 / 9.0, -1.0 / 7.0, 1.0 / 5.0, -1.0 / 3.0, 1.0}) {
    p = k + t2 * p;
  }
  return p;
}

// Log(R): rotation vector with angle in [0, pi]. Stable near 0 and near pi.
// Inline: it is the inner loop of every solver. Below 120 degrees the skew
// part is v = sin(theta) axis and the trace gives cos(theta), so
// theta = atan2(|v|, cos theta); beyond, through the quaternion.
inline Eigen::Vector3d LogSO3(const Eigen::Matrix3d& rotation) {
  const double c = 0.5 * (rotation.trace() - 1.0);
  if (c <= -0.5) return LogSO3ViaQuaternion(rotation);
  const Eigen::Vector3d v(0.5 * (rotation(2, 1) - rotation(1, 2)), 0.5 * (rotation(0, 2) - rotation(2, 0)),
                          0.5 * (rotation(1, 0) - rotation(0, 1)));
  const double s2 = v.squaredNorm();
  // theta / sin(theta) = 1 + theta^2 / 6 + O(theta^4).
  if (s2 < 1e-16) return (1.0 + s2 / 6.0) * v;
  const double s = std::sqrt(s2);
  // Below ~5.7 degrees (t = tan(theta) <= 0.1, most residuals of a solve)
  // atan(t) / t by its series: several times cheaper than atan2, which
  // showed as a large share of a solve's profile.
  if (s <= 0.1 * c) return (AtanRatioSeries(s2 / (c * c)) / c) * v;
  return (std::atan2(s, c) / s) * v;
}

// Log of the rotation of a unit quaternion q = (w, v): theta = 2 atan2(|v|,
// |w|), in [0, pi]. Below ~11 degrees (t = |v| / |w| <= 0.1) atan(t) / t by
// its series, as in LogSO3.
inline Eigen::Vector3d LogUnitQuaternion(const Eigen::Quaterniond& q) {
  const double w = std::abs(q.w());
  const Eigen::Vector3d v = q.w() < 0.0 ? Eigen::Vector3d(-q.vec()) : Eigen::Vector3d(q.vec());
  const double s2 = v.squaredNorm();
  if (s2 <= 0.01 * w * w) return (2.0 * AtanRatioSeries(s2 / (w * w)) / w) * v;
  const double s = std::sqrt(s2);
  return (2.0 * std::atan2(s, w) / s) * v;
}

// Inverse of the right Jacobian of SO(3): Log(Exp(phi) Exp(d)) ~ phi + Jr^-1(phi) d.
Eigen::Matrix3d RightJacobianInverseSO3(const Eigen::Vector3d& phi_rad);

// Angle of R_a^T R_b in radians, in [0, pi].
double AngularDistanceRad(const Eigen::Matrix3d& rotation_a, const Eigen::Matrix3d& rotation_b);

// Rotation angle of a single rotation, radians in [0, pi].
double RotationAngleRad(const Eigen::Matrix3d& rotation);

// Nearest rotation in Frobenius norm (SVD with the determinant fixed to +1).
Eigen::Matrix3d ProjectToSO3(const Eigen::Matrix3d& matrix);

// True if every entry is finite, R^T R = I within tolerance and det(R) = +1.
bool IsRotationMatrix(const Eigen::Matrix3d& matrix, double tolerance = 1e-6);

// Quaternion (w, x, y, z) -> rotation matrix. The quaternion must be non-zero;
// it is normalised here.
Eigen::Matrix3d QuaternionToRotation(double qw, double qx, double qy, double qz);

// Rotation matrix -> unit quaternion (w, x, y, z) with w >= 0.
Eigen::Vector4d RotationToQuaternion(const Eigen::Matrix3d& rotation);

// R = Rz(yaw) * Ry(pitch) * Rx(roll) (TORO / GTSAM Rot3::Ypr convention).
Eigen::Matrix3d RotationFromRollPitchYaw(double roll_rad, double pitch_rad, double yaw_rad);

// Jacobian J such that R(rpy + d) ~ R(rpy) * Exp(J d): maps roll/pitch/yaw
// perturbations to a right perturbation of the rotation above.
Eigen::Matrix3d RollPitchYawToRightTangentJacobian(double roll_rad, double pitch_rad);

constexpr double kPi = 3.14159265358979323846;
inline double DegToRad(double deg) { return deg * kPi / 180.0; }
inline double RadToDeg(double rad) { return rad * 180.0 / kPi; }

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_GEOMETRY_SO3_H_
