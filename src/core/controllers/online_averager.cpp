#include "rotation_averaging/core/controllers/online_averager.h"

#include "rotation_averaging/core/geometry/so3.h"

#include <algorithm>
#include <set>

#include "rotation_averaging/core/eval/rotation_evaluation.h"
#include "rotation_averaging/core/io/graph_io.h"
#include "rotation_averaging/util/text_lines.h"
#include "rotation_averaging/util/option_check.h"

namespace rotation_averaging {

using Clock = std::chrono::steady_clock;

bool OnlineAveragerOptions::Validate(std::string* error) const {
  std::string averaging_error;
  return OptionCheck()
      .NotNan("solve_period_s", solve_period_s)
      .AtLeast("max_queue", static_cast<double>(max_queue), 1)
      .AtLeast("max_views", static_cast<double>(max_views), 2)
      .AtLeast("max_edges", static_cast<double>(max_edges), 1)
      .AtLeast("local_solve_hops", local.hops, 1)
      .AtLeast("local_solve_max_views", static_cast<double>(local.max_views), 1)
      .AtLeast("full_solve_every", full_solve_every, 1)
      .Require(averaging.Validate(&averaging_error), averaging_error)
      .Ok(error);
}

OnlineAverager::OnlineAverager(const OnlineAveragerOptions& options)
    : options_(options), solution_(std::make_shared<OnlineSolution>()) {
  solve_period_s_ = options.solve_period_s;
}

void OnlineAverager::SetSolvePeriod(double seconds) {
  solve_period_s_ = seconds;
  RequestSolve();  // wake the worker so the new period applies now
}

OnlineAverager::~OnlineAverager() { Stop(); }

std::string OnlineAverager::KeyframeName(const KeyframeKey& key) {
  return key.frame_id + "@" + std::to_string(key.stamp_ns);
}

bool OnlineAverager::ParseKeyframeName(const std::string& name, KeyframeKey* key) {
  const std::size_t at = name.rfind('@');
  if (at == std::string::npos || at == 0) return false;
  std::int64_t stamp = 0;
  try {
    std::size_t used = 0;
    stamp = std::stoll(name.substr(at + 1), &used);
    if (used != name.size() - at - 1) return false;
  } catch (const std::exception&) {
    return false;
  }
  key->frame_id = name.substr(0, at);
  key->stamp_ns = stamp;
  return true;
}

bool OnlineAverager::AddRelativeRotation(const KeyframeRelativeRotation& m, std::string* error, bool* queue_full) {
  if (queue_full) *queue_full = false;
  auto reject = [&](const std::string& why, std::uint64_t OnlineAveragerStats::*counter) {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++(stats_.*counter);
    if (error) *error = why;
    return false;
  };
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++stats_.received;
  }
  if (m.keyframe1.frame_id.empty() || m.keyframe2.frame_id.empty()) {
    return reject("empty camera frame id", &OnlineAveragerStats::rejected_invalid);
  }
  if (m.keyframe1.frame_id.find_first_of(" \t\r\n@") != std::string::npos ||
      m.keyframe2.frame_id.find_first_of(" \t\r\n@") != std::string::npos) {
    return reject("camera frame id contains whitespace or '@'", &OnlineAveragerStats::rejected_invalid);
  }
  if (!(m.keyframe1 < m.keyframe2) && !(m.keyframe2 < m.keyframe1)) {
    return reject("a keyframe related to itself (" + KeyframeName(m.keyframe1) + ")",
                  &OnlineAveragerStats::rejected_invalid);
  }
  // Validate rotation and covariance exactly as the graph will.
  RelativeRotation probe;
  probe.view1 = 0;
  probe.view2 = 1;
  probe.rotation = m.rotation;
  probe.has_covariance = m.has_covariance;
  probe.covariance = m.covariance;
  probe.num_inliers = m.num_inliers;
  std::string why;
  bool repaired = false;
  if (!validator_.ValidateEdge(&probe, &why, &repaired)) {
    return reject(why, &OnlineAveragerStats::rejected_invalid);
  }
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    if (queue_.size() >= options_.max_queue) {
      if (queue_full) *queue_full = true;
      return reject("input queue full (" + std::to_string(options_.max_queue) + ")",
                    &OnlineAveragerStats::dropped_queue_full);
    }
    queue_.push_back(m);
  }
  if (m.source == EdgeSource::kLoopClosure && options_.solve_early_on_loop_closure) RequestSolve();
  return true;
}

