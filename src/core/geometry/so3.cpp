#include "rotation_averaging/core/geometry/so3.h"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>

namespace rotation_averaging {

Eigen::Matrix3d Hat(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

Eigen::Matrix3d ExpSO3(const Eigen::Vector3d& omega) {
  const double theta2 = omega.squaredNorm();
  const Eigen::Matrix3d w = Hat(omega);
  double a, b;  // R = I + a [w] + b [w]^2
  if (theta2 < 1e-10) {
    a = 1.0 - theta2 / 6.0;
    b = 0.5 - theta2 / 24.0;
  } else {
    const double theta = std::sqrt(theta2);
    a = std::sin(theta) / theta;
    b = (1.0 - std::cos(theta)) / theta2;
  }
  return Eigen::Matrix3d::Identity() + a * w + b * w * w;
}

Eigen::Vector3d LogSO3ViaQuaternion(const Eigen::Matrix3d& rotation) {
  // Near pi the skew part vanishes: go through the quaternion.
  Eigen::Quaterniond q(rotation);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  const Eigen::Vector3d v = q.vec();
  const double n = v.norm();
  // theta = 2 atan2(|v|, w); omega = theta * v / |v|.
  const double scale = n < 1e-10 ? 2.0 / q.w() * (1.0 - n * n / (3.0 * q.w() * q.w()))
                                 : 2.0 * std::atan2(n, q.w()) / n;
  return scale * v;
}

Eigen::Matrix3d RightJacobianInverseSO3(const Eigen::Vector3d& phi) {
  const double theta2 = phi.squaredNorm();
  const Eigen::Matrix3d w = Hat(phi);
  double c;
  if (theta2 < 1e-2) {
    // c = 1/theta^2 - cot(theta/2) / (2 theta) by its series: below 0.1 rad
    // the next term is under 3e-16 of c, while the closed form loses ~1e-13
    // to cancellation there, and the series needs no sin and cos (IRLS
    // residuals are mostly this small; this runs per edge per iteration).
    c = 1.0 / 12.0 + theta2 * (1.0 / 720.0 + theta2 * (1.0 / 30240.0 + theta2 / 1209600.0));
  } else {
    const double theta = std::sqrt(theta2);
    c = 1.0 / theta2 - (1.0 + std::cos(theta)) / (2.0 * theta * std::sin(theta));
    if (!std::isfinite(c)) c = 1.0 / theta2;  // theta at pi: Jacobian is singular there.
  }
  return Eigen::Matrix3d::Identity() + 0.5 * w + c * w * w;
}

double RotationAngleRad(const Eigen::Matrix3d& rotation) {
  // Through the quaternion: accurate for small and for large angles.
  Eigen::Quaterniond q(rotation);
  q.normalize();
  return 2.0 * std::atan2(q.vec().norm(), std::abs(q.w()));
}

double AngularDistanceRad(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return RotationAngleRad(a.transpose() * b);
}

Eigen::Matrix3d ProjectToSO3(const Eigen::Matrix3d& matrix) {
  // Nearly orthonormal input (rotations read from text files, rounded to a
  // few digits): Newton's iteration X <- (X + X^-T) / 2 for the orthogonal
  // polar factor, which is the SVD's U V^T when det > 0, converges
  // quadratically from there in two or three steps, several times cheaper
  // than the SVD that the readers of large graphs spent most of their time in.
  if (matrix.allFinite() && matrix.determinant() > 0.0 &&
      (matrix.transpose() * matrix - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-2) {
    Eigen::Matrix3d x = matrix;
    for (int k = 0; k < 8; ++k) {
      const Eigen::Matrix3d next = 0.5 * (x + x.inverse().transpose());
      const double change = (next - x).cwiseAbs().maxCoeff();
      x = next;
      if (change < 1e-15) break;
    }
    return x;
  }
  Eigen::JacobiSVD<Eigen::Matrix3d> svd(matrix, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Eigen::Matrix3d d = Eigen::Matrix3d::Identity();
  d(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0.0 ? -1.0 : 1.0;
  return svd.matrixU() * d * svd.matrixV().transpose();
}

bool IsRotationMatrix(const Eigen::Matrix3d& m, double tolerance) {
  if (!m.allFinite()) return false;
  if ((m.transpose() * m - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() > tolerance) return false;
  return std::abs(m.determinant() - 1.0) <= tolerance;
}

Eigen::Matrix3d QuaternionToRotation(double qw, double qx, double qy, double qz) {
  Eigen::Quaterniond q(qw, qx, qy, qz);
  q.normalize();
  return q.toRotationMatrix();
}

Eigen::Vector4d RotationToQuaternion(const Eigen::Matrix3d& rotation) {
  Eigen::Quaterniond q(rotation);
  q.normalize();
  if (q.w() < 0.0) q.coeffs() = -q.coeffs();
  return Eigen::Vector4d(q.w(), q.x(), q.y(), q.z());
}

Eigen::Matrix3d RotationFromRollPitchYaw(double roll, double pitch, double yaw) {
  return (Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()) *
          Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()) *
          Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()))
      .toRotationMatrix();
}

Eigen::Matrix3d RollPitchYawToRightTangentJacobian(double roll, double pitch) {
  // R = Rz Ry Rx:  R^T dR/droll = [e_x],  R^T dR/dpitch = [Rx^T e_y],
  // R^T dR/dyaw = [(Ry Rx)^T e_z].
  const Eigen::Matrix3d rx = Eigen::AngleAxisd(roll, Eigen::Vector3d::UnitX()).toRotationMatrix();
  const Eigen::Matrix3d ry = Eigen::AngleAxisd(pitch, Eigen::Vector3d::UnitY()).toRotationMatrix();
  Eigen::Matrix3d j;
  j.col(0) = Eigen::Vector3d::UnitX();
  j.col(1) = rx.transpose() * Eigen::Vector3d::UnitY();
  j.col(2) = (ry * rx).transpose() * Eigen::Vector3d::UnitZ();
  return j;
}

}  // namespace rotation_averaging
