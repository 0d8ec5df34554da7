#include "rotation_averaging/controllers/online_averager.h"

#include "rotation_averaging/geometry/so3.h"

#include <algorithm>

#include "rotation_averaging/eval/rotation_evaluation.h"
#include "rotation_averaging/io/graph_io.h"
#include "rotation_averaging/io/text_lines.h"

namespace rotation_averaging {

using Clock = std::chrono::steady_clock;

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
        graph_.AddView(id, KeyframeName(key));
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
      ++accepted;
      ++applied;
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

bool OnlineAverager::SolveLocked() {
  ViewOrientations orientations;
  RotationAveragingOptions averaging;
  std::uint64_t generation = 0;
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    DrainQueue();
    generation = generation_;
    orientations = warm_start_;
    averaging = options_.averaging;
  }
  // graph_ and keys_ change only under solve_mutex_, which this thread holds
  // (DrainQueue above, Reset, LoadGraph): read them in place rather than copy
  // them (a copy of a 10,000-keyframe graph was a sizeable part of a re-solve).
  const ViewGraph& snapshot = graph_;
  const std::vector<KeyframeKey>& keys = keys_;
  if (snapshot.NumEdges() == 0) return false;
  const auto start = Clock::now();
  auto solution = std::make_shared<OnlineSolution>();
  const bool cold = orientations.empty();
  const bool ok = SolveRotationAveraging(snapshot, averaging, &orientations, &solution->summary);
  if (ok && cold) {
    // A cold solve has its own gauge: rotate it onto the previous solution
    // (one robust global rotation) so published frames do not jump.
    const std::shared_ptr<const OnlineSolution> previous = Solution();
    std::vector<Eigen::Matrix3d> before, after;
    for (const auto& [id, r] : orientations) {
      if (id >= keys.size()) continue;
      auto it = previous->orientations.find(keys[id]);
      if (it == previous->orientations.end()) continue;
      before.push_back(it->second);
      after.push_back(r);
    }
    if (!before.empty()) {
      const Eigen::Matrix3d g = AlignRotations(before, after);  // after ~ before * g
      for (auto& [id, r] : orientations) r = r * g.transpose();
    }
  }
  const double seconds = std::chrono::duration<double>(Clock::now() - start).count();
  {
    std::lock_guard<std::mutex> lock(stats_mutex_);
    ++stats_.solves;
    stats_.last_solve_s = seconds;
    if (!ok) ++stats_.failed_solves;
    stats_.components = solution->summary.components.size();
    stats_.outlier_edges = solution->summary.num_outlier_edges;
  }
  if (!ok) return false;  // the previous good solution stays published
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    if (generation != generation_) return false;  // reset or reloaded while solving: discard
    for (const auto& [id, r] : orientations) warm_start_[id] = r;
  }
  const std::vector<std::vector<ViewId>> components = snapshot.ConnectedComponents();
  for (std::size_t c = 0; c < components.size(); ++c) {
    if (components[c].size() < 2) continue;
    for (ViewId id : components[c]) solution->component[keys[id]] = static_cast<int>(c);
  }
  for (const auto& [id, r] : orientations) solution->orientations[keys[id]] = r;
  for (const auto& [id, c] : solution->summary.view_covariances) {
    if (id < keys.size()) solution->covariance[keys[id]] = c;
  }
  const std::vector<RelativeRotation>& graph_edges = snapshot.Edges();
  solution->edges.reserve(graph_edges.size());
  for (std::size_t k = 0; k < graph_edges.size() && k < solution->summary.edges.size(); ++k) {
    const EdgeResult& result = solution->summary.edges[k];
    if (!result.solved || graph_edges[k].view1 >= keys.size() || graph_edges[k].view2 >= keys.size()) continue;
    solution->edges.push_back(SolvedEdge{keys[graph_edges[k].view1], keys[graph_edges[k].view2],
                                         graph_edges[k].source, RadToDeg(result.residual_rad), result.robust_weight});
  }
  std::function<void(std::shared_ptr<const OnlineSolution>)> callback;
  {
    std::lock_guard<std::mutex> lock(solution_mutex_);
    solution->sequence = solution_->sequence + 1;
    solution_ = solution;
    callback = callback_;
  }
  if (callback) callback(solution);
  return true;
}

bool OnlineAverager::SolveNow() {
  std::lock_guard<std::mutex> lock(solve_mutex_);
  return SolveLocked();
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

bool OnlineAverager::SaveGraph(const std::string& path, std::string* error) const {
  ViewGraph copy;
  {
    std::lock_guard<std::mutex> lock(graph_mutex_);
    copy = graph_;
  }
  return WriteRotavgGraph(path, copy, error);
}

bool OnlineAverager::LoadGraph(const std::string& path, std::string* error) {
  ViewGraph loaded;
  const ReadReport report = ReadRotavgGraph(path, &loaded);
  if (!report.ok()) {
    if (error) *error = report.error;
    return false;
  }
  std::map<KeyframeKey, ViewId> ids;
  std::vector<KeyframeKey> keys;
  ViewGraph renumbered;
  std::map<ViewId, ViewId> old_to_new;
  for (const View& v : loaded.Views()) {
    KeyframeKey key;
    if (!ParseKeyframeName(v.name, &key)) {
      if (error) *error = path + ": view '" + v.name + "' is not named <frame_id>@<stamp_ns>";
      return false;
    }
    const ViewId id = keys.size();
    ids[key] = id;
    keys.push_back(key);
    old_to_new[v.id] = id;
    renumbered.AddView(id, v.name);
  }
  for (RelativeRotation e : loaded.Edges()) {
    e.view1 = old_to_new.at(e.view1);
    e.view2 = old_to_new.at(e.view2);
    renumbered.AddEdge(e, nullptr, DuplicatePolicy::kKeepBoth);
  }
  {
    std::lock_guard<std::mutex> solve_lock(solve_mutex_);
    {
      std::lock_guard<std::mutex> lock(graph_mutex_);
      graph_ = std::move(renumbered);
      ids_ = std::move(ids);
      keys_ = std::move(keys);
      warm_start_.clear();
      ++generation_;
    }
    {
      std::lock_guard<std::mutex> lock(queue_mutex_);
      queue_.clear();
    }
    SolveLocked();
  }
  if (!report.warnings.empty() && error) *error = report.warnings.front();
  return true;
}

}  // namespace rotation_averaging