std::size_t OnlineAverager::DrainQueue() {
  std::deque<KeyframeRelativeRotation> pending;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    pending.swap(queue_);
  }
  std::size_t applied = 0;
  std::uint64_t accepted = 0, rejected = 0, capped = 0;
  for (const KeyframeRelativeRotation& m : pending) {
    ViewId ids[2];
    bool ok = true;
    for (int k = 0; k < 2 && ok; ++k) {
      const KeyframeKey& key = k == 0 ? m.keyframe1 : m.keyframe2;
      auto it = ids_.find(key);
      if (it != ids_.end()) {
        ids[k] = it->second;
      } else if (graph_.NumViews() >= options_.max_views) {
        ok = false;
      } else {
        const ViewId id = keys_.size();
        ids_[key] = id;
        keys_.push_back(key);
        const std::string name = KeyframeName(key);
        graph_.AddView(id, name);
        if (background_graph_valid_) RecordAddition(GraphAddition{id, name, false, RelativeRotation()});
        new_views_.push_back(id);
        ids[k] = id;
      }
    }
    if (!ok || graph_.NumEdges() >= options_.max_edges) {
      ++capped;
      continue;
    }
    RelativeRotation edge;
    edge.view1 = ids[0];
    edge.view2 = ids[1];
    edge.rotation = m.rotation;
    edge.has_covariance = m.has_covariance;
    edge.covariance = m.covariance;
    edge.num_inliers = m.num_inliers;
    edge.source = m.source;
    edge.channel = m.channel;
    if (graph_.AddEdge(edge) == AddEdgeResult::kRejected) {
      ++rejected;
    } else {
      if (background_graph_valid_) RecordAddition(GraphAddition{0, std::string(), true, edge});
      ++accepted;
      ++applied;
      if (edge.source == EdgeSource::kLoopClosure) loop_closure_since_full_ = true;
      for (ViewId id : ids) {
        if (id >= changed_flag_.size()) changed_flag_.resize(id + 1, 0);
        if (!changed_flag_[id]) {
          changed_flag_[id] = 1;
          changed_.push_back(id);
        }
      }
    }
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  stats_.accepted += accepted;
  stats_.rejected_invalid += rejected;
  stats_.dropped_cap += capped;
  stats_.views = graph_.NumViews();
  stats_.edges = graph_.NumEdges();
  return applied;
}

void OnlineAverager::RecordAddition(GraphAddition addition) {
  background_additions_.push_back(std::move(addition));
  // Past half the graph's edges a copy is cheaper than the replay it saves
  // (and the list would grow without bound while no background solve starts).
  if (background_additions_.size() > graph_.NumEdges() / 2 + 64) {
    background_graph_valid_ = false;
    background_additions_.clear();
  }
}

OnlineAverager::FullSolve OnlineAverager::RunFullSolve(ViewGraph* background_graph, std::vector<GraphAddition> additions,
                                                      const RotationAveragingOptions& options,
                                                      ViewOrientations orientations, std::uint64_t generation) {
  // The same calls, in the same order, on a copy of the graph they were made
  // on leave the same graph.
  for (const GraphAddition& a : additions) {
    if (a.is_edge) {
      background_graph->AddEdge(a.edge);
    } else {
      background_graph->AddView(a.view, a.name);
    }
  }
  const ViewGraph& graph = *background_graph;
  FullSolve result;
  result.generation = generation;
  result.ok = SolveRotationAveraging(graph, options, &orientations, &result.summary);
  result.orientations = std::move(orientations);
  result.components = graph.ConnectedComponents();
  return result;
}

void OnlineAverager::TakeComponents(const std::vector<std::vector<ViewId>>& components,
                                    const RotationAveragingSummary& summary) {
  component_label_.assign(keys_.size(), -1);
  label_scale_.assign(components.size(), 0.0);
  for (std::size_t c = 0; c < components.size(); ++c) {
    if (components[c].size() < 2) continue;
    for (ViewId id : components[c]) {
      if (id < component_label_.size()) component_label_[id] = static_cast<int>(c);
    }
  }
  for (const ComponentSummary& cs : summary.components) {
    if (cs.gauge_view < component_label_.size() && component_label_[cs.gauge_view] >= 0) {
      label_scale_[component_label_[cs.gauge_view]] = cs.loss_scale;
    }
  }
}

