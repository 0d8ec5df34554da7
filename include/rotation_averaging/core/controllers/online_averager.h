// Public header of rotation_averaging::core (docs/embedding.md).
// Online rotation averaging for a live mapping stack, free of ROS: keyframes
// identified by (camera frame id, capture stamp) come in with relative
// rotations between them; a worker thread periodically re-solves the graph
// (warm-started from the last solution) on a snapshot, so producers never
// wait for a solve. The ROS node and the bag replay tool wrap this class.
#ifndef ROTATION_AVERAGING_CORE_CONTROLLERS_ONLINE_AVERAGER_H_
#define ROTATION_AVERAGING_CORE_CONTROLLERS_ONLINE_AVERAGER_H_

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "rotation_averaging/core/estimators/rotation_averaging.h"
#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {

// A keyframe: the camera that took it and the capture stamp, nanoseconds.
struct KeyframeKey {
  std::string frame_id;
  std::int64_t stamp_ns = 0;
  bool operator<(const KeyframeKey& o) const {
    return frame_id != o.frame_id ? frame_id < o.frame_id : stamp_ns < o.stamp_ns;
  }
  bool operator==(const KeyframeKey& o) const { return frame_id == o.frame_id && stamp_ns == o.stamp_ns; }
  bool operator!=(const KeyframeKey& o) const { return !(*this == o); }
};

// One relative rotation between two keyframes, in the conventions of
// core/geometry/so3.h: rotation = R_1 R_2^T, covariance (rad^2) of a right
// perturbation, in keyframe 2's camera frame.
struct KeyframeRelativeRotation {
  KeyframeKey keyframe1, keyframe2;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  bool has_covariance = false;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();
  int num_inliers = 0;
  EdgeSource source = EdgeSource::kOther;
  std::uint32_t channel = 0;  // see RelativeRotation::channel
};

struct OnlineAveragerOptions {
  RotationAveragingOptions averaging;
  double solve_period_s = 1.0;          // periodic re-solve; <= 0: only on request
  bool solve_early_on_loop_closure = true;  // a new loop closure wakes the solver at once
  std::size_t max_queue = 10000;        // pending measurements; beyond, new ones are dropped and counted
  std::size_t max_views = 1000000;      // caps: new keyframes / edges beyond them are dropped and counted
  std::size_t max_edges = 10000000;
  // Local re-solves for large graphs. With at least local_solve_min_views
  // keyframes, a solve after a small change (new keyframes and their edges,
  // a loop closure) moves only the neighbourhood of the change
  // (SolveRotationAveragingLocally with `local`), holding the rest of the
  // last solution fixed; every full_solve_every local solves a full solve
  // (warm-started) revisits the whole graph. Changes that join two solved
  // components, touch more than local.max_views keyframes, a cold start, new
  // options and the L1-IRLS solver always take a full solve; a loop-closure
  // edge makes the next full solve due at once. 0 disables.
  // The latency per updated solution against full re-solves, and the
  // accuracy of both: results/online.md.
  std::size_t local_solve_min_views = 3000;
  LocalSolveOptions local;  // previous_component is set by the averager
  int full_solve_every = 10;
  // Run the periodic full solve in a second thread on a snapshot of the
  // graph, while local solves go on; its result is taken by the first solve
  // after it has finished (keyframes added since the snapshot are then
  // re-solved locally around them). Off: the full solve runs in the solve
  // that is due, so the sequence of solutions depends only on the input and
  // not on timing (the bag replay uses that).
  bool background_full_solves = true;

  // True if every field (and `averaging`) is within its range; otherwise
  // false, with `error` naming the first field that is not.
  bool Validate(std::string* error) const;
};

// Counters for diagnostics; all monotonic.
struct OnlineAveragerStats {
  std::uint64_t received = 0;           // measurements offered
  std::uint64_t accepted = 0;           // added to the graph (or replaced an edge)
  std::uint64_t rejected_invalid = 0;   // failed validation (NaN, not a rotation, bad covariance, self-loop)
  std::uint64_t dropped_queue_full = 0;
  std::uint64_t dropped_cap = 0;        // view or edge cap reached
  std::size_t queued = 0;               // measurements waiting for the next solve (at most max_queue)
  std::uint64_t solves = 0;
  std::uint64_t local_solves = 0;       // of `solves`: local re-solves (see local_solve_min_views)
  std::uint64_t background_solves = 0;  // full solves run in the background and taken into a solution
  std::uint64_t failed_solves = 0;
  std::uint64_t overruns = 0;           // solves that took longer than the period
  double last_solve_s = 0.0;
  std::size_t views = 0, edges = 0, components = 0, outlier_edges = 0;
};

