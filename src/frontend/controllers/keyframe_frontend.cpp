#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "frontend/controllers/keyframe_frontend_keyframe.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <set>

#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/option_check.h"
#include "rotation_averaging/util/parallel_for.h"
#include "rotation_averaging/util/time_distribution.h"

namespace rotation_averaging {
namespace {

using Clock = std::chrono::steady_clock;

}  // namespace

EdgeCorrespondences InlierCorrespondences(const std::vector<Eigen::Vector2d>& pa, const std::vector<Eigen::Vector2d>& pb,
                                          const Eigen::Matrix3d& k1, const Eigen::Matrix3d& k2,
                                          const RelativePoseResult& pose) {
  std::vector<Eigen::Vector2d> n1, n2;
  n1.reserve(pose.inliers.size());
  n2.reserve(pose.inliers.size());
  const Eigen::Matrix3d k1_inverse = k1.inverse(), k2_inverse = k2.inverse();
  for (int m : pose.inliers) {
    n1.push_back((k1_inverse * pa[m].homogeneous()).hnormalized());
    n2.push_back((k2_inverse * pb[m].homogeneous()).hnormalized());
  }
  return MakeEdgeCorrespondences(0, 1, std::move(n1), std::move(n2), pose.translation, pose.sigma_px,
                                 0.5 * (k1(0, 0) + k1(1, 1)));
}


bool KeyframeFrontendOptions::Validate(std::string* error) const {
  std::string relative_pose_error;
  return OptionCheck()
      .Within("downsample", features.downsample, 1e-3, 1.0)
      .AtLeast("max_features", features.max_features, 1)
      .AtLeast("rig_stamp_tolerance_s", rig_stamp_tolerance_s, 0.0)
      .AtLeast("covisibility_window", covisibility_window, 1)
      .AtLeast("min_track_matches", min_track_matches, 8)
      .AtLeast("num_threads", num_threads, 0)
      .AtLeast("max_loop_candidates", max_loop_candidates, 0)
      .AtLeast("loop_exclude_recent", loop_exclude_recent, 0)
      .AtLeast("compact_features", compact_features, 20)
      .AtLeast("min_retrieval_score_ratio", min_retrieval_score_ratio, 0.0)
      .AtLeast("retrieval_sample", retrieval_sample, 1)
      .AtLeast("min_retrieval_votes", min_retrieval_votes, 0)
      .AtLeast("min_loop_inliers", min_loop_inliers, 5)
      .Within("compact_loop_inlier_fraction", compact_loop_inlier_fraction, 1e-3, 1.0)
      .Above("loop_consistency_deg", loop_consistency_deg, 0.0)
      .Within("loop_jackknife_grid", loop_jackknife_grid, 0, 16)
      .Require(relative_pose.Validate(&relative_pose_error), relative_pose_error)
      .Ok(error);
}

KeyframeFrontend::KeyframeFrontend(const KeyframeFrontendOptions& options)
    : options_(options), focal_monitor_(options.focal_monitor) {
  // A SIFT vocabulary describes SIFT descriptors only.
  if (options_.vocabulary && (options_.features.type != FeatureType::kSift || options_.vocabulary->Dimension() != 128)) {
    options_.vocabulary.reset();
  }
  if (options_.vocabulary) inverted_index_ = std::make_unique<InvertedIndex>(options_.vocabulary->NumWords());
}
KeyframeFrontend::~KeyframeFrontend() = default;

std::vector<KeyframeFrontend::PairOutcome> KeyframeFrontend::VerifyPairs(const std::vector<PairTask>& tasks,
                                                                         const Keyframe& newer) {
  const auto start = Clock::now();
  std::vector<PairOutcome> outcomes = VerifyPairs(tasks, std::vector<const Keyframe*>{&newer});
  stats_.pairs_s += SecondsSince(start);
  for (const PairOutcome& outcome : outcomes) stats_.pair_times.Add(outcome.seconds);  // in task order
  return outcomes;
}

std::vector<KeyframeFrontend::PairOutcome> KeyframeFrontend::VerifyPairs(const std::vector<PairTask>& tasks,
                                                                         const std::vector<const Keyframe*>& newers) {
  std::vector<PairOutcome> outcomes(tasks.size());
  // A compact keyframe is matched within the vocabulary's branches;
  // without branch matching it gets a temporary index of its unpacked
  // descriptors, prepared here once for all the pairs it is in. A new
  // keyframe is compact only when it comes from an added database
  // (LinkAddedKeyframes).
  auto by_branch = [&](const Keyframe& a, const Keyframe& newer) {
    return a.compact && options_.match_compact_by_vocabulary && options_.vocabulary &&
           a.features.words.size() == a.features.keypoints_px.size() &&
           newer.features.words.size() == newer.features.keypoints_px.size();
  };
  // Each new keyframe's two nearest branches per feature, for matches across
  // a boundary (a compact one's descriptors unpacked to find them).
  std::vector<std::vector<int>> newer_branches(newers.size());
  std::vector<bool> have_branches(newers.size(), false);
  std::vector<ImageFeatures> newer_matchable(newers.size());
  std::vector<std::unique_ptr<FeatureIndex>> newer_temporary(newers.size());
  std::vector<ImageFeatures> matchable(tasks.size());
  std::vector<std::unique_ptr<FeatureIndex>> temporary(tasks.size());
  for (std::size_t t = 0; t < tasks.size(); ++t) {
    const Keyframe& a = *keyframes_[tasks[t].older];
    const int n = tasks[t].newer;
    const Keyframe& newer = *newers[n];
    if (by_branch(a, newer)) {
      if (!have_branches[n]) {
        newer_branches[n] = options_.vocabulary->NearestCells(
            newer.compact ? SiftDescriptorsAsFloat(newer.features) : newer.features.descriptors, 2);
        have_branches[n] = true;
      }
      continue;
    }
    if (newer.compact && !newer_temporary[n]) {
      newer_matchable[n] = MatchableFeatures(newer.features);
      newer_temporary[n] = std::make_unique<FeatureIndex>(newer_matchable[n]);
    }
    if (!a.compact) continue;
    matchable[t] = MatchableFeatures(a.features);
    temporary[t] = std::make_unique<FeatureIndex>(matchable[t]);
  }
  ParallelFor(static_cast<int>(tasks.size()), ResolveThreadCount(options_.num_threads), [&](int t) {
    const auto pair_start = Clock::now();
    const Keyframe& a = *keyframes_[tasks[t].older];
    const int n = tasks[t].newer;
    const Keyframe& newer = *newers[n];
    const ImageFeatures& a_features = a.compact && temporary[t] ? matchable[t] : a.features;
    const ImageFeatures& newer_features = newer_temporary[n] ? newer_matchable[n] : newer.features;
    const FeatureIndex* newer_index = newer_temporary[n] ? newer_temporary[n].get() : newer.index.get();
    // A pair within one capture is estimated in the order of the camera
    // frames, whichever image came first (see PairTask::newer_first).
    const bool swap = tasks[t].newer_first && !a.compact;
    RelativePoseOptions relative_pose = options_.relative_pose;
    if (tasks[t].source == EdgeSource::kLoopClosure || tasks[t].wide) {
      relative_pose.jackknife_grid = std::max(relative_pose.jackknife_grid, options_.loop_jackknife_grid);
    }
    bool tracks_failed = false;
    {
      std::vector<Eigen::Vector2d> pa, pb;
      if (!swap && TrackCorrespondences(tasks[t], a, newer, &pa, &pb)) {
        // KLT's points share a local bias (the window does not deform with
        // the view), and the Sampson error cannot see its part along the
        // epipolar lines: the cell jackknife covers it, as for loop closures.
        RelativePoseOptions track_pose = relative_pose;
        track_pose.jackknife_grid = std::max(relative_pose.jackknife_grid, options_.loop_jackknife_grid);
        const RelativePoseResult pose =
            EstimateRelativePoseWithCovariance(pa, pb, a.track_camera.k, newer.track_camera.k, track_pose);
        if (pose.success) {
          FillOutcome(tasks[t], a, a, newer, false, track_pose.jackknife_grid, {}, std::move(pa), std::move(pb),
                      a.track_camera.k, newer.track_camera.k, pose, &outcomes[t]);
          outcomes[t].from_tracks = true;
          // The focal-length check and correction hold points in the
          // features' image: a pair of full-resolution tracks is theirs
          // only when the features are not downsampled.
          if (!(a.k == a.track_camera.k && newer.k == newer.track_camera.k)) {
            outcomes[t].focal_sample.reset();
            outcomes[t].points1.reset();
            outcomes[t].points2.reset();
            outcomes[t].pose.reset();
          }
          outcomes[t].seconds = SecondsSince(pair_start);
          return;
        }
        tracks_failed = true;
      }
    }
    std::vector<std::pair<int, int>> matches;
    if (swap) {
      matches = MatchFeatures(newer.features, *newer.index, a.features, *a.index, options_.matching);
    } else if (by_branch(a, newer)) {
      std::vector<int> a_branches;
      for (int w : a.features.words) a_branches.push_back(options_.vocabulary->CellOf(w));
      matches = MatchFeaturesByGroup(a.features, a_branches, newer.features, newer_branches[n], options_.matching);
    } else {
      matches = MatchFeatures(a_features, a.compact ? *temporary[t] : *a.index, newer_features, *newer_index,
                              options_.matching);
    }
    const Keyframe& first = swap ? newer : a;
    const Keyframe& second = swap ? a : newer;
    const ImageFeatures& first_features = swap ? newer.features : a_features;
    std::vector<Eigen::Vector2d> pa, pb;
    pa.reserve(matches.size());
    pb.reserve(matches.size());
    for (const auto& [i, j] : matches) {
      pa.push_back(first_features.keypoints_px[i]);
      pb.push_back(second.features.keypoints_px[j]);
    }
    const RelativePoseResult pose = EstimateRelativePoseWithCovariance(pa, pb, first.k, second.k, relative_pose);
    FillOutcome(tasks[t], a, first, second, swap, relative_pose.jackknife_grid, matches, std::move(pa), std::move(pb),
                first.k, second.k, pose, &outcomes[t]);
    outcomes[t].tracks_failed = tracks_failed;
    outcomes[t].seconds = SecondsSince(pair_start);
  });
  return outcomes;
}

bool KeyframeFrontend::TrackCorrespondences(const PairTask& task, const Keyframe& a, const Keyframe& newer,
                                            std::vector<Eigen::Vector2d>* pa, std::vector<Eigen::Vector2d>* pb) const {
  // Tracks are followed within one camera's stream only, and loop closures
  // are between images no track spans.
  if (task.source == EdgeSource::kLoopClosure || a.compact || newer.compact || a.loaded_chain >= 0 ||
      a.key.frame_id != newer.key.frame_id || a.tracks.empty() || newer.tracks.empty()) {
    return false;
  }
  std::vector<cv::Point2f> points1, points2;
  for (const auto& [p, q] : SharedTracks(a.tracks, newer.tracks)) {
    points1.emplace_back(static_cast<float>(p.x()), static_cast<float>(p.y()));
    points2.emplace_back(static_cast<float>(q.x()), static_cast<float>(q.y()));
  }
  if (static_cast<int>(points1.size()) < options_.min_track_matches) return false;
  std::vector<bool> kept;
  RetrackBetween(a.track_pyramid, newer.track_pyramid, points1, &points2, &kept, options_.tracker);
  // Tracks are pixels of the full-resolution image, whatever the features'
  // downsample: undistorted with the camera's own K, and estimated with it.
  for (std::size_t i = 0; i < points1.size(); ++i) {
    if (!kept[i]) continue;
    pa->emplace_back(points1[i].x, points1[i].y);
    pb->emplace_back(points2[i].x, points2[i].y);
  }
  if (a.track_camera.HasDistortion()) UndistortPixels(a.track_camera, a.track_camera.k, pa);
  if (newer.track_camera.HasDistortion()) UndistortPixels(newer.track_camera, newer.track_camera.k, pb);
  std::size_t valid = 0;
  for (std::size_t i = 0; i < pa->size(); ++i) {
    if (!(*pa)[i].allFinite() || !(*pb)[i].allFinite()) continue;
    (*pa)[valid] = (*pa)[i];
    (*pb)[valid] = (*pb)[i];
    ++valid;
  }
  pa->resize(valid);
  pb->resize(valid);
  return static_cast<int>(valid) >= options_.min_track_matches;
}

void KeyframeFrontend::FillOutcome(const PairTask& task, const Keyframe& a, const Keyframe& first,
                                   const Keyframe& second, bool swap, int jackknife_grid,
                                   const std::vector<std::pair<int, int>>& matches, std::vector<Eigen::Vector2d> pa,
                                   std::vector<Eigen::Vector2d> pb, const Eigen::Matrix3d& k1,
                                   const Eigen::Matrix3d& k2, const RelativePoseResult& pose,
                                   PairOutcome* outcome) const {
  PairOutcome& out = *outcome;
  out.newer_first = swap;
  out.jackknife_grid = jackknife_grid;
  if (!pose.success) {
    out.failure = TwoViewFailureName(pose.failure);
    return;
  }
  // The pose maps the first camera to the second; the edge is (first, second).
  out.success = true;
  out.rotation_model = pose.model == TwoViewModel::kRotation;
  out.edge.keyframe1 = first.key;
  out.edge.keyframe2 = second.key;
  out.edge.rotation = pose.EdgeRotation();
  out.edge.has_covariance = true;
  out.edge.covariance = pose.covariance;
  out.edge.num_inliers = static_cast<int>(pose.inliers.size());
  // Pairs from tracks (no matches) count no feature's inliers.
  if (!matches.empty()) {
    out.inlier_features.reserve(pose.inliers.size());
    for (int m : pose.inliers) {
      const auto& [i, j] = matches[m];
      out.inlier_features.emplace_back(swap ? j : i, swap ? i : j);
    }
  }
  out.edge.source = task.source;
  if (a.resumed && task.source == EdgeSource::kSequential && out.edge.num_inliers < LoopInliersNeeded(a)) {
    out.success = false;
    out.failure = "resumed_too_few_inliers";
    return;
  }
  if (options_.keep_correspondences) {
    out.correspondences = std::make_shared<const EdgeCorrespondences>(InlierCorrespondences(pa, pb, k1, k2, pose));
  }
  const FocalMonitorOptions& focal = options_.focal_monitor;
  if (focal.enabled && first.key.frame_id == second.key.frame_id && first.k == second.k &&
      pose.model == TwoViewModel::kEssential && static_cast<int>(pose.inliers.size()) >= focal.focal.min_inliers) {
    out.focal_sample = MakeFocalSample(pa, pb, pose, focal.max_matches_per_pair);
  }
  if (focal.hold_for_correction) {
    out.points1 = std::make_shared<std::vector<Eigen::Vector2d>>(std::move(pa));
    out.points2 = std::make_shared<std::vector<Eigen::Vector2d>>(std::move(pb));
    out.pose = std::make_shared<RelativePoseResult>(pose);
  }
}

void KeyframeFrontend::KeepCorrespondences(const PairOutcome& outcome) {
  if (!outcome.correspondences) return;
  correspondences_.push_back({outcome.edge.keyframe1, outcome.edge.keyframe2, *outcome.correspondences});
}

std::vector<KeyframeCorrespondences> KeyframeFrontend::TakeCorrespondences() {
  std::vector<KeyframeCorrespondences> out;
  out.swap(correspondences_);
  return out;
}

void KeyframeFrontend::CountInliers(const PairTask& task, const PairOutcome& outcome, Keyframe* newer) {
  Keyframe& older = *keyframes_[task.older];
  const bool older_full = !older.compact && older.inlier_hits.size() == older.features.keypoints_px.size();
  for (const auto& [i, j] : outcome.inlier_features) {
    if (older_full && older.inlier_hits[i] < std::numeric_limits<std::uint16_t>::max()) ++older.inlier_hits[i];
    if (newer->inlier_hits[j] < std::numeric_limits<std::uint16_t>::max()) ++newer->inlier_hits[j];
  }
}

void KeyframeFrontend::Count(const PairOutcome& outcome) {
  stats_.track_pairs += outcome.from_tracks;
  stats_.track_pairs_matched_instead += outcome.tracks_failed;
  if (outcome.success) {
    stats_.rotation_model_edges += outcome.rotation_model;
  } else {
    ++stats_.failed_pairs;
    ++stats_.failures[outcome.failure];
  }
}

double KeyframeFrontend::LoopInliersNeeded(const Keyframe& older) const {
  return older.compact ? options_.compact_loop_inlier_fraction * options_.min_loop_inliers : options_.min_loop_inliers;
}

const std::vector<int>& KeyframeFrontend::ChainOf(const Keyframe& keyframe) const {
  return keyframe.loaded_chain >= 0 ? loaded_chains_[keyframe.loaded_chain] : by_camera_.at(keyframe.key.frame_id);
}

bool KeyframeFrontend::ChainRotation(int a, int b, Eigen::Matrix3d* r_ab, Eigen::Matrix3d* covariance) const {
  const Keyframe& ka = *keyframes_[a];
  const Keyframe& kb = *keyframes_[b];
  if (ka.key.frame_id != kb.key.frame_id || ka.loaded_chain != kb.loaded_chain) return false;
  const std::vector<int>& chain = ChainOf(ka);
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  Eigen::Matrix3d sum = covariance ? *covariance : Eigen::Matrix3d::Zero();
  for (int p = ka.camera_position + 1; p <= kb.camera_position; ++p) {
    const Keyframe& k = *keyframes_[chain[p]];
    if (!k.has_sequential) return false;
    r = r * k.sequential_rotation;  // R_a,p = R_a,p-1 R_p-1,p
    sum += k.sequential_covariance;
  }
  *r_ab = r;
  if (covariance) *covariance = sum;
  return true;
}

void KeyframeFrontend::FilterInconsistentLoops(std::vector<KeyframeRelativeRotation>* loops,
                                               std::vector<int>* old_ends_io) {
  const std::vector<int>& old_ends = *old_ends_io;
  const int n = static_cast<int>(loops->size());
  if (n < 2) return;
  std::vector<int> agree(n, 0), compared(n, 0);
  for (int i = 0; i < n; ++i) {
    for (int j = i + 1; j < n; ++j) {
      // Order the old ends along the chain: a (earlier), c (later).
      const bool i_first = keyframes_[old_ends[i]]->camera_position <= keyframes_[old_ends[j]]->camera_position;
      const int a = i_first ? i : j, c = i_first ? j : i;
      Eigen::Matrix3d r_ac;
      if (!ChainRotation(old_ends[a], old_ends[c], &r_ac)) continue;
      const Eigen::Matrix3d predicted = r_ac * (*loops)[c].rotation;  // R_ab = R_ac R_cb
      const double angle = AngularDistanceRad(predicted, (*loops)[a].rotation);
      const double spread = std::sqrt(((*loops)[a].covariance + (*loops)[c].covariance).trace());
      const bool ok = angle <= DegToRad(options_.loop_consistency_deg) + 3.0 * spread;
      ++compared[i];
      ++compared[j];
      if (ok) {
        ++agree[i];
        ++agree[j];
      }
    }
  }
  std::vector<bool> keep(n, true);
  if (n == 2) {
    if (compared[0] > 0 && agree[0] == 0) keep[(*loops)[0].num_inliers >= (*loops)[1].num_inliers ? 1 : 0] = false;
  } else {
    for (int i = 0; i < n; ++i) keep[i] = compared[i] == 0 || 2 * agree[i] >= compared[i];
  }
  DropLoops(keep, loops, old_ends_io, &stats_.loops_rejected_inconsistent);
}

void KeyframeFrontend::DropLoops(const std::vector<bool>& keep, std::vector<KeyframeRelativeRotation>* loops,
                                 std::vector<int>* old_ends, std::uint64_t* dropped) {
  std::vector<KeyframeRelativeRotation> kept;
  std::vector<int> kept_ends;
  for (std::size_t i = 0; i < keep.size(); ++i) {
    if (keep[i]) {
      kept.push_back((*loops)[i]);
      kept_ends.push_back((*old_ends)[i]);
    } else {
      ++*dropped;
    }
  }
  loops->swap(kept);
  old_ends->swap(kept_ends);
}

void KeyframeFrontend::KeepOneLoopPerPlace(std::vector<KeyframeRelativeRotation>* loops,
                                           std::vector<int>* old_ends) {
  const int n = static_cast<int>(loops->size());
  if (n < 2) return;
  // Most inliers first; ties in retrieval order.
  std::vector<int> order(n);
  for (int i = 0; i < n; ++i) order[i] = i;
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return (*loops)[a].num_inliers > (*loops)[b].num_inliers; });
  const auto neighbours = [&](int a, int b) {
    const Keyframe& ka = *keyframes_[a];
    const Keyframe& kb = *keyframes_[b];
    return &ChainOf(ka) == &ChainOf(kb) && std::abs(ka.camera_position - kb.camera_position) <= 1;
  };
  std::vector<bool> keep(n, false);
  std::vector<int> kept_ends;
  for (int i : order) {
    const int end = (*old_ends)[i];
    keep[i] = std::none_of(kept_ends.begin(), kept_ends.end(), [&](int k) { return neighbours(k, end); });
    if (keep[i]) kept_ends.push_back(end);
  }
  DropLoops(keep, loops, old_ends, &stats_.loops_same_place);
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                                    const Eigen::Matrix3d& k) {
  CameraIntrinsics camera;
  camera.k = k;
  return AddKeyframe(key, image, camera);
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                                    const CameraIntrinsics& camera) {
  return AddKeyframe(key, image, camera, {});
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                                    const CameraIntrinsics& given,
                                                                    const std::vector<TrackedPoint>& tracks) {
  std::vector<KeyframeRelativeRotation> edges;
  // A focal length corrected by the check (ApplyFocalCorrection), and a
  // lens where camera_info describes none (ApplyLensCorrection), replace the
  // given ones before anything, undistortion included.
  given_focal_px_[key.frame_id] = given.k(0, 0);
  const CameraIntrinsics camera = CameraInUse(key.frame_id, given);
  // A second image under one key (a driver that repeats a stamp, a bag
  // played twice, a key of a loaded database) would be a second view under
  // the name of the first.
  if (!keys_.insert(key).second) {
    ++stats_.duplicate_keyframes;
    return edges;
  }
  std::unique_ptr<Keyframe> kf = DescribeKeyframe(key, image, camera, tracks);
  const double pairs_before = stats_.pairs_s;
  ++stats_.keyframes;
  if (kf->features.keypoints_px.size() < 20) {
    keyframes_.push_back(std::move(kf));
    by_camera_[key.frame_id].push_back(static_cast<int>(keyframes_.size()) - 1);
    return edges;
  }

  CompactDue(key.stamp_ns);
  const std::vector<int>& same = by_camera_[key.frame_id];
  kf->camera_position = static_cast<int>(same.size());
  const int window = std::min(std::max(1, options_.covisibility_window), static_cast<int>(same.size()));
  std::set<int> related;
  std::vector<PairTask> tasks = ChainAndRigTasks(key, same, window, &related);
  const std::vector<PairTask> candidates = LoopCandidates(*kf, related, same);
  std::vector<PairOutcome> outcomes, verified_loops;
  VerifyKeyframePairs(same, window, candidates, kf.get(), &tasks, &outcomes, &verified_loops);
  for (std::size_t t = 0; t < tasks.size(); ++t) {
    if (outcomes[t].success) UseChainOrRigEdge(tasks[t], outcomes[t], camera, same, kf.get(), &edges);
  }
  // Loop closures: enough inliers, and consistent with each other.
  std::vector<std::size_t> accepted;
  for (const KeyframeRelativeRotation& e : AcceptLoops(candidates, verified_loops, &accepted)) edges.push_back(e);
  for (std::size_t c : accepted) {
    CountInliers(candidates[c], verified_loops[c], kf.get());
    MonitorFocal(verified_loops[c], *kf, camera);
    KeepCorrespondences(verified_loops[c]);
    HoldPair(candidates[c], verified_loops[c], static_cast<int>(keyframes_.size()), false);
  }
  StoreKeyframe(std::move(kf));
  stats_.last_pairs_s = stats_.pairs_s - pairs_before;
  if (options_.focal_monitor.enabled || options_.focal_monitor.hold_for_correction) stats_.focal_bytes = FocalBytes();
  return edges;
}

