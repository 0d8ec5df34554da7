#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/random_draws.h"

#include <gtest/gtest.h>

#include <random>

namespace rotation_averaging {
namespace {

TEST(So3, ExpLogRoundTripIncludingNearZeroAndNearPi) {
  std::mt19937 rng(3);
  std::normal_distribution<double> normal;
  for (double angle : {0.0, 1e-12, 1e-7, 1e-3, 0.5, 2.0, kPi - 1e-3, kPi - 1e-8}) {
    for (int k = 0; k < 20; ++k) {
      const Eigen::Vector3d axis = DrawVector3(rng, normal).normalized();
      const Eigen::Vector3d w = angle * axis;
      const Eigen::Matrix3d r = ExpSO3(w);
      EXPECT_TRUE(IsRotationMatrix(r, 1e-12));
      const Eigen::Matrix3d expected = Eigen::AngleAxisd(angle, axis).toRotationMatrix();
      EXPECT_LT((r - expected).norm(), 1e-12);
      const Eigen::Vector3d back = LogSO3(r);
      // Near pi, w and -w are the same rotation.
      EXPECT_LT(std::min((back - w).norm(), (back + w).norm()), 1e-7) << angle;
      EXPECT_NEAR(RotationAngleRad(r), angle, 1e-8);
    }
  }
}

// Small angles take a series for atan(t) / t instead of atan2: it must agree
// with atan2 (in long double) to rounding, on both sides of the switch.
TEST(So3, LogSeriesBranchAgreesWithAtan2) {
  std::mt19937 rng(4);
  std::normal_distribution<double> normal;
  double worst = 0.0;
  for (double angle = 1e-7; angle < 0.2; angle *= 1.05) {
    const Eigen::Vector3d axis = DrawVector3(rng, normal).normalized();
    const Eigen::Matrix3d r = ExpSO3(angle * axis);
    const long double c = 0.5L * (static_cast<long double>(r.trace()) - 1.0L);
    const Eigen::Vector3d v(0.5 * (r(2, 1) - r(1, 2)), 0.5 * (r(0, 2) - r(2, 0)), 0.5 * (r(1, 0) - r(0, 1)));
    const long double s = std::sqrt(static_cast<long double>(v.squaredNorm()));
    const Eigen::Vector3d expected = static_cast<double>(std::atan2(s, c) / s) * v;
    const Eigen::Vector3d log = LogSO3(r);
    worst = std::max(worst, (log - expected).norm() / expected.norm());
    EXPECT_NEAR(log.norm(), angle, 1e-12 * angle + 1e-15) << angle;
  }
  EXPECT_LT(worst, 1e-15);
}

TEST(So3, LogOfAUnitQuaternionAgreesWithLogOfItsMatrix) {
  std::mt19937 rng(5);
  std::normal_distribution<double> normal;
  double worst = 0.0;
  for (double angle = 1e-8; angle < kPi - 1e-6; angle = std::min(angle * 1.05, angle + 0.01)) {
    const Eigen::Vector3d omega = angle * DrawVector3(rng, normal).normalized();
    const Eigen::Quaterniond q(Eigen::AngleAxisd(angle, omega.normalized()));
    // Either sign of the quaternion is the same rotation.
    for (const double sign : {1.0, -1.0}) {
      const Eigen::Quaterniond signed_q(sign * q.coeffs());
      const Eigen::Vector3d log = LogUnitQuaternion(signed_q);
      worst = std::max(worst, (log - omega).norm() / angle);
      EXPECT_LT((log - LogSO3(signed_q.toRotationMatrix())).norm(), 1e-9 * angle + 1e-15) << angle;
    }
  }
  EXPECT_LT(worst, 1e-13);
}

TEST(So3, QuaternionConversionsAgreeWithEigen) {
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.3, -1.2, 0.7));
  const Eigen::Vector4d q = RotationToQuaternion(r);
  EXPECT_GE(q[0], 0.0);
  EXPECT_NEAR(q.norm(), 1.0, 1e-15);
  EXPECT_LT((QuaternionToRotation(q[0], q[1], q[2], q[3]) - r).norm(), 1e-12);
  EXPECT_LT((QuaternionToRotation(-q[0], -q[1], -q[2], -q[3]) - r).norm(), 1e-12);
  // Non-unit input is normalised.
  EXPECT_LT((QuaternionToRotation(2 * q[0], 2 * q[1], 2 * q[2], 2 * q[3]) - r).norm(), 1e-12);
}

TEST(So3, ProjectionRecoversNoisyRotationAndFixesReflection) {
  const Eigen::Matrix3d r = ExpSO3(Eigen::Vector3d(0.1, 0.2, 0.3));
  Eigen::Matrix3d noisy = r;
  noisy(0, 1) += 1e-4;
  EXPECT_TRUE(IsRotationMatrix(ProjectToSO3(noisy), 1e-12));
  EXPECT_LT(AngularDistanceRad(ProjectToSO3(noisy), r), 1e-4);
  Eigen::Matrix3d reflection = r;
  reflection.col(2) *= -1.0;
  EXPECT_NEAR(ProjectToSO3(reflection).determinant(), 1.0, 1e-12);
}

TEST(So3, RightJacobianInverseMatchesFiniteDifferences) {
  const Eigen::Vector3d phi(0.4, -0.8, 1.1);
  const Eigen::Matrix3d jinv = RightJacobianInverseSO3(phi);
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    d[k] = h;
    const Eigen::Vector3d numeric = (LogSO3(ExpSO3(phi) * ExpSO3(d)) - LogSO3(ExpSO3(phi) * ExpSO3(-d))) / (2 * h);
    EXPECT_LT((numeric - jinv.col(k)).norm(), 1e-6);
  }
}

TEST(So3, RollPitchYawJacobianIsARightPerturbation) {
  const double roll = 0.3, pitch = -0.5, yaw = 1.2;
  const Eigen::Matrix3d j = RollPitchYawToRightTangentJacobian(roll, pitch);
  const Eigen::Matrix3d r = RotationFromRollPitchYaw(roll, pitch, yaw);
  const double h = 1e-6;
  for (int k = 0; k < 3; ++k) {
    Eigen::Vector3d d = Eigen::Vector3d::Zero();
    d[k] = h;
    const Eigen::Matrix3d rp = RotationFromRollPitchYaw(roll + d[0], pitch + d[1], yaw + d[2]);
    EXPECT_LT((LogSO3(r.transpose() * rp) / h - j.col(k)).norm(), 1e-5);
  }
}

TEST(So3, ConventionRelativeRotationMapsCameraJToCameraI) {
  // R_ij = R_i R_j^T maps camera-j coordinates to camera-i coordinates.
  const Eigen::Matrix3d ri = ExpSO3(Eigen::Vector3d(0.1, 0.5, -0.2));
  const Eigen::Matrix3d rj = ExpSO3(Eigen::Vector3d(-0.7, 0.2, 0.4));
  const Eigen::Vector3d x_world(1.0, 2.0, 3.0);
  EXPECT_LT((ri * rj.transpose() * (rj * x_world) - ri * x_world).norm(), 1e-12);
}

}  // namespace
}  // namespace rotation_averaging