bool OnlineAverager::SolveLocked(bool force_full) {
  ViewOrientations orientations;
  RotationAveragingOptions averaging;
  std::uint64_t generation = 0, options_epoch = 0;
  std::vector<ViewId> changed;
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    DrainQueue();
    generation = generation_;
    options_epoch = options_epoch_;
    orientations = warm_start_;
    averaging = options_.averaging;
  }
  changed.swap(changed_);
  for (ViewId id : changed) changed_flag_[id] = 0;
  // graph_, ids_ and keys_ change only under solve_mutex_, which this thread holds
  // (DrainQueue above, Reset, LoadGraph): read them in place rather than copy
  // them (a copy of a large graph was a sizeable part of a re-solve).
  if (graph_.NumEdges() == 0) return false;
  const auto start = Clock::now();
  auto solution = std::make_shared<OnlineSolution>();
  const bool cold = orientations.empty();
  const bool local_enabled = options_.local_solve_min_views > 0 && graph_.NumViews() >= options_.local_solve_min_views &&
                             averaging.solver != SolverType::kL1Irls && !cold && !force_full;
  std::map<KeyframeKey, Eigen::Matrix3d> background_covariances;
  const bool took_background =
      TakeBackgroundSolve(generation, force_full, cold, &orientations, &changed, &background_covariances);
  const SolveRun run = RunSolve(averaging, local_enabled, took_background, changed, &orientations, &solution->summary);
  if (run.ok && !run.local) KeepPublishedFrames(run.components, &orientations);
  RecordSolve(run.ok, run.local, std::chrono::duration<double>(Clock::now() - start).count(), solution->summary);
  if (!run.ok) {
    // The previous good solution stays published.
    RequeueChanged(changed);
    return false;
  }
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    if (generation != generation_) return false;  // reset or reloaded while solving: discard
  }
  FillSolution(run, took_background, orientations, std::move(background_covariances), solution.get());
  if (run.local) MaybeStartBackgroundSolve(orientations, averaging, generation);
  Publish(solution, options_epoch, &orientations);
  return true;
}

bool OnlineAverager::TakeBackgroundSolve(std::uint64_t generation, bool force_full, bool cold,
                                         ViewOrientations* orientations, std::vector<ViewId>* changed,
                                         std::map<KeyframeKey, Eigen::Matrix3d>* covariances) {
  // One still running is never waited for.
  bool took = false;
  if (background_.valid() && background_.wait_for(std::chrono::seconds(0)) == std::future_status::ready) {
    FullSolve full = background_.get();
    if (!background_stale_ && !force_full && !cold && full.ok && full.generation == generation) {
      // Views that came after the snapshot keep their current orientations
      // and are re-solved locally around them.
      KeepPublishedFrames(full.components, &full.orientations);
      for (auto& [id, r] : full.orientations) (*orientations)[id] = r;
      TakeComponents(full.components, full.summary);
      edge_results_ = std::move(full.summary.edges);
      *covariances = CovariancesByKey(full.summary.view_covariances);
      for (ViewId id : changed_since_snapshot_) changed->push_back(id);
      took = true;
      local_solves_since_full_ = 0;
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++stats_.background_solves;
    } else {
      // Dropped: the keyframes it would have started from the tree are new
      // again for the next full solve.
      new_views_.insert(new_views_.end(), snapshot_new_views_.begin(), snapshot_new_views_.end());
    }
    snapshot_new_views_.clear();
    changed_since_snapshot_.clear();
    background_stale_ = false;
  }
  if (background_.valid()) changed_since_snapshot_.insert(changed_since_snapshot_.end(), changed->begin(), changed->end());
  return took;
}