// An edge of a solve, with how the robust loss treated it.
struct SolvedEdge {
  KeyframeKey keyframe1, keyframe2;
  EdgeSource source = EdgeSource::kOther;
  double residual_deg = 0.0;    // |Log(M^T R_1 R_2^T)| at the solution
  double robust_weight = 0.0;   // rho'(s) in [0, 1]: 0 is a rejected outlier
};

// The latest solution: world-to-camera orientation per keyframe.
struct OnlineSolution {
  std::uint64_t sequence = 0;  // increases with every successful solve
  // The background refinement whose corrections the orientations carry
  // (frontend/controllers/keyframe_refiner.h); 0: the averaging's alone.
  std::uint64_t refinement_sequence = 0;
  bool local = false;          // a local re-solve: `summary` covers the re-solved region only
  std::map<KeyframeKey, Eigen::Matrix3d> orientations;
  std::map<KeyframeKey, int> component;  // index of the connected component, largest first
  std::vector<SolvedEdge> edges;         // every edge of the solved graph
  // Posterior covariance (rad^2) where computed (components of at most
  // RotationAveragingOptions::posterior_covariance_max_views): left
  // perturbation of the world-to-camera rotation, R = Exp(d) R_hat, relative
  // to the component's gauge keyframe.
  std::map<KeyframeKey, Eigen::Matrix3d> covariance;
  RotationAveragingSummary summary;
};

// A graph file of OnlineAverager::SaveGraph, read and checked: every view
// named "<frame_id>@<stamp_ns>", no keyframe twice.
struct SavedKeyframeGraph {
  std::string path;                                // where it was read from (for messages)
  ViewGraph graph;
  std::map<ViewId, Eigen::Matrix3d> orientations;  // saved with it (graph file version 2)
  std::map<ViewId, KeyframeKey> keys;              // the keyframe each view names
  std::vector<std::string> warnings;
};
bool ReadSavedKeyframeGraph(const std::string& path, SavedKeyframeGraph* saved, std::string* error);

class OnlineAverager {
 public:
  explicit OnlineAverager(const OnlineAveragerOptions& options);
  ~OnlineAverager();  // stops the worker
  OnlineAverager(const OnlineAverager&) = delete;
  OnlineAverager& operator=(const OnlineAverager&) = delete;

  // Validates and enqueues; never blocks on a solve. Returns false (with
  // `error`) if the measurement was rejected or dropped; the reason is counted.
  // `queue_full` (optional) tells a valid measurement dropped at the full
  // queue (counted in dropped_queue_full) from an invalid one.
  bool AddRelativeRotation(const KeyframeRelativeRotation& measurement, std::string* error = nullptr,
                           bool* queue_full = nullptr);

  // Starts the worker thread (periodic solves). Without it, call SolveNow().
  void Start();
  void Stop();
  // Applies pending measurements and solves in the calling thread; returns
  // whether the solve succeeded. Thread-safe with the worker. A local or a
  // full solve as the options say; SolveFullNow always solves the whole graph
  // (and drops a background full solve still running).
  bool SolveNow();
  bool SolveFullNow();
  // Asks the worker for a solve as soon as possible.
  void RequestSolve();
  // Clears graph, queue and solution (counters are kept).
  void Reset();
  // Used from the next solve, which the worker runs at once even without new
  // input, starting cold (not warm-started from the previous solution).
  void SetAveragingOptions(const RotationAveragingOptions& options);
  void SetSolvePeriod(double seconds);  // <= 0: only on request; takes effect at the next wake-up
  double SolvePeriod() const { return solve_period_s_.load(); }

  std::shared_ptr<const OnlineSolution> Solution() const;
  OnlineAveragerStats Stats() const;
  // Edges in the graph (applied measurements) by source kind.
  std::map<EdgeSource, std::size_t> EdgesBySource() const;
  // Called by the worker after every successful solve (from its thread).
  void SetSolutionCallback(std::function<void(std::shared_ptr<const OnlineSolution>)> callback);