std::unique_ptr<KeyframeFrontend::Keyframe> KeyframeFrontend::DescribeKeyframe(const KeyframeKey& key,
                                                                              const cv::Mat& image,
                                                                              const CameraIntrinsics& camera,
                                                                              const std::vector<TrackedPoint>& tracks) {
  auto kf = std::make_unique<Keyframe>();
  kf->key = key;
  const auto start = Clock::now();
  kf->features = ExtractFeatures(image, options_.features);
  const double s = options_.features.downsample > 0.0 ? options_.features.downsample : 1.0;
  kf->k = ScaleIntrinsics(camera.k, s);
  // Every two-view step below assumes an ideal pinhole camera: keypoints of
  // a raw image are moved to where that camera would have seen them. A
  // rectified camera's are left exactly as detected.
  stats_.keypoints_outside_model += UndistortFeatures(camera, kf->k, &kf->features);
  if (camera.HasDistortion()) {
    kf->lens = camera;
    kf->lens.k = kf->k;
  }
  if (!tracks.empty()) {
    // Tracks as FeatureTracker gives them: inside the image, in increasing
    // id order; any other point is dropped.
    for (const TrackedPoint& t : tracks) {
      const bool inside = t.px.allFinite() && t.px.x() >= 0.0 && t.px.y() >= 0.0 && t.px.x() <= image.cols - 1 &&
                          t.px.y() <= image.rows - 1;
      if (inside && (kf->tracks.empty() || t.id > kf->tracks.back().id)) kf->tracks.push_back(t);
    }
    kf->track_camera = camera;
    kf->track_pyramid = TrackPyramid(image, options_.tracker, false);
  }
  kf->index = std::make_unique<FeatureIndex>(kf->features);
  kf->inlier_hits.assign(kf->features.keypoints_px.size(), 0);
  stats_.last_features_s = SecondsSince(start);
  stats_.features_s += stats_.last_features_s;
  stats_.last_retrieval_s = stats_.last_pairs_s = 0.0;
  if (options_.vocabulary) {
    // Words first: retrieval scores them, and pairs with a compact keyframe
    // are matched within the vocabulary's branches.
    const auto words_start = Clock::now();
    kf->features.words = options_.vocabulary->Assign(kf->features.descriptors);
    kf->bow = options_.vocabulary->Describe(kf->features.words);
    stats_.last_retrieval_s = SecondsSince(words_start);
  }
  return kf;
}