OnlineAverager::SolveRun OnlineAverager::RunSolve(const RotationAveragingOptions& averaging, bool local_enabled,
                                                  bool took_background, const std::vector<ViewId>& changed,
                                                  ViewOrientations* orientations, RotationAveragingSummary* summary) {
  SolveRun run;
  // A loop closure makes the full solve due at once: a local solve moves only
  // the neighbourhoods of its two ends, while the loop's error belongs spread
  // over the whole loop.
  const bool full_due =
      (local_solves_since_full_ >= options_.full_solve_every || loop_closure_since_full_) && !options_.background_full_solves;
  if (local_enabled && (!full_due || took_background)) {
    if (changed.empty()) {
      run.local = true;  // nothing new beyond a background solve taken
      run.ok = true;
      summary->edges.assign(graph_.NumEdges(), EdgeResult());
    } else {
      LocalSolveOptions local_options = options_.local;
      local_options.component_labels = &component_label_;
      local_options.label_loss_scale = &label_scale_;
      const LocalSolveOutcome outcome =
          SolveRotationAveragingLocally(graph_, changed, local_options, averaging, orientations, summary);
      // kNeedsFullSolve leaves the orientations as they were; after kFailed
      // the full solve below starts from the region's initial orientations.
      run.ok = run.local = outcome == LocalSolveOutcome::kSolved || outcome == LocalSolveOutcome::kNothingToSolve;
    }
    if (run.local) ++local_solves_since_full_;
  }
  if (!run.local) {
    background_stale_ = background_.valid();
    // Keyframes added since the last full solve start from the spanning tree
    // rather than from where local solves put them: the full solve then runs
    // the robust start (L1 + GNC) when the start disagrees with the edges, as
    // it does when every solve is a full one, and repairs what the local
    // solves placed wrongly.
    StartFromTree(orientations);
    run.components = graph_.ConnectedComponents();
    StartJoinedComponentsFromTree(run.components, orientations);
    run.ok = SolveRotationAveraging(graph_, averaging, orientations, summary);
    local_solves_since_full_ = 0;
    loop_closure_since_full_ = false;
  }
  return run;
}

void OnlineAverager::KeepPublishedFrames(const std::vector<std::vector<ViewId>>& components,
                                         ViewOrientations* orientations) const {
  const std::shared_ptr<const OnlineSolution> previous = Solution();
  if (previous->orientations.empty()) return;
  // The frame is fitted on at most this many of a component's keyframes,
  // evenly spread: the fit is robust and the corrections of a re-solve are
  // small, while a fit on every keyframe of a large map would cost the
  // solve that takes a background solve tens of milliseconds.
  constexpr std::size_t kFrameSample = 256;
  for (const std::vector<ViewId>& component : components) {
    // The component (of the last full solve) most of these keyframes were
    // in; -1: keyframes that came since, or a map just loaded.
    const int keep = MostViewsLabel(component, /*count_unlabelled=*/true).first;
    std::vector<ViewId> members;
    for (ViewId id : component) {
      if (LabelOf(id) == keep) members.push_back(id);
    }
    const std::size_t stride = std::max<std::size_t>(1, members.size() / kFrameSample);
    std::vector<Eigen::Matrix3d> before, after;
    for (std::size_t k = 0; k < members.size(); k += stride) {
      const ViewId id = members[k];
      if (id >= keys_.size()) continue;
      const auto published = previous->orientations.find(keys_[id]);
      const auto solved = orientations->find(id);
      if (published == previous->orientations.end() || solved == orientations->end()) continue;
      before.push_back(published->second);
      after.push_back(solved->second);
    }
    if (before.empty()) continue;
    const Eigen::Matrix3d g = AlignRotations(before, after);  // after ~ before * g
    for (ViewId id : component) {
      const auto it = orientations->find(id);
      if (it != orientations->end()) it->second = it->second * g.transpose();
    }
  }
}

void OnlineAverager::RecordSolve(bool ok, bool local, double seconds, const RotationAveragingSummary& summary) {
  std::lock_guard<std::mutex> lock(stats_mutex_);
  ++stats_.solves;
  stats_.local_solves += local;
  stats_.last_solve_s = seconds;
  if (!ok) ++stats_.failed_solves;
  if (!local) stats_.components = summary.components.size();
  stats_.outlier_edges = summary.num_outlier_edges;
}

void OnlineAverager::RequeueChanged(const std::vector<ViewId>& changed) {
  for (ViewId id : changed) {
    if (id < changed_flag_.size() && !changed_flag_[id]) {
      changed_flag_[id] = 1;
      changed_.push_back(id);
    }
  }
}

