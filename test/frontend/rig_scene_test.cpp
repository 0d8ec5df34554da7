#include "rotation_averaging/sim/rig_scene.h"

#include <gtest/gtest.h>

#include <cmath>

#include <opencv2/core.hpp>

#include "rotation_averaging/core/geometry/so3.h"

namespace rotation_averaging {
namespace {

TEST(RigScene, GroundTruthMatchesTheRigGeometry) {
  RigSceneOptions o;
  o.num_captures = 24;
  o.WithWidth(160);
  const RigScene scene(o);
  ASSERT_EQ(scene.Cameras().size(), 2u);
  // The loop closes: the last capture is one step before the first.
  EXPECT_NEAR((scene.RigPosition(0) - scene.RigPosition(o.num_captures)).norm(), 0.0, 1e-9);
  // Camera orientations differ by the fixed extrinsic rotation at every capture.
  for (int c = 0; c < o.num_captures; c += 5) {
    const Eigen::Matrix3d relative = scene.WorldToCamera(c, 0) * scene.WorldToCamera(c, 1).transpose();
    EXPECT_LT(AngularDistanceRad(relative, scene.Cameras()[0].camera_from_rig *
                                               scene.Cameras()[1].camera_from_rig.transpose()),
              1e-12);
    // The front camera looks along the direction of travel.
    const Eigen::Vector3d forward = scene.WorldToCamera(c, 0).transpose() * Eigen::Vector3d::UnitZ();
    const Eigen::Vector3d travel = (scene.RigPosition(c + 1) - scene.RigPosition(c - 1)).normalized();
    EXPECT_GT(forward.dot(travel), std::cos(DegToRad(10.0)));
  }
  // Images are deterministic and textured.
  const cv::Mat a = scene.Render(3, 1), b = scene.Render(3, 1);
  ASSERT_EQ(a.rows, 120);
  EXPECT_EQ(cv::norm(a, b, cv::NORM_INF), 0.0);
  cv::Scalar mean, stddev;
  cv::meanStdDev(a, mean, stddev);
  EXPECT_GT(stddev[0], 20.0);
}

TEST(RigScene, ACameraTurnedHalfAroundItsAxisSeesItsImageTurnedAboutThePrincipalPoint) {
  // The renderer and Intrinsics() must agree on where a pixel's centre is:
  // turned 180 degrees about its optical axis, the camera sees pixel (x, y)
  // at 2 c - (x, y) for K's principal point c = (W/2, H/2).
  RigSceneOptions o;
  o.WithWidth(160);
  o.noise_grey = 0.0;
  const RigScene scene(o);
  const Eigen::Matrix3d world_to_camera = scene.WorldToCamera(5, 0);
  const Eigen::Matrix3d half_turn = Eigen::Vector3d(-1.0, -1.0, 1.0).asDiagonal();
  const cv::Mat image = scene.RenderView(world_to_camera, scene.CameraCentre(5, 0), 1);
  const cv::Mat turned = scene.RenderView(half_turn * world_to_camera, scene.CameraCentre(5, 0), 1);
  const Eigen::Matrix3d k = scene.Intrinsics();
  int compared = 0, same = 0;
  for (int y = 0; y < image.rows; ++y) {
    for (int x = 0; x < image.cols; ++x) {
      const int xt = static_cast<int>(2.0 * k(0, 2)) - x, yt = static_cast<int>(2.0 * k(1, 2)) - y;
      if (xt < 0 || yt < 0 || xt >= image.cols || yt >= image.rows) continue;
      ++compared;
      same += image.at<std::uint8_t>(y, x) == turned.at<std::uint8_t>(yt, xt);
    }
  }
  ASSERT_GT(compared, image.rows * image.cols / 2);
  EXPECT_EQ(same, compared);
}

}  // namespace
}  // namespace rotation_averaging
