// How precisely KLT tracks (frontend/features/feature_tracker.h) and SIFT
// matches place a point of one image in another, against the truth: a
// camera turning on the spot over a real photograph (or the renderer's
// room), image t being image 0 moved by the homography K R_t K^-1 (exact
// for a turning camera) with fresh grey-level noise. For each number of
// images between the pair: the tracks' points (tracked from image to image),
// the same re-tracked between the two images (RetrackBetween, as the
// keyframe front end does), and SIFT matched between the two (the ratio
// test and mutual check), each with its count and its median distance from
// where the homography puts the point. Writes a markdown table to stdout.
//   rotavg_track_precision [--step-deg D] [--steps 1,5,10,20] IMAGE|render ...
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <opencv2/imgcodecs.hpp>
#include <opencv2/imgproc.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/features/feature_tracker.h"
#include "rotation_averaging/frontend/features/features.h"
#include "rotation_averaging/sim/rig_scene.h"
#include "rotation_averaging/sim/turning_view.h"

namespace rotation_averaging {
namespace {

constexpr int kWidth = 640, kHeight = 480;  // TurningViewOptions' (f = 420 px: the renderer's field of view)
constexpr double kSiftOutlierPx = 3.0;  // a SIFT match further than this is a wrong one, not imprecise

double Median(std::vector<double> v) {
  if (v.empty()) return std::nan("");
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

// The photograph reduced so that the 640x480 view spans most of it.
cv::Mat LoadBase(const std::string& source) {
  if (source == "render") {
    RigSceneOptions options;
    options.noise_grey = 0.0;
    return RigScene(options).Render(5, 0, 160);
  }
  const cv::Mat photo = cv::imread(source, cv::IMREAD_GRAYSCALE);
  if (photo.empty()) return photo;
  cv::Mat base;
  const double scale = 960.0 / photo.cols;
  cv::resize(photo, base, cv::Size(), scale, scale, cv::INTER_AREA);
  return base;
}

std::string Name(const std::string& source) {
  if (source == "render") return "the renderer's room";
  const std::size_t slash = source.find_last_of('/');
  const std::size_t images = source.rfind("/images/");
  if (images != std::string::npos && images > 0) {
    const std::size_t scene = source.find_last_of('/', images - 1);
    return source.substr(scene + 1, images - scene - 1) + " " + source.substr(slash + 1);
  }
  return source.substr(slash + 1);
}

void Row(const std::string& source, const TurningView& camera, int steps, double step_deg) {
  FeatureTrackerOptions options;
  FeatureTracker tracker(options);
  const cv::Mat first_image = camera.View(0);
  const std::vector<TrackedPoint> first = tracker.Track(first_image);
  cv::Mat image = first_image;
  std::vector<TrackedPoint> last = first;
  for (int t = 1; t <= steps; ++t) {
    image = camera.View(t);
    last = tracker.Track(image);
  }
  std::vector<cv::Point2f> points1, points2;
  std::vector<double> tracked;
  for (const auto& [p, q] : SharedTracks(first, last)) {
    points1.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
    points2.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
    tracked.push_back(camera.Error(steps, p, q));
  }
  std::vector<bool> kept;
  RetrackBetween(TrackPyramid(first_image, options, false), TrackPyramid(image, options, false), points1, &points2,
                 &kept, options);
  std::vector<double> retracked;
  for (std::size_t i = 0; i < points1.size(); ++i) {
    if (kept[i]) {
      retracked.push_back(camera.Error(steps, Eigen::Vector2d(points1[i].x, points1[i].y),
                                       Eigen::Vector2d(points2[i].x, points2[i].y)));
    }
  }
  FeatureOptions features;
  features.max_features = 1500;  // config/demo.yaml's
  const ImageFeatures a = ExtractFeatures(first_image, features), b = ExtractFeatures(image, features);
  std::vector<double> sift;
  for (const auto& [i, j] : MatchFeatures(a, b, MatchOptions())) {
    const double e = camera.Error(steps, a.keypoints_px[i], b.keypoints_px[j]);
    if (e < kSiftOutlierPx) sift.push_back(e);
  }
  std::printf("| %s | %d (%.1f deg) | %zu | %.3f | %zu | %.3f | %zu | %.3f |\n", Name(source).c_str(), steps,
              steps * step_deg, tracked.size(), Median(tracked), retracked.size(), Median(retracked), sift.size(),
              Median(sift));
}

int Main(int argc, char** argv) {
  double step_deg = 0.8;
  std::vector<int> steps = {1, 5, 10, 20};
  std::vector<std::string> sources;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    if (arg == "--step-deg" && i + 1 < argc) {
      step_deg = std::atof(argv[++i]);
    } else if (arg == "--steps" && i + 1 < argc) {
      steps.clear();
      std::stringstream list(argv[++i]);
      for (std::string s; std::getline(list, s, ',');) steps.push_back(std::atoi(s.c_str()));
    } else if (arg == "--help" || arg == "-h") {
      std::cout << "usage: rotavg_track_precision [--step-deg D] [--steps 1,5,10,20] IMAGE|render ...\n";
      return 0;
    } else {
      sources.push_back(arg);
    }
  }
  if (sources.empty() || step_deg <= 0.0) {
    std::cerr << "rotavg_track_precision: give one or more images (or render), and a positive --step-deg\n";
    return 2;
  }
  std::printf("| image | images apart | tracks | tracked (px) | re-tracked | re-tracked (px) | SIFT matches | SIFT (px) |\n");
  std::printf("|---|---|---|---|---|---|---|---|\n");
  for (const std::string& source : sources) {
    const cv::Mat base = LoadBase(source);
    if (base.empty() || base.cols < kWidth || base.rows < kHeight) {
      std::cerr << "rotavg_track_precision: cannot read " << source << " as an image of at least 640x480\n";
      return 1;
    }
    TurningViewOptions options;
    options.step_deg = step_deg;
    const TurningView camera(base, options);
    for (int s : steps) Row(source, camera, s, step_deg);
  }
  return 0;
}

}  // namespace
}  // namespace rotation_averaging

int main(int argc, char** argv) { return rotation_averaging::Main(argc, argv); }