void OnlineAverager::FillSolution(const SolveRun& run, bool took_background, const ViewOrientations& orientations,
                                  std::map<KeyframeKey, Eigen::Matrix3d> background_covariances,
                                  OnlineSolution* solution) {
  const std::vector<RelativeRotation>& graph_edges = graph_.Edges();
  edge_results_.resize(graph_edges.size());
  if (!run.local) {
    TakeComponents(run.components, solution->summary);
    edge_results_ = solution->summary.edges;
    solution->covariance = CovariancesByKey(solution->summary.view_covariances);
  } else {
    // Only the region changed: its edges' results; the posterior
    // covariances of the last full solve (keyframes since have none yet).
    for (std::size_t k = 0; k < graph_edges.size() && k < solution->summary.edges.size(); ++k) {
      if (solution->summary.edges[k].solved) edge_results_[k] = solution->summary.edges[k];
    }
    solution->covariance = took_background ? std::move(background_covariances) : Solution()->covariance;
    solution->local = true;
  }
  // ids_ is in key order: the published maps are built by appending at
  // their end (O(n)) rather than by n searches with string comparisons.
  for (const auto& [key, id] : ids_) {
    if (id < component_label_.size() && component_label_[id] >= 0) {
      solution->component.emplace_hint(solution->component.end(), key, component_label_[id]);
    }
    const auto it = orientations.find(id);
    if (it != orientations.end()) solution->orientations.emplace_hint(solution->orientations.end(), key, it->second);
  }
  solution->edges.reserve(graph_edges.size());
  for (std::size_t k = 0; k < graph_edges.size(); ++k) {
    const EdgeResult& result = edge_results_[k];
    if (!result.solved || graph_edges[k].view1 >= keys_.size() || graph_edges[k].view2 >= keys_.size()) continue;
    solution->edges.push_back(SolvedEdge{keys_[graph_edges[k].view1], keys_[graph_edges[k].view2],
                                         graph_edges[k].source, RadToDeg(result.residual_rad), result.robust_weight});
  }
}

void OnlineAverager::MaybeStartBackgroundSolve(const ViewOrientations& orientations,
                                               const RotationAveragingOptions& averaging, std::uint64_t generation) {
  if (!options_.background_full_solves || background_.valid() ||
      !(local_solves_since_full_ >= options_.full_solve_every || loop_closure_since_full_)) {
    return;
  }
  ViewOrientations start_from = orientations;
  snapshot_new_views_ = new_views_;
  StartFromTree(&start_from);
  loop_closure_since_full_ = false;
  // No background solve is running (background_ is not valid), so its
  // graph can be replaced here.
  std::vector<GraphAddition> additions;
  if (!background_graph_valid_) {
    background_graph_ = std::make_unique<ViewGraph>(graph_);
    background_graph_valid_ = true;
  } else {
    additions.swap(background_additions_);
  }
  background_additions_.clear();
  background_ = std::async(std::launch::async, &OnlineAverager::RunFullSolve, background_graph_.get(),
                           std::move(additions), averaging, std::move(start_from), generation);
  changed_since_snapshot_.clear();
  background_stale_ = false;
}

void OnlineAverager::Publish(std::shared_ptr<OnlineSolution> solution, std::uint64_t options_epoch,
                             ViewOrientations* orientations) {
  {
    // The next solve starts here (Reset and LoadGraph, which clear it, wait
    // for solve_mutex_; SetAveragingOptions may have cleared it meanwhile:
    // then the next solve is cold, as asked).
    std::lock_guard<std::mutex> lock(graph_mutex_);
    if (options_epoch == options_epoch_) warm_start_.swap(*orientations);
  }
  std::function<void(std::shared_ptr<const OnlineSolution>)> callback;
  {
    std::lock_guard<std::mutex> lock(solution_mutex_);
    solution->sequence = solution_->sequence + 1;
    solution_ = solution;
    callback = callback_;
  }
  if (callback) callback(solution);
}