std::vector<KeyframeFrontend::PairTask> KeyframeFrontend::ChainAndRigTasks(const KeyframeKey& key,
                                                                           const std::vector<int>& same, int window,
                                                                           std::set<int>* related) {
  std::vector<PairTask> tasks;
  // Sequential: the previous keyframe of this camera.
  for (int r = 1; r <= window; ++r) related->insert(same[same.size() - r]);
  if (!same.empty()) tasks.push_back({same.back(), EdgeSource::kSequential});
  // Rig: the other cameras' keyframes of the same capture.
  const std::int64_t tolerance_ns = static_cast<std::int64_t>(options_.rig_stamp_tolerance_s * 1e9);
  for (const auto& [camera, indices] : by_camera_) {
    if (camera == key.frame_id) continue;
    for (auto it = indices.rbegin(); it != indices.rend(); ++it) {
      const Keyframe& other = *keyframes_[*it];
      if (std::llabs(other.key.stamp_ns - key.stamp_ns) <= tolerance_ns) {
        // Two cameras with known extrinsics need no image edge.
        if (rig_calibrated_.count(camera) && rig_calibrated_.count(key.frame_id)) {
          ++stats_.rig_pairs_skipped;
        } else {
          tasks.push_back({*it, EdgeSource::kRig, key.frame_id < camera});
        }
        related->insert(*it);
      }
      if (other.key.stamp_ns < key.stamp_ns - tolerance_ns) break;  // older captures of that camera
    }
  }
  return tasks;
}

