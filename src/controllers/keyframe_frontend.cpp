#include "rotation_averaging/controllers/keyframe_frontend.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <set>

#include "rotation_averaging/geometry/so3.h"

namespace rotation_averaging {
namespace {

using Clock = std::chrono::steady_clock;
double Seconds(Clock::time_point since) { return std::chrono::duration<double>(Clock::now() - since).count(); }

}  // namespace

struct KeyframeFrontend::Keyframe {
  KeyframeKey key;
  int camera_position = 0;               // index in by_camera_[key.frame_id]
  bool has_sequential = false;           // sequential edge from the previous keyframe of its camera
  Eigen::Matrix3d sequential_rotation;   // R_prev,this
  Eigen::Matrix3d sequential_covariance;
  ImageFeatures features;
  std::unique_ptr<FeatureIndex> index;
  Eigen::Matrix3d k;  // intrinsics of the (resized) image the features come from
};

KeyframeFrontend::KeyframeFrontend(const KeyframeFrontendOptions& options) : options_(options) {}
KeyframeFrontend::~KeyframeFrontend() = default;

bool KeyframeFrontend::Relate(const Keyframe& a, const Keyframe& b, EdgeSource source, KeyframeRelativeRotation* out) {
  const auto start = Clock::now();
  const std::vector<std::pair<int, int>> matches =
      MatchFeatures(a.features, *a.index, b.features, *b.index, options_.matching);
  std::vector<Eigen::Vector2d> pa, pb;
  pa.reserve(matches.size());
  pb.reserve(matches.size());
  for (const auto& [i, j] : matches) {
    pa.push_back(a.features.keypoints_px[i]);
    pb.push_back(b.features.keypoints_px[j]);
  }
  const RelativePoseResult pose = EstimateRelativePoseWithCovariance(pa, pb, a.k, b.k, options_.relative_pose);
  stats_.pairs_s += Seconds(start);
  if (!pose.success) {
    ++stats_.failed_pairs;
    ++stats_.failures[TwoViewFailureName(pose.failure)];
    return false;
  }
  // The pose maps a's camera to b's; the edge is (a, b).
  out->keyframe1 = a.key;
  out->keyframe2 = b.key;
  out->rotation = pose.EdgeRotation();
  out->has_covariance = true;
  out->covariance = pose.covariance;
  out->num_inliers = static_cast<int>(pose.inliers.size());
  out->source = source;
  return true;
}

bool KeyframeFrontend::ChainRotation(int a, int b, Eigen::Matrix3d* r_ab) const {
  const Keyframe& ka = *keyframes_[a];
  const Keyframe& kb = *keyframes_[b];
  if (ka.key.frame_id != kb.key.frame_id) return false;
  const std::vector<int>& chain = by_camera_.at(ka.key.frame_id);
  Eigen::Matrix3d r = Eigen::Matrix3d::Identity();
  for (int p = ka.camera_position + 1; p <= kb.camera_position; ++p) {
    const Keyframe& k = *keyframes_[chain[p]];
    if (!k.has_sequential) return false;
    r = r * k.sequential_rotation;  // R_a,p = R_a,p-1 R_p-1,p
  }
  *r_ab = r;
  return true;
}

void KeyframeFrontend::FilterInconsistentLoops(std::vector<KeyframeRelativeRotation>* loops,
                                               const std::vector<int>& old_ends) {
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
  std::vector<KeyframeRelativeRotation> kept;
  for (int i = 0; i < n; ++i) {
    if (keep[i]) kept.push_back((*loops)[i]);
    else ++stats_.loops_rejected_inconsistent;
  }
  loops->swap(kept);
}

std::vector<KeyframeRelativeRotation> KeyframeFrontend::AddKeyframe(const KeyframeKey& key, const cv::Mat& image,
                                                                    const Eigen::Matrix3d& k) {
  std::vector<KeyframeRelativeRotation> edges;
  auto kf = std::make_unique<Keyframe>();
  kf->key = key;
  const auto start = Clock::now();
  kf->features = ExtractFeatures(image, options_.features);
  kf->index = std::make_unique<FeatureIndex>(kf->features);
  const double s = options_.features.downsample > 0.0 ? options_.features.downsample : 1.0;
  kf->k = ScaleIntrinsics(k, s);
  stats_.features_s += Seconds(start);
  ++stats_.keyframes;
  if (kf->features.keypoints_px.size() < 20) {
    keyframes_.push_back(std::move(kf));
    by_camera_[key.frame_id].push_back(static_cast<int>(keyframes_.size()) - 1);
    return edges;
  }

  std::set<int> related;
  // Sequential: the previous keyframe of this camera.
  const std::vector<int>& same = by_camera_[key.frame_id];
  kf->camera_position = static_cast<int>(same.size());
  if (!same.empty()) {
    KeyframeRelativeRotation e;
    if (Relate(*keyframes_[same.back()], *kf, EdgeSource::kSequential, &e)) {
      edges.push_back(e);
      ++stats_.sequential_edges;
      kf->has_sequential = true;
      kf->sequential_rotation = e.rotation;
      kf->sequential_covariance = e.covariance;
    }
    related.insert(same.back());
  }
  // Rig: the other cameras' keyframes of the same capture.
  const std::int64_t tolerance_ns = static_cast<std::int64_t>(options_.rig_stamp_tolerance_s * 1e9);
  for (const auto& [camera, indices] : by_camera_) {
    if (camera == key.frame_id) continue;
    for (auto it = indices.rbegin(); it != indices.rend(); ++it) {
      const Keyframe& other = *keyframes_[*it];
      if (std::llabs(other.key.stamp_ns - key.stamp_ns) <= tolerance_ns) {
        KeyframeRelativeRotation e;
        // Two cameras with known extrinsics need no image edge.
        const bool calibrated = rig_calibrated_.count(camera) && rig_calibrated_.count(key.frame_id);
        if (calibrated) ++stats_.rig_pairs_skipped;
        if (!calibrated && Relate(other, *kf, EdgeSource::kRig, &e)) {
          edges.push_back(e);
          ++stats_.rig_edges;
        }
        related.insert(*it);
      }
      if (other.key.stamp_ns < key.stamp_ns - tolerance_ns) break;  // older captures of that camera
    }
  }
  // Loop closures: vote with a sample of descriptors, verify the best.
  if (options_.max_loop_candidates > 0) {
    const auto retrieval_start = Clock::now();
    std::set<int> recent;
    for (int r = 0; r < options_.loop_exclude_recent && r < static_cast<int>(same.size()); ++r) {
      recent.insert(same[same.size() - 1 - r]);
    }
    const cv::Mat& d = kf->features.descriptors;
    cv::Mat sample;
    if (d.rows <= options_.retrieval_sample) {
      sample = d;
    } else {
      sample.create(options_.retrieval_sample, d.cols, d.type());
      for (int r = 0; r < options_.retrieval_sample; ++r) {
        d.row(static_cast<int>(static_cast<long long>(r) * d.rows / options_.retrieval_sample)).copyTo(sample.row(r));
      }
    }
    std::vector<std::pair<int, int>> votes;  // (votes, keyframe index)
    for (int i = 0; i < static_cast<int>(keyframes_.size()); ++i) {
      if (related.count(i) || recent.count(i) || keyframes_[i]->features.keypoints_px.size() < 20) continue;
      const std::vector<int> nn = keyframes_[i]->index->RatioMatches(sample, options_.matching.ratio);
      const int count = static_cast<int>(std::count_if(nn.begin(), nn.end(), [](int j) { return j >= 0; }));
      if (count >= options_.min_retrieval_votes) votes.emplace_back(count, i);
    }
    std::sort(votes.rbegin(), votes.rend());
    stats_.retrieval_s += Seconds(retrieval_start);
    std::vector<KeyframeRelativeRotation> loops;
    std::vector<int> old_ends;
    for (int c = 0; c < options_.max_loop_candidates && c < static_cast<int>(votes.size()); ++c) {
      ++stats_.loop_candidates_tried;
      KeyframeRelativeRotation e;
      if (Relate(*keyframes_[votes[c].second], *kf, EdgeSource::kLoopClosure, &e)) {
        if (e.num_inliers < options_.min_loop_inliers) {
          ++stats_.failed_pairs;
          ++stats_.failures["loop_too_few_inliers"];
          continue;
        }
        loops.push_back(e);
        old_ends.push_back(votes[c].second);
      }
    }
    FilterInconsistentLoops(&loops, old_ends);
    for (const KeyframeRelativeRotation& e : loops) {
      edges.push_back(e);
      ++stats_.loop_closure_edges;
    }
  }
  keyframes_.push_back(std::move(kf));
  by_camera_[key.frame_id].push_back(static_cast<int>(keyframes_.size()) - 1);
  return edges;
}

}  // namespace rotation_averaging