std::map<KeyframeKey, Eigen::Matrix3d> OnlineAverager::CovariancesByKey(
    const std::map<ViewId, Eigen::Matrix3d>& by_id) const {
  // In key order (ids_), appended at the end: O(n), no key comparisons.
  std::map<KeyframeKey, Eigen::Matrix3d> by_key;
  if (by_id.empty()) return by_key;
  for (const auto& [key, id] : ids_) {
    const auto it = by_id.find(id);
    if (it != by_id.end()) by_key.emplace_hint(by_key.end(), key, it->second);
  }
  return by_key;
}

void OnlineAverager::StartFromTree(ViewOrientations* orientations) {
  for (ViewId id : new_views_) orientations->erase(id);
  new_views_.clear();
}

void OnlineAverager::StartJoinedComponentsFromTree(const std::vector<std::vector<ViewId>>& components,
                                                   ViewOrientations* orientations) const {
  for (const std::vector<ViewId>& component : components) {
    const auto [keep, labels] = MostViewsLabel(component, /*count_unlabelled=*/false);
    if (labels < 2) continue;
    for (ViewId id : component) {
      const int label = LabelOf(id);
      if (label >= 0 && label != keep) orientations->erase(id);
    }
  }
}

int OnlineAverager::LabelOf(ViewId id) const {
  return id < component_label_.size() ? component_label_[id] : -1;
}

std::pair<int, std::size_t> OnlineAverager::MostViewsLabel(const std::vector<ViewId>& component,
                                                           bool count_unlabelled) const {
  std::map<int, std::size_t> count;  // previous label -> keyframes
  for (ViewId id : component) {
    const int label = LabelOf(id);
    if (label >= 0 || count_unlabelled) ++count[label];
  }
  if (count.empty()) return {-1, 0};
  int keep = count.begin()->first;
  for (const auto& [label, n] : count) {
    if (n > count[keep]) keep = label;
  }
  return {keep, count.size()};
}

void OnlineAverager::ClearLocalState() {
  loop_closure_since_full_ = false;
  new_views_.clear();
  snapshot_new_views_.clear();
  changed_.clear();
  changed_flag_.clear();
  changed_since_snapshot_.clear();
  component_label_.clear();
  label_scale_.clear();
  edge_results_.clear();
  local_solves_since_full_ = 0;
  background_stale_ = background_.valid();  // its generation is gone as well
  // The graph was replaced: the next background solve starts from a copy.
  // (One still running keeps using its graph until it is taken.)
  background_graph_valid_ = false;
  background_additions_.clear();
}

bool OnlineAverager::SolveNow() {
  std::lock_guard<std::mutex> lock(solve_mutex_);
  return SolveLocked(false);
}

bool OnlineAverager::SolveFullNow() {
  std::lock_guard<std::mutex> lock(solve_mutex_);
  return SolveLocked(true);
}

void OnlineAverager::RequestSolve() {
  {
    std::lock_guard<std::mutex> lock(wake_mutex_);
    wake_requested_ = true;
  }
  wake_.notify_one();
}

void OnlineAverager::Start() {
  if (running_.exchange(true)) return;
  worker_ = std::thread(&OnlineAverager::WorkerLoop, this);
}

void OnlineAverager::Stop() {
  if (!running_.exchange(false)) return;
  wake_.notify_all();
  if (worker_.joinable()) worker_.join();
}

void OnlineAverager::WorkerLoop() {
  auto period_now = [this] {
    const double seconds = solve_period_s_.load();
    return std::make_pair(seconds > 0.0, std::chrono::duration_cast<Clock::duration>(
                                             std::chrono::duration<double>(seconds > 0.0 ? seconds : 3600.0)));
  };
  auto next = Clock::now() + period_now().second;
  while (running_) {
    {
      std::unique_lock<std::mutex> lock(wake_mutex_);
      wake_.wait_until(lock, next, [this] { return wake_requested_ || !running_; });
      wake_requested_ = false;
    }
    if (!running_) break;
    const auto start = Clock::now();
    bool pending = false;
    {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      pending = !queue_.empty();
    }
    if (force_solve_.exchange(false) || pending || Solution()->sequence == 0) SolveNow();
    const auto [periodic, period] = period_now();
    next = start + period;
    if (periodic && Clock::now() > next) {
      // Overran the period: report it and start the next period now rather
      // than stacking solves to catch up.
      std::lock_guard<std::mutex> lock(stats_mutex_);
      ++stats_.overruns;
      next = Clock::now() + period;
    }
  }
}