std::vector<KeyframeFrontend::PairTask> KeyframeFrontend::LoopCandidates(const Keyframe& kf,
                                                                         const std::set<int>& related,
                                                                         const std::vector<int>& same) {
  std::vector<PairTask> candidates;
  if (options_.max_loop_candidates <= 0) return candidates;
  const auto retrieval_start = Clock::now();
  std::set<int> excluded = related;
  for (int r = 0; r < options_.loop_exclude_recent && r < static_cast<int>(same.size()); ++r) {
    excluded.insert(same[same.size() - 1 - r]);
  }
  const std::vector<int> retrieved = options_.vocabulary
                                         ? RetrieveByVocabulary(kf, excluded, same.empty() ? -1 : same.back())
                                         : RetrieveByVoting(kf, excluded);
  stats_.last_retrieval_s += SecondsSince(retrieval_start);
  stats_.retrieval_s += stats_.last_retrieval_s;
  for (int c : retrieved) candidates.push_back({c, EdgeSource::kLoopClosure});
  stats_.loop_candidates_tried += candidates.size();
  return candidates;
}

void KeyframeFrontend::VerifyKeyframePairs(const std::vector<int>& same, int window,
                                           const std::vector<PairTask>& candidates, Keyframe* kf,
                                           std::vector<PairTask>* tasks, std::vector<PairOutcome>* outcomes,
                                           std::vector<PairOutcome>* verified_loops) {
  // Loop-closure candidates: retrieval does not depend on this keyframe's
  // pairs, so all of them are verified in one batch on the thread pool.
  // Older keyframes of the window bridge a failed previous pair. Failures
  // come in runs (a stretch of pure rotation, a blurred stretch): when the
  // previous keyframe of this camera needed a bridge, they are verified in
  // the same batch, which costs idle threads rather than a second round.
  std::vector<PairTask> fallback;
  for (int r = 2; r <= window; ++r) {
    PairTask task{same[same.size() - r], EdgeSource::kSequential};
    task.wide = options_.window_pairs;
    fallback.push_back(task);
  }
  // With window_pairs they are verified whatever the previous pair gives.
  const bool speculate = !fallback.empty() && (options_.window_pairs || keyframes_[same.back()]->bridged);
  std::vector<PairTask> batch = *tasks;
  batch.insert(batch.end(), candidates.begin(), candidates.end());
  if (speculate) batch.insert(batch.end(), fallback.begin(), fallback.end());
  const std::vector<PairOutcome> verified_batch = VerifyPairs(batch, *kf);
  outcomes->assign(verified_batch.begin(), verified_batch.begin() + tasks->size());
  verified_loops->assign(verified_batch.begin() + tasks->size(),
                         verified_batch.begin() + tasks->size() + candidates.size());
  for (const PairOutcome& o : *outcomes) Count(o);
  if (!same.empty() && !(*outcomes)[0].success && !fallback.empty()) {
    // The previous pair failed: the newest older keyframe of the window that
    // verifies keeps the chain whole.
    const std::vector<PairOutcome> verified =
        speculate ? std::vector<PairOutcome>(verified_batch.end() - fallback.size(), verified_batch.end())
                  : VerifyPairs(fallback, *kf);
    for (const PairOutcome& o : verified) Count(o);
    for (std::size_t f = 0; f < fallback.size(); ++f) {
      if (!verified[f].success) continue;
      tasks->push_back(fallback[f]);
      outcomes->push_back(verified[f]);
      ++stats_.chain_bridged;
      kf->bridged = true;
      break;
    }
  } else if (!same.empty() && (*outcomes)[0].success && options_.window_pairs) {
    const std::vector<PairOutcome> verified(verified_batch.end() - fallback.size(), verified_batch.end());
    KeepConsistentWindowPairs(same.back(), fallback, verified, tasks, outcomes);
  }
}

