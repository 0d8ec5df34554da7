// Random vectors and quaternions drawn in a fixed order. C++ leaves the
// order in which the arguments of one call are evaluated unspecified (gcc
// evaluates them right to left, clang left to right), so
// `Eigen::Vector3d(d(rng), d(rng), d(rng))` makes other data with another
// compiler: other synthetic graphs, other rendered scenes, other test
// inputs. These draw one value per statement, the last component first
// (the order in which gcc evaluates such a call, so that the data stay the
// ones the package's results were made with).
#ifndef ROTATION_AVERAGING_UTIL_RANDOM_DRAWS_H_
#define ROTATION_AVERAGING_UTIL_RANDOM_DRAWS_H_

#include <Eigen/Core>
#include <Eigen/Geometry>

namespace rotation_averaging {

// (dx(rng), dy(rng)), dy drawn first.
template <typename Rng, typename Dx, typename Dy>
Eigen::Vector2d DrawVector2(Rng& rng, Dx& dx, Dy& dy) {
  const double y = dy(rng);
  const double x = dx(rng);
  return Eigen::Vector2d(x, y);
}
template <typename Rng, typename D>
Eigen::Vector2d DrawVector2(Rng& rng, D& d) {
  return DrawVector2(rng, d, d);
}

// (dx(rng), dy(rng), dz(rng)), dz drawn first, then dy.
template <typename Rng, typename Dx, typename Dy, typename Dz>
Eigen::Vector3d DrawVector3(Rng& rng, Dx& dx, Dy& dy, Dz& dz) {
  const double z = dz(rng);
  const double y = dy(rng);
  const double x = dx(rng);
  return Eigen::Vector3d(x, y, z);
}
template <typename Rng, typename D>
Eigen::Vector3d DrawVector3(Rng& rng, D& d) {
  return DrawVector3(rng, d, d, d);
}

// Eigen::Quaterniond(w, x, y, z) with each coefficient d(rng), z drawn
// first and w last; not normalised.
template <typename Rng, typename D>
Eigen::Quaterniond DrawQuaternion(Rng& rng, D& d) {
  const double z = d(rng);
  const double y = d(rng);
  const double x = d(rng);
  const double w = d(rng);
  return Eigen::Quaterniond(w, x, y, z);
}

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_UTIL_RANDOM_DRAWS_H_