void OnlineAverager::Reset() {
  std::lock_guard<std::mutex> solve_lock(solve_mutex_);
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    queue_.clear();
  }
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    graph_.Clear();
    ids_.clear();
    keys_.clear();
    warm_start_.clear();
    ++generation_;
  }
  ClearLocalState();
  {
    std::lock_guard<std::mutex> lock(solution_mutex_);
    auto empty = std::make_shared<OnlineSolution>();
    empty->sequence = solution_->sequence + 1;
    solution_ = empty;
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  stats_.views = stats_.edges = stats_.components = stats_.outlier_edges = 0;
}

void OnlineAverager::SetAveragingOptions(const RotationAveragingOptions& options) {
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    options_.averaging = options;
    ++options_epoch_;
    // Start the next solve cold (spanning tree + robust start): a warm start
    // from a solution of another loss can sit in that loss's basin (measured:
    // MAGSAC warm-started from a squared-loss solution stayed 5x off).
    warm_start_.clear();
  }
  force_solve_ = true;
  RequestSolve();
}

std::shared_ptr<const OnlineSolution> OnlineAverager::Solution() const {
  std::lock_guard<std::mutex> lock(solution_mutex_);
  return solution_;
}

std::map<EdgeSource, std::size_t> OnlineAverager::EdgesBySource() const {
  std::map<EdgeSource, std::size_t> counts;
  std::lock_guard<std::mutex> lock(graph_mutex_);
  for (const RelativeRotation& e : graph_.Edges()) ++counts[e.source];
  return counts;
}

OnlineAveragerStats OnlineAverager::Stats() const {
  std::size_t queued = 0;
  {
    std::lock_guard<std::mutex> lock(queue_mutex_);
    queued = queue_.size();
  }
  std::lock_guard<std::mutex> lock(stats_mutex_);
  OnlineAveragerStats s = stats_;
  s.queued = queued;
  return s;
}

void OnlineAverager::SetSolutionCallback(std::function<void(std::shared_ptr<const OnlineSolution>)> callback) {
  std::lock_guard<std::mutex> lock(solution_mutex_);
  callback_ = std::move(callback);
}

void OnlineAverager::SnapshotGraph(ViewGraph* graph, std::map<ViewId, Eigen::Matrix3d>* orientations) const {
  const std::shared_ptr<const OnlineSolution> solution = Solution();
  orientations->clear();
  std::lock_guard<std::mutex> lock(graph_mutex_);
  *graph = graph_;
  // The published orientations go with the graph: a restarted node starts
  // from them and keeps the frames it published (LoadGraph).
  for (const auto& [key, r] : solution->orientations) {
    const auto it = ids_.find(key);
    if (it != ids_.end()) orientations->emplace(it->second, r);
  }
}

void OnlineAverager::PendingGraph(ViewGraph* graph, std::map<KeyframeKey, ViewId>* ids, ViewOrientations* start) {
  std::lock_guard<std::mutex> solve_lock(solve_mutex_);
  std::lock_guard<std::mutex> lock(graph_mutex_);
  DrainQueue();
  *graph = graph_;
  *ids = ids_;
  *start = warm_start_;
}

bool OnlineAverager::SaveGraph(const std::string& path, std::string* error) const {
  ViewGraph graph;
  std::map<ViewId, Eigen::Matrix3d> orientations;
  SnapshotGraph(&graph, &orientations);
  return WriteRotavgGraph(path, graph, error, &orientations);
}

bool ReadSavedKeyframeGraph(const std::string& path, SavedKeyframeGraph* saved, std::string* error) {
  *saved = SavedKeyframeGraph();
  saved->path = path;
  const ReadReport report = ReadRotavgGraph(path, &saved->graph, &saved->orientations);
  if (!report.ok()) {
    if (error) *error = report.error;
    return false;
  }
  saved->warnings = report.warnings;
  std::set<KeyframeKey> seen;
  for (const View& v : saved->graph.Views()) {
    KeyframeKey& key = saved->keys[v.id];
    if (!OnlineAverager::ParseKeyframeName(v.name, &key)) {
      if (error) *error = path + ": view '" + v.name + "' is not named <frame_id>@<stamp_ns>";
      return false;
    }
    if (!seen.insert(key).second) {
      if (error) *error = path + ": two views are named '" + v.name + "'";
      return false;
    }
  }
  return true;
}