void KeyframeFrontend::KeepConsistentWindowPairs(int previous_index, const std::vector<PairTask>& window_tasks,
                                                 const std::vector<PairOutcome>& verified,
                                                 std::vector<PairTask>* tasks, std::vector<PairOutcome>* outcomes) {
  // The previous pair holds: each verified older pair of the window is kept
  // when it agrees with the chain through the previous keyframe,
  // R_older,new = R_older,previous R_previous,new, within three standard
  // deviations of the pair's and the chain's covariances. Unlike a loop
  // closure's check, no angle is added for the drift of a long chain: over
  // the window the chain has none beyond its covariance, and wrong pairs
  // that verify on repeated structure err tenths of a degree to degrees.
  const KeyframeRelativeRotation previous = (*outcomes)[0].edge;
  for (std::size_t f = 0; f < window_tasks.size(); ++f) {
    Count(verified[f]);
    if (!verified[f].success) continue;
    Eigen::Matrix3d r_op, chain_covariance = previous.covariance;
    if (!ChainRotation(window_tasks[f].older, previous_index, &r_op, &chain_covariance)) continue;
    const KeyframeRelativeRotation& e = verified[f].edge;
    const double angle = AngularDistanceRad(r_op * previous.rotation, e.rotation);
    const double spread = std::sqrt((e.covariance + chain_covariance).trace());
    if (angle > 3.0 * spread) {
      ++stats_.window_rejected_inconsistent;
      continue;
    }
    tasks->push_back(window_tasks[f]);
    outcomes->push_back(verified[f]);
    ++stats_.window_edges;
  }
}

