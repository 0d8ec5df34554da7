#include "rotation_averaging/frontend/controllers/keyframe_selector.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <iostream>
#include <map>
#include <set>

#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>

#include "common/test_data.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/core/io/orientation_io.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/sim/rig_scene.h"

namespace rotation_averaging {
namespace {

// The demo rig (two cameras, 90 deg apart) as a 20 Hz stream at 256x192,
// turning 0.75 deg per capture: the tests play the first 100-120 captures.
RigSceneOptions StreamOptions() {
  RigSceneOptions o;
  o.WithWidth(256);
  o.num_captures = 480;  // one lap in 24 s
  o.capture_period_s = 0.05;
  return o;
}

SelectorFrame Frame(const RigScene& scene, int capture, int camera) {
  SelectorFrame f;
  f.camera = scene.Cameras()[camera].frame_id;
  f.stamp_ns = static_cast<std::int64_t>(std::llround(scene.CaptureTime(capture) * 1e9)) + 1'000'000'000LL;
  f.image = scene.Render(capture, camera);
  f.intrinsics.k = scene.Intrinsics();
  return f;
}

std::string Name(const SelectorFrame& f) { return f.camera + "@" + std::to_string(f.stamp_ns); }

TEST(KeyframeSelector, AStillCameraMakesOneKeyframeUnlessAnIntervalIsSet) {
  const RigScene scene(StreamOptions());
  const SelectorFrame first = Frame(scene, 0, 0);
  for (double interval : {0.0, 0.5}) {
    KeyframeSelectionOptions options;
    options.max_interval_s = interval;
    KeyframeSelector selector(options);
    int keyframes = 0;
    for (int i = 0; i < 40; ++i) {  // 2 s of the same view (the sensor noise of one frame)
      SelectorFrame f = first;
      f.stamp_ns += i * 50'000'000LL;
      keyframes += static_cast<int>(selector.Offer(f).size());
    }
    EXPECT_EQ(keyframes, interval == 0.0 ? 1 : 4) << "interval " << interval;
    EXPECT_EQ(selector.Stats().frames, 40u);
    EXPECT_EQ(selector.Stats().first, 1u);
    EXPECT_EQ(selector.Stats().keyframes + selector.Stats().skipped, 40u);
  }
}

// With tracks and with the reduced images' KLT alone (the default).
TEST(KeyframeSelector, KeyframesFollowTheMotionAndCostLittle) {
  const RigScene scene(StreamOptions());
  for (const bool tracks : {true, false}) {
    KeyframeSelectionOptions options;
    options.tracks = tracks;
    KeyframeSelector selector(options);
    std::vector<int> keyframe_captures;
    for (int c = 0; c < 120; ++c) {
      const std::vector<SelectorFrame> keyframes = selector.Offer(Frame(scene, c, 0));
      if (keyframes.empty()) continue;
      keyframe_captures.push_back(c);
      EXPECT_EQ(keyframes[0].tracks.empty(), !tracks);
    }
    const KeyframeSelectionStats& stats = selector.Stats();
    // The camera turns by 90 deg over these captures: a keyframe every few
    // degrees, far fewer than the frames.
    EXPECT_GE(keyframe_captures.size(), 6u) << "tracks " << tracks;
    EXPECT_LE(keyframe_captures.size(), 40u) << "tracks " << tracks;
    EXPECT_GT(stats.by_motion + stats.by_tracking, 0u);
    // Between consecutive keyframes the camera moved at least about the
    // threshold (image motion includes parallax, so a little less rotation
    // can trigger one), and never many times it.
    for (std::size_t k = 1; k < keyframe_captures.size(); ++k) {
      const double turned = RadToDeg(RotationAngleRad(scene.WorldToCamera(keyframe_captures[k], 0) *
                                                      scene.WorldToCamera(keyframe_captures[k - 1], 0).transpose()));
      EXPECT_GT(turned, 0.3 * options.min_motion_deg) << "keyframes at " << keyframe_captures[k - 1] << ", "
                                                      << keyframe_captures[k] << ", tracks " << tracks;
      EXPECT_LT(turned, 2.5 * options.min_motion_deg) << "tracks " << tracks;
    }
    std::cout << keyframe_captures.size() << " keyframes of 120 frames" << (tracks ? " with tracks" : "")
              << "; check " << 1e3 * stats.tracking_s / stats.frames << " ms per frame at 256x192\n";
  }
}

// With tracks: every keyframe (its own camera's, or a rig capture's held
// frame) carries its camera's tracks, consecutive keyframes share enough of
// them to be related through, the keyframes follow the motion as without
// tracks, and two runs over the same frames give the same keyframes and
// the same tracks.
TEST(KeyframeSelector, WithTracksEveryKeyframeCarriesItsTracks) {
  const RigScene scene(StreamOptions());
  KeyframeSelectionOptions options;
  options.tracks = true;
  std::vector<std::vector<SelectorFrame>> runs(2);
  for (auto& run : runs) {
    KeyframeSelector selector(options);
    for (int c = 0; c < 120; ++c) {
      for (int camera = 0; camera < 2; ++camera) {
        for (SelectorFrame& k : selector.Offer(Frame(scene, c, camera))) run.push_back(std::move(k));
      }
    }
    const KeyframeSelectionStats& stats = selector.Stats();
    EXPECT_GT(stats.by_motion + stats.by_tracking, 0u);
    EXPECT_GT(stats.by_rig, 0u);
    EXPECT_EQ(stats.keyframes + stats.skipped, 240u);
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  std::map<std::string, std::vector<std::size_t>> by_camera;
  for (std::size_t i = 0; i < runs[0].size(); ++i) {
    const SelectorFrame& k = runs[0][i];
    EXPECT_EQ(Name(k), Name(runs[1][i]));
    ASSERT_EQ(k.tracks.size(), runs[1][i].tracks.size());
    for (std::size_t t = 0; t < k.tracks.size(); ++t) {
      EXPECT_EQ(k.tracks[t].id, runs[1][i].tracks[t].id);
      EXPECT_EQ(k.tracks[t].px, runs[1][i].tracks[t].px);
    }
    EXPECT_GE(k.tracks.size(), 50u) << Name(k);
    for (std::size_t t = 1; t < k.tracks.size(); ++t) EXPECT_LT(k.tracks[t - 1].id, k.tracks[t].id);
    by_camera[k.camera].push_back(i);
  }
  ASSERT_EQ(by_camera.size(), 2u);
  for (const auto& [camera, indices] : by_camera) {
    // The camera turns by 90 deg over these captures (as without tracks).
    EXPECT_GE(indices.size(), 6u) << camera;
    EXPECT_LE(indices.size(), 40u) << camera;
    for (std::size_t k = 1; k < indices.size(); ++k) {
      const SelectorFrame& a = runs[0][indices[k - 1]];
      const SelectorFrame& b = runs[0][indices[k]];
      EXPECT_GE(SharedTracks(a.tracks, b.tracks).size(), 30u) << Name(a) << " - " << Name(b);
    }
  }
}

// The cameras of one capture become keyframes together, and the keyframes
// do not depend on which camera's image of a capture arrives first.
TEST(KeyframeSelector, RigCapturesBecomeKeyframesTogetherInAnyArrivalOrder) {
  const RigScene scene(StreamOptions());
  std::vector<std::array<SelectorFrame, 2>> captures;
  for (int c = 0; c < 100; ++c) captures.push_back({Frame(scene, c, 0), Frame(scene, c, 1)});
  std::vector<std::string> runs[3];
  for (int order = 0; order < 3; ++order) {
    KeyframeSelector selector{KeyframeSelectionOptions()};
    for (std::size_t c = 0; c < captures.size(); ++c) {
      // 0: front first; 1: left first; 2: alternating.
      const bool left_first = order == 1 || (order == 2 && c % 2 == 1);
      for (int i = 0; i < 2; ++i) {
        for (const SelectorFrame& k : selector.Offer(captures[c][left_first ? 1 - i : i])) runs[order].push_back(Name(k));
      }
    }
  }
  std::set<std::string> sorted[3];
  for (int order = 0; order < 3; ++order) sorted[order] = std::set<std::string>(runs[order].begin(), runs[order].end());
  EXPECT_EQ(sorted[0], sorted[1]);
  EXPECT_EQ(sorted[0], sorted[2]);
  // Every keyframe capture holds both cameras.
  std::map<std::string, int> per_stamp;
  for (const std::string& name : sorted[0]) ++per_stamp[name.substr(name.find('@') + 1)];
  EXPECT_GT(per_stamp.size(), 5u);
  for (const auto& [stamp, n] : per_stamp) EXPECT_EQ(n, 2) << stamp;
}

// A camera faster than the rig tolerance: its own keyframe does not make its
// next frames keyframes (only other cameras' frames of a capture are).
TEST(KeyframeSelector, AFastCameraIsNotItsOwnRig) {
  KeyframeSelectionOptions options;
  options.rig_stamp_tolerance_s = 0.02;  // loosely synchronised cameras
  KeyframeSelector selector(options);
  const RigScene scene(StreamOptions());
  SelectorFrame f = Frame(scene, 0, 0);
  int keyframes = 0;
  for (int i = 0; i < 30; ++i) {  // 60 Hz, the same view
    f.stamp_ns += 16'666'667LL;
    keyframes += static_cast<int>(selector.Offer(f).size());
  }
  EXPECT_EQ(keyframes, 1);
}

TEST(KeyframeSelector, ABlankViewWaitsForTexture) {
  KeyframeSelector selector{KeyframeSelectionOptions()};
  SelectorFrame blank;
  blank.camera = "cam";
  blank.image = cv::Mat(240, 320, CV_8U, cv::Scalar(128));
  blank.intrinsics.k << 300, 0, 160, 0, 300, 120, 0, 0, 1;
  for (int i = 0; i < 5; ++i) {
    blank.stamp_ns = (i + 1) * 50'000'000LL;
    EXPECT_EQ(selector.Offer(blank).size(), i == 0 ? 1u : 0u) << i;  // the first, then nothing to gain
  }
  const RigScene scene(StreamOptions());
  SelectorFrame textured = Frame(scene, 0, 0);
  textured.camera = "cam";
  textured.stamp_ns = 10 * 50'000'000LL;
  EXPECT_EQ(selector.Offer(textured).size(), 1u);
}

// Real photographs of a camera walking along a facade while turning to keep
// it in view (Strecha entry-P10, 6-17 deg apart, a quarter of full width,
// offered one a second): the corners on the facade move less than the camera
// turns, so the corners' motion alone lets photographs go that turned well
// past the threshold since their keyframe, and their pairs widen. With
// keyframe_min_rotation_deg every photograph that turned past it (by more
// than the estimate's error) is a keyframe.
TEST(KeyframeSelector, PhotographsCirclingAFacadeAreKeyframesByTheirRotation) {
  const std::string scene = SharedDataPath("strecha/entry-P10");
  ROTAVG_REQUIRE_SHARED_DATA(scene);
  NamedOrientations truth;
  ASSERT_TRUE(ReadStrechaGroundTruth(scene, &truth).ok());
  Eigen::Matrix3d k;
  std::string error;
  ASSERT_TRUE(ReadIntrinsics(scene + "/images/K.txt", &k, &error)) << error;
  std::vector<SelectorFrame> frames;
  std::vector<Eigen::Matrix3d> world_to_camera;
  for (const auto& [name, rotation] : truth) {
    const cv::Mat full = cv::imread(scene + "/images/" + name, cv::IMREAD_GRAYSCALE);
    ASSERT_FALSE(full.empty()) << name;
    SelectorFrame f;
    f.camera = "camera";
    f.stamp_ns = static_cast<std::int64_t>(frames.size() + 1) * 1'000'000'000LL;
    cv::resize(full, f.image, cv::Size(), 0.25, 0.25, cv::INTER_AREA);
    f.intrinsics.k = ScaleIntrinsics(k, 0.25);
    frames.push_back(f);
    world_to_camera.push_back(rotation);
  }
  ASSERT_EQ(frames.size(), 10u);
  auto turned = [&](std::size_t a, std::size_t b) {
    return RadToDeg(RotationAngleRad(world_to_camera[b] * world_to_camera[a].transpose()));
  };
  constexpr double kThreshold = 6.0, kEstimateError = 2.0;
  for (const double min_rotation : {0.0, kThreshold}) {
    KeyframeSelectionOptions options;
    options.min_rotation_deg = min_rotation;
    KeyframeSelector selector(options);
    std::vector<std::size_t> keyframes;
    for (std::size_t i = 0; i < frames.size(); ++i) {
      if (!selector.Offer(frames[i]).empty()) keyframes.push_back(i);
    }
    // The most a photograph that was let go had turned since its keyframe.
    double passed_over = 0.0;
    for (std::size_t i = 0, last = 0; i < frames.size(); ++i) {
      if (std::find(keyframes.begin(), keyframes.end(), i) != keyframes.end()) {
        last = i;
        continue;
      }
      passed_over = std::max(passed_over, turned(last, i));
    }
    if (min_rotation > 0.0) {
      EXPECT_GT(selector.Stats().by_rotation, 0u);
      EXPECT_LT(passed_over, kThreshold + kEstimateError) << keyframes.size() << " keyframes";
    } else {
      EXPECT_EQ(selector.Stats().by_rotation, 0u);
      EXPECT_GT(passed_over, 2.0 * kThreshold) << keyframes.size() << " keyframes";
    }
    std::cout << "keyframe_min_rotation_deg " << min_rotation << ": " << keyframes.size()
              << " keyframes of 10 photographs; the most a photograph let go had turned: " << passed_over << " deg\n";
  }
}

// Frames of 640x480 and 641x481 reduce to the same tracking image: the
// rotation check does not compare a frame with a keyframe of another size at
// full resolution (OpenCV refuses two sizes), and the selector goes on.
TEST(KeyframeSelector, AFrameOfAnotherSizeIsNotComparedAtFullResolution) {
  RigSceneOptions o;
  o.num_captures = 4;
  const RigScene scene(o);
  KeyframeSelectionOptions options;
  ASSERT_GT(options.min_rotation_deg, 0.0);
  KeyframeSelector selector(options);
  SelectorFrame first = Frame(scene, 0, 0);
  ASSERT_EQ(first.image.cols, 640);
  ASSERT_EQ(selector.Offer(first).size(), 1u);
  SelectorFrame other = first;
  other.stamp_ns += 500'000'000LL;  // past the rotation check's period
  cv::resize(first.image, other.image, cv::Size(641, 481), 0.0, 0.0, cv::INTER_LINEAR);
  std::vector<SelectorFrame> keyframes;
  EXPECT_NO_THROW(keyframes = selector.Offer(other));
  EXPECT_TRUE(keyframes.empty());  // the same view: no motion, no rotation
  EXPECT_EQ(selector.Stats().rotation_checks, 0u);
  // A frame of the keyframe's own size is checked.
  SelectorFrame same = first;
  same.stamp_ns += 1'000'000'000LL;
  EXPECT_TRUE(selector.Offer(same).empty());
  EXPECT_EQ(selector.Stats().rotation_checks, 1u);
}

TEST(KeyframeSelector, OptionsAreChecked) {
  KeyframeSelectionOptions o;
  std::string error;
  EXPECT_TRUE(o.Validate(&error)) << error;
  o.min_tracked_fraction = 1.5;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("keyframe_min_tracked_fraction"), std::string::npos) << error;
  o = KeyframeSelectionOptions();
  o.min_motion_deg = std::nan("");
  EXPECT_FALSE(o.Validate(&error));
  o = KeyframeSelectionOptions();
  o.min_rotation_deg = -1.0;
  EXPECT_FALSE(o.Validate(&error));
  EXPECT_NE(error.find("keyframe_min_rotation_deg"), std::string::npos) << error;
  o = KeyframeSelectionOptions();
  o.corners = 3;
  EXPECT_FALSE(o.Validate(&error));
}

}  // namespace
}  // namespace rotation_averaging
