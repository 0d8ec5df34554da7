#include "rotation_averaging/frontend/controllers/map_store.h"

#include <chrono>
#include <filesystem>
#include <utility>
#include <vector>

#include "rotation_averaging/core/io/graph_io.h"

namespace rotation_averaging {

std::string KeyframeDatabasePath(const std::string& graph_path) { return graph_path + ".keyframes"; }
std::string RigPath(const std::string& graph_path) { return graph_path + ".rig"; }
std::string RefinementPath(const std::string& graph_path) { return graph_path + ".refinement"; }

MapStore::MapStore(OnlineAverager* averager, RigModel* rig, KeyframeFrontend* frontend, std::mutex* frontend_mutex,
                   AddEdge add_edge, FrontendChanged frontend_changed, KeyframeRefiner* refiner)
    : refiner_(refiner),
      averager_(averager),
      rig_(rig),
      frontend_(frontend),
      frontend_mutex_(frontend_mutex),
      add_edge_(std::move(add_edge)),
      frontend_changed_(std::move(frontend_changed)) {}

bool MapStore::Save(const std::string& graph_path, std::string* error, std::string* note) {
  using Clock = std::chrono::steady_clock;
  auto seconds_since = [](Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); };
  std::lock_guard<std::mutex> save_lock(save_mutex_);
  MapSaveTiming timing;
  const auto start = Clock::now();
  // Each part is copied while its lock is held and written after: a solve or
  // a keyframe waits for the copy, not for the disk.
  ViewGraph graph;
  std::map<ViewId, Eigen::Matrix3d> orientations;
  averager_->SnapshotGraph(&graph, &orientations);
  timing.graph_lock_s = seconds_since(start);
  // The graph first, the database last: a save cut short between them leaves
  // a database older than the graph.
  if (!WriteRotavgGraph(graph_path, graph, error, &orientations)) return false;
  if (!rig_->Save(RigPath(graph_path), error)) return false;
  std::string saved = "view graph saved to " + graph_path;
  const std::string refinement_path = RefinementPath(graph_path);
  if (refiner_) {
    if (!refiner_->SaveCorrections(refinement_path, error)) return false;
    saved += ", the refinement's corrections to " + refinement_path;
  } else {
    // Corrections left from an earlier save to this path belong to another
    // map's keyframes.
    std::error_code ec;
    std::filesystem::remove(refinement_path, ec);
  }
  const std::string database_path = KeyframeDatabasePath(graph_path);
  if (frontend_ && frontend_->UsesVocabulary()) {
    KeyframeDatabase database;
    const auto frontend_start = Clock::now();
    {
      std::lock_guard<std::mutex> lock(*frontend_mutex_);
      if (!frontend_->SnapshotDatabase(&database, error)) return false;
    }
    timing.frontend_lock_s = seconds_since(frontend_start);
    if (!WriteKeyframeDatabase(database_path, database, error)) return false;
    saved += ", " + std::to_string(database.keyframes.size()) + " keyframes to " + database_path;
  } else {
    // A database left from an earlier save to this path belongs to another
    // graph: loading it with this one would relate new keyframes to views
    // the graph does not have.
    std::error_code ec;
    if (std::filesystem::remove(database_path, ec)) saved += "; the older " + database_path + " removed";
    if (frontend_) saved += "; no keyframe database (retrieval by voting: vocabulary none)";
  }
  timing.total_s = seconds_since(start);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    last_save_timing_ = timing;
  }
  if (note) *note = saved;
  return true;
}

MapSaveTiming MapStore::LastSaveTiming() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return last_save_timing_;
}

bool MapStore::Check(const std::string& graph_path, SavedKeyframeGraph* graph, bool* have_rig, RigModel::Saved* rig,
                     bool* have_refinement, std::map<KeyframeKey, Eigen::Matrix3d>* corrections,
                     std::string* error) const {
  if (!ReadSavedKeyframeGraph(graph_path, graph, error)) return false;
  // The rig's captures: without them a saved capture would stay one
  // orientation of the rig frame, and the cameras' keyframes in it unknown.
  std::error_code ec;
  *have_rig = std::filesystem::exists(RigPath(graph_path), ec);
  if (*have_rig && !RigModel::ReadFile(RigPath(graph_path), rig, error)) return false;
  *have_refinement = refiner_ && std::filesystem::exists(RefinementPath(graph_path), ec);
  return !*have_refinement || KeyframeRefiner::ReadCorrections(RefinementPath(graph_path), corrections, error);
}

