#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"

#include "rotation_averaging/frontend/controllers/focal_corrector.h"

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <limits>
#include <numeric>
#include <sstream>

#ifdef __linux__
#include <sys/resource.h>
#include <sys/syscall.h>
#include <unistd.h>
#endif

#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/util/option_check.h"
#include "rotation_averaging/util/text_lines.h"

namespace rotation_averaging {
namespace {

int Root(std::vector<int>* parent, int i) {
  while ((*parent)[i] != i) i = (*parent)[i] = (*parent)[(*parent)[i]];
  return i;
}

// Newest first: by stamp, then by frame (keyframes of one capture).
bool Newer(const KeyframeKey& a, const KeyframeKey& b) {
  return a.stamp_ns != b.stamp_ns ? a.stamp_ns > b.stamp_ns : a.frame_id < b.frame_id;
}

// Linux keeps a nice value per thread, and a thread std::async starts is
// new each time: raising this one's leaves every other thread as it was.
// Failing (not Linux, or a sandbox that forbids it) leaves it as it was.
void LowerThisThreadsPriority(int niceness) {
#ifdef __linux__
  if (niceness <= 0) return;
  const id_t tid = static_cast<id_t>(syscall(SYS_gettid));
  errno = 0;
  const int current = getpriority(PRIO_PROCESS, tid);
  if (errno != 0) return;
  setpriority(PRIO_PROCESS, tid, std::min(19, current + niceness));
#else
  (void)niceness;
#endif
}

// The views of `by_view` that belong to a rig capture, by capture.
std::map<KeyframeKey, std::vector<ViewId>> ByCapture(const std::map<ViewId, Eigen::Matrix3d>& by_view,
                                                     const std::vector<KeyframeKey>& keys,
                                                     const KeyframeRefiner::RigCaptures& rig) {
  std::map<KeyframeKey, std::vector<ViewId>> out;
  for (const auto& [id, value] : by_view) {
    const auto it = rig.find(keys[id]);
    if (it != rig.end()) out[it->second.first].push_back(id);
  }
  return out;
}

}  // namespace

KeyframeRefinerOptions::KeyframeRefinerOptions() {
  adjustment.max_iterations = 50;  // docs/decisions.md, "50 iterations per stage"
}

bool KeyframeRefinerOptions::Validate(std::string* error) const {
  return OptionCheck()
      .AtLeast("refinement_max_keyframes", max_keyframes, 3)
      .Above("refinement_max_correction_deg", max_correction_deg, 0.0)
      .Above("refinement_max_correspondence_mib", max_correspondence_mib, 0.0)
      .AtLeast("refinement min_correspondences", adjustment.min_correspondences, 5)
      .AtLeast("refinement_max_iterations", adjustment.max_iterations, 1)
      .Within("refinement_niceness", background_niceness, 0, 19)
      .Within("refinement_jackknife_grid", adjustment.covariance_cell_grid, 0, 16)
      .Ok(error);
}

KeyframeRefiner::KeyframeRefiner(const KeyframeRefinerOptions& options) : options_(options) {}

KeyframeRefiner::~KeyframeRefiner() { Wait(); }

std::size_t KeyframeRefiner::EdgeBytes(const EdgeCorrespondences& e) {
  return sizeof(HeldEdge) + (e.points1.capacity() + e.points2.capacity()) * sizeof(Eigen::Vector2d);
}

void KeyframeRefiner::Add(std::vector<KeyframeCorrespondences> edges) {
  std::lock_guard<std::mutex> lock(mutex_);
  for (KeyframeCorrespondences& e : edges) {
    if (e.keyframe1 == e.keyframe2) continue;
    if (static_cast<int>(e.points.points1.size()) < options_.adjustment.min_correspondences ||
        e.points.points1.size() != e.points.points2.size() || !CorrespondencesAreFinite(e.points, true)) {
      continue;
    }
    e.points.points1.shrink_to_fit();
    e.points.points2.shrink_to_fit();
    HeldEdge& held = edges_[{e.keyframe1, e.keyframe2}];
    if (held.points) stats_.bytes -= EdgeBytes(*held.points);
    held.keyframe1 = std::move(e.keyframe1);
    held.keyframe2 = std::move(e.keyframe2);
    held.points = std::make_shared<const EdgeCorrespondences>(std::move(e.points));
    stats_.bytes += EdgeBytes(*held.points);
  }
  stats_.edges_held = edges_.size();
  if (options_.sweep_back) LetGoBeyondBudget();
}

void KeyframeRefiner::ScaleCamera(const std::string& frame_id, double scale) {
  if (!(scale > 0.0) || !std::isfinite(scale)) return;
  std::lock_guard<std::mutex> lock(mutex_);
  focal_agreed_.erase(frame_id);  // the next refinement checks the new focal length
  const auto scaled = camera_scales_.emplace(frame_id, 1.0).first;
  scaled->second *= scale;
  const auto estimate = stats_.focal.find(frame_id);
  if (estimate != stats_.focal.end()) ScaleEstimate(1.0 / scale, &estimate->second);
  for (auto& [key, held] : edges_) {
    const bool first = held.keyframe1.frame_id == frame_id, second = held.keyframe2.frame_id == frame_id;
    if (!first && !second) continue;
    // A new copy: a refinement under way may share the one held.
    auto scaled_points = std::make_shared<EdgeCorrespondences>(*held.points);
    if (first) {
      for (Eigen::Vector2d& p : scaled_points->points1) p /= scale;
    }
    if (second) {
      for (Eigen::Vector2d& p : scaled_points->points2) p /= scale;
    }
    held.points = std::move(scaled_points);
  }
}

void KeyframeRefiner::HoldFocal(const std::string& frame_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  focal_held_.insert(frame_id);
  stats_.focal.erase(frame_id);
}

std::map<KeyframeKey, bool> KeyframeRefiner::Current(const OnlineSolution& cameras, const RigCaptures& rig,
                                                     std::map<KeyframeKey, int>* edges) const {
  for (const auto& [key, held] : edges_) {
    ++(*edges)[held.keyframe1];
    ++(*edges)[held.keyframe2];
  }
  std::map<KeyframeKey, bool> by_capture;
  const auto capture = [&rig](const KeyframeKey& key) -> const KeyframeKey& {
    const auto member = rig.find(key);
    return member == rig.end() ? key : member->second.first;
  };
  for (const auto& [key, count] : *edges) {
    if (cameras.orientations.count(key) == 0) continue;
    const auto then = tried_.find(key);
    const bool current =
        then != tried_.end() && then->second.sequence == cameras.sequence && count <= then->second.edges;
    auto [it, added] = by_capture.emplace(capture(key), current);
    it->second = it->second && current;
  }
  std::map<KeyframeKey, bool> out;
  for (const auto& [key, count] : *edges) {
    if (cameras.orientations.count(key)) out.emplace(key, by_capture.at(capture(key)));
  }
  return out;
}

std::size_t KeyframeRefiner::Pending(const OnlineSolution& cameras, const RigCaptures& rig) const {
  if (!options_.sweep_back) return 0;
  std::lock_guard<std::mutex> lock(mutex_);
  std::map<KeyframeKey, int> edges;
  std::size_t pending = 0;
  for (const auto& [key, current] : Current(cameras, rig, &edges)) pending += !current;
  return pending;
}

KeyframeRefiner::Input KeyframeRefiner::SelectWindow(const OnlineSolution& cameras, const RigCaptures& rig) const {
  std::lock_guard<std::mutex> lock(mutex_);
  Input input;
  const std::size_t window = std::min(cameras.orientations.size(), static_cast<std::size_t>(options_.max_keyframes));
  std::map<KeyframeKey, bool> current;
  if (options_.sweep_back) current = Current(cameras, rig, &input.edges);
  // The first refinement of a solution adjusts its newest keyframes, as the
  // front end adds them. Refined again (the input gone quiet, the end of a
  // bag), it sweeps back over those the earlier windows had no room for, a
  // window at a time, newest first: a window of the keyframes the averaging
  // had moved furthest since their last correction, scattered along the
  // map, came out less accurate than the averaging alone on a 600-keyframe
  // bag (docs/decisions.md, "The sweep back").
  const bool again = std::any_of(current.begin(), current.end(), [](const auto& c) { return c.second; }) &&
                     std::any_of(current.begin(), current.end(), [](const auto& c) { return !c.second; });
  std::vector<KeyframeKey> newest;
  newest.reserve(cameras.orientations.size());
  if (!again) {
    for (const auto& [key, r] : cameras.orientations) newest.push_back(key);
  } else {
    for (const auto& [key, c] : current) {
      if (!c) newest.push_back(key);
    }
  }
  const std::size_t taken = std::min(window, newest.size());
  std::partial_sort(newest.begin(), newest.begin() + taken, newest.end(), Newer);
  newest.resize(taken);
  if (!again && taken > 0 && taken < cameras.orientations.size()) input.oldest_kept = newest.back();
  for (const KeyframeKey& key : newest) {
    if (input.edges.count(key)) input.window.push_back(key);
  }
  std::map<KeyframeKey, ViewId> ids;
  const auto in_window = [&](const KeyframeKey& k) {
    return std::binary_search(newest.begin(), newest.end(), k, Newer);
  };
  for (const auto& [key, held] : edges_) {
    const bool first = in_window(held.keyframe1), second = in_window(held.keyframe2);
    if (!first && !second) continue;
    if (!(first && second)) {
      // An edge from the window to a keyframe outside it (the pairs of the
      // window's oldest keyframes, loop closures to places seen before it):
      // that keyframe joins the adjustment with its orientation held as the
      // averaging has it, so that the window's older end and its loops stay
      // where the whole map's averaging puts them; an adjustment of the
      // window alone is an open arc that bends along its length. (Held as
      // published instead, with the corrections earlier windows left it, or
      // with the fitted rotation below kept, the long runs came out less
      // accurate: docs/decisions.md, "The keyframes before the window are
      // held".)
      const KeyframeKey& outside = first ? held.keyframe2 : held.keyframe1;
      if (!options_.hold_outside || cameras.orientations.count(outside) == 0) continue;
    }
    for (const auto& [k, inside] : {std::pair(&held.keyframe1, first), std::pair(&held.keyframe2, second)}) {
      if (ids.count(*k) == 0) {
        if (!inside) input.held.insert(static_cast<ViewId>(input.keys.size()));
        ids.emplace(*k, static_cast<ViewId>(input.keys.size()));
        input.keys.push_back(*k);
      }
    }
    input.points.push_back(held.points);
    input.views.emplace_back(ids.at(held.keyframe1), ids.at(held.keyframe2));
  }
  input.camera_scales = camera_scales_;
  input.focal_held = focal_held_;
  if (options_.hold_agreed_focal) input.focal_held.insert(focal_agreed_.begin(), focal_agreed_.end());
  for (std::size_t v = 0; v < input.keys.size(); ++v) {
    // (A keyframe outside the window is held as the averaging has it:
    // SelectWindow's comment.)
    const auto correction = corrections_.find(input.keys[v]);
    if (input.held.count(static_cast<ViewId>(v))) {
      // Sweeping back, the keyframes a window adjusted in this solution are
      // held as published: the newer end of the sweep's window is where
      // they put it (on the four-camera 20 Hz stream, held as the averaging
      // has them: 0.0027 deg against 0.0023; docs/decisions.md, "The sweep
      // back").
      const auto c = current.find(input.keys[v]);
      if (again && c != current.end() && c->second && correction != corrections_.end()) {
        input.start_corrections.emplace(static_cast<ViewId>(v), correction->second);
      }
      continue;
    }
    if (correction != corrections_.end()) input.start_corrections.emplace(static_cast<ViewId>(v), correction->second);
    const auto centre = centres_.find(input.keys[v]);
    if (centre != centres_.end()) input.start_centres.emplace(static_cast<ViewId>(v), centre->second);
  }
  return input;
}

void KeyframeRefiner::ScaleEstimate(double factor, BundleAdjustmentFocal::Estimate* e) {
  e->scale *= factor;
  e->sigma *= factor;
  e->sigma_matches *= factor;
  e->sigma_principal_point *= factor;
}

bool KeyframeRefiner::Refine(const OnlineSolution& cameras, const RigCaptures& rig) {
  std::lock_guard<std::mutex> run(run_mutex_);  // after a background one
  return Run(cameras, rig, SelectWindow(cameras, rig), false);
}

bool KeyframeRefiner::Run(const OnlineSolution& cameras, const RigCaptures& rig, const Input& input, bool staged) {
  const auto start = std::chrono::steady_clock::now();
  const std::vector<KeyframeKey>& keys = input.keys;
  std::vector<EdgeCorrespondences> edges;
  edges.reserve(input.points.size());
  for (std::size_t i = 0; i < input.points.size(); ++i) {
    edges.push_back(*input.points[i]);
    edges.back().view1 = input.views[i].first;
    edges.back().view2 = input.views[i].second;
  }
  Outcome found;
  found.camera_scales = input.camera_scales;
  ViewOrientations averaged;
  for (std::size_t v = 0; v < keys.size(); ++v) averaged[static_cast<ViewId>(v)] = cameras.orientations.at(keys[v]);
  // The adjustment starts where the last one left the keyframes both
  // hold (the orientations published since, and their centres): it then
  // has only the keyframes added since to settle.
  ViewOrientations adjusted = averaged;
  for (const auto& [v, c] : input.start_corrections) adjusted[v] = c * averaged.at(v);
  std::unordered_map<ViewId, Eigen::Vector3d> centres;
  BundleAdjustmentSummary summary;
  // (Without the averaging's covariances there is nothing to publish them
  // with: posterior_covariance_max_views.)
  const bool with_covariance = options_.covariances && !cameras.covariance.empty();
  BundleAdjustmentCovariance adjusted_covariance;
  BundleAdjustmentFocal focal;
  if (options_.estimate_focal) {
    for (std::size_t v = 0; v < keys.size(); ++v) {
      if (input.focal_held.count(keys[v].frame_id) == 0) focal.camera[static_cast<ViewId>(v)] = keys[v].frame_id;
    }
  }
  // The cameras of a rig capture turn together in the adjustment, as the
  // averaging holds them: each camera's tracks then hold every camera of
  // its captures.
  BundleAdjustmentRig rig_views;
  rig_views.joint_covariance = options_.rig_joint_covariance;
  {
    std::map<KeyframeKey, std::int64_t> numbered;
    for (std::size_t v = 0; v < keys.size(); ++v) {
      const auto it = rig.find(keys[v]);
      if (it == rig.end()) continue;
      const auto capture = numbered.emplace(it->second.first, static_cast<std::int64_t>(numbered.size())).first;
      rig_views.views[static_cast<ViewId>(v)] = BundleAdjustmentRig::Member{capture->second, it->second.second};
    }
  }
  bool ok = !edges.empty() && RefineRotationsWithBundleAdjustment(
                                   edges, options_.adjustment, &adjusted, &summary, &centres,
                                   with_covariance ? &adjusted_covariance : nullptr,
                                   options_.estimate_focal ? &focal : nullptr, &input.start_centres, &rig_views,
                                   &input.held);
  std::string report = edges.empty() ? "no edge with correspondences among the solved keyframes" : summary.Report();
  // An adjustment whose cameras still move when its last stage runs out of
  // iterations has found no minimum: its tracks leave some keyframes free
  // along a valley (a short chain through a strong lens: there, views moved
  // 1-2.7 deg and kept moving at 100 iterations, and the keyframes it held
  // best moved by 0.1-0.2 deg, several times their error). Where the tracks
  // determine the keyframes, the adjustment settles in a fraction of its
  // iterations (BundleAdjustmentOptions::settled_rotation_rad).
  if (ok && !summary.converged) {
    ok = false;
    report += "; its cameras had not settled after refinement_max_iterations: the averaging's orientations kept";
  }
  // The focal estimates of an adjustment that succeeded stand even where
  // its corrections are held back below: a focal length a few percent off
  // bends the averaging by more than max_correction_deg, which is what the
  // adjustment with the focal length free then finds.
  if (ok) found.focal = std::move(focal.estimates);

  // Each camera's keyframes in each group the edges connect keep the
  // averaging's frame: the adjustment relates two cameras only through the
  // few tracks both see (a rig's cameras look apart), and a whole camera
  // turned against another is the mode it determines worst (on the rendered
  // rig at 20 Hz, 320x240, without extrinsics: each camera as a whole 0.4-0.6
  // deg from the averaging, in opposite directions). How the cameras sit
  // relative to each other is the averaging's, from its rig pairs. The
  // cameras of a rig with known extrinsics turned together in the
  // adjustment: their keyframes keep it as one.
  std::vector<int> group(keys.size());
  std::iota(group.begin(), group.end(), 0);
  for (const EdgeCorrespondences& e : edges) group[Root(&group, e.view1)] = Root(&group, e.view2);
  std::map<std::int64_t, ViewId> first_of_capture;
  for (const auto& [id, member] : rig_views.views) {
    const ViewId first = first_of_capture.emplace(member.capture, id).first->second;
    group[Root(&group, static_cast<int>(id))] = Root(&group, static_cast<int>(first));
  }
  std::map<ViewId, Eigen::Matrix3d> corrections;
  if (ok) {
    // A camera whose keyframes before the window were held keeps the frame
    // they hold: that is the averaging's already, and a rotation fitted to
    // the window's keyframes would turn it away from them.
    std::map<std::pair<int, std::string>, std::vector<ViewId>> members;
    std::set<std::pair<int, std::string>> anchored;
    for (const auto& [id, r] : adjusted) {
      const std::pair<int, std::string> camera{Root(&group, static_cast<int>(id)),
                                               rig.count(keys[id]) ? std::string() : keys[id].frame_id};
      if (input.held.count(id)) {
        anchored.insert(camera);
      } else {
        members[camera].push_back(id);
      }
    }
    for (const auto& [g, ids] : members) {
      std::vector<Eigen::Matrix3d> from, to;
      for (ViewId id : ids) {
        from.push_back(adjusted.at(id));
        to.push_back(averaged.at(id));
      }
      const Eigen::Matrix3d align =
          anchored.count(g) ? Eigen::Matrix3d::Identity() : AlignRotations(from, to);  // adjusted * align ~ averaged
      for (ViewId id : ids) {
        const Eigen::Matrix3d c = ProjectToSO3(adjusted.at(id) * align * averaged.at(id).transpose());
        if (!c.allFinite()) {
          ok = false;
          report += "; a correction is not finite";
          break;
        }
        corrections[id] = c;
      }
      if (!ok) break;
    }
  }
  if (ok && !rig.empty()) {
    for (const auto& [capture, ids] : ByCapture(corrections, keys, rig)) {
      Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
      for (ViewId id : ids) {
        const Eigen::Matrix3d& e = rig.at(keys[id]).second;
        sum += e.transpose() * corrections.at(id) * e;
      }
      const Eigen::Matrix3d mean = ProjectToSO3(sum);
      for (ViewId id : ids) {
        const Eigen::Matrix3d& e = rig.at(keys[id]).second;
        corrections[id] = e * mean * e.transpose();
      }
    }
  }
  // A keyframe the adjustment moved too far (a view its tracks hardly
  // hold, pulled by a few wrong ones) keeps what it had; more than a
  // quarter of them is a divergence, and nothing changes.
  std::size_t held_back = 0;
  double largest = 0.0;
  std::vector<double> moved_deg;
  for (auto it = corrections.begin(); ok && it != corrections.end();) {
    const double moved = RadToDeg(RotationAngleRad(it->second));
    if (moved > options_.max_correction_deg) {
      ++held_back;
      it = corrections.erase(it);
      continue;
    }
    largest = std::max(largest, moved);
    moved_deg.push_back(moved);
    ++it;
  }
  if (ok && held_back > 0) {
    std::ostringstream why;
    why << "; " << held_back << " of " << held_back + corrections.size() << " keyframes moved beyond "
        << options_.max_correction_deg << " deg (refinement_max_correction_deg)";
    if (4 * held_back > held_back + corrections.size()) {
      ok = false;
      why << ": the averaging's orientations kept";
    } else {
      why << ": those keep what they had";
    }
    report += why.str();
  }

  found.seconds = SecondsSince(start);
  found.iterations = summary.iterations;
  found.sequence = cameras.sequence;
  found.ok = ok;
  found.report = std::move(report);
  for (const auto& [id, c] : corrections) found.corrections.emplace(keys[id], c);
  // Every keyframe chosen, also one whose edges all lead to keyframes the
  // solution has not placed: another refinement of this solution would
  // find it the same.
  for (const KeyframeKey& key : input.window) found.tried.emplace(key, Tried{cameras.sequence, input.edges.at(key)});
  if (ok) {
    for (const auto& [id, c] : centres) found.centres.emplace(keys[id], c);
  }
  std::nth_element(moved_deg.begin(), moved_deg.begin() + moved_deg.size() / 2, moved_deg.end());
  found.median_deg = moved_deg.empty() ? 0.0 : moved_deg[moved_deg.size() / 2];
  found.largest_deg = largest;
  found.held_back = held_back;
  found.oldest_kept = input.oldest_kept;
  if (ok && with_covariance) found.covariances = Covariances(adjusted_covariance, cameras, keys, corrections, rig);
  std::lock_guard<std::mutex> lock(mutex_);
  if (staged) {
    staged_ = std::move(found);
    return ok;
  }
  return Take(found);
}

std::map<KeyframeKey, KeyframeRefiner::RelativeCovariance> KeyframeRefiner::Covariances(
    const BundleAdjustmentCovariance& adjusted, const OnlineSolution& cameras, const std::vector<KeyframeKey>& keys,
    const std::map<ViewId, Eigen::Matrix3d>& corrections, const RigCaptures& rig) {
  std::map<KeyframeKey, RelativeCovariance> out;
  if (adjusted.index.empty()) return out;
  // The reference: the corrected keyframe the averaging holds best (its
  // gauge keyframe, of covariance zero, when that is in the window).
  std::optional<ViewId> reference;
  double smallest = std::numeric_limits<double>::infinity();
  for (const auto& [id, c] : corrections) {
    const auto averaged = cameras.covariance.find(keys[id]);
    if (averaged == cameras.covariance.end() || !averaged->second.allFinite()) continue;
    if (averaged->second.trace() < smallest) {
      smallest = averaged->second.trace();
      reference = id;
    }
  }
  if (!reference) return out;
  const auto reference_rig = rig.find(keys[*reference]);
  // The reference capture's view of each camera: with each camera's own
  // covariance (refinement_rig_joint_covariance: false) a view is tied to
  // its own camera's views by its tracks, and to another camera's only
  // through the few tracks both see; relative to that camera's view of the
  // reference capture, which the rig's extrinsics hold to the reference.
  std::map<std::string, ViewId> reference_of_camera;
  if (reference_rig != rig.end()) {
    for (std::size_t v = 0; v < keys.size(); ++v) {
      const auto member = rig.find(keys[v]);
      if (member != rig.end() && member->second.first == reference_rig->second.first &&
          adjusted.index.count(static_cast<ViewId>(v))) {
        reference_of_camera.emplace(keys[v].frame_id, static_cast<ViewId>(v));
      }
    }
  }
  std::map<ViewId, Eigen::Matrix3d> relative;
  for (const auto& [id, c] : corrections) {
    const auto in_rig = rig.find(keys[id]);
    Eigen::Matrix3d covariance;
    const auto own_camera =
        in_rig == rig.end() ? reference_of_camera.end() : reference_of_camera.find(keys[id].frame_id);
    const ViewId against = own_camera == reference_of_camera.end() ? *reference : own_camera->second;
    if (id == *reference || (reference_rig != rig.end() && in_rig != rig.end() &&
                             in_rig->second.first == reference_rig->second.first)) {
      covariance.setZero();  // the reference's capture: held to it by the rig's extrinsics
    } else if (!adjusted.Relative(id, against, &covariance)) {
      continue;  // not tied to the reference by the tracks: the averaging's stays
    }
    relative[id] = covariance;
  }
  // The cameras of a rig capture share one correction, the mean of theirs in
  // the rig's frame, and the covariance of the camera its own tracks hold
  // best (the smallest trace): the capture is held at least as well as by
  // that camera's tracks alone. The mean of theirs let a camera that sees
  // little widen every capture; their information summed, or the joint
  // problem's, counts the cameras' tracks as independent, and was too
  // narrow on the two-camera 20 Hz stream (results/posterior.md, "A rig's covariances";
  // docs/decisions.md, "A rig capture's covariance").
  for (const auto& [capture, ids] : ByCapture(relative, keys, rig)) {
    Eigen::Matrix3d best;
    double smallest_trace = std::numeric_limits<double>::infinity();
    for (ViewId id : ids) {
      const Eigen::Matrix3d& e = rig.at(keys[id]).second;
      const Eigen::Matrix3d in_rig = e.transpose() * relative.at(id) * e;
      if (in_rig.trace() < smallest_trace) {
        smallest_trace = in_rig.trace();
        best = in_rig;
      }
    }
    for (ViewId id : ids) {
      const Eigen::Matrix3d& e = rig.at(keys[id]).second;
      relative[id] = e * best * e.transpose();
    }
  }
  for (const auto& [id, c] : relative) out[keys[id]] = RelativeCovariance{keys[*reference], c};
  return out;
}

bool KeyframeRefiner::Take(const Outcome& found) {
  ++stats_.runs;
  stats_.times.Add(found.seconds);
  stats_.last_ok = found.ok;
  stats_.last_report = found.report;
  stats_.last_iterations = found.iterations;
  if (!found.focal.empty()) {
    // The estimates were made with the focal lengths in use as it started.
    // A camera held since it agreed keeps its last estimate.
    for (auto it = stats_.focal.begin(); it != stats_.focal.end();) {
      it = focal_agreed_.count(it->first) ? std::next(it) : stats_.focal.erase(it);
    }
    for (auto [camera, e] : found.focal) {
      const auto then = found.camera_scales.find(camera);
      const auto now = camera_scales_.find(camera);
      ScaleEstimate((then == found.camera_scales.end() ? 1.0 : then->second) /
                        (now == camera_scales_.end() ? 1.0 : now->second),
                    &e);
      stats_.focal[camera] = e;
      if (options_.hold_agreed_focal && found.ok &&
          JudgeFocalEstimate(e, options_.focal_min_correction) == FocalVerdict::kAgrees) {
        focal_agreed_.insert(camera);
      }
    }
    stats_.focal_refinement = stats_.runs;
  }
  // A refinement that changed nothing has tried its keyframes all the
  // same: the same solution would fail the same way.
  for (const auto& [key, t] : found.tried) tried_[key] = t;
  if (!found.ok) {
    ++stats_.failed;
    return false;
  }
  for (const auto& [key, c] : found.corrections) corrections_[key] = c;
  for (const auto& [key, c] : found.covariances) covariances_[key] = c;
  centres_ = found.centres;
  ++stats_.applied;
  stats_.covariance_keyframes = covariances_.size();
  stats_.solution_sequence = found.sequence;
  stats_.corrected_keyframes = corrections_.size();
  stats_.median_correction_deg = found.median_deg;
  stats_.max_correction_deg = found.largest_deg;
  stats_.held_back = found.held_back;
  // Edges both of whose keyframes are older than the window will not be
  // refined again: let them go.
  if (!options_.sweep_back && found.oldest_kept) {
    const KeyframeKey& oldest_kept = *found.oldest_kept;
    for (auto it = edges_.begin(); it != edges_.end();) {
      if (Newer(oldest_kept, it->second.keyframe1) && Newer(oldest_kept, it->second.keyframe2)) {
        stats_.bytes -= EdgeBytes(*it->second.points);
        it = edges_.erase(it);
      } else {
        ++it;
      }
    }
    stats_.edges_held = edges_.size();
  }
  return true;
}

void KeyframeRefiner::LetGoBeyondBudget() {
  const double budget = options_.max_correspondence_mib * 1024.0 * 1024.0;
  if (static_cast<double>(stats_.bytes) <= budget) return;
  // Oldest first by the newer of the two keyframes: an edge goes when
  // neither of its keyframes is younger than those of the edges kept.
  std::vector<std::pair<KeyframeKey, std::pair<KeyframeKey, KeyframeKey>>> by_age;
  by_age.reserve(edges_.size());
  for (const auto& [key, held] : edges_) {
    by_age.emplace_back(Newer(held.keyframe1, held.keyframe2) ? held.keyframe1 : held.keyframe2, key);
  }
  std::sort(by_age.begin(), by_age.end(), [](const auto& a, const auto& b) {
    if (a.first == b.first) return a.second < b.second;
    return Newer(b.first, a.first);
  });
  // A tenth below the budget, so that the next edges do not sort them all again.
  for (const auto& [newer, key] : by_age) {
    if (static_cast<double>(stats_.bytes) <= 0.9 * budget) break;
    const auto it = edges_.find(key);
    stats_.bytes -= EdgeBytes(*it->second.points);
    edges_.erase(it);
  }
  stats_.edges_held = edges_.size();
}

bool KeyframeRefiner::RefineInBackground(std::shared_ptr<const OnlineSolution> cameras, RigCaptures rig,
                                         std::function<void(bool)> done, bool staged) {
  if (running_.exchange(true)) return false;
  if (background_.valid()) background_.get();  // finished: running_ was false
  Input input = SelectWindow(*cameras, rig);
  background_ = std::async(std::launch::async, [this, cameras = std::move(cameras), rig = std::move(rig),
                                                input = std::move(input), done = std::move(done), staged] {
    LowerThisThreadsPriority(options_.background_niceness);
    bool ok;
    {
      std::lock_guard<std::mutex> run(run_mutex_);
      ok = Run(*cameras, rig, input, staged);
    }
    // Before running_ falls: a refinement started from `done`, or waiting
    // in the starting thread for this one's end, would deadlock.
    if (done) done(ok);
    running_ = false;
  });
  return true;
}

void KeyframeRefiner::Wait() {
  if (background_.valid()) background_.get();
}

bool KeyframeRefiner::Commit() {
  Wait();
  std::lock_guard<std::mutex> lock(mutex_);
  if (!staged_) return false;
  const bool taken = Take(*staged_);
  staged_.reset();
  return taken;
}

void KeyframeRefiner::Reset() {
  std::lock_guard<std::mutex> lock(mutex_);
  edges_.clear();
  corrections_.clear();
  tried_.clear();
  covariances_.clear();
  centres_.clear();
  focal_agreed_.clear();
  staged_.reset();
  stats_.edges_held = 0;
  stats_.bytes = 0;
  stats_.corrected_keyframes = 0;
  stats_.covariance_keyframes = 0;
  stats_.focal.clear();
}

namespace {
constexpr char kCorrectionsHeader[] = "# rotation_averaging refinement v1";
}  // namespace

std::map<KeyframeKey, Eigen::Matrix3d> KeyframeRefiner::Corrections() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return corrections_;
}