  // Graph persistence in the package's graph file format (core/io/graph_io.h);
  // view names encode the keyframe as "<frame_id>@<stamp_ns>".
  bool SaveGraph(const std::string& path, std::string* error) const;
  // What SaveGraph writes: the graph and the published orientations by view,
  // copied under the graph lock only (a solve waits for that much, not for
  // the file).
  void SnapshotGraph(ViewGraph* graph, std::map<ViewId, Eigen::Matrix3d>* orientations) const;
  // The graph as the next solve will see it (the queued measurements applied
  // to it first, as a solve would), the view of each keyframe in it, and
  // the warm start of the next solve: for a caller that solves variants of
  // it (core/estimators/loop_calibration.h). Waits for a solve under way.
  void PendingGraph(ViewGraph* graph, std::map<KeyframeKey, ViewId>* ids, ViewOrientations* start);
  // Replaces the graph (and drops the measurements queued) with a saved
  // one, then solves; its first solve starts from the orientations saved
  // with it, so its keyframes keep the frames they were published in. A
  // refused file leaves the graph as it was; `error` gets the file's first
  // warning on success, if it had any.
  bool LoadGraph(const std::string& path, std::string* error);
  bool LoadGraph(const SavedKeyframeGraph& saved, std::string* error);
  // Adds a saved graph (another session's or robot's map) to the one held,
  // then solves. Its keyframes already held are the same keyframes, and the
  // edges among them are not added again. Its other keyframes start where it
  // had them: rotated into the frame of the keyframes held when the two
  // share some, else in its own frame, a component of its own until a loop
  // closure joins it to another. A refused file leaves the graph as it was.
  struct AddedGraph {
    std::size_t views = 0, views_held = 0;  // added; already held
    std::size_t edges = 0, edges_held = 0;  // added; among keyframes already held, left out
  };
  bool AddGraph(const std::string& path, AddedGraph* added, std::string* error);
  bool AddGraph(const SavedKeyframeGraph& saved, AddedGraph* added, std::string* error);
  static std::string KeyframeName(const KeyframeKey& key);
  static bool ParseKeyframeName(const std::string& name, KeyframeKey* key);

 private:
  // LoadGraph (replace) and AddGraph: the one way a saved graph comes in.
  bool TakeGraph(const SavedKeyframeGraph& saved, bool replace, AddedGraph* added, std::string* error);
  void WorkerLoop();
  std::size_t DrainQueue();  // applies queued measurements to the graph; needs graph_mutex_
  bool SolveLocked(bool force_full);  // needs solve_mutex_
  // The steps of SolveLocked, in order (all need solve_mutex_).
  // Takes a finished background full solve, unless a foreground full solve
  // ran since its snapshot: its orientations into `orientations`, the views
  // that came after its snapshot into `changed`. True if taken.
  bool TakeBackgroundSolve(std::uint64_t generation, bool force_full, bool cold, ViewOrientations* orientations,
                           std::vector<ViewId>* changed, std::map<KeyframeKey, Eigen::Matrix3d>* covariances);
  // A local re-solve around `changed` when allowed and no full solve is due,
  // else a full one (whose components go to `components`).
  struct SolveRun {
    bool ok = false;
    bool local = false;
    std::vector<std::vector<ViewId>> components;  // of the graph, after a full solve
  };
  SolveRun RunSolve(const RotationAveragingOptions& averaging, bool local_enabled, bool took_background,
                    const std::vector<ViewId>& changed, ViewOrientations* orientations,
                    RotationAveragingSummary* summary);
  // A full solve holds one view of each component where it was (its gauge),
  // so the component's frame would follow that one view's correction; a
  // cold solve has a gauge of its own. Each component of `components` is
  // rotated instead onto the published orientations of its views, one
  // robust rotation fitted on them (on an even sample of a large one): its
  // frame as a whole stays. A component that joins components solved apart
  // keeps the frame of the one with the most views.
  void KeepPublishedFrames(const std::vector<std::vector<ViewId>>& components, ViewOrientations* orientations) const;
  // A view's component at the last full solve (-1: none: new since, or a
  // singleton).
  int LabelOf(ViewId id) const;
  // The label most of `component`'s views had (of equal counts the smallest)
  // and how many labels they had; -1 counts as a label when
  // `count_unlabelled`.
  std::pair<int, std::size_t> MostViewsLabel(const std::vector<ViewId>& component, bool count_unlabelled) const;
  void RecordSolve(bool ok, bool local, double seconds, const RotationAveragingSummary& summary);
  // After a failed solve the changed views wait for the next one.
  void RequeueChanged(const std::vector<ViewId>& changed);
  // The published solution: orientations, components, edges and covariances by keyframe.
  void FillSolution(const SolveRun& run, bool took_background, const ViewOrientations& orientations,
                    std::map<KeyframeKey, Eigen::Matrix3d> background_covariances, OnlineSolution* solution);
  // Starts the periodic full solve in the background when it is due.
  void MaybeStartBackgroundSolve(const ViewOrientations& orientations, const RotationAveragingOptions& averaging,
                                 std::uint64_t generation);
  // Keeps `orientations` as the next warm start and publishes `solution`.
  void Publish(std::shared_ptr<OnlineSolution> solution, std::uint64_t options_epoch, ViewOrientations* orientations);
  // The full solve of a snapshot, run in the background.
  struct FullSolve {
    std::uint64_t generation = 0;
    bool ok = false;
    ViewOrientations orientations;
    RotationAveragingSummary summary;
    std::vector<std::vector<ViewId>> components;
  };
  // A view or an edge added to graph_, to be replayed on background_graph_.
  struct GraphAddition {
    ViewId view = 0;
    std::string name;
    bool is_edge = false;
    RelativeRotation edge;
  };
  // Replays `additions` on `graph` (the background copy), then solves it.
  static FullSolve RunFullSolve(ViewGraph* graph, std::vector<GraphAddition> additions,
                                const RotationAveragingOptions& options, ViewOrientations orientations,
                                std::uint64_t generation);
  void RecordAddition(GraphAddition addition);
  void ClearLocalState();  // needs solve_mutex_
  // Drops the keyframes added since the last full solve from its start.
  void StartFromTree(ViewOrientations* orientations);
  // Posterior covariances by keyframe (solve_mutex_ held).
  std::map<KeyframeKey, Eigen::Matrix3d> CovariancesByKey(const std::map<ViewId, Eigen::Matrix3d>& by_id) const;
  // Components solved apart are in different frames: where new edges joined
  // them, only the largest keeps its warm start; the others are placed from
  // it along the spanning tree (a warm start mixing two frames made the
  // joined solve end 90 deg off: test JoiningComponentsTakesAFullSolve).
  void StartJoinedComponentsFromTree(const std::vector<std::vector<ViewId>>& components,
                                     ViewOrientations* orientations) const;
  // Labels and loss scales of the components of a full solve (see local_).
  void TakeComponents(const std::vector<std::vector<ViewId>>& components, const RotationAveragingSummary& summary);