bool OnlineAverager::LoadGraph(const std::string& path, std::string* error) {
  SavedKeyframeGraph saved;
  return ReadSavedKeyframeGraph(path, &saved, error) && LoadGraph(saved, error);
}

bool OnlineAverager::LoadGraph(const SavedKeyframeGraph& saved, std::string* error) {
  return TakeGraph(saved, /*replace=*/true, nullptr, error);
}

bool OnlineAverager::AddGraph(const std::string& path, AddedGraph* added, std::string* error) {
  SavedKeyframeGraph saved;
  return ReadSavedKeyframeGraph(path, &saved, error) && AddGraph(saved, added, error);
}

bool OnlineAverager::AddGraph(const SavedKeyframeGraph& saved, AddedGraph* added, std::string* error) {
  return TakeGraph(saved, /*replace=*/false, added, error);
}

bool OnlineAverager::TakeGraph(const SavedKeyframeGraph& saved, bool replace, AddedGraph* added,
                               std::string* error) {
  const ViewGraph& loaded = saved.graph;
  AddedGraph result;
  {
    std::lock_guard<std::mutex> solve_lock(solve_mutex_);
    {
      std::lock_guard<std::mutex> lock(graph_mutex_);
      const std::size_t views_held = replace ? 0 : graph_.NumViews(), edges_held = replace ? 0 : graph_.NumEdges();
      if (views_held + loaded.NumViews() > options_.max_views || edges_held + loaded.NumEdges() > options_.max_edges) {
        if (error) *error = saved.path + ": the map would exceed max_views or max_edges";
        return false;
      }
      if (replace) {
        graph_.Clear();
        ids_.clear();
        keys_.clear();
        warm_start_.clear();
        std::lock_guard<std::mutex> queue_lock(queue_mutex_);
        queue_.clear();
      }
      // A keyframe already held is the same keyframe: maps saved from one
      // history (a session that loaded the other's map) share it, and the
      // edges among such keyframes, which are held already.
      std::map<ViewId, ViewId> id_of;
      std::set<ViewId> held;
      for (const auto& [old_id, key] : saved.keys) {
        const auto it = ids_.find(key);
        if (it != ids_.end()) {
          id_of[old_id] = it->second;
          held.insert(old_id);
          continue;
        }
        const ViewId id = keys_.size();
        ids_[key] = id;
        keys_.push_back(key);
        graph_.AddView(id, KeyframeName(key));
        id_of[old_id] = id;
        ++result.views;
      }
      result.views_held = held.size();
      for (RelativeRotation e : loaded.Edges()) {
        if (held.count(e.view1) && held.count(e.view2)) {
          ++result.edges_held;
          continue;
        }
        e.view1 = id_of.at(e.view1);
        e.view2 = id_of.at(e.view2);
        if (graph_.AddEdge(e, nullptr, DuplicatePolicy::kKeepBoth) != AddEdgeResult::kRejected) ++result.edges;
      }
      // The keyframes start where their map had them (its gauge views keep
      // them, so they stay in the frames published before the save), in the
      // frame of the keyframes held if the maps share some (one rotation
      // fitted on those), else in their map's own frame: a component of
      // their own until a loop closure joins it to another.
      std::vector<Eigen::Matrix3d> mine, theirs;
      for (const auto& [old_id, r] : saved.orientations) {
        if (!held.count(old_id)) continue;
        const auto it = warm_start_.find(id_of.at(old_id));
        if (it == warm_start_.end()) continue;
        mine.push_back(it->second);
        theirs.push_back(r);
      }
      const Eigen::Matrix3d g = mine.empty() ? Eigen::Matrix3d::Identity() : AlignRotations(mine, theirs);
      for (const auto& [old_id, r] : saved.orientations) {
        if (!held.count(old_id)) warm_start_[id_of.at(old_id)] = mine.empty() ? r : Eigen::Matrix3d(r * g.transpose());
      }
      ++generation_;
    }
    ClearLocalState();
    SolveLocked(true);
  }
  if (added) *added = result;
  if (!saved.warnings.empty() && error) *error = saved.warnings.front();
  return true;
}

}  // namespace rotation_averaging