void KeyframeRefiner::SetCorrections(const std::map<KeyframeKey, Eigen::Matrix3d>& corrections, bool replace) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (replace) corrections_.clear();
  for (const auto& [key, c] : corrections) corrections_.emplace(key, c);
  stats_.corrected_keyframes = corrections_.size();
}

bool KeyframeRefiner::SaveCorrections(const std::string& path, std::string* error) const {
  std::ostringstream body;
  body.precision(17);
  body << kCorrectionsHeader << "\n# CORRECTION frame_id stamp_ns qw qx qy qz (R_published = C R_averaged)\n";
  for (const auto& [key, c] : Corrections()) {
    if (key.frame_id.empty() || key.frame_id.find_first_of(" \t\r\n") != std::string::npos) {
      if (error) *error = "frame id '" + key.frame_id + "' is empty or contains whitespace";
      return false;
    }
    const Eigen::Vector4d q = RotationToQuaternion(c);
    body << "CORRECTION " << key.frame_id << ' ' << key.stamp_ns << ' ' << q[0] << ' ' << q[1] << ' ' << q[2] << ' '
         << q[3] << '\n';
  }
  const std::string text = body.str();
  return WriteFileAtomically(path, [&](std::ostream& out) -> std::string {
    out << text << EndRecord(text);
    return "";
  }, error);
}