bool MapStore::Load(const std::string& graph_path, std::string* error, std::string* note,
                    std::map<KeyframeKey, Eigen::Matrix3d>* saved_orientations) {
  // The graph is read and the rig file checked before the database replaces
  // the front end's keyframes: a refused map leaves everything as it was.
  SavedKeyframeGraph graph;
  bool have_rig = false, have_refinement = false;
  RigModel::Saved saved_rig;
  std::map<KeyframeKey, Eigen::Matrix3d> corrections;
  if (!Check(graph_path, &graph, &have_rig, &saved_rig, &have_refinement, &corrections, error)) return false;
  std::string loaded = "view graph of " + std::to_string(graph.graph.NumViews()) + " views loaded from " + graph_path;
  const std::string rig = RigPath(graph_path);
  std::error_code ec;
  const std::string database = KeyframeDatabasePath(graph_path);
  if (frontend_) {
    if (!std::filesystem::exists(database, ec)) {
      loaded += "; no keyframe database beside it: new keyframes cannot relate to the old ones";
    } else if (!frontend_->UsesVocabulary()) {
      loaded += "; its keyframe database is not loaded (it needs a vocabulary, and vocabulary is none):"
                " new keyframes cannot relate to the old ones";
    } else {
      std::lock_guard<std::mutex> lock(*frontend_mutex_);
      if (!frontend_->LoadDatabase(database, error)) return false;
      loaded += ", " + std::to_string(frontend_->NumKeyframes()) + " keyframes from " + database;
      frontend_changed_();
    }
  }
  std::string graph_note;
  if (!averager_->LoadGraph(graph, &graph_note)) {
    if (error) *error = graph_note;
    return false;
  }
  if (!graph_note.empty()) loaded += " (" + graph_note + ")";
  if (saved_orientations) {
    saved_orientations->clear();
    for (const auto& [id, r] : graph.orientations) saved_orientations->emplace(graph.keys.at(id), r);
  }
  if (have_rig) {
    rig_->Replace(std::move(saved_rig));
    loaded += ", " + std::to_string(rig_->NumCaptures()) + " rig captures from " + rig;
  }
  if (refiner_) {
    // The keyframes held before are gone, and with them their correspondences.
    refiner_->Reset();
    refiner_->SetCorrections(corrections, true);
    if (have_refinement) {
      loaded += ", the refinement's corrections of " + std::to_string(corrections.size()) + " keyframes from " +
                RefinementPath(graph_path);
    }
  }
  if (note) *note = loaded;
  return true;
}

bool MapStore::Add(const std::string& graph_path, std::string* error, std::string* note, std::size_t* linked_edges) {
  if (linked_edges) *linked_edges = 0;
  // The files are checked before anything is added (the database as it is
  // added): a refused map leaves what is held as it was.
  SavedKeyframeGraph graph;
  bool have_rig = false, have_refinement = false;
  RigModel::Saved saved_rig;
  std::map<KeyframeKey, Eigen::Matrix3d> corrections;
  if (!Check(graph_path, &graph, &have_rig, &saved_rig, &have_refinement, &corrections, error)) return false;
  std::error_code ec;
  std::string added_note = "map " + graph_path + " added:";
  const std::string database = KeyframeDatabasePath(graph_path);
  // Loop closures between its keyframes and those held, found as it is added
  // (a map that shares none of them); they go to the averager after its
  // graph and rig captures, which they refer to.
  std::vector<KeyframeRelativeRotation> links;
  std::size_t already_held = 0;
  const bool with_database = frontend_ && frontend_->UsesVocabulary() && std::filesystem::exists(database, ec);
  if (with_database) {
    std::lock_guard<std::mutex> lock(*frontend_mutex_);
    const std::size_t before = frontend_->NumKeyframes();
    if (!frontend_->AddDatabase(database, &already_held, error, &links)) return false;
    added_note += " " + std::to_string(frontend_->NumKeyframes() - before) + " keyframes to retrieve from (" +
                  std::to_string(already_held) + " already held),";
    frontend_changed_();
  } else if (frontend_) {
    added_note += " no keyframe database (" +
                  std::string(frontend_->UsesVocabulary() ? "none beside it" : "vocabulary none") +
                  "): new keyframes cannot relate to its keyframes,";
  }
  OnlineAverager::AddedGraph added;
  std::string graph_note;
  if (!averager_->AddGraph(graph, &added, &graph_note)) {
    if (error) *error = graph_note;
    return false;
  }
  added_note += " " + std::to_string(added.views) + " views and " + std::to_string(added.edges) + " edges (" +
                std::to_string(added.views_held) + " views and " + std::to_string(added.edges_held) +
                " edges already held)";
  if (!graph_note.empty()) added_note += " (" + graph_note + ")";
  if (have_rig) {
    const std::size_t before = rig_->NumCaptures();
    rig_->Merge(std::move(saved_rig));
    added_note += ", " + std::to_string(rig_->NumCaptures() - before) + " rig captures";
  }
  if (have_refinement) {
    refiner_->SetCorrections(corrections, false);
    added_note += ", the refinement's corrections of " + std::to_string(corrections.size()) + " keyframes";
  }
  if (with_database) {
    std::size_t linked = 0;
    for (const KeyframeRelativeRotation& e : links) {
      std::string why;
      if (add_edge_(e, &why)) ++linked;
    }
    if (linked_edges) *linked_edges = linked;
    added_note += already_held > 0 ? "; joined through the keyframes it shares"
                                   : "; " + std::to_string(linked) + " loop closures to the keyframes held";
    averager_->RequestSolve();
  }
  if (note) *note = added_note;
  return true;
}

}  // namespace rotation_averaging
