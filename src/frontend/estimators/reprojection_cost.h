// Internal to the package: may change between versions.
// The bundle adjustment's reprojection residual with closed-form
// derivatives. It is evaluated for every observation at every iteration;
// Ceres' automatic derivatives carry ten-dimensional dual numbers through the
// angle-axis rotation and the projection (a quarter to a third of each
// stage's time: docs/decisions.md, "Closed-form derivatives"), where the
// chain rule below needs one rotation matrix and a few 2 x 3 products.
#ifndef ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_REPROJECTION_COST_H_
#define ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_REPROJECTION_COST_H_

#include <ceres/cost_function.h>

#include <Eigen/Core>
#include <cmath>
#include <optional>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {

// R = Exp(w) and the left Jacobian J with Exp(w + d) = Exp(J d) Exp(w) to
// first order: J = I + b [w]x + c [w]x^2, b = (1 - cos t) / t^2,
// c = (t - sin t) / t^3. Below t^2 = 1e-2 b and c by their series (the
// closed forms lose digits to cancellation there; the next terms are under
// 1e-15 of them).
inline void RotationAndLeftJacobian(const Eigen::Vector3d& w, Eigen::Matrix3d* rotation, Eigen::Matrix3d* jacobian) {
  const double t2 = w.squaredNorm();
  const Eigen::Matrix3d k = Hat(w), k2 = k * k;
  double a, b, c;  // R = I + a [w]x + b [w]x^2
  if (t2 < 1e-2) {
    a = 1.0 - t2 / 6.0 * (1.0 - t2 / 20.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0)));
    b = 0.5 - t2 / 24.0 * (1.0 - t2 / 30.0 * (1.0 - t2 / 56.0 * (1.0 - t2 / 90.0)));
    c = 1.0 / 6.0 - t2 / 120.0 * (1.0 - t2 / 42.0 * (1.0 - t2 / 72.0 * (1.0 - t2 / 110.0)));
  } else {
    const double t = std::sqrt(t2);
    a = std::sin(t) / t;
    b = (1.0 - std::cos(t)) / t2;
    c = (1.0 - a) / t2;
  }
  *rotation = Eigen::Matrix3d::Identity() + a * k + b * k2;
  if (jacobian) *jacobian = Eigen::Matrix3d::Identity() + b * k + c * k2;
}

// Whitened reprojection error of one observation x (normalised coordinates
// of the camera's intrinsics, whitened by 1 / sigma): with y = E R(w) (X - c)
// the point X in the camera with angle-axis orientation w (world to camera;
// a rig camera's: its capture's, E its camera_from_rig) and centre c,
//   r = (a y_{0,1} / y_2 - x) / sigma,
// a the camera's focal scale when it is estimated (a fourth parameter
// block), 1 otherwise. Parameter blocks: w, c, X[, a].
class ReprojectionCost : public ceres::CostFunction {
 public:
  ReprojectionCost(const Eigen::Vector2d& x, double inverse_sigma, std::optional<Eigen::Matrix3d> from_rig,
                   bool with_focal)
      : x_(x), inverse_sigma_(inverse_sigma), from_rig_(std::move(from_rig)), with_focal_(with_focal) {
    set_num_residuals(2);
    *mutable_parameter_block_sizes() = with_focal ? std::vector<int>{3, 3, 3, 1} : std::vector<int>{3, 3, 3};
  }

  bool Evaluate(double const* const* parameters, double* residuals, double** jacobians) const override {
    const Eigen::Map<const Eigen::Vector3d> w(parameters[0]), c(parameters[1]), point(parameters[2]);
    const double a = with_focal_ ? parameters[3][0] : 1.0;
    const bool rotation_jacobian = jacobians != nullptr && jacobians[0] != nullptr;
    Eigen::Matrix3d rotation, left;
    RotationAndLeftJacobian(w, &rotation, rotation_jacobian ? &left : nullptr);
    const Eigen::Vector3d z = rotation * (point - c);
    const Eigen::Vector3d y = from_rig_ ? Eigen::Vector3d(*from_rig_ * z) : z;
    const double inverse_depth = 1.0 / y[2];
    const Eigen::Vector2d projected(y[0] * inverse_depth, y[1] * inverse_depth);
    residuals[0] = inverse_sigma_ * (a * projected[0] - x_[0]);
    residuals[1] = inverse_sigma_ * (a * projected[1] - x_[1]);
    if (jacobians == nullptr) return true;
    // d r / d y, then through E to d r / d z.
    const double g = inverse_sigma_ * a * inverse_depth;
    Eigen::Matrix<double, 2, 3> by_y;
    by_y << g, 0.0, -g * projected[0], 0.0, g, -g * projected[1];
    const Eigen::Matrix<double, 2, 3> by_z = from_rig_ ? Eigen::Matrix<double, 2, 3>(by_y * *from_rig_) : by_y;
    using Block = Eigen::Map<Eigen::Matrix<double, 2, 3, Eigen::RowMajor>>;
    // d z / d w = -[z]x J (a left perturbation of R by J dw).
    if (rotation_jacobian) Block{jacobians[0]} = -by_z * Hat(z) * left;
    const Eigen::Matrix<double, 2, 3> by_point = by_z * rotation;
    if (jacobians[1] != nullptr) Block{jacobians[1]} = -by_point;
    if (jacobians[2] != nullptr) Block{jacobians[2]} = by_point;
    if (with_focal_ && jacobians[3] != nullptr) {
      jacobians[3][0] = inverse_sigma_ * projected[0];
      jacobians[3][1] = inverse_sigma_ * projected[1];
    }
    return true;
  }

 private:
  Eigen::Vector2d x_;
  double inverse_sigma_;
  std::optional<Eigen::Matrix3d> from_rig_;
  bool with_focal_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_REPROJECTION_COST_H_