bool KeyframeRefiner::ReadCorrections(const std::string& path, std::map<KeyframeKey, Eigen::Matrix3d>* corrections,
                                      std::string* error) {
  std::map<KeyframeKey, Eigen::Matrix3d> read;
  auto record = [&](const std::vector<std::string_view>& tokens, std::string* why) {
    std::uint64_t stamp = 0;
    double q[4];
    if (tokens.size() != 7 || tokens[0] != "CORRECTION" || !ParseUint64(tokens[2], &stamp) ||
        !ParseQuaternion(&tokens[3], q)) {
      *why = "expected 'CORRECTION frame_id stamp_ns qw qx qy qz'";
      return false;
    }
    if (!IsUnitQuaternion(q)) {
      *why = "not a unit quaternion";
      return false;
    }
    const KeyframeKey key{std::string(tokens[1]), static_cast<std::int64_t>(stamp)};
    if (!read.emplace(key, QuaternionToRotation(q[0], q[1], q[2], q[3])).second) {
      *why = "keyframe listed twice";
      return false;
    }
    return true;
  };
  if (!ReadEndRecordedFile(path, kCorrectionsHeader, "refinement", record, error)) return false;
  *corrections = std::move(read);
  return true;
}

void KeyframeRefiner::Apply(OnlineSolution* cameras) const {
  std::lock_guard<std::mutex> lock(mutex_);
  for (auto& [key, r] : cameras->orientations) {
    const auto c = corrections_.find(key);
    if (c != corrections_.end()) r = c->second * r;
  }
  cameras->refinement_sequence = stats_.applied;
  // Relative to the component's gauge keyframe: the reference's own
  // covariance in this solution, carried into the keyframe's frame. All
  // computed before any is replaced (a reference is corrected too).
  std::vector<std::pair<KeyframeKey, Eigen::Matrix3d>> adjusted;
  for (const auto& [key, held] : covariances_) {
    const auto own = cameras->covariance.find(key);
    const auto reference = cameras->covariance.find(held.reference);
    const auto component = cameras->component.find(key);
    const auto reference_component = cameras->component.find(held.reference);
    const auto orientation = cameras->orientations.find(key);
    const auto reference_orientation = cameras->orientations.find(held.reference);
    if (own == cameras->covariance.end() || reference == cameras->covariance.end() ||
        component == cameras->component.end() || reference_component == cameras->component.end() ||
        component->second != reference_component->second || orientation == cameras->orientations.end() ||
        reference_orientation == cameras->orientations.end()) {
      continue;
    }
    const Eigen::Matrix3d r = orientation->second * reference_orientation->second.transpose();
    adjusted.emplace_back(key, held.covariance + r * reference->second * r.transpose());
  }
  for (const auto& [key, c] : adjusted) cameras->covariance[key] = c;
}

KeyframeRefinerStats KeyframeRefiner::Stats() const {
  std::lock_guard<std::mutex> lock(mutex_);
  KeyframeRefinerStats out = stats_;
  out.focal_agreed = focal_agreed_;
  return out;
}

}  // namespace rotation_averaging
