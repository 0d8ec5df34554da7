// The map on disk: the averager's view graph, beside it the rig model's
// cameras and captures and, with an image front end that has a vocabulary,
// its keyframe database, each written atomically. Saves copy each part
// under the lock that guards it and write after, so solves and keyframes
// wait for the copies, not for the disk. Loads and adds read and check
// every file before anything held changes. No ROS type: the node and the
// replay reach it through their keyframe pipeline.
#ifndef ROTATION_AVERAGING_FRONTEND_CONTROLLERS_MAP_STORE_H_
#define ROTATION_AVERAGING_FRONTEND_CONTROLLERS_MAP_STORE_H_

#include <Eigen/Core>
#include <cstddef>
#include <functional>
#include <map>
#include <mutex>
#include <string>

#include "rotation_averaging/core/controllers/rig_model.h"
#include "rotation_averaging/frontend/controllers/keyframe_frontend.h"
#include "rotation_averaging/frontend/controllers/keyframe_refiner.h"
#include "rotation_averaging/core/controllers/online_averager.h"

namespace rotation_averaging {

// Where a map's keyframe database goes, beside its graph at `graph_path`:
// ".keyframes" appended.
std::string KeyframeDatabasePath(const std::string& graph_path);
// Where its rig model goes (RigModel::Save): ".rig" appended.
std::string RigPath(const std::string& graph_path);
// Where the background refinement's corrections go
// (KeyframeRefiner::SaveCorrections): ".refinement" appended.
std::string RefinementPath(const std::string& graph_path);

// How long a save held what other threads wait for, and how long it took in
// all (the files written after the copies; seconds).
struct MapSaveTiming {
  double graph_lock_s = 0.0;     // the graph and solution copied: solves wait
  double frontend_lock_s = 0.0;  // the keyframes copied: new keyframes wait
  double total_s = 0.0;
};

class MapStore {
 public:
  // Puts an edge into the graph (through the rig model); false when refused.
  using AddEdge = std::function<bool(const KeyframeRelativeRotation&, std::string* error)>;
  // Called, with `frontend_mutex` held, after the front end's keyframes
  // changed (a database loaded or added).
  using FrontendChanged = std::function<void()>;

  // `frontend` may be null (no image front end); it is used only while
  // `frontend_mutex` is held. `refiner` may be null (no background
  // refinement): with one, a map keeps its keyframes' corrections.
  MapStore(OnlineAverager* averager, RigModel* rig, KeyframeFrontend* frontend, std::mutex* frontend_mutex,
           AddEdge add_edge, FrontendChanged frontend_changed, KeyframeRefiner* refiner = nullptr);

  // Saves the map at `graph_path` (graph, RigPath, KeyframeDatabasePath).
  // `note` (if given) says what was saved or why the database was not. One
  // save at a time: saves to one path go through the same temporaries.
  bool Save(const std::string& graph_path, std::string* error, std::string* note = nullptr);
  // Of the last Save that succeeded.
  MapSaveTiming LastSaveTiming() const;
  // Loads a saved map in place of the one held: the view graph, the rig
  // model if its file is beside it, and the keyframe database if there is
  // one and there is a front end, so that new keyframes relate to the old
  // ones by loop closures. A file that is refused leaves, with the reason in
  // `error`, what is held as it was. `saved_orientations` (if given): the
  // orientations saved with the graph, by keyframe.
  bool Load(const std::string& graph_path, std::string* error, std::string* note = nullptr,
            std::map<KeyframeKey, Eigen::Matrix3d>* saved_orientations = nullptr);
  // Adds a saved map (another session's, another robot's) to the one held:
  // its graph (OnlineAverager::AddGraph), its rig captures and its
  // keyframes, with the loop closures found between its keyframes and those
  // held (`linked` gets how many went into the graph). A refused map leaves
  // what is held as it was.
  bool Add(const std::string& graph_path, std::string* error, std::string* note = nullptr,
           std::size_t* linked = nullptr);

 private:
  // Reads the graph of a saved map and its rig file, if any (views named as
  // keyframes, a rig file that reads), before any part is used: `rig` is
  // what the rig file holds, applied once the rest has loaded.
  // So are the refinement's corrections (`have_refinement`, `corrections`).
  bool Check(const std::string& graph_path, SavedKeyframeGraph* graph, bool* have_rig, RigModel::Saved* rig,
             bool* have_refinement, std::map<KeyframeKey, Eigen::Matrix3d>* corrections, std::string* error) const;

  KeyframeRefiner* refiner_ = nullptr;
  OnlineAverager* averager_;
  RigModel* rig_;
  KeyframeFrontend* frontend_;
  std::mutex* frontend_mutex_;
  AddEdge add_edge_;
  FrontendChanged frontend_changed_;
  std::mutex save_mutex_;     // one save at a time
  mutable std::mutex mutex_;  // last_save_timing_
  MapSaveTiming last_save_timing_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_CONTROLLERS_MAP_STORE_H_
