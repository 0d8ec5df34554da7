// Public header of rotation_averaging::core (docs/embedding.md).
// View graph: views (keyed by a 64-bit id) and relative-rotation edges.
//
// Conventions are those of core/geometry/so3.h: an edge (i, j) stores
// R_ij = R_i R_j^T with world-to-camera R_i, and its optional covariance C_ij
// (rad^2) is that of a right perturbation, in camera j's frame.
//
// Duplicate policy: an edge is identified by its unordered view pair AND its
// source kind. By default (DuplicatePolicy::kReplace, for live input) adding
// an edge whose (pair, source) already exists REPLACES the old one (a front
// end re-estimating the same pair); edges of different sources between the
// same pair (say a sequential edge and a loop closure) are independent
// measurements and are BOTH kept and used. File readers use kKeepBoth: a file
// that lists a pair twice holds two measurements, and both are used.
//
// Every edge is validated when added: non-finite or non-rotation matrices,
// self-loops and unknown views are rejected; a covariance that is not finite
// is rejected, one that is asymmetric or not positive definite is repaired
// (symmetrised, eigenvalues floored) when that is safe. Each outcome is
// counted in ViewGraph::InputStats, so callers can report it.
#ifndef ROTATION_AVERAGING_CORE_SCENE_VIEW_GRAPH_H_
#define ROTATION_AVERAGING_CORE_SCENE_VIEW_GRAPH_H_

#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <unordered_map>
#include <vector>

namespace rotation_averaging {

using ViewId = std::uint64_t;
// One orientation per view (world-to-camera R_i), keyed by view id.
using ViewOrientations = std::unordered_map<ViewId, Eigen::Matrix3d>;

enum class EdgeSource : std::uint8_t { kRig = 0, kSequential = 1, kLoopClosure = 2, kOther = 3 };
const char* EdgeSourceName(EdgeSource source);
// Parses "rig", "sequential", "loop_closure", "other"; false if unknown.
bool ParseEdgeSource(const std::string& text, EdgeSource* source);

struct View {
  ViewId id = 0;
  std::string name;  // Used in orientation files; defaults to the decimal id.
};

struct RelativeRotation {
  ViewId view1 = 0;
  ViewId view2 = 0;
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();  // R_12 = R_1 R_2^T
  bool has_covariance = false;
  Eigen::Matrix3d covariance = Eigen::Matrix3d::Identity();  // rad^2, right perturbation
  int num_inliers = 0;                                       // 0 if unknown
  EdgeSource source = EdgeSource::kOther;
  // Tells independent measurements of one pair and source apart (e.g. the
  // sequential edges of two cameras of a rig, which relate the same two rig
  // captures): kReplace replaces only an edge of the same channel.
  std::uint32_t channel = 0;

  // The same measurement seen from view2: R_21 = R_12^T, with the covariance
  // moved to view1's frame (C_21 = R_12 C_12 R_12^T).
  RelativeRotation Inverted() const;
};

enum class AddEdgeResult { kAdded, kReplaced, kRejected };
enum class DuplicatePolicy { kReplace, kKeepBoth };

class ViewGraph {
 public:
  struct InputStats {
    std::size_t edges_added = 0;
    std::size_t edges_replaced = 0;
    std::size_t rejected_self_loop = 0;
    std::size_t rejected_unknown_view = 0;
    std::size_t rejected_bad_rotation = 0;
    std::size_t rejected_bad_covariance = 0;
    std::size_t repaired_covariance = 0;
    std::size_t Rejected() const {
      return rejected_self_loop + rejected_unknown_view + rejected_bad_rotation + rejected_bad_covariance;
    }
  };

  struct ValidationOptions {
    // A rotation whose R^T R deviates from I by more than this is rejected;
    // smaller deviations (rounding in text files) are projected onto SO(3).
    double rotation_tolerance = 1e-3;
    // Relative asymmetry |C - C^T| / |C| tolerated (and symmetrised) before rejecting.
    double covariance_asymmetry_tolerance = 1e-3;
    // Eigenvalues of a covariance below floor * largest eigenvalue are raised to it.
    double covariance_eigenvalue_floor = 1e-9;
  };

  ViewGraph() = default;
  explicit ViewGraph(const ValidationOptions& options) : validation_(options) {}

  // Adds a view; returns false (and changes nothing) if the id exists. An
  // empty name becomes the decimal id.
  bool AddView(ViewId id, const std::string& name = "");
  bool HasView(ViewId id) const { return view_index_.count(id) > 0; }
  const View* FindView(ViewId id) const;
  // Removes a view and every edge touching it. False if unknown.
  bool RemoveView(ViewId id);

  // Validates and adds (or replaces) an edge; both views must exist. On
  // rejection, `error` (if given) says why. kReplace replaces the edge of the
  // same pair, source and channel.
  AddEdgeResult AddEdge(const RelativeRotation& edge, std::string* error = nullptr,
                        DuplicatePolicy duplicates = DuplicatePolicy::kReplace);
  // Removes the edge(s) of this pair and source (either direction). False if absent.
  bool RemoveEdge(ViewId view1, ViewId view2, EdgeSource source);
  void Clear();

  std::size_t NumViews() const { return views_.size(); }
  std::size_t NumEdges() const { return edges_.size(); }
  const std::vector<View>& Views() const { return views_; }
  const std::vector<RelativeRotation>& Edges() const { return edges_; }
  const InputStats& Stats() const { return stats_; }
  const ValidationOptions& Validation() const { return validation_; }

  // Connected components as lists of view ids, largest first; views in a
  // component are sorted by id. Isolated views form components of size one.
  std::vector<std::vector<ViewId>> ConnectedComponents() const;

  // Validates an edge without adding it: fixes what can be fixed in `edge`
  // and returns false with a reason if it must be rejected.
  bool ValidateEdge(RelativeRotation* edge, std::string* error, bool* covariance_repaired) const;

 private:
  struct EdgeKey {
    ViewId a, b;
    EdgeSource source;
    bool operator==(const EdgeKey& o) const { return a == o.a && b == o.b && source == o.source; }
  };
  struct EdgeKeyHash {
    std::size_t operator()(const EdgeKey& k) const;
  };
  static EdgeKey KeyOf(ViewId v1, ViewId v2, EdgeSource source);
  void EraseEdgeAt(std::size_t index);

  ValidationOptions validation_;
  std::vector<View> views_;
  std::unordered_map<ViewId, std::size_t> view_index_;
  std::vector<RelativeRotation> edges_;
  // (pair, source) -> indices of its edges (more than one only with kKeepBoth).
  std::unordered_map<EdgeKey, std::vector<std::size_t>, EdgeKeyHash> edge_index_;
  InputStats stats_;
};

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_CORE_SCENE_VIEW_GRAPH_H_