  OnlineAveragerOptions options_;
  const ViewGraph validator_;  // validates measurements without taking the graph lock
  mutable std::mutex queue_mutex_;
  std::deque<KeyframeRelativeRotation> queue_;
  // graph_mutex_ guards graph_, ids_, keys_ and warm_start_; graph_, ids_
  // and keys_ are only modified with solve_mutex_ held too, so the solving
  // thread reads them without graph_mutex_.
  mutable std::mutex graph_mutex_;
  ViewGraph graph_;
  std::map<KeyframeKey, ViewId> ids_;
  std::vector<KeyframeKey> keys_;  // by ViewId
  ViewOrientations warm_start_;
  std::uint64_t generation_ = 0;  // bumped by Reset and LoadGraph: a solve started before is discarded
  std::uint64_t options_epoch_ = 0;  // bumped by SetAveragingOptions: a solve started before keeps the next one cold
  // Local re-solve state (solve_mutex_): views touched since the last solve
  // and since the snapshot of the running background solve; component label
  // per view and loss scale per label from the last full solve; results of
  // every edge (by graph index) for the published solution.
  std::vector<ViewId> changed_, changed_since_snapshot_;
  std::vector<ViewId> new_views_;  // keyframes added since the last full solve (or its snapshot)
  std::vector<ViewId> snapshot_new_views_;  // new_views_ when the running background solve was started
  std::vector<char> changed_flag_;
  std::vector<int> component_label_;
  std::vector<double> label_scale_;
  std::vector<EdgeResult> edge_results_;
  int local_solves_since_full_ = 0;
  bool loop_closure_since_full_ = false;  // a loop-closure edge arrived since the last full solve (or snapshot)
  // The background full solve's own copy of the graph, brought up to date at
  // each start by replaying in the background thread what was added to
  // graph_ since the last start: starting one then costs the additions, not
  // a copy of the whole graph in the solving thread, which grows with the
  // map. Only a running background solve touches it; copied afresh after
  // Reset and LoadGraph, and when the additions outgrow half the graph.
  std::unique_ptr<ViewGraph> background_graph_;
  std::vector<GraphAddition> background_additions_;
  bool background_graph_valid_ = false;
  std::future<FullSolve> background_;  // after background_graph_: waited for before it is destroyed
  bool background_stale_ = false;  // a full solve ran in the foreground since the snapshot
  std::mutex solve_mutex_;  // one solve at a time
  mutable std::mutex solution_mutex_;
  std::shared_ptr<const OnlineSolution> solution_;
  std::function<void(std::shared_ptr<const OnlineSolution>)> callback_;
  mutable std::mutex stats_mutex_;
  OnlineAveragerStats stats_;
  std::mutex wake_mutex_;
  std::condition_variable wake_;
  bool wake_requested_ = false;
  std::atomic<bool> running_{false};
  std::atomic<double> solve_period_s_{1.0};
  std::atomic<bool> force_solve_{false};  // options changed: solve at the next wake-up even without new input
  std::thread worker_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_CONTROLLERS_ONLINE_AVERAGER_H_
