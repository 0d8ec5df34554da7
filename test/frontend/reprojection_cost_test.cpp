#include "frontend/estimators/reprojection_cost.h"

#include <ceres/autodiff_cost_function.h>
#include <ceres/rotation.h>
#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <memory>
#include <random>
#include <vector>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

// The residual as automatic derivatives see it: Ceres' own angle-axis
// rotation, the projection, the focal scale.
struct Reference {
  Eigen::Vector2d x;
  double inverse_sigma;
  std::optional<Eigen::Matrix3d> from_rig;

  template <typename T>
  bool operator()(const T* w, const T* c, const T* point, const T* a, T* residual) const {
    const T d[3] = {point[0] - c[0], point[1] - c[1], point[2] - c[2]};
    T y[3];
    ceres::AngleAxisRotatePoint(w, d, y);
    if (from_rig) {
      const T z[3] = {y[0], y[1], y[2]};
      for (int r = 0; r < 3; ++r) {
        y[r] = T((*from_rig)(r, 0)) * z[0] + T((*from_rig)(r, 1)) * z[1] + T((*from_rig)(r, 2)) * z[2];
      }
    }
    residual[0] = T(inverse_sigma) * (a[0] * y[0] / y[2] - T(x.x()));
    residual[1] = T(inverse_sigma) * (a[0] * y[1] / y[2] - T(x.y()));
    return true;
  }
};

// Orientations from the identity to a half turn, the small angles where
// the closed forms give way to their series among them.
std::vector<Eigen::Vector3d> Orientations() {
  std::vector<Eigen::Vector3d> out;
  const Eigen::Vector3d axis = Eigen::Vector3d(0.3, -0.8, 0.5).normalized();
  for (double angle : {0.0, 1e-9, 1e-5, 0.01, 0.0999, 0.1001, 0.7, 2.0, 3.1, M_PI}) out.push_back(angle * axis);
  return out;
}

TEST(ReprojectionCost, ResidualsAndJacobiansMatchAutomaticDerivatives) {
  std::mt19937 rng(5);
  std::normal_distribution<double> normal(0.0, 1.0);
  const Eigen::Matrix3d from_rig = ExpSO3(Eigen::Vector3d(0.1, 1.4, -0.2));
  int compared = 0;
  for (const Eigen::Vector3d& w : Orientations()) {
    for (bool rig : {false, true}) {
      for (bool focal : {false, true}) {
        const Eigen::Matrix3d e = rig ? from_rig : Eigen::Matrix3d::Identity();
        const Eigen::Vector3d c(normal(rng), normal(rng), normal(rng));
        // A point in front of the camera, off its axis.
        const Eigen::Matrix3d r = ExpSO3(w);
        const Eigen::Vector3d in_camera(0.3 * normal(rng), 0.3 * normal(rng), 4.0 + normal(rng));
        const Eigen::Vector3d point = r.transpose() * e.transpose() * in_camera + c;
        const Eigen::Vector2d x(0.25 * normal(rng), 0.25 * normal(rng));
        const double inverse_sigma = 250.0, a = focal ? 1.03 : 1.0;
        const std::optional<Eigen::Matrix3d> rig_rotation = rig ? std::optional<Eigen::Matrix3d>(from_rig) : std::nullopt;

        const ReprojectionCost cost(x, inverse_sigma, rig_rotation, focal);
        ceres::AutoDiffCostFunction<Reference, 2, 3, 3, 3, 1> reference(new Reference{x, inverse_sigma, rig_rotation});
        const double* parameters[4] = {w.data(), c.data(), point.data(), &a};
        double residual[2], expected[2];
        double jw[6], jc[6], jx[6], ja[2], ew[6], ec[6], ex[6], ea[2];
        double* jacobians[4] = {jw, jc, jx, ja};
        double* expected_jacobians[4] = {ew, ec, ex, ea};
        ASSERT_TRUE(cost.Evaluate(parameters, residual, jacobians));
        ASSERT_TRUE(reference.Evaluate(parameters, expected, expected_jacobians));
        const double angle = w.norm();
        for (int i = 0; i < 2; ++i) {
          EXPECT_NEAR(residual[i], expected[i], 1e-9 * std::max(1.0, std::abs(expected[i]))) << "angle " << angle;
        }
        const auto close = [&](const double* got, const double* want, int n, const char* block) {
          double scale = 1.0;
          for (int k = 0; k < n; ++k) scale = std::max(scale, std::abs(want[k]));
          for (int k = 0; k < n; ++k) {
            EXPECT_NEAR(got[k], want[k], 1e-9 * scale) << block << " " << k << ", angle " << angle << ", rig " << rig;
          }
        };
        close(jw, ew, 6, "orientation");
        close(jc, ec, 6, "centre");
        close(jx, ex, 6, "point");
        if (focal) close(ja, ea, 2, "focal scale");
        // Without Jacobians, or with some of them, the residual is the same.
        double alone[2];
        ASSERT_TRUE(cost.Evaluate(parameters, alone, nullptr));
        EXPECT_EQ(alone[0], residual[0]);
        EXPECT_EQ(alone[1], residual[1]);
        double* some[4] = {nullptr, jc, nullptr, nullptr};
        ASSERT_TRUE(cost.Evaluate(parameters, alone, some));
        EXPECT_EQ(alone[0], residual[0]);
        ++compared;
      }
    }
  }
  EXPECT_EQ(compared, 40);
}

TEST(ReprojectionCost, LeftJacobianIsTheDerivativeOfTheExponential) {
  // Exp(w + d) Exp(w)^T = Exp(J d) to first order: the central difference
  // of Log(Exp(w + h e_k) Exp(w)^T) / h is J's column k.
  for (const Eigen::Vector3d& w : Orientations()) {
    if (w.norm() > 3.0) continue;  // Log's branch cut at a half turn
    Eigen::Matrix3d rotation, jacobian;
    RotationAndLeftJacobian(w, &rotation, &jacobian);
    EXPECT_LT((rotation - ExpSO3(w)).norm(), 1e-14) << w.norm();
    const double h = 1e-6;
    for (int k = 0; k < 3; ++k) {
      const Eigen::Vector3d step = h * Eigen::Vector3d::Unit(k);
      const Eigen::Vector3d column = (LogSO3(ExpSO3(w + step) * rotation.transpose()) -
                                      LogSO3(ExpSO3(w - step) * rotation.transpose())) /
                                     (2.0 * h);
      EXPECT_LT((column - jacobian.col(k)).norm(), 1e-8) << "angle " << w.norm() << ", column " << k;
    }
  }
}

}  // namespace
}  // namespace rotation_averaging
