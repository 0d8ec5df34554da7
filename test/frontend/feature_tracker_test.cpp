#include "rotation_averaging/frontend/features/feature_tracker.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <memory>
#include <opencv2/imgproc.hpp>
#include <set>

#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/sim/turning_view.h"

namespace rotation_averaging {
namespace {

double Median(std::vector<double> v) {
  EXPECT_FALSE(v.empty());
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// A camera turning on the spot over a rendered view, `step_deg` per image
// (sim/turning_view.h): image t is image 0 moved by a known homography.
class TurningCamera {
 public:
  explicit TurningCamera(double step_deg) {
    RigSceneOptions scene_options;
    scene_options.noise_grey = 0.0;
    scene_options.WithWidth(480);
    const RigScene scene(scene_options);
    TurningViewOptions options;
    options.width = 480;
    options.height = 360;
    options.focal_px = scene.Intrinsics()(0, 0);
    options.step_deg = step_deg;
    view_ = std::make_unique<TurningView>(scene.Render(5, 0, 80), options);
  }
  cv::Mat Image(int t) const { return view_->View(t); }
  double Error(int t, const Eigen::Vector2d& p0, const Eigen::Vector2d& pt) const { return view_->Error(t, p0, pt); }

 private:
  std::unique_ptr<TurningView> view_;
};

TEST(FeatureTracker, TracksFollowTheImagesAndKeepTheirIds) {
  const TurningCamera camera(0.8);
  FeatureTrackerOptions options;
  FeatureTracker tracker(options);
  const std::vector<TrackedPoint> first = tracker.Track(camera.Image(0));
  ASSERT_GE(first.size(), 200u);
  EXPECT_LE(first.size(), static_cast<std::size_t>(options.max_tracks));
  std::vector<TrackedPoint> last;
  std::set<std::uint64_t> seen;
  for (const TrackedPoint& p : first) seen.insert(p.id);
  for (int t = 1; t <= 3; ++t) {
    last = tracker.Track(camera.Image(t));
    for (std::size_t i = 1; i < last.size(); ++i) ASSERT_LT(last[i - 1].id, last[i].id) << "in id order";
    for (const TrackedPoint& p : last) seen.insert(p.id);
  }
  // A camera turning 0.8 deg per image loses few of its tracks in 3 images,
  // and each lands where the homography puts it, to hundredths of a pixel.
  const auto shared = SharedTracks(first, last);
  EXPECT_GE(shared.size(), first.size() * 8 / 10);
  std::vector<double> errors;
  for (const auto& [p, q] : shared) errors.push_back(camera.Error(3, p, q));
  EXPECT_LT(Median(errors), 0.1);
  // After a reset no new track takes an id that was used before: a keyframe
  // from before the gap shares no track with one after it.
  tracker.Reset();
  EXPECT_EQ(tracker.NumTracks(), 0u);
  const std::vector<TrackedPoint> after = tracker.Track(camera.Image(4));
  ASSERT_FALSE(after.empty());
  for (const TrackedPoint& p : after) EXPECT_EQ(seen.count(p.id), 0u) << p.id;
  EXPECT_TRUE(SharedTracks(first, after).empty());
}

TEST(FeatureTracker, AnImageOfAnotherSizeStartsAnew) {
  const TurningCamera camera(0.8);
  FeatureTracker tracker{FeatureTrackerOptions()};
  const std::vector<TrackedPoint> first = tracker.Track(camera.Image(0));
  cv::Mat smaller;
  cv::resize(camera.Image(1), smaller, cv::Size(), 0.5, 0.5, cv::INTER_AREA);
  const std::vector<TrackedPoint> next = tracker.Track(smaller);
  ASSERT_FALSE(next.empty());
  EXPECT_TRUE(SharedTracks(first, next).empty());
  for (const TrackedPoint& p : next) {
    EXPECT_LT(p.px.x(), smaller.cols);
    EXPECT_LT(p.px.y(), smaller.rows);
  }
}

// Over a keyframe pair's 8 deg the view's perspective changes: points
// tracked from image to image are off by a tenth of a pixel or more (each
// step's error adds up, and KLT's window does not deform), re-tracking them
// between the two images through the homography the tracks fit is not.
TEST(FeatureTracker, RetrackingBetweenTwoImagesRemovesTheTracksDrift) {
  const TurningCamera camera(0.8);
  FeatureTrackerOptions options;
  FeatureTracker tracker(options);
  const cv::Mat image0 = camera.Image(0);
  const std::vector<TrackedPoint> first = tracker.Track(image0);
  constexpr int kSteps = 10;
  cv::Mat image;
  std::vector<TrackedPoint> last;
  for (int t = 1; t <= kSteps; ++t) {
    image = camera.Image(t);
    last = tracker.Track(image);
  }
  std::vector<cv::Point2f> points1, points2;
  std::vector<double> chained;
  for (const auto& [p, q] : SharedTracks(first, last)) {
    points1.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
    points2.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
    chained.push_back(camera.Error(kSteps, p, q));
  }
  ASSERT_GE(points1.size(), 100u);
  std::vector<bool> kept;
  RetrackBetween(TrackPyramid(image0, options, false), TrackPyramid(image, options, false), points1, &points2, &kept,
                 options);
  std::vector<double> retracked;
  for (std::size_t i = 0; i < points1.size(); ++i) {
    if (!kept[i]) continue;
    retracked.push_back(camera.Error(kSteps, Eigen::Vector2d(points1[i].x, points1[i].y),
                                     Eigen::Vector2d(points2[i].x, points2[i].y)));
  }
  EXPECT_GE(retracked.size(), chained.size() * 8 / 10);
  const double chained_px = Median(chained), retracked_px = Median(retracked);
  std::cout << "after " << kSteps << " images: tracked " << chained_px << " px, re-tracked " << retracked_px
            << " px (median)\n";
  EXPECT_GT(chained_px, 0.08);
  EXPECT_LT(retracked_px, 0.05);
  EXPECT_LT(retracked_px, 0.5 * chained_px);
}

TEST(FeatureTracker, SharedTracksPairsPointsById) {
  const std::vector<TrackedPoint> a{{1, {1, 1}}, {3, {3, 3}}, {4, {4, 4}}, {9, {9, 9}}};
  const std::vector<TrackedPoint> b{{2, {20, 20}}, {3, {30, 30}}, {9, {90, 90}}, {10, {100, 100}}};
  const auto shared = SharedTracks(a, b);
  ASSERT_EQ(shared.size(), 2u);
  EXPECT_EQ(shared[0].first, Eigen::Vector2d(3, 3));
  EXPECT_EQ(shared[0].second, Eigen::Vector2d(30, 30));
  EXPECT_EQ(shared[1].first, Eigen::Vector2d(9, 9));
  EXPECT_EQ(shared[1].second, Eigen::Vector2d(90, 90));
  EXPECT_TRUE(SharedTracks(a, {}).empty());
}

TEST(FeatureTracker, OptionsOutOfRangeAreNamed) {
  FeatureTrackerOptions options;
  std::string error;
  EXPECT_TRUE(options.Validate(&error)) << error;
  options.max_tracks = 3;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("max_tracks"), std::string::npos) << error;
  options = FeatureTrackerOptions();
  options.forward_backward_px = 0.0;
  EXPECT_FALSE(options.Validate(&error));
  EXPECT_NE(error.find("track_forward_backward_px"), std::string::npos) << error;
}

}  // namespace
}  // namespace rotation_averaging