void KeyframeFrontend::UseChainOrRigEdge(const PairTask& task, const PairOutcome& outcome,
                                         const CameraIntrinsics& camera, const std::vector<int>& same, Keyframe* kf,
                                         std::vector<KeyframeRelativeRotation>* edges) {
  const KeyframeRelativeRotation& e = outcome.edge;
  edges->push_back(e);
  CountInliers(task, outcome, kf);
  MonitorFocal(outcome, *kf, camera);
  KeepCorrespondences(outcome);
  HoldPair(task, outcome, static_cast<int>(keyframes_.size()),
           task.source != EdgeSource::kRig && task.older == same.back());
  if (task.source == EdgeSource::kRig) {
    ++stats_.rig_edges;
    return;
  }
  ++stats_.sequential_edges;
  if (task.older == same.back()) {  // the previous keyframe: the chain loop closures are checked along
    kf->has_sequential = true;
    kf->sequential_rotation = e.rotation;
    kf->sequential_covariance = e.covariance;
  }
}

void KeyframeFrontend::StoreKeyframe(std::unique_ptr<Keyframe> kf) {
  const KeyframeKey key = kf->key;
  if (inverted_index_) inverted_index_->Add(static_cast<int>(keyframes_.size()), kf->bow);
  stats_.keyframe_bytes += KeyframeBytes(*kf);
  keyframes_.push_back(std::move(kf));
  std::vector<int>& chain = by_camera_[key.frame_id];
  chain.push_back(static_cast<int>(keyframes_.size()) - 1);
  // The keyframe leaving this camera's recent window: rig, sequential and
  // bridging pairs only reach into the window, loop closures need less. It
  // is compacted once a later capture arrives, so that every camera's image
  // of this capture sees the same keyframes whatever order they came in.
  const int recent = std::max(1, options_.covisibility_window);
  // Its tracks and their pyramid served the pairs of the window alone.
  if (static_cast<int>(chain.size()) > recent) ReleaseTracks(keyframes_[chain[chain.size() - 1 - recent]].get());
  if (options_.vocabulary && static_cast<int>(chain.size()) > recent) {
    due_compaction_.push_back({chain[chain.size() - 1 - recent], key.stamp_ns});
  }
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::AcceptLoops(const std::vector<PairTask>& candidates,
                                                                     const std::vector<PairOutcome>& verified,
                                                                     std::vector<std::size_t>* accepted) {
  std::vector<KeyframeRelativeRotation> loops;
  std::vector<int> old_ends;
  for (std::size_t c = 0; c < candidates.size(); ++c) {
    Count(verified[c]);
    if (!verified[c].success) continue;
    if (verified[c].edge.num_inliers < LoopInliersNeeded(*keyframes_[candidates[c].older])) {
      ++stats_.failed_pairs;
      ++stats_.failures["loop_too_few_inliers"];
      continue;
    }
    loops.push_back(verified[c].edge);
    old_ends.push_back(candidates[c].older);
  }
  FilterInconsistentLoops(&loops, &old_ends);
  if (options_.one_loop_per_place) KeepOneLoopPerPlace(&loops, &old_ends);
  accepted->clear();
  for (const KeyframeRelativeRotation& e : loops) {
    ++stats_.loop_closure_edges;
    for (std::size_t c = 0; c < candidates.size(); ++c) {
      const KeyframeKey& k1 = keyframes_[candidates[c].older]->key;
      if (k1 == e.keyframe1) accepted->push_back(c);
    }
  }
  return loops;
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::LinkAddedKeyframes(int first_added) {
  std::vector<KeyframeRelativeRotation> links;
  const int end = static_cast<int>(keyframes_.size());
  if (first_added <= 0 || first_added >= end || options_.max_loop_candidates <= 0 || !inverted_index_) return links;
  // Retrieval per added keyframe, in order; verification of many added
  // keyframes' candidates at once, so that every thread has pairs to verify.
  const auto start = Clock::now();
  constexpr int kKeyframesPerBatch = 64;
  for (int batch = first_added; batch < end; batch += kKeyframesPerBatch) {
    std::vector<PairTask> tasks;
    std::vector<const Keyframe*> newers;
    std::vector<std::pair<std::size_t, std::size_t>> ranges;  // each added keyframe's tasks
    for (int i = batch; i < std::min(end, batch + kKeyframesPerBatch); ++i) {
      const Keyframe& added = *keyframes_[i];
      const std::size_t first_task = tasks.size();
      if (added.features.keypoints_px.size() >= 20) {
        double min_score = 0.0;
        if (options_.min_retrieval_score_ratio > 0.0 && added.camera_position > 0) {
          const int previous = ChainOf(added)[added.camera_position - 1];
          min_score = options_.min_retrieval_score_ratio * BowScore(added.bow, keyframes_[previous]->bow);
        }
        const std::vector<std::pair<double, int>> hits =
            inverted_index_->Query(added.bow, options_.max_loop_candidates, min_score, [&](int id) {
              return id >= first_added || keyframes_[id]->features.keypoints_px.size() < 20;
            });
        for (const auto& [score, id] : hits) {
          PairTask task{id, EdgeSource::kLoopClosure};
          task.newer = static_cast<int>(newers.size());
          tasks.push_back(task);
        }
      }
      newers.push_back(&added);
      ranges.emplace_back(first_task, tasks.size());
    }
    stats_.loop_candidates_tried += tasks.size();
    const std::vector<PairOutcome> verified = VerifyPairs(tasks, newers);
    for (const auto& [first, last] : ranges) {
      const std::vector<PairTask> candidates(tasks.begin() + first, tasks.begin() + last);
      const std::vector<PairOutcome> outcomes(verified.begin() + first, verified.begin() + last);
      std::vector<std::size_t> accepted;
      for (const KeyframeRelativeRotation& e : AcceptLoops(candidates, outcomes, &accepted)) links.push_back(e);
    }
  }
  stats_.map_links += links.size();
  stats_.map_link_s += SecondsSince(start);
  return links;
}

std::string KeyframeFrontend::RetrievalName() const {
  return options_.vocabulary
             ? "vocabulary of " + std::to_string(options_.vocabulary->NumWords()) + " words (inverted index)"
             : "voting over every keyframe (no vocabulary)";
}

std::size_t KeyframeFrontend::KeyframeBytes(const Keyframe& keyframe) const {
  // The bag of words, and its entries in the inverted index.
  std::size_t bytes = FeatureMemoryBytes(keyframe.features) + 2 * keyframe.bow.size() * sizeof(std::pair<int, float>) +
                      keyframe.tracks.size() * sizeof(TrackedPoint);
  for (const cv::Mat& level : keyframe.track_pyramid) bytes += level.total() * level.elemSize();
  return bytes;
}

void KeyframeFrontend::CompactDue(std::int64_t stamp_ns) {
  const std::int64_t tolerance_ns = static_cast<std::int64_t>(options_.rig_stamp_tolerance_s * 1e9);
  std::vector<std::pair<int, std::int64_t>> later;
  for (const auto& [index, capture_ns] : due_compaction_) {
    if (capture_ns < stamp_ns - tolerance_ns) {
      Compact(keyframes_[index].get());
    } else {
      later.emplace_back(index, capture_ns);
    }
  }
  due_compaction_.swap(later);
}

void KeyframeFrontend::ReleaseTracks(Keyframe* keyframe) {
  if (keyframe->tracks.empty() && keyframe->track_pyramid.empty()) return;
  stats_.keyframe_bytes -= KeyframeBytes(*keyframe);
  keyframe->tracks.clear();
  keyframe->tracks.shrink_to_fit();
  keyframe->track_pyramid.clear();
  stats_.keyframe_bytes += KeyframeBytes(*keyframe);
}

void KeyframeFrontend::Compact(Keyframe* keyframe) {
  if (keyframe->compact) return;
  stats_.keyframe_bytes -= KeyframeBytes(*keyframe);
  keyframe->features = CompactFeatures(keyframe->features, options_.compact_features, keyframe->inlier_hits);
  keyframe->inlier_hits.clear();
  keyframe->inlier_hits.shrink_to_fit();
  keyframe->index.reset();
  keyframe->compact = true;
  stats_.keyframe_bytes += KeyframeBytes(*keyframe);
  stats_.compact_bytes += KeyframeBytes(*keyframe);
  ++stats_.compacted_keyframes;
}

std::vector<int> KeyframeFrontend::RetrieveByVocabulary(const Keyframe& kf, const std::set<int>& excluded,
                                                        int previous) {
  double min_score = 0.0;
  if (previous >= 0 && options_.min_retrieval_score_ratio > 0.0) {
    min_score = options_.min_retrieval_score_ratio * BowScore(kf.bow, keyframes_[previous]->bow);
  }
  const std::vector<std::pair<double, int>> hits =
      inverted_index_->Query(kf.bow, options_.max_loop_candidates, min_score, [&](int id) {
        return excluded.count(id) > 0 || keyframes_[id]->features.keypoints_px.size() < 20;
      });
  std::vector<int> out;
  for (const auto& [score, id] : hits) out.push_back(id);
  return out;
}

std::vector<int> KeyframeFrontend::RetrieveByVoting(const Keyframe& kf, const std::set<int>& excluded) {
  const cv::Mat& d = kf.features.descriptors;
  cv::Mat sample;
  if (d.rows <= options_.retrieval_sample) {
    sample = d;
  } else {
    sample.create(options_.retrieval_sample, d.cols, d.type());
    for (int r = 0; r < options_.retrieval_sample; ++r) {
      d.row(static_cast<int>(static_cast<long long>(r) * d.rows / options_.retrieval_sample)).copyTo(sample.row(r));
    }
  }
  std::vector<int> counts(keyframes_.size(), 0);
  ParallelFor(static_cast<int>(keyframes_.size()), ResolveThreadCount(options_.num_threads), [&](int i) {
    if (excluded.count(i) || keyframes_[i]->features.keypoints_px.size() < 20) return;
    const std::vector<int> nn = keyframes_[i]->index->RatioMatches(sample, options_.matching.ratio);
    counts[i] = static_cast<int>(std::count_if(nn.begin(), nn.end(), [](int j) { return j >= 0; }));
  });
  std::vector<std::pair<int, int>> votes;  // (votes, keyframe index)
  for (int i = 0; i < static_cast<int>(counts.size()); ++i) {
    if (counts[i] >= options_.min_retrieval_votes) votes.emplace_back(counts[i], i);
  }
  std::sort(votes.rbegin(), votes.rend());
  std::vector<int> out;
  for (int c = 0; c < options_.max_loop_candidates && c < static_cast<int>(votes.size()); ++c) {
    out.push_back(votes[c].second);
  }
  return out;
}

}  // namespace rotation_averaging
