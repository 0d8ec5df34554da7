#include "frontend/estimators/adjustment_tracks.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>
#include <vector>

namespace rotation_averaging {
namespace adjustment {
namespace {

// Three cameras a unit apart on the x axis, looking along +z, and tracks of
// points 4-6 units in front of them, observed exactly.
class StrayPoints : public ::testing::Test {
 protected:
  void SetUp() override {
    for (int k = 0; k < 3; ++k) {
      AdjustedView v;
      v.id = static_cast<ViewId>(k);
      v.rotation = Eigen::AngleAxisd(0.05 * k, Eigen::Vector3d::UnitY()).toRotationMatrix();
      v.centre = Eigen::Vector3d(k, 0.0, 0.0);
      views.push_back(v);
    }
    for (int j = 0; j < 20; ++j) {
      const Eigen::Vector3d point(0.1 * j - 0.5, 0.05 * j - 0.3, 4.0 + 0.1 * j);
      truth.push_back(point);
      Track t;
      for (int k = 0; k < 3; ++k) {
        const Eigen::Vector3d y = views[k].rotation * (point - views[k].centre);
        t.observations.push_back({k, y.head<2>() / y.z()});
      }
      // Where an adjustment left it: near, not on, the truth.
      t.point = point + Eigen::Vector3d(1e-3, -2e-3, 5e-3);
      tracks.push_back(t);
    }
  }
  const double min_parallax = 1.0 * M_PI / 180.0;
  std::vector<AdjustedView> views;
  std::vector<Track> tracks;
  std::vector<Eigen::Vector3d> truth;
};

TEST_F(StrayPoints, PointsInFrontOfEveryCameraKeepTheirPlace) {
  const std::vector<Track> before = tracks;
  EXPECT_EQ(RetriangulateStrayPoints(views, min_parallax, &tracks), 0);
  ASSERT_EQ(tracks.size(), before.size());
  for (std::size_t j = 0; j < tracks.size(); ++j) EXPECT_EQ(tracks[j].point, before[j].point) << j;
}

TEST_F(StrayPoints, PointBehindACameraOrOnItsCentreIsTriangulatedAgain) {
  // Reflected through camera 0's centre: the same pixel there, behind it.
  tracks[3].point = 2.0 * views[0].centre - truth[3];
  // Come to rest a ten-millionth of the depth from camera 1's centre.
  tracks[7].point = views[1].centre + Eigen::Vector3d(0.0, 0.0, 5e-7);
  EXPECT_EQ(RetriangulateStrayPoints(views, min_parallax, &tracks), 0);
  ASSERT_EQ(tracks.size(), 20u);
  EXPECT_LT((tracks[3].point - truth[3]).norm(), 1e-9);
  EXPECT_LT((tracks[7].point - truth[7]).norm(), 1e-9);
  // The others are not touched (the midpoint would put them on the truth).
  EXPECT_GT((tracks[5].point - truth[5]).norm(), 1e-3);
}

TEST_F(StrayPoints, TrackThatCannotBeTriangulatedInFrontIsLeftOut) {
  // Camera 2 sees this point in the opposite direction: the rays' midpoint
  // lies behind a camera whatever the point.
  tracks[4].observations[2].x = -tracks[4].observations[2].x + Eigen::Vector2d(3.0, 0.0);
  tracks[4].point = 2.0 * views[2].centre - truth[4];
  const std::size_t kept_track = 5;
  const Eigen::Vector3d kept_point = tracks[kept_track].point;
  EXPECT_EQ(RetriangulateStrayPoints(views, min_parallax, &tracks), 1);
  ASSERT_EQ(tracks.size(), 19u);
  // The tracks after it move up one place, unchanged.
  EXPECT_EQ(tracks[kept_track - 1].point, kept_point);
}

TEST_F(StrayPoints, NoTracksNothingToDo) {
  tracks.clear();
  EXPECT_EQ(RetriangulateStrayPoints(views, min_parallax, &tracks), 0);
  EXPECT_TRUE(tracks.empty());
}

}  // namespace
}  // namespace adjustment
}  // namespace rotation_averaging
