#include "rotation_averaging/controllers/keyframe_frontend.h"

#include <gtest/gtest.h>
#include "test_data.h"

#include <filesystem>
#include <functional>
#include <map>
#include <opencv2/imgcodecs.hpp>
#include <set>

#include "rotation_averaging/controllers/image_pipeline.h"
#include "rotation_averaging/eval/rotation_evaluation.h"
#include "rotation_averaging/geometry/so3.h"
#include "rotation_averaging/io/orientation_io.h"
#include "rotation_averaging/scene/rig_scene.h"

namespace rotation_averaging {
namespace {

namespace fs = std::filesystem;

struct CastleRun {
  KeyframeFrontendStats stats;
  std::set<std::pair<int, int>> loops;  // image indices of the loop closures
  double with_loops_deg = 0.0, chain_deg = 0.0;  // median errors, all edges / sequential edges only
};

// castle-P19 fed as one camera's keyframes at 1/4 scale, averaged with and
// without its loop closures.
CastleRun RunCastle(const std::string& dir, int covisibility_window) {
  CastleRun run;
  const std::vector<std::string> images = ListImages(dir + "/images");
  EXPECT_EQ(images.size(), 19u);
  CameraIntrinsics intrinsics;
  std::string error;
  EXPECT_TRUE(ReadCameraIntrinsics(dir + "/images/K.txt", &intrinsics, &error)) << error;
  KeyframeFrontendOptions options;
  options.features.downsample = 0.25;
  options.covisibility_window = covisibility_window;
  KeyframeFrontend frontend(options);
  OnlineAverager averager(OnlineAveragerOptions{});
  OnlineAverager sequential_only(OnlineAveragerOptions{});
  NamedOrientations gt_all, gt;
  EXPECT_TRUE(ReadGroundTruth(dir, GroundTruthFormat::kStrecha, &gt_all).ok());
  std::map<std::string, std::string> key_to_image;
  for (int i = 0; i < static_cast<int>(images.size()); ++i) {
    const KeyframeKey key{"castle_cam", 1'000'000'000LL * (i + 1)};
    key_to_image[OnlineAverager::KeyframeName(key)] = fs::path(images[i]).filename().string();
    const cv::Mat image = cv::imread(images[i], cv::IMREAD_GRAYSCALE);
    for (const KeyframeRelativeRotation& e : frontend.AddKeyframe(key, image, intrinsics.k)) {
      EXPECT_TRUE(averager.AddRelativeRotation(e, &error)) << error;
      if (e.source == EdgeSource::kSequential) sequential_only.AddRelativeRotation(e);
      if (e.source == EdgeSource::kLoopClosure) {
        run.loops.insert({static_cast<int>(e.keyframe1.stamp_ns / 1'000'000'000LL) - 1,
                          static_cast<int>(e.keyframe2.stamp_ns / 1'000'000'000LL) - 1});
      }
    }
  }
  run.stats = frontend.Stats();
  auto median_error = [&](OnlineAverager& a) {
    EXPECT_TRUE(a.SolveNow());
    NamedOrientations est;
    for (const auto& [key, r] : a.Solution()->orientations) {
      const std::string image = key_to_image.at(OnlineAverager::KeyframeName(key));
      est[image] = r;
      gt[image] = gt_all.at(image);
    }
    const EvaluationResult e = EvaluateOrientations(est, gt);
    EXPECT_EQ(e.views_common, 19u);
    return e.median_error_deg;
  };
  run.with_loops_deg = median_error(averager);
  run.chain_deg = median_error(sequential_only);
  std::cout << "castle at 1/4, covisibility window " << covisibility_window << ": sequential edges "
            << run.stats.sequential_edges << ", loop closures " << run.stats.loop_closure_edges << " of "
            << run.stats.loop_candidates_tried << " candidates (" << run.stats.loops_rejected_inconsistent
            << " rejected as inconsistent); loops:";
  for (const auto& [a, b] : run.loops) std::cout << " " << a << "-" << b;
  std::cout << "; median " << run.with_loops_deg << " deg with loop closures, " << run.chain_deg
            << " deg from the sequential edges alone\n";
  return run;
}

bool ClosesTheLoop(const CastleRun& run) {
  bool closes = false;
  for (const auto& [a, b] : run.loops) closes = closes || (b >= 16 && a <= 2);
  return closes;
}

// castle-P19 walks around a courtyard and returns to its start: fed as one
// camera's keyframes, the last images must close the loop with the first.
TEST(KeyframeFrontend, CastleClosesTheLoopAndAveragesToGroundTruth) {
  const std::string dir = SharedDataPath("strecha/castle-P19");
  if (!fs::exists(dir)) GTEST_SKIP() << "shared data absent: " << dir;
  const CastleRun run = RunCastle(dir, KeyframeFrontendOptions().covisibility_window);
  EXPECT_TRUE(ClosesTheLoop(run)) << "no loop closure between the last and the first images";
  EXPECT_GE(run.stats.sequential_edges, 16u);
  // 18 sequential edges erring 0.05-0.7 deg and a few loop closures. Without
  // the loop consistency check the loop 2-18 (110 inliers, 3.1 deg off while
  // its covariance predicted 0.26 deg) got in and gave 0.75 deg; the check
  // rejects it because it disagrees with 0-18 and 1-18 through the chain 0-1-2.
  EXPECT_GE(run.stats.loops_rejected_inconsistent, 1u);
  EXPECT_LT(run.with_loops_deg, 0.5);
  EXPECT_LT(run.chain_deg, 1.0);
}

// The demo room seen by one camera; `world_to_camera` and `centres` give
// each keyframe's pose.
struct RenderedSequence {
  std::vector<cv::Mat> images;
  std::vector<Eigen::Matrix3d> world_to_camera;
  Eigen::Matrix3d k;
};

std::vector<KeyframeRelativeRotation> Feed(KeyframeFrontend* frontend, const RenderedSequence& seq) {
  std::vector<KeyframeRelativeRotation> edges;
  for (std::size_t i = 0; i < seq.images.size(); ++i) {
    for (const KeyframeRelativeRotation& e :
         frontend->AddKeyframe(KeyframeKey{"cam", static_cast<std::int64_t>(i + 1) * 1'000'000'000LL}, seq.images[i],
                               seq.k)) {
      edges.push_back(e);
    }
  }
  return edges;
}

int Index(const KeyframeKey& key) { return static_cast<int>(key.stamp_ns / 1'000'000'000LL) - 1; }

// Components of the keyframes in `members` under `edges` (union-find).
int Components(const std::vector<KeyframeRelativeRotation>& edges, const std::set<int>& members) {
  std::map<int, int> parent;
  for (int m : members) parent[m] = m;
  std::function<int(int)> find = [&](int x) { return parent[x] == x ? x : parent[x] = find(parent[x]); };
  for (const KeyframeRelativeRotation& e : edges) parent[find(Index(e.keyframe1))] = find(Index(e.keyframe2));
  std::set<int> roots;
  for (int m : members) roots.insert(find(m));
  return static_cast<int>(roots.size());
}

double EdgeErrorDeg(const RenderedSequence& seq, const KeyframeRelativeRotation& e) {
  const Eigen::Matrix3d truth =
      seq.world_to_camera[Index(e.keyframe1)] * seq.world_to_camera[Index(e.keyframe2)].transpose();
  return RadToDeg(AngularDistanceRad(e.rotation, truth));
}

// A camera panning on the spot, 6 deg per keyframe: no parallax at all, so
// every pair comes from the rotation-only model, and the chain is whole.
TEST(KeyframeFrontend, TurningOnTheSpotGivesRotationEdges) {
  RigSceneOptions scene_options;
  scene_options.num_cameras = 1;
  const RigScene scene(scene_options);
  RenderedSequence seq;
  seq.k = scene.Intrinsics();
  const Eigen::Vector3d centre = scene.CameraCentre(0, 0);
  for (int i = 0; i < 6; ++i) {
    // Pan about the camera's own vertical (optical y) axis.
    seq.world_to_camera.push_back(ExpSO3(Eigen::Vector3d(0.0, DegToRad(6.0 * i), 0.0)) * scene.WorldToCamera(0, 0));
    seq.images.push_back(scene.RenderView(seq.world_to_camera.back(), centre, 100 + i));
  }
  KeyframeFrontendOptions options;
  options.max_loop_candidates = 0;
  KeyframeFrontend frontend(options);
  const std::vector<KeyframeRelativeRotation> edges = Feed(&frontend, seq);
  ASSERT_EQ(edges.size(), 5u) << "failures: " << frontend.Stats().failed_pairs;
  EXPECT_EQ(frontend.Stats().rotation_model_edges, 5u);
  for (const KeyframeRelativeRotation& e : edges) EXPECT_LT(EdgeErrorDeg(seq, e), 0.05);
  // Without the rotation model these pairs have no parallax and fail.
  options.relative_pose.rotation_model = false;
  KeyframeFrontend essential_only(options);
  EXPECT_LT(Feed(&essential_only, seq).size(), 5u);
}

// A keyframe that cannot be matched (a blank frame) fails its pairs; the
// next keyframe is related to the one before it instead, so the chain of the
// others stays one component. With a window of one it splits.
TEST(KeyframeFrontend, AFailedPairDoesNotCutTheChain) {
  RigSceneOptions scene_options;
  scene_options.num_cameras = 1;
  scene_options.num_captures = 40;  // small steps along the circle
  const RigScene scene(scene_options);
  RenderedSequence seq;
  seq.k = scene.Intrinsics();
  std::set<int> members;
  for (int i = 0; i < 7; ++i) {
    seq.world_to_camera.push_back(scene.WorldToCamera(i, 0));
    seq.images.push_back(i == 3 ? cv::Mat(scene_options.height, scene_options.width, CV_8UC1, cv::Scalar(128))
                                : scene.Render(i, 0));
    if (i != 3) members.insert(i);
  }
  KeyframeFrontendOptions options;
  options.max_loop_candidates = 0;
  KeyframeFrontend frontend(options);
  const std::vector<KeyframeRelativeRotation> edges = Feed(&frontend, seq);
  EXPECT_EQ(Components(edges, members), 1);
  EXPECT_EQ(frontend.Stats().chain_bridged, 1u);
  for (const KeyframeRelativeRotation& e : edges) EXPECT_LT(EdgeErrorDeg(seq, e), 0.2);
  options.covisibility_window = 1;
  KeyframeFrontend no_window(options);
  EXPECT_EQ(Components(Feed(&no_window, seq), members), 2);
}

// Verification and retrieval run on a thread pool; the edges must not depend
// on how many threads there are.
TEST(KeyframeFrontend, EdgesDoNotDependOnTheThreadCount) {
  RigSceneOptions scene_options;
  scene_options.num_captures = 16;  // revisits after a full circle: retrieval has candidates
  scene_options.WithWidth(480);
  const RigScene scene(scene_options);
  std::vector<std::vector<KeyframeRelativeRotation>> runs;
  for (const int threads : {1, 3}) {
    KeyframeFrontendOptions options;
    options.num_threads = threads;
    options.features.max_features = 600;
    KeyframeFrontend frontend(options);
    runs.emplace_back();
    for (int c = 0; c < scene_options.num_captures; ++c) {
      for (int cam = 0; cam < scene_options.num_cameras; ++cam) {
        const KeyframeKey key{scene.Cameras()[cam].frame_id, (c + 1) * 1'000'000'000LL};
        for (const KeyframeRelativeRotation& e : frontend.AddKeyframe(key, scene.Render(c, cam), scene.Intrinsics())) {
          runs.back().push_back(e);
        }
      }
    }
  }
  ASSERT_EQ(runs[0].size(), runs[1].size());
  ASSERT_GT(runs[0].size(), 20u);
  for (std::size_t i = 0; i < runs[0].size(); ++i) {
    const KeyframeRelativeRotation &a = runs[0][i], &b = runs[1][i];
    EXPECT_EQ(OnlineAverager::KeyframeName(a.keyframe1), OnlineAverager::KeyframeName(b.keyframe1));
    EXPECT_EQ(OnlineAverager::KeyframeName(a.keyframe2), OnlineAverager::KeyframeName(b.keyframe2));
    EXPECT_TRUE(a.rotation == b.rotation) << "edge " << i;
    EXPECT_TRUE(a.covariance == b.covariance) << "edge " << i;
    EXPECT_EQ(a.num_inliers, b.num_inliers);
    EXPECT_EQ(a.source, b.source);
  }
}

}  // namespace
}  // namespace rotation_averaging
