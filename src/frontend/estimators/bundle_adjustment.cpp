#include "rotation_averaging/frontend/estimators/bundle_adjustment.h"

#include <ceres/ceres.h>

#include <Eigen/Cholesky>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <map>
#include <numeric>
#include <optional>
#include <set>
#include <sstream>
#include <tuple>

#include "frontend/estimators/adjustment_tracks.h"
#include "frontend/estimators/reprojection_cost.h"
#include "rotation_averaging/core/geometry/so3.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"
#include "rotation_averaging/util/blas_threads.h"

namespace rotation_averaging {
namespace {

using adjustment::AdjustedView;
using adjustment::Observation;
using adjustment::Ray;
using adjustment::Track;
using adjustment::Triangulate;

// c_j - c_i - s d: the least-unsquared-deviations residual of one edge.
struct CentreDeviation {
  explicit CentreDeviation(const Eigen::Vector3d& d) : d_(d) {}

  template <typename T>
  bool operator()(const T* ci, const T* cj, const T* s, T* residual) const {
    for (int k = 0; k < 3; ++k) residual[k] = cj[k] - ci[k] - s[0] * T(d_[k]);
    return true;
  }

  Eigen::Vector3d d_;
};

// A pair of the rotation-only model: its matches join the tracks, but it
// gives no direction between the centres.
bool RotationOnly(const EdgeCorrespondences& e) { return e.translation.isZero(0.0); }

int Root(std::vector<int>* parent, int v) {
  while ((*parent)[v] != v) v = (*parent)[v] = (*parent)[(*parent)[v]];
  return v;
}

// Joins the sets of a and b; the smaller root stays the root.
void Unite(std::vector<int>* parent, int a, int b) {
  a = Root(parent, a);
  b = Root(parent, b);
  if (a != b) (*parent)[std::max(a, b)] = std::min(a, b);
}

// `group` (union-find parents over the views) with each rig camera joined
// to its capture's: the views that turn as one, or by one held rotation.
std::vector<int> WithCaptures(std::vector<int> group, const std::vector<AdjustedView>& views) {
  for (std::size_t k = 0; k < views.size(); ++k) {
    if (views[k].capture >= 0) Unite(&group, static_cast<int>(k), views[k].capture);
  }
  return group;
}

// The parameter block of a view's rotation: its own, or its capture's.
double* RotationBlock(std::vector<AdjustedView>* views, int k) {
  AdjustedView& v = (*views)[k];
  return v.capture >= 0 ? (*views)[v.capture].rig_angle_axis.data() : v.angle_axis.data();
}

std::optional<Eigen::Matrix3d> FromRig(const AdjustedView& v) {
  return v.capture >= 0 ? std::optional<Eigen::Matrix3d>(v.from_rig) : std::nullopt;
}

Eigen::Matrix3d AngleAxisToRotation(const Eigen::Vector3d& w) {
  return Eigen::AngleAxisd(w.norm(), w.norm() > 0.0 ? w.normalized() : Eigen::Vector3d::UnitX()).toRotationMatrix();
}

// The view's rotation from its parameter block.
Eigen::Matrix3d CurrentRotation(const std::vector<AdjustedView>& views, const AdjustedView& v) {
  return v.capture >= 0 ? Eigen::Matrix3d(v.from_rig * AngleAxisToRotation(views[v.capture].rig_angle_axis))
                        : AngleAxisToRotation(v.angle_axis);
}

// The rig's captures with two or more views here: each view's capture and
// E; the capture's rotation the chordal mean of E^T R of its views, and
// each view's rotation E times it.
void JoinRigCaptures(const BundleAdjustmentRig& rig, std::vector<AdjustedView>* views) {
  std::map<std::int64_t, std::vector<int>> captures;
  for (std::size_t k = 0; k < views->size(); ++k) {
    const auto it = rig.views.find((*views)[k].id);
    if (it != rig.views.end() && it->second.camera_from_rig.allFinite()) {
      captures[it->second.capture].push_back(static_cast<int>(k));
    }
  }
  for (const auto& [capture, members] : captures) {
    if (members.size() < 2) continue;
    // A capture with a view given as held turns as that view has it.
    const bool held = std::any_of(members.begin(), members.end(), [&](int k) { return (*views)[k].orientation_held; });
    Eigen::Matrix3d sum = Eigen::Matrix3d::Zero();
    for (int k : members) {
      if (held && !(*views)[k].orientation_held) continue;
      const Eigen::Matrix3d e = ProjectToSO3(rig.views.at((*views)[k].id).camera_from_rig);
      sum += e.transpose() * (*views)[k].rotation;
    }
    const Eigen::AngleAxisd mean(ProjectToSO3(sum));
    AdjustedView& holder = (*views)[members.front()];
    holder.rig_angle_axis = mean.angle() * mean.axis();
    for (int k : members) {
      AdjustedView& v = (*views)[k];
      v.capture = members.front();
      v.from_rig = ProjectToSO3(rig.views.at(v.id).camera_from_rig);
      v.rotation = CurrentRotation(*views, v);
      const Eigen::AngleAxisd own(v.rotation);
      v.angle_axis = own.angle() * own.axis();
    }
  }
}

ceres::Solver::Options SolverOptions(int max_iterations) {
  ceres::Solver::Options options;
  options.linear_solver_type = ceres::SPARSE_SCHUR;
  options.max_num_iterations = std::max(1, max_iterations);
  // One thread: Ceres sums the gradient and the Schur complement over
  // threads in the order they finish, so more threads give results that
  // differ in the last bits from run to run.
  options.num_threads = 1;
  options.logging_type = ceres::SILENT;
  return options;
}

double WhitenedSquaredError(const AdjustedView& v, const Track& t, const Observation& o) {
  const Eigen::Vector3d y = v.rotation * (t.point - v.centre);
  return ((v.focal_scale * (y.head<2>() / y.z()) - o.x) / v.sigma).squaredNorm();
}

// The edges the adjustment can use (distinct oriented views, enough finite
// correspondences) and their views, in id order (the gauge and the solves do
// not depend on hashing), each with the median pixel noise of its edges.
void SelectEdgesAndViews(const std::vector<EdgeCorrespondences>& edges, const BundleAdjustmentOptions& options,
                         const ViewOrientations& orientations, std::vector<const EdgeCorrespondences*>* used,
                         std::map<ViewId, int>* index, std::vector<AdjustedView>* views,
                         BundleAdjustmentSummary* summary) {
  for (const EdgeCorrespondences& e : edges) {
    const auto a = orientations.find(e.view1), b = orientations.find(e.view2);
    if (e.view1 == e.view2 || a == orientations.end() || b == orientations.end() ||
        e.points1.size() != e.points2.size() ||
        static_cast<int>(e.points1.size()) < std::max(1, options.min_correspondences) ||
        !CorrespondencesAreFinite(e, true) || !a->second.allFinite() || !b->second.allFinite()) {
      ++summary->edges_skipped;
      continue;
    }
    summary->edges_rotation_only += RotationOnly(e);
    used->push_back(&e);
    index->emplace(e.view1, 0);
    index->emplace(e.view2, 0);
  }
  for (auto& [id, k] : *index) {
    k = static_cast<int>(views->size());
    AdjustedView v;
    v.id = id;
    v.rotation = orientations.at(id);
    Eigen::AngleAxisd angle_axis(v.rotation);
    v.angle_axis = angle_axis.angle() * angle_axis.axis();
    views->push_back(v);
  }
  std::vector<std::vector<double>> sigmas(views->size());
  for (const EdgeCorrespondences* e : *used) {
    sigmas[index->at(e->view1)].push_back(e->sigma);
    sigmas[index->at(e->view2)].push_back(e->sigma);
  }
  for (std::size_t v = 0; v < views->size(); ++v) {
    auto mid = sigmas[v].begin() + sigmas[v].size() / 2;
    std::nth_element(sigmas[v].begin(), mid, sigmas[v].end());
    (*views)[v].sigma = *mid;
  }
}

// Tracks: keypoints linked by the matches; a keypoint is its view and its
// coordinates, which are the same numbers in every edge it is in. Tracks
// holding two keypoints of one view, or seen in too few views, are left out.
std::vector<Track> BuildTracks(const std::vector<const EdgeCorrespondences*>& used, const std::map<ViewId, int>& index,
                               const BundleAdjustmentOptions& options, BundleAdjustmentSummary* summary) {
  std::map<std::tuple<int, double, double>, int> keypoints;
  std::vector<Observation> keypoint_list;
  std::vector<int> parent;
  auto keypoint = [&](int view, const Eigen::Vector2d& x) {
    const auto [it, added] = keypoints.emplace(std::make_tuple(view, x.x(), x.y()), static_cast<int>(parent.size()));
    if (added) {
      parent.push_back(it->second);
      keypoint_list.push_back({view, x});
    }
    return it->second;
  };
  for (const EdgeCorrespondences* e : used) {
    const int v1 = index.at(e->view1), v2 = index.at(e->view2);
    for (std::size_t m = 0; m < e->points1.size(); ++m) {
      const int a = keypoint(v1, e->points1[m]), b = keypoint(v2, e->points2[m]);  // in this order: ids by arrival
      Unite(&parent, a, b);
    }
  }
  std::map<int, Track> by_root;
  for (std::size_t k = 0; k < keypoint_list.size(); ++k) {
    by_root[Root(&parent, static_cast<int>(k))].observations.push_back(keypoint_list[k]);
  }
  std::vector<Track> tracks;
  for (auto& [root, track] : by_root) {
    std::vector<int> seen;
    for (const Observation& o : track.observations) seen.push_back(o.view);
    std::sort(seen.begin(), seen.end());
    if (std::adjacent_find(seen.begin(), seen.end()) != seen.end()) {
      ++summary->tracks_inconsistent;
      continue;
    }
    if (static_cast<int>(seen.size()) < std::max(2, options.min_track_views)) {
      ++summary->tracks_short;
      continue;
    }
    tracks.push_back(std::move(track));
  }
  return tracks;
}

ceres::Problem::Options ProblemOptions() {
  ceres::Problem::Options problem_options;
  problem_options.loss_function_ownership = ceres::DO_NOT_TAKE_OWNERSHIP;
  return problem_options;
}

// Centres by least unsquared deviations, the orientations held, from the
// edges with a translation direction; each group of views they connect has
// its first view's centre held, or, where `known` gives centres (an earlier
// adjustment's), those held and the others placed among them. False, with
// `message`, if Ceres fails.
bool PlaceCentres(const std::vector<const EdgeCorrespondences*>& used, const std::map<ViewId, int>& index,
                  const BundleAdjustmentOptions& options, const std::unordered_map<ViewId, Eigen::Vector3d>* known,
                  std::vector<AdjustedView>* views, BundleAdjustmentSummary* summary, std::string* message) {
  std::vector<int> linked(views->size());
  std::iota(linked.begin(), linked.end(), 0);
  for (const EdgeCorrespondences* e : used) {
    if (RotationOnly(*e)) continue;
    Unite(&linked, index.at(e->view1), index.at(e->view2));
  }
  std::vector<bool> group_given(views->size(), false);
  if (known) {
    for (std::size_t k = 0; k < views->size(); ++k) {
      const auto it = known->find((*views)[k].id);
      if (it == known->end() || !it->second.allFinite()) continue;
      (*views)[k].centre = it->second;
      (*views)[k].centre_given = true;
      group_given[Root(&linked, static_cast<int>(k))] = true;
    }
  }
  ceres::Problem problem(ProblemOptions());
  // sqrt(1 + r^2) - 1 on the norm of each edge's 3-vector: L1 beyond a
  // small fraction of the shortest baseline (s >= 1).
  ceres::SoftLOneLoss loss(0.01);
  std::vector<double> scales(used.size(), 1.0);
  for (std::size_t k = 0; k < used.size(); ++k) {
    const EdgeCorrespondences& e = *used[k];
    if (RotationOnly(e)) continue;
    AdjustedView& vi = (*views)[index.at(e.view1)];
    AdjustedView& vj = (*views)[index.at(e.view2)];
    const Eigen::Matrix3d r21 = vj.rotation * vi.rotation.transpose();
    // t_21 = R_j (c_i - c_j), so c_j - c_i = -R_j^T t_21.
    const Eigen::Vector3d d = -(vj.rotation.transpose() * BestTranslationDirection(e, r21)).normalized();
    problem.AddResidualBlock(new ceres::AutoDiffCostFunction<CentreDeviation, 3, 3, 3, 1>(new CentreDeviation(d)),
                             &loss, vi.centre.data(), vj.centre.data(), &scales[k]);
    problem.SetParameterLowerBound(&scales[k], 0, 1.0);
  }
  for (std::size_t k = 0; k < views->size(); ++k) {
    const int root = Root(&linked, static_cast<int>(k));
    const bool hold = group_given[root] ? (*views)[k].centre_given : root == static_cast<int>(k);
    if (hold && problem.HasParameterBlock((*views)[k].centre.data())) {
      problem.SetParameterBlockConstant((*views)[k].centre.data());
    }
  }
  if (problem.NumResidualBlocks() > 0) {
    ceres::Solver::Options solver_options = SolverOptions(options.max_iterations);
    solver_options.linear_solver_type = ceres::SPARSE_NORMAL_CHOLESKY;
    ceres::Solver::Summary ceres_summary;
    ceres::Solve(solver_options, &problem, &ceres_summary);
    summary->iterations += static_cast<int>(ceres_summary.iterations.size()) - 1;
    if (!ceres_summary.IsSolutionUsable()) {
      *message = ceres_summary.message;
      return false;
    }
  }
  // A view the directions leave out but a rotation-only pair links to one
  // they place was taken from that view's centre.
  std::vector<bool> placed(views->size());
  for (std::size_t k = 0; k < views->size(); ++k) {
    placed[k] = (*views)[k].centre_given || problem.HasParameterBlock((*views)[k].centre.data());
  }
  for (bool moved = true; moved;) {
    moved = false;
    for (const EdgeCorrespondences* e : used) {
      const int a = index.at(e->view1), b = index.at(e->view2);
      if (!RotationOnly(*e) || placed[a] == placed[b]) continue;
      const int from = placed[a] ? a : b, to = placed[a] ? b : a;
      (*views)[to].centre = (*views)[from].centre;
      placed[to] = moved = true;
    }
  }
  return true;
}

// Points from the midpoint of their rays; tracks whose rays meet at too
// small an angle are left out.
void TriangulateAll(const std::vector<AdjustedView>& views, double min_parallax_rad, std::vector<Track>* tracks,
                    BundleAdjustmentSummary* summary) {
  std::vector<Track> kept;
  for (Track& t : *tracks) {
    if (Triangulate(views, min_parallax_rad, &t)) {
      kept.push_back(std::move(t));
    } else {
      ++summary->tracks_unconstrained;
    }
  }
  *tracks = std::move(kept);
}

// RMS whitened reprojection error per coordinate.
double RmsSigmas(const std::vector<AdjustedView>& views, const std::vector<Track>& tracks) {
  double sum = 0.0;
  std::size_t n = 0;
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) sum += WhitenedSquaredError(views[o.view], t, o), ++n;
  }
  return n ? std::sqrt(sum / (2.0 * n)) : 0.0;
}

// Ends a stage once its cameras stand still: two successful steps in a row
// that turn no view by more than `rotation_rad`, move no centre by more than
// `centre_fraction` of the map's extent (the median distance of the centres
// from their mean) and change no focal scale by more than `focal`. The cost
// is no measure of that: points far from the cameras, which hardly hold a
// view, creep along their rays for many iterations while every camera is
// already where it stays (on the rendered rig the orientations settle to
// within 1e-6 rad in 6-10 iterations and Ceres' cost-based test then takes
// the stage to its iteration limit).
class CamerasSettled : public ceres::IterationCallback {
 public:
  CamerasSettled(const std::vector<AdjustedView>* views, double rotation_rad, double centre_fraction, double focal)
      : views_(views), rotation_rad_(rotation_rad), focal_(focal) {
    Eigen::Vector3d mean = Eigen::Vector3d::Zero();
    for (const AdjustedView& v : *views_) mean += v.centre;
    mean /= static_cast<double>(std::max<std::size_t>(1, views_->size()));
    std::vector<double> distance;
    for (const AdjustedView& v : *views_) distance.push_back((v.centre - mean).norm());
    double extent = 0.0;
    if (!distance.empty()) {
      std::nth_element(distance.begin(), distance.begin() + distance.size() / 2, distance.end());
      extent = distance[distance.size() / 2];
    }
    centre_ = centre_fraction * extent;
    Remember();
  }
  ceres::CallbackReturnType operator()(const ceres::IterationSummary& iteration) override {
    if (!iteration.step_is_successful || iteration.iteration == 0) return ceres::SOLVER_CONTINUE;
    bool still = true;
    for (std::size_t k = 0; k < views_->size() && still; ++k) {
      const AdjustedView& v = (*views_)[k];
      still = RotationAngleRad(Rotation(v) * rotations_[k].transpose()) <= rotation_rad_ &&
              (v.centre - centres_[k]).norm() <= centre_ &&
              std::abs(v.focal_scale - focal_scales_[k]) <= focal_;
    }
    Remember();
    settled_ = still ? settled_ + 1 : 0;
    return settled_ >= 2 ? ceres::SOLVER_TERMINATE_SUCCESSFULLY : ceres::SOLVER_CONTINUE;
  }

 private:
  void Remember() {
    rotations_.clear();
    centres_.clear();
    focal_scales_.clear();
    for (const AdjustedView& v : *views_) {
      rotations_.push_back(Rotation(v));
      centres_.push_back(v.centre);
      focal_scales_.push_back(v.focal_scale);
    }
  }
  Eigen::Matrix3d Rotation(const AdjustedView& v) const {
    return v.capture >= 0 ? Eigen::Matrix3d(v.from_rig * ExpSO3((*views_)[v.capture].rig_angle_axis))
                          : ExpSO3(v.angle_axis);
  }
  const std::vector<AdjustedView>* views_;
  const double rotation_rad_, focal_;
  double centre_ = 0.0;
  int settled_ = 0;
  std::vector<Eigen::Matrix3d> rotations_;
  std::vector<Eigen::Vector3d> centres_;
  std::vector<double> focal_scales_;
};

// The reduced camera system's size up to which the adjustment eliminates
// the points into a dense matrix (DENSE_SCHUR) rather than a sparse one.
// Up to a few hundred views the dense matrix is indexed directly where the
// sparse one looks every block up in a hash map as the points are
// eliminated, and its Cholesky factor costs a few milliseconds
// (docs/decisions.md). Beyond it (an offline map of thousands of views) the
// dense factor's cubic cost takes over.
constexpr int kDenseSchurMaxDimension = 1500;

// The tangent dimension of the variables the Schur complement keeps: the
// ordering's second group (views, captures and focal scales) less those
// held constant.
int CameraSystemDimension(const ceres::Problem& problem, const ceres::ParameterBlockOrdering& ordering) {
  const auto& groups = ordering.group_to_elements();
  const auto it = groups.find(1);
  if (it == groups.end()) return 0;
  int dimension = 0;
  for (double* block : it->second) {
    if (!problem.IsParameterBlockConstant(block)) dimension += problem.ParameterBlockTangentSize(block);
  }
  return dimension;
}

// Minimises the whitened reprojection errors under `loss` over points,
// centres and (unless held) orientations and the cameras' focal scales
// (`focal_scales`, by AdjustedView::camera). True if the solution is usable.
bool Adjust(bool hold_orientations, ceres::LossFunction* loss, const BundleAdjustmentOptions& options,
            std::vector<AdjustedView>* views, std::vector<Track>* tracks, std::vector<double>* focal_scales,
            BundleAdjustmentSummary* summary, ceres::Solver::Summary* ceres_summary) {
  ceres::Problem problem(ProblemOptions());
  auto* ordering = new ceres::ParameterBlockOrdering;
  summary->observations = 0;
  // Each camera's scale is one parameter block: the focal_scale of its
  // first view, so that it lies among the views' blocks, in their order.
  // Ceres orders a group's blocks by address (ParameterBlockOrdering holds
  // a set of pointers), the fill-reducing ordering of the Schur complement
  // starts from that order, and a different one changes the last bits: an
  // array of their own would lie before or after the views as the heap
  // has it, and a replay's refined orientations differed from run to run.
  std::vector<int> first_view(focal_scales->size(), -1);
  for (std::size_t k = 0; k < views->size(); ++k) {
    AdjustedView& v = (*views)[k];
    if (v.camera < 0 || first_view[v.camera] >= 0) continue;
    first_view[v.camera] = static_cast<int>(k);
    v.focal_scale = (*focal_scales)[v.camera];
  }
  for (Track& t : *tracks) {
    problem.AddParameterBlock(t.point.data(), 3);
    ordering->AddElementToGroup(t.point.data(), 0);
    for (const Observation& o : t.observations) {
      AdjustedView& v = (*views)[o.view];
      double* w = RotationBlock(views, o.view);
      if (v.camera >= 0) {
        double* a = &(*views)[first_view[v.camera]].focal_scale;
        problem.AddResidualBlock(new ReprojectionCost(o.x, 1.0 / v.sigma, FromRig(v), true), loss, w,
                                 v.centre.data(), t.point.data(), a);
        ordering->AddElementToGroup(a, 1);
        if (hold_orientations) problem.SetParameterBlockConstant(a);
      } else {
        problem.AddResidualBlock(new ReprojectionCost(o.x, 1.0 / v.sigma, FromRig(v), false), loss, w,
                                 v.centre.data(), t.point.data());
      }
      ++summary->observations;
    }
  }
  // The gauge of each group of views the tracks connect: its first view's
  // orientation and centre are held, and one coordinate of the centre of
  // the view farthest from it (its largest offset), which fixes the scale;
  // a free gauge would leave the normal equations singular. The farthest:
  // a view near the first (the next keyframe of a camera that turned in
  // place, where step 2 put it a unit away) holds the scale by a baseline
  // the tracks hardly see, and the adjustment then spends its iterations
  // growing the rest of the map away from that pair (on the rendered rig,
  // its extent 500-fold over 40 iterations, none of them converged). Where
  // an earlier adjustment gave centres, both views are of those: the views
  // step 2 placed among them are rough.
  // A rig's captures tie the groups their cameras' tracks make: each group
  // of views the tracks or the captures connect has one rotation held (its
  // first group's first view's), and each group the tracks connect its own
  // centre and scale.
  std::vector<int> group(views->size());
  std::iota(group.begin(), group.end(), 0);
  for (const Track& t : *tracks) {
    for (const Observation& o : t.observations) Unite(&group, t.observations.front().view, o.view);
  }
  std::vector<int> turning = WithCaptures(group, *views);
  std::vector<bool> rotation_held(views->size(), false);
  // A view given as held holds its rotation (its capture's), and with it
  // the rotation gauge of every view that turns with it or that the tracks
  // tie to it: the group's first view then holds its centre only.
  for (std::size_t k = 0; k < views->size(); ++k) {
    if (!(*views)[k].orientation_held || !problem.HasParameterBlock((*views)[k].centre.data())) continue;
    problem.SetParameterBlockConstant(RotationBlock(views, static_cast<int>(k)));
    rotation_held[Root(&turning, static_cast<int>(k))] = true;
  }
  std::vector<bool> group_given(views->size(), false);
  for (std::size_t k = 0; k < views->size(); ++k) {
    if ((*views)[k].centre_given && problem.HasParameterBlock((*views)[k].centre.data())) {
      group_given[Root(&group, static_cast<int>(k))] = true;
    }
  }
  const auto candidate = [&](std::size_t k, int g) { return !group_given[g] || (*views)[k].centre_given; };
  std::vector<int> first(views->size(), -1);
  for (std::size_t k = 0; k < views->size(); ++k) {
    AdjustedView& v = (*views)[k];
    if (!problem.HasParameterBlock(v.centre.data())) continue;
    double* w = RotationBlock(views, static_cast<int>(k));
    ordering->AddElementToGroup(w, 1);
    ordering->AddElementToGroup(v.centre.data(), 1);
    const int g = Root(&group, static_cast<int>(k));
    if (hold_orientations) problem.SetParameterBlockConstant(w);
    if (first[g] < 0 && candidate(k, g)) first[g] = static_cast<int>(k);
  }
  std::vector<int> farthest(views->size(), -1);
  std::vector<double> distance(views->size(), 0.0);
  for (std::size_t k = 0; k < views->size(); ++k) {
    const AdjustedView& v = (*views)[k];
    if (!problem.HasParameterBlock(v.centre.data())) continue;
    const int g = Root(&group, static_cast<int>(k));
    if (first[g] == static_cast<int>(k)) {
      const int turns = Root(&turning, static_cast<int>(k));
      if (!rotation_held[turns]) problem.SetParameterBlockConstant(RotationBlock(views, static_cast<int>(k)));
      rotation_held[turns] = true;
      problem.SetParameterBlockConstant(v.centre.data());
      continue;
    }
    // (A view at its first view's centre, across a rotation-only pair,
    // cannot hold the scale.)
    const double d = (v.centre - (*views)[first[g]].centre).norm();
    if (candidate(k, g) && d > distance[g]) {
      distance[g] = d;
      farthest[g] = static_cast<int>(k);
    }
  }
  for (std::size_t g = 0; g < views->size(); ++g) {
    if (farthest[g] < 0) continue;
    const AdjustedView& v = (*views)[farthest[g]];
    int axis = 0;
    (v.centre - (*views)[first[g]].centre).cwiseAbs().maxCoeff(&axis);
    problem.SetManifold((*views)[farthest[g]].centre.data(), new ceres::SubsetManifold(3, {axis}));
  }
  ceres::Solver::Options solver_options = SolverOptions(options.max_iterations);
  if (CameraSystemDimension(problem, *ordering) <= kDenseSchurMaxDimension) {
    solver_options.linear_solver_type = ceres::DENSE_SCHUR;
  }
  solver_options.linear_solver_ordering.reset(ordering);
  // The first stage only places centres and points for the next (its
  // orientations held): a thousandth of the map's extent is enough there.
  CamerasSettled settled(views, options.settled_rotation_rad,
                         hold_orientations ? 1e2 * options.settled_centre_fraction : options.settled_centre_fraction,
                         options.settled_focal);
  solver_options.update_state_every_iteration = true;
  solver_options.callbacks.push_back(&settled);
  ceres::Solve(solver_options, &problem, ceres_summary);
  summary->iterations += static_cast<int>(ceres_summary->iterations.size()) - 1;
  summary->failed_steps += static_cast<int>(
      std::count_if(ceres_summary->iterations.begin() + (ceres_summary->iterations.empty() ? 0 : 1),
                    ceres_summary->iterations.end(), [](const ceres::IterationSummary& i) { return !i.step_is_valid; }));
  for (std::size_t c = 0; c < first_view.size(); ++c) {
    if (first_view[c] >= 0) (*focal_scales)[c] = (*views)[first_view[c]].focal_scale;
  }
  for (AdjustedView& v : *views) {
    v.rotation = CurrentRotation(*views, v);
    if (v.capture >= 0) {
      const Eigen::AngleAxisd own(v.rotation);
      v.angle_axis = own.angle() * own.axis();
    }
    if (v.camera >= 0) v.focal_scale = (*focal_scales)[v.camera];
  }
  return ceres_summary->IsSolutionUsable();
}

// Drops the observations beyond options.outlier_sigmas, then the tracks left
// in too few views.
void DropOutlierObservations(const std::vector<AdjustedView>& views, const BundleAdjustmentOptions& options,
                             std::vector<Track>* tracks, BundleAdjustmentSummary* summary) {
  const double outlier = options.outlier_sigmas * options.outlier_sigmas;
  std::vector<Track> kept;
  for (Track& t : *tracks) {
    Track fitted;
    for (const Observation& o : t.observations) {
      if (WhitenedSquaredError(views[o.view], t, o) <= outlier) {
        fitted.observations.push_back(o);
      } else {
        ++summary->observations_dropped;
      }
    }
    if (static_cast<int>(fitted.observations.size()) >= std::max(2, options.min_track_views)) {
      kept.push_back(std::move(fitted));
    }
  }
  *tracks = std::move(kept);
}

// The cell of each observation's view: a grid x grid partition of the
// bounding box of that view's observations; one index per (view, cell) that
// holds any, in the order of the views.
std::vector<std::vector<int>> ObservationCells(const std::vector<AdjustedView>& views, const std::vector<Track>& tracks,
                                               int grid, int* cells) {
  const std::size_t n = views.size();
  std::vector<Eigen::Vector2d> lo(n, Eigen::Vector2d::Constant(INFINITY)), hi(n, Eigen::Vector2d::Constant(-INFINITY));
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) {
      lo[o.view] = lo[o.view].cwiseMin(o.x);
      hi[o.view] = hi[o.view].cwiseMax(o.x);
    }
  }
  const auto cell_index = [grid](double v, double low, double high) {
    return high > low ? std::clamp(static_cast<int>((v - low) / (high - low) * grid), 0, grid - 1) : 0;
  };
  const auto key = [&](const Observation& o) {
    const int v = o.view;
    return std::make_pair(v, cell_index(o.x.y(), lo[v].y(), hi[v].y()) * grid + cell_index(o.x.x(), lo[v].x(), hi[v].x()));
  };
  std::map<std::pair<int, int>, int> numbered;  // in (view, cell) order, whatever order the tracks meet them in
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) numbered.emplace(key(o), 0);
  }
  int next = 0;
  for (auto& [cell, number] : numbered) number = next++;
  std::vector<std::vector<int>> out(tracks.size());
  for (std::size_t k = 0; k < tracks.size(); ++k) {
    for (const Observation& o : tracks[k].observations) out[k].push_back(numbered.at(key(o)));
  }
  *cells = next;
  return out;
}

// E[w x] / E[x] for x the squared norm of a 2-vector of unit Gaussian noise
// (chi-square, 2 degrees of freedom) and w = 1 / (1 + x / a^2) Cauchy's
// weight at scale a: what Cauchy's weights take off the sum of squares of
// residuals that are all inliers (0.72 at a = 3), so that dividing by it
// makes the variance factor 1 on noise the pixel model describes.
double CauchyWeightedSquaresFraction(double a) {
  const double a2 = a * a, step = 0.01;
  double weighted = 0.0;
  for (double x = 0.5 * step; x < 80.0; x += step) weighted += x / (1.0 + x / a2) * 0.5 * std::exp(-0.5 * x) * step;
  return weighted / 2.0;
}

Eigen::Matrix3d Skew(const Eigen::Vector3d& v) {
  Eigen::Matrix3d m;
  m << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return m;
}

// A view's variables in the covariance's normal equations: the first of
// its rotation's three and the first of its centre's three (-1: held).
struct ViewVariables {
  std::array<int, 2> at{-1, -1};
  bool All() const { return at[0] >= 0 && at[1] >= 0; }
  // Of its q-th of six (rotation, centre); -1: held.
  int Index(int q) const { return at[q / 3] >= 0 ? at[q / 3] + q % 3 : -1; }
};

// s(i, j) += m, m over the six of each view; held parts left out.
template <typename M>
void AddBlock(const ViewVariables& i, const ViewVariables& j, const M& m, Eigen::MatrixXd* s) {
  for (int p = 0; p < 2; ++p) {
    if (i.at[p] < 0) continue;
    for (int q = 0; q < 2; ++q) {
      if (j.at[q] >= 0) s->block<3, 3>(i.at[p], j.at[q]) += m.template block<3, 3>(3 * p, 3 * q);
    }
  }
}

// column `c` of `m` at the view's variables += v (six).
template <typename V>
void AddSegment(const ViewVariables& i, const V& v, int c, Eigen::MatrixXd* m) {
  for (int p = 0; p < 2; ++p) {
    if (i.at[p] >= 0) m->col(c).segment<3>(i.at[p]) += v.template segment<3>(3 * p);
  }
}

// The bias-reduced linearisation's gain g(l) = ((1 - l)^-1/2 - 1) / l for a
// leverage l in [0, 1], clamped to 0.99 (where one cell or cluster alone
// fixes a direction, (1 - l)^-1/2 diverges): (I - H)^-1/2 u = u + H g(H) u.
double BiasReducedGain(double leverage) {
  const double l = std::clamp(leverage, 0.0, 0.99);
  return l > 1e-9 ? (1.0 / std::sqrt(1.0 - l) - 1.0) / l : 0.5;
}

// What the bias-reduced linearisation adds to a cluster's score u, with D
// its information and K the block of S^-1 over its variables: D g(K D) K u,
// g (BiasReducedGain) on the eigenvalues of the leverage K D. By Lanczos'
// method in the inner product
// <x, y> = x^T D y, in which K D is symmetric: k steps over the Krylov space
// of K D and K u (fully reorthogonalised), g taken on the k x k
// tridiagonal's eigenvalues. What of K u the inner product does not see is
// in the null space of D, where g(K D) is g(0) and D then takes it out. A
// cluster of tracks spans tens to hundreds of variables, where factoring or
// diagonalising for each cluster would be most of the covariance's time; g
// is smooth on [0, 0.99], and 24 steps (all of them, below 24 variables)
// leave it exact where the leverage has few large eigenvalues.
Eigen::VectorXd LeverageGain(const Eigen::MatrixXd& k_block, const Eigen::MatrixXd& d, const Eigen::VectorXd& u) {
  const int n = static_cast<int>(u.size());
  const Eigen::VectorXd z = k_block * u;
  Eigen::VectorXd dz = d * z;
  const double norm2 = z.dot(dz);
  if (!(norm2 > 0.0)) return Eigen::VectorXd::Zero(n);
  const double norm = std::sqrt(norm2);
  const int k_max = std::min(n, 24);
  Eigen::MatrixXd q(n, k_max), dq(n, k_max);  // the basis, and D times it
  Eigen::VectorXd alpha(k_max), beta(k_max);
  q.col(0) = z / norm;
  dq.col(0) = dz / norm;
  int k = 0;
  while (k < k_max) {
    Eigen::VectorXd v = k_block * dq.col(k);
    alpha[k] = dq.col(k).dot(v);
    for (int twice = 0; twice < 2; ++twice) v -= q.leftCols(k + 1) * (dq.leftCols(k + 1).transpose() * v);
    const Eigen::VectorXd dv = d * v;
    const double b2 = v.dot(dv);
    beta[k] = b2 > 0.0 ? std::sqrt(b2) : 0.0;
    ++k;
    if (k == k_max || !(beta[k - 1] > 1e-12 * (std::abs(alpha[k - 1]) + 1.0))) break;
    q.col(k) = v / beta[k - 1];
    dq.col(k) = dv / beta[k - 1];
  }
  Eigen::MatrixXd t = Eigen::MatrixXd::Zero(k, k);
  for (int i = 0; i < k; ++i) {
    t(i, i) = alpha[i];
    if (i + 1 < k) t(i, i + 1) = t(i + 1, i) = beta[i];
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(t);
  Eigen::VectorXd g(k);
  for (int i = 0; i < k; ++i) {
    g[i] = BiasReducedGain(eigen.eigenvalues()[i]);
  }
  // D Q_k g(T) e_1 |z|_D.
  return norm * (dq.leftCols(k) * (eigen.eigenvectors() * (g.asDiagonal() * eigen.eigenvectors().row(0).transpose())));
}

// The orientations' joint covariance at the adjusted solution under Cauchy's
// loss of scale `loss_scale` (see BundleAdjustmentCovariance): the normal
// equations over each view's left rotation perturbation and centre, each
// track's point eliminated (its 3 x 3 block), every observation weighted by
// the loss' rho'. Each group's held view (the first of it, as Adjust holds
// it) has no variables; the scale, which Adjust holds through one
// coordinate, is held here by a penalty along the direction that scales
// every centre about the held one, which no observation sees, so that the
// rotations' covariance does not depend on which coordinate held it.
// The jackknife: each cell's move, S^-1 u_c with u_c its score on the
// reduced system (corrected for its leverage, below), the one Gauss-Newton
// step its observations pull the solution by, and
// C = (g - 1) / g sum_c (m_c - mean)(m_c - mean)^T over the g cells. With
// `track_clusters`, the same over clusters of whole tracks, those that
// start in one cell (their points eliminated within the cluster).
// With `focal` (one entry per estimated camera, AdjustedView::camera), each
// camera's focal scale is a variable too, and its deviation is filled in
// (BundleAdjustmentFocal): its principal point's offset is a further
// variable there, of prior deviation `principal_point_sigma` times the
// width of the camera's observations, for that part alone.
bool ComputeCovariance(const std::vector<AdjustedView>& views, const std::vector<Track>& tracks, double loss_scale,
                       int grid, bool track_clusters, double principal_point_sigma, BundleAdjustmentCovariance* out,
                       std::vector<BundleAdjustmentFocal::Estimate>* focal) {
  const int n = static_cast<int>(views.size());
  std::vector<int> group(n);
  std::iota(group.begin(), group.end(), 0);
  std::vector<bool> observed(n, false);
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) {
      Unite(&group, t.observations.front().view, o.view);
      observed[o.view] = true;
    }
  }
  // As Adjust holds them: each group the tracks connect its first view's
  // centre (and its scale, below), each group the tracks or a rig's
  // captures connect one rotation, that of its first view. A view's
  // variables (ViewVariables): its rotation's (a rig camera's: its
  // capture's, which its cameras share), then its centre's.
  std::vector<int> turning = WithCaptures(group, views);
  std::vector<ViewVariables> var(n);
  std::vector<int> held(n, -1), block_variable(n, -1);  // by rotation block: -2 held
  std::vector<bool> rotation_held(n, false);
  int dim = 0, groups = 0;
  for (int k = 0; k < n; ++k) {
    if (!observed[k]) continue;
    const int g = Root(&group, k);
    int& block = block_variable[views[k].capture >= 0 ? views[k].capture : k];
    bool centre_held = false;
    if (held[g] < 0) {
      held[g] = k;
      ++groups;
      centre_held = true;
      // (The first view of its rotation's group too, if the first of its
      // groups: no view of that group has placed the block before it.)
      const int t = Root(&turning, k);
      if (!rotation_held[t] && block == -1) block = -2;
      rotation_held[t] = true;
    }
    if (block == -1) block = dim, dim += 3;
    var[k].at[0] = std::max(block, -1);
    if (!centre_held) var[k].at[1] = dim, dim += 3;
  }
  if (dim == 0) return false;
  // After the views' variables: each estimated camera's focal scale, then
  // its principal point's offset (two).
  const int view_dim = dim, cameras = focal ? static_cast<int>(focal->size()) : 0;
  std::vector<int> var_f(cameras, -1), var_p(cameras, -1);
  std::vector<double> lo_x(cameras, INFINITY), hi_x(cameras, -INFINITY);
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) {
      const int c = views[o.view].camera;
      if (c < 0 || c >= cameras) continue;
      lo_x[c] = std::min(lo_x[c], o.x.x());
      hi_x[c] = std::max(hi_x[c], o.x.x());
    }
  }
  for (int c = 0; c < cameras; ++c) {
    if (hi_x[c] > lo_x[c]) var_f[c] = dim++;
  }
  const int focal_dim = dim;
  for (int c = 0; c < cameras; ++c) {
    if (var_f[c] >= 0) var_p[c] = dim, dim += 2;
  }
  int cells = 0;
  const std::vector<std::vector<int>> cell_of = ObservationCells(views, tracks, std::max(1, grid), &cells);
  Eigen::MatrixXd s = Eigen::MatrixXd::Zero(dim, dim);
  Eigen::MatrixXd scores = grid > 0 ? Eigen::MatrixXd::Zero(dim, cells) : Eigen::MatrixXd();
  // Each cell's information on its own view's variables (the points
  // eliminated), for its leverage; and the view's first variable (-1: held).
  std::vector<Eigen::Matrix<double, 6, 6>> cell_information(grid > 0 ? cells : 0,
                                                            Eigen::Matrix<double, 6, 6>::Zero());
  std::vector<int> cell_view(grid > 0 ? cells : 0, -1);
  const double a2 = loss_scale * loss_scale;
  double weighted_squares = 0.0;
  // Sums of Cauchy's weights and of their squares over the observations:
  // the jackknives' bread (below).
  double weight_sum = 0.0, squared_weight_sum = 0.0;
  std::size_t residuals = 0;
  using Matrix63 = Eigen::Matrix<double, 6, 3>;
  using Matrix26 = Eigen::Matrix<double, 2, 6>;
  using Vector6d = Eigen::Matrix<double, 6, 1>;
  std::vector<Matrix63> b;
  std::vector<Eigen::Vector3d> gx;
  std::vector<Eigen::Matrix<double, 6, 6>> a;
  std::vector<Vector6d> gc;
  // An observation's focal scale and principal point offset (e: 3 columns,
  // their variables in ei; -1 where its view's camera is not estimated).
  std::vector<Eigen::Matrix3d> be, aee;
  std::vector<Eigen::Matrix<double, 3, 6>> aec;
  std::vector<Eigen::Vector3d> ge;
  std::vector<std::array<int, 3>> ei;
  // What the leverage correction's second pass needs of each track (grid > 0):
  // its point's inverse information and each observation's coupling of its
  // view to the point (and of its camera's focal scale, where estimated).
  struct Eliminated {
    bool used = false;
    Eigen::Matrix3d hpp_inv;
    std::vector<Matrix63> b;
    std::vector<Eigen::RowVector3d> focal_b;
    std::vector<Eigen::Matrix<double, 1, 6>> focal_view;
    std::vector<int> focal_row;
  };
  std::vector<Eliminated> eliminated(grid > 0 ? tracks.size() : 0);
  // The clusters of whole tracks (track_clusters): the tracks that start in
  // one cell, each cluster's information and score over its own variables
  // (its tracks' views' and focal scales', sorted), the points eliminated.
  // Made one cluster at a time once S^-1 is known, each from its tracks
  // linearised again: held for every cluster at once, their information
  // took 0.3-0.5 GiB on the 600-keyframe bag's windows.
  struct TrackCluster {
    std::vector<int> variables;
    std::vector<std::size_t> members;  // its tracks
  };
  std::vector<TrackCluster> clusters(track_clusters && grid > 0 ? cells : 0);
  const auto observation_variables = [&](const Observation& o) {
    std::array<int, 7> at;
    for (int q = 0; q < 6; ++q) at[q] = var[o.view].Index(q);
    const int c = views[o.view].camera;
    at[6] = c >= 0 && c < cameras ? var_f[c] : -1;
    return at;
  };
  if (!clusters.empty()) {
    for (std::size_t k = 0; k < tracks.size(); ++k) {
      clusters[cell_of[k][0]].members.push_back(k);
      std::vector<int>& v = clusters[cell_of[k][0]].variables;
      for (const Observation& o : tracks[k].observations) {
        for (const int at : observation_variables(o)) {
          if (at >= 0) v.push_back(at);
        }
      }
    }
    for (TrackCluster& c : clusters) {
      std::sort(c.variables.begin(), c.variables.end());
      c.variables.erase(std::unique(c.variables.begin(), c.variables.end()), c.variables.end());
    }
  }
  // A track's observations linearised at the solution (b, gx, a, gc and
  // the focal rows above; if *squares is given, their weighted squared
  // residuals added to it and their weights to weight_sum and
  // squared_weight_sum, once per track in the first pass): its point's
  // information, which eliminating the point inverts.
  const auto linearise = [&](std::size_t k, double* squares) -> Eigen::Matrix3d {
    const Track& t = tracks[k];
    const std::size_t m = t.observations.size();
    b.assign(m, Matrix63::Zero());
    gx.assign(m, Eigen::Vector3d::Zero());
    a.assign(m, Eigen::Matrix<double, 6, 6>::Zero());
    gc.assign(m, Vector6d::Zero());
    if (cameras > 0) {
      be.assign(m, Eigen::Matrix3d::Zero());
      aee.assign(m, Eigen::Matrix3d::Zero());
      aec.assign(m, Eigen::Matrix<double, 3, 6>::Zero());
      ge.assign(m, Eigen::Vector3d::Zero());
      ei.assign(m, {-1, -1, -1});
    }
    Eigen::Matrix3d hpp = Eigen::Matrix3d::Zero();
    for (std::size_t i = 0; i < m; ++i) {
      const Observation& o = t.observations[i];
      const AdjustedView& v = views[o.view];
      const Eigen::Vector3d y = v.rotation * (t.point - v.centre);
      Eigen::Matrix<double, 2, 3> p;
      p << 1.0 / y.z(), 0.0, -y.x() / (y.z() * y.z()), 0.0, 1.0 / y.z(), -y.y() / (y.z() * y.z());
      p /= v.sigma;
      const bool estimated = v.camera >= 0 && v.camera < cameras && var_f[v.camera] >= 0;
      if (estimated) p *= v.focal_scale;
      const Eigen::Vector2d r = (v.focal_scale * (y.head<2>() / y.z()) - o.x) / v.sigma;
      const double w = 1.0 / (1.0 + r.squaredNorm() / a2);
      Matrix26 jc;
      jc.leftCols<3>() = -p * Skew(y);
      // A rig camera turns by its capture's perturbation: d_view = E d_capture.
      if (v.capture >= 0) jc.leftCols<3>() = (jc.leftCols<3>() * v.from_rig).eval();
      jc.rightCols<3>() = -p * v.rotation;
      const Eigen::Matrix<double, 2, 3> jx = p * v.rotation;
      hpp.noalias() += w * jx.transpose() * jx;
      b[i] = w * jc.transpose() * jx;
      gx[i] = w * jx.transpose() * r;
      a[i] = w * jc.transpose() * jc;
      gc[i] = w * jc.transpose() * r;
      if (estimated) {
        // d r / d a = proj / sigma; d r / d offset = I / sigma (x = a proj + offset).
        Eigen::Matrix<double, 2, 3> je;
        je.col(0) = y.head<2>() / (y.z() * v.sigma);
        je.rightCols<2>() = Eigen::Matrix2d::Identity() / v.sigma;
        be[i] = w * je.transpose() * jx;
        aee[i] = w * je.transpose() * je;
        aec[i] = w * je.transpose() * jc;
        ge[i] = w * je.transpose() * r;
        ei[i] = {var_f[v.camera], var_p[v.camera], var_p[v.camera] + 1};
      }
      if (squares) {
        *squares += w * r.squaredNorm();
        weight_sum += w;
        squared_weight_sum += w * w;
      }
    }
    return hpp;
  };
  // The track's reduced information and score, of what linearise left:
  // over each observation's view (six) and focal scale (one),
  // D = A - B Hpp^-1 B^T and u = g - B Hpp^-1 g_x, added to its cluster's
  // (over the cluster's variables).
  const auto add_to_cluster = [&](const Track& t, const Eigen::Matrix3d& hpp_inv, const TrackCluster& cluster,
                                  Eigen::MatrixXd* information, Eigen::VectorXd* score) {
    const std::size_t m = t.observations.size();
    using Matrix73 = Eigen::Matrix<double, 7, 3>;
    std::vector<std::array<int, 7>> local(m);
    std::vector<Matrix73> b7(m, Matrix73::Zero());
    Eigen::Vector3d gx_sum = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < m; ++i) gx_sum += gx[i];
    for (std::size_t i = 0; i < m; ++i) {
      const std::array<int, 7> at = observation_variables(t.observations[i]);
      for (int q = 0; q < 7; ++q) {
        local[i][q] = at[q] < 0 ? -1
                                : static_cast<int>(std::lower_bound(cluster.variables.begin(),
                                                                    cluster.variables.end(), at[q]) -
                                                   cluster.variables.begin());
      }
      b7[i].topRows<6>() = b[i];
      Eigen::Matrix<double, 7, 7> a7 = Eigen::Matrix<double, 7, 7>::Zero();
      a7.topLeftCorner<6, 6>() = a[i];
      Eigen::Matrix<double, 7, 1> g7 = Eigen::Matrix<double, 7, 1>::Zero();
      g7.head<6>() = gc[i];
      if (cameras > 0 && ei[i][0] >= 0) {
        b7[i].row(6) = be[i].row(0);
        a7.block<1, 6>(6, 0) = aec[i].row(0);
        a7.block<6, 1>(0, 6) = aec[i].row(0).transpose();
        a7(6, 6) = aee[i](0, 0);
        g7[6] = ge[i](0);
      }
      g7 -= b7[i] * (hpp_inv * gx_sum);
      for (int p = 0; p < 7; ++p) {
        if (local[i][p] < 0) continue;
        (*score)[local[i][p]] += g7[p];
        for (int q = 0; q < 7; ++q) {
          if (local[i][q] >= 0) (*information)(local[i][p], local[i][q]) += a7(p, q);
        }
      }
    }
    for (std::size_t i = 0; i < m; ++i) {
      const Matrix73 bi = b7[i] * hpp_inv;
      for (std::size_t j = 0; j < m; ++j) {
        const Eigen::Matrix<double, 7, 7> cross = bi * b7[j].transpose();
        for (int p = 0; p < 7; ++p) {
          if (local[i][p] < 0) continue;
          for (int q = 0; q < 7; ++q) {
            if (local[j][q] >= 0) (*information)(local[i][p], local[j][q]) -= cross(p, q);
          }
        }
      }
    }
  };
  for (std::size_t k = 0; k < tracks.size(); ++k) {
    const Track& t = tracks[k];
    const std::size_t m = t.observations.size();
    const Eigen::Matrix3d hpp = linearise(k, &weighted_squares);
    residuals += 2 * m;
    // (Triangulated with parallax, so not expected: a point the weights leave
    // undetermined is left out, as if its track were not there.)
    const Eigen::LDLT<Eigen::Matrix3d> ldlt(hpp);
    if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) continue;
    const Eigen::Matrix3d hpp_inv = ldlt.solve(Eigen::Matrix3d::Identity());
    if (grid > 0) {
      Eliminated& e = eliminated[k];
      e.used = true;
      e.hpp_inv = hpp_inv;
      e.b = b;
      if (cameras > 0) {
        for (std::size_t i = 0; i < m; ++i) {
          e.focal_b.push_back(be[i].row(0));
          e.focal_view.push_back(aec[i].row(0));
          e.focal_row.push_back(ei[i][0]);
        }
      }
    }
    for (std::size_t i = 0; i < m; ++i) {
      const ViewVariables& vi = var[t.observations[i].view];
      if (vi.at[0] < 0 && vi.at[1] < 0) continue;
      AddBlock(vi, vi, a[i], &s);
      const Matrix63 bi = b[i] * hpp_inv;
      if (grid > 0) {
        AddSegment(vi, gc[i], cell_of[k][i], &scores);
        cell_information[cell_of[k][i]] += a[i] - bi * b[i].transpose();
        // (A view with its rotation or centre held has no leverage
        // correction: its cell's block is not of its own variables.)
        if (vi.All()) cell_view[cell_of[k][i]] = t.observations[i].view;
      }
      for (std::size_t j = 0; j < m; ++j) {
        const Eigen::Matrix<double, 6, 6> cross = -(bi * b[j].transpose());
        AddBlock(vi, var[t.observations[j].view], cross, &s);
      }
      if (grid > 0) {
        for (std::size_t j = 0; j < m; ++j) {
          const Vector6d pull = -(bi * gx[j]);
          AddSegment(vi, pull, cell_of[k][j], &scores);
        }
      }
    }
    if (cameras > 0) {
      // The focal scales' and principal points' rows and columns: the
      // same elimination of the point, element by element.
      for (std::size_t i = 0; i < m; ++i) {
        const ViewVariables& vi = var[t.observations[i].view];
        if (ei[i][0] < 0) continue;
        const Eigen::Matrix3d bei = be[i] * hpp_inv;
        for (int p = 0; p < 3; ++p) {
          for (int q = 0; q < 3; ++q) s(ei[i][p], ei[i][q]) += aee[i](p, q);
          for (int q = 0; q < 6; ++q) {
            const int at = vi.Index(q);
            if (at < 0) continue;
            s(ei[i][p], at) += aec[i](p, q);
            s(at, ei[i][p]) += aec[i](p, q);
          }
          if (grid > 0 && p == 0) scores(ei[i][0], cell_of[k][i]) += ge[i](0);
        }
        for (std::size_t j = 0; j < m; ++j) {
          const ViewVariables& vj = var[t.observations[j].view];
          const Eigen::Matrix<double, 3, 6> cross = bei * b[j].transpose();
          for (int p = 0; p < 3; ++p) {
            for (int q = 0; q < 6; ++q) {
              const int at = vj.Index(q);
              if (at < 0) continue;
              s(ei[i][p], at) -= cross(p, q);
              s(at, ei[i][p]) -= cross(p, q);
            }
          }
          if (ei[j][0] >= 0) {
            const Eigen::Matrix3d both = bei * be[j].transpose();
            for (int p = 0; p < 3; ++p) {
              for (int q = 0; q < 3; ++q) s(ei[i][p], ei[j][q]) -= both(p, q);
            }
          }
          if (grid > 0) scores(ei[i][0], cell_of[k][j]) -= bei.row(0).dot(gx[j]);
        }
      }
    }
  }
  // Each view's own block, before the scale's penalty: the cells' leverage.
  std::vector<Eigen::Matrix<double, 6, 6>> view_blocks(n);
  for (int k = 0; k < n; ++k) {
    if (!var[k].All()) continue;
    for (int p = 0; p < 6; ++p) {
      for (int q = 0; q < 6; ++q) view_blocks[k](p, q) = s(var[k].Index(p), var[k].Index(q));
    }
  }
  // The scale direction of each group, held by a penalty on its own scale.
  const double penalty = s.topLeftCorner(view_dim, view_dim).trace() / view_dim;
  for (int g = 0; g < n; ++g) {
    if (held[g] < 0) continue;
    Eigen::VectorXd direction = Eigen::VectorXd::Zero(view_dim);
    for (int k = 0; k < n; ++k) {
      if (var[k].at[1] >= 0 && Root(&group, k) == g) {
        direction.segment<3>(var[k].at[1]) = views[k].centre - views[held[g]].centre;
      }
    }
    if (direction.norm() > 0.0) direction.normalize();
    s.topLeftCorner(view_dim, view_dim).noalias() += penalty * direction * direction.transpose();
  }
  // S^-1 restricted to the rotations' columns. A direction the tracks hardly
  // fix (a wall seen head on: turning the cameras and moving them sideways
  // together, bas-relief) leaves S close to singular, and the sums of the
  // elimination can leave it a little indefinite there: then its eigenvalues
  // are floored at 1e-12 of the largest, a variance as large as the
  // adjustment can express (what it can say: nothing).
  const auto inverse_columns = [](const Eigen::MatrixXd& s, const Eigen::MatrixXd& rhs) -> Eigen::MatrixXd {
    const Eigen::LLT<Eigen::MatrixXd> llt(s);
    if (llt.info() == Eigen::Success) return llt.solve(rhs);
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(s);
    if (eigen.info() != Eigen::Success) return Eigen::MatrixXd();
    const double floor = 1e-12 * eigen.eigenvalues().cwiseAbs().maxCoeff();
    const Eigen::VectorXd inverse = eigen.eigenvalues().cwiseMax(floor).cwiseInverse();
    return eigen.eigenvectors() * (inverse.asDiagonal() * (eigen.eigenvectors().transpose() * rhs));
  };
  // The rotation rows of S^-1.
  std::vector<int> rotation_rows, rotation_views;
  out->index.clear();
  out->orientations.clear();
  out->group.clear();
  for (int k = 0; k < n; ++k) {
    if (!observed[k]) continue;
    out->index[views[k].id] = static_cast<int>(out->orientations.size());
    out->orientations.push_back(views[k].rotation);
    out->group.push_back(Root(&turning, k));
    rotation_rows.push_back(var[k].at[0]);
    rotation_views.push_back(k);
  }
  const int blocks = static_cast<int>(rotation_rows.size());
  // The rotations' columns, then the focal scales'; of the system without
  // the principal points (the adjustment held them).
  const int focal_columns = focal_dim - view_dim;
  Eigen::MatrixXd selector = Eigen::MatrixXd::Zero(focal_dim, 3 * blocks + focal_columns);
  for (int k = 0; k < blocks; ++k) {
    // d_view = E d_capture for a rig camera: the selector's block is E^T.
    const AdjustedView& v = views[rotation_views[k]];
    if (rotation_rows[k] >= 0) {
      selector.block<3, 3>(rotation_rows[k], 3 * k) =
          v.capture >= 0 ? Eigen::Matrix3d(v.from_rig.transpose()) : Eigen::Matrix3d::Identity();
    }
  }
  for (int f = 0; f < focal_columns; ++f) selector(view_dim + f, 3 * blocks + f) = 1.0;
  const Eigen::MatrixXd reduced =
      dim == focal_dim ? s : Eigen::MatrixXd(s.topLeftCorner(focal_dim, focal_dim));
  // The clusters' leverage needs S^-1 over each cluster's variables, which
  // together are all of them: then the whole inverse, and its columns.
  const Eigen::MatrixXd inverse =
      clusters.empty() ? Eigen::MatrixXd() : inverse_columns(reduced, Eigen::MatrixXd::Identity(focal_dim, focal_dim));
  if (!clusters.empty() && (inverse.rows() != focal_dim || !inverse.allFinite())) return false;
  // (The selector's columns are unit vectors, or a rig camera's E^T over its
  // capture's three: each column of S^-1 S_sel is a few of S^-1's.)
  const auto select = [&](const Eigen::MatrixXd& m) {
    Eigen::MatrixXd picked = Eigen::MatrixXd::Zero(m.rows(), selector.cols());
    for (int c = 0; c < selector.cols(); ++c) {
      for (int r = 0; r < selector.rows(); ++r) {
        if (selector(r, c) != 0.0) picked.col(c) += selector(r, c) * m.col(r);
      }
    }
    return picked;
  };
  const Eigen::MatrixXd columns = clusters.empty() ? inverse_columns(reduced, selector) : select(inverse);
  if (columns.rows() != focal_dim || !columns.allFinite()) return false;
  const double redundancy = static_cast<double>(residuals) - (focal_dim - groups) - 3.0 * tracks.size();
  out->variance_factor =
      redundancy >= 10.0 ? weighted_squares / (CauchyWeightedSquaresFraction(loss_scale) * redundancy) : 1.0;
  const Eigen::MatrixXd joint = out->variance_factor * (selector.transpose() * columns);
  // The jackknives' bread. A cell's or a cluster's move is S^-1 u_c, S the
  // normal equations on Cauchy's weights w (IRLS), but how far the robust
  // estimate follows its data is set by the robust cost's Hessian, whose
  // part from an observation is (w I + 2 w' r r^T) J^T J-wise, w' = dw/ds of
  // its squared whitened residual s: with r of any isotropic distribution
  // its expectation is E[w + s w'] J^T J = E[w^2] J^T J (Cauchy's w + s w' =
  // w^2), where S has E[w] J^T J. Each move is then sum w / sum w^2 times
  // S^-1 u_c (1.17 on Gaussian noise at the pixel model's sigma, the loss at
  // 3 sigma; 1.12 on the fitted residuals, a little shorter, of
  // bundle_adjustment_test), and the jackknives' covariances its square; the
  // leverage K D is unchanged (K grows as D shrinks). The expectation, not
  // the realised Hessian: that one is indefinite for every residual beyond
  // the loss' scale, and keeps S's structure only up to a rank-one term per
  // observation. (The pixel model is normalised to Gaussian noise by
  // CauchyWeightedSquaresFraction instead.)
  out->jackknife_bread = squared_weight_sum > 0.0 ? weight_sum / squared_weight_sum : 1.0;
  const double bread2 = out->jackknife_bread * out->jackknife_bread;
  out->pixel_model = joint.topLeftCorner(3 * blocks, 3 * blocks);
  out->cells = grid > 0 ? cells : 0;
  if (grid > 0 && cells >= 2) {
    // Each cell's score is taken from the fitted residuals, which the
    // cell's own pull on its view has shrunk, by (I - H_c) with H_c its
    // leverage: large, since a cell is one of grid x grid parts of what
    // fixes its view, and more of some directions of it. The bias-reduced linearisation
    // (Bell & McCaffrey, 2002) undoes it with (I - H_c)^-1/2, which makes the
    // estimate unbiased for independent noise (the exact delete-one-cell
    // step, (I - H_c)^-1, overshoots, and diverges where one cell alone fixes
    // a direction of its view). H_c is the cell's leverage on its own view
    // with the others held: with D_c its information there (its share of the
    // view's block S_vv, the points eliminated) and S_vv^-1/2 D_c S_vv^-1/2
    // = Q diag(l) Q^T (l in [0, 1]), the score gains
    // D_c S_vv^-1/2 Q diag(g(l)) Q^T S_vv^-1/2 u_cv, g(l) = ((1 - l)^-1/2 - 1) / l.
    std::vector<Vector6d> delta(cells, Vector6d::Zero());
    std::vector<bool> corrected(cells, false);
    for (int c = 0; c < cells; ++c) {
      const int v = cell_view[c];
      if (v < 0) continue;
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> block(view_blocks[v]);
      if (!(block.eigenvalues().minCoeff() > 0.0)) continue;
      const Eigen::Matrix<double, 6, 6> root_inverse = block.eigenvectors() *
                                                       block.eigenvalues().cwiseSqrt().cwiseInverse().asDiagonal() *
                                                       block.eigenvectors().transpose();
      const Eigen::Matrix<double, 6, 6>& d = cell_information[c];
      const Eigen::SelfAdjointEigenSolver<Eigen::Matrix<double, 6, 6>> h(root_inverse * d * root_inverse);
      Vector6d g;
      for (int i = 0; i < 6; ++i) {
        g[i] = BiasReducedGain(h.eigenvalues()[i]);
      }
      Vector6d own;
      for (int q = 0; q < 6; ++q) own[q] = scores(var[v].Index(q), c);
      delta[c] = root_inverse * h.eigenvectors() * g.asDiagonal() * h.eigenvectors().transpose() * root_inverse * own;
      corrected[c] = true;
      AddSegment(var[v], Vector6d(d * delta[c]), c, &scores);
    }
    // The corrected residuals pull the other views that see the cell's
    // points (and the focal scales) as well as its own: their score is
    // J^T dr, dr = J_c delta over the cell's observations with the points
    // eliminated, so that it stays balanced (a rigid turn of every view and
    // point leaves it unchanged) like the score it corrects. Its own view's
    // part alone is a net torque at the cell's view, which a long window
    // carries along its whole length: the far end's deviation then grows
    // with the window, to over seven times the pixel model's on a corridor
    // of 30 views of independent noise (bundle_adjustment_test,
    // TheJackknifeStaysWithThePixelModelAlongALongWindowOfIndependentNoise).
    for (std::size_t k = 0; k < tracks.size(); ++k) {
      const Eliminated& e = eliminated[k];
      if (!e.used) continue;
      const std::vector<Observation>& o = tracks[k].observations;
      for (std::size_t j = 0; j < o.size(); ++j) {
        const int c = cell_of[k][j];
        if (!corrected[c]) continue;
        const Eigen::Vector3d pull = e.hpp_inv * (e.b[j].transpose() * delta[c]);
        for (std::size_t i = 0; i < o.size(); ++i) {
          if (i != j) AddSegment(var[o[i].view], Vector6d(-(e.b[i] * pull)), c, &scores);
          if (e.focal_row.empty() || e.focal_row[i] < 0) continue;
          scores(e.focal_row[i], c) += (i == j ? e.focal_view[j].dot(delta[c]) : 0.0) - e.focal_b[i].dot(pull);
        }
      }
    }
    // 3 blocks (and the focal scales) x cells: Z u_c (Z symmetric).
    const Eigen::MatrixXd steps = columns.transpose() * scores.topRows(focal_dim);
    const Eigen::VectorXd mean = steps.rowwise().mean();
    const Eigen::MatrixXd centred = steps.colwise() - mean;
    const Eigen::MatrixXd jackknife = (bread2 * (cells - 1) / cells) * (centred * centred.transpose());
    out->jackknife = jackknife.topLeftCorner(3 * blocks, 3 * blocks);
    for (int c = 0; c < cameras; ++c) {
      if (var_f[c] >= 0) (*focal)[c].sigma_matches = jackknife(var_f[c] - view_dim + 3 * blocks, var_f[c] - view_dim + 3 * blocks);
    }
  } else {
    out->jackknife.resize(0, 0);
  }
  out->track_clusters = 0;
  out->track_jackknife.resize(0, 0);
  if (!clusters.empty()) {
    // Each cluster's score corrected for its leverage as the cells' are
    // (the bias-reduced linearisation), here exactly: a cluster's points are
    // its own, so its leverage is K D over its views' (and focal scales')
    // variables alone, K the block of S^-1 there, with every other variable
    // free; the score gains D g(K D) K u (LeverageGain). D annihilates a
    // rigid turn of all views and points, so the gain, like the score, is
    // balanced.
    Eigen::MatrixXd steps(columns.cols(), clusters.size());
    int used = 0;
    for (const TrackCluster& cluster : clusters) {
      const int size = static_cast<int>(cluster.variables.size());
      Eigen::MatrixXd information = Eigen::MatrixXd::Zero(size, size);
      Eigen::VectorXd score = Eigen::VectorXd::Zero(size);
      bool any = false;  // a track with a determined point
      for (const std::size_t k : cluster.members) {
        const Eigen::LDLT<Eigen::Matrix3d> ldlt(linearise(k, nullptr));
        if (ldlt.info() != Eigen::Success || !(ldlt.vectorD().minCoeff() > 0.0)) continue;  // (as above)
        add_to_cluster(tracks[k], ldlt.solve(Eigen::Matrix3d::Identity()), cluster, &information, &score);
        any = true;
      }
      if (!any) continue;
      Eigen::MatrixXd k(size, size);
      for (int p = 0; p < size; ++p) {
        for (int q = 0; q < size; ++q) k(p, q) = inverse(cluster.variables[p], cluster.variables[q]);
      }
      const Eigen::VectorXd corrected = score + LeverageGain(k, information, score);
      // Z u_c, u_c nonzero on the cluster's variables alone.
      steps.col(used).setZero();
      for (int p = 0; p < size; ++p) steps.col(used) += corrected[p] * columns.row(cluster.variables[p]).transpose();
      ++used;
    }
    if (used >= 2) {
      const int g = used;
      const Eigen::MatrixXd centred = steps.leftCols(g).colwise() - steps.leftCols(g).rowwise().mean();
      const Eigen::MatrixXd jackknife = (bread2 * (g - 1) / g) * (centred * centred.transpose());
      out->track_jackknife = jackknife.topLeftCorner(3 * blocks, 3 * blocks);
      out->track_clusters = g;
      for (int c = 0; c < cameras; ++c) {
        if (var_f[c] < 0) continue;
        const int f = var_f[c] - view_dim + 3 * blocks;
        (*focal)[c].sigma_matches = std::max((*focal)[c].sigma_matches, jackknife(f, f));
      }
    }
  }
  if (focal_columns > 0) {
    // The principal points: a prior of principal_point_sigma of each
    // camera's width (in the variance factor's units, so that the scaled
    // covariance holds it at that), then what the focal scales' variance
    // gains.
    for (int c = 0; c < cameras; ++c) {
      if (var_f[c] < 0) continue;
      const double sigma = std::max(principal_point_sigma * (hi_x[c] - lo_x[c]), 1e-12);
      for (int q = 0; q < 2; ++q) s(var_p[c] + q, var_p[c] + q) += out->variance_factor / (sigma * sigma);
    }
    Eigen::MatrixXd focal_selector = Eigen::MatrixXd::Zero(dim, focal_columns);
    for (int f = 0; f < focal_columns; ++f) focal_selector(view_dim + f, f) = 1.0;
    const Eigen::MatrixXd with_principal_points = inverse_columns(s, focal_selector);
    if (with_principal_points.rows() != dim || !with_principal_points.allFinite()) return false;
    for (int c = 0; c < cameras; ++c) {
      if (var_f[c] < 0) continue;
      const int f = var_f[c] - view_dim;
      const double matches = joint(3 * blocks + f, 3 * blocks + f);
      const double total = out->variance_factor * with_principal_points(var_f[c], f);
      BundleAdjustmentFocal::Estimate& e = (*focal)[c];
      e.sigma_matches = std::sqrt(std::max(matches, e.sigma_matches));  // (the jackknife's variance, if any)
      e.sigma_principal_point = std::sqrt(std::max(total - matches, 0.0));
      e.sigma = std::hypot(e.sigma_matches, e.sigma_principal_point);
      e.determined = std::isfinite(e.sigma) && e.sigma > 0.0;
    }
  }
  if (!out->pixel_model.allFinite() || !out->jackknife.allFinite() || !out->track_jackknife.allFinite()) {
    out->index.clear();
    return false;
  }
  return true;
}

}  // namespace

std::string BundleAdjustmentSummary::Report() const {
  std::ostringstream out;
  out << "bundle adjustment: " << views << " views";
  if (views_held > 0) out << " (" << views_held << " held)";
  out << ", " << edges_used << " edges (" << edges_rotation_only
      << " of the rotation-only model, " << edges_skipped << " unusable), "
      << tracks << " tracks (" << tracks_inconsistent << " inconsistent, " << tracks_short << " in too few views, "
      << tracks_unconstrained
      << " without parallax or behind a camera), " << observations << " observations (" << observations_dropped
      << " dropped), rms reprojection error " << initial_rms_sigmas << " sigma at the centres from the pairs, "
      << final_rms_sigmas << " sigma adjusted, "
      << iterations << " iterations";
  if (failed_steps > 0) out << " (" << failed_steps << " failed steps)";
  out << ", " << time_s << " s" << (converged ? "" : " (not converged)");
  if (covariance_time_s > 0.0) out << " (covariance " << covariance_time_s << " s)";
  if (!status.empty()) out << ": " << status;
  return out.str();
}

bool BundleAdjustmentCovariance::Relative(ViewId view, ViewId reference, Eigen::Matrix3d* covariance) const {
  const auto a = index.find(view), b = index.find(reference);
  if (a == index.end() || b == index.end() || group[a->second] != group[b->second]) return false;
  const int i = a->second, j = b->second;
  if (i == j) {
    covariance->setZero();
    return true;
  }
  // d = d_v - R d_r with R = R_hat_v R_hat_r^T: the reference's perturbation
  // seen in the view's frame.
  const Eigen::Matrix3d r = orientations[i] * orientations[j].transpose();
  const auto relative = [&](const Eigen::MatrixXd& joint) -> Eigen::Matrix3d {
    if (joint.rows() == 0) return Eigen::Matrix3d::Zero();
    const Eigen::Matrix3d vr = joint.block<3, 3>(3 * i, 3 * j);
    const Eigen::Matrix3d c = joint.block<3, 3>(3 * i, 3 * i) - vr * r.transpose() - r * vr.transpose() +
                              r * joint.block<3, 3>(3 * j, 3 * j) * r.transpose();
    return 0.5 * (c + c.transpose());
  };
  *covariance = LoewnerMax(LoewnerMax(relative(pixel_model), relative(jackknife)), relative(track_jackknife));
  return covariance->allFinite();
}

bool RefineRotationsWithBundleAdjustment(const std::vector<EdgeCorrespondences>& edges,
                                         const BundleAdjustmentOptions& options, ViewOrientations* orientations,
                                         BundleAdjustmentSummary* summary,
                                         std::unordered_map<ViewId, Eigen::Vector3d>* centres,
                                         BundleAdjustmentCovariance* covariance, BundleAdjustmentFocal* focal,
                                         const std::unordered_map<ViewId, Eigen::Vector3d>* start_centres,
                                         const BundleAdjustmentRig* rig,
                                         const std::set<ViewId>* held_orientations) {
  HoldOpenBlasToOneThread();  // Ceres' sparse Schur solves call it every iteration
  const auto start = std::chrono::steady_clock::now();
  *summary = BundleAdjustmentSummary();
  auto finish = [&](bool ok, const std::string& status) {
    summary->status = status;
    summary->time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    return ok;
  };
  std::map<ViewId, int> index;
  std::vector<AdjustedView> views;
  std::vector<const EdgeCorrespondences*> used;
  SelectEdgesAndViews(edges, options, *orientations, &used, &index, &views, summary);
  if (used.empty()) return finish(false, "no edge with enough correspondences between oriented views");
  if (held_orientations) {
    for (AdjustedView& v : views) v.orientation_held = held_orientations->count(v.id) > 0;
  }
  if (rig) JoinRigCaptures(*rig, &views);
  // The cameras whose focal lengths are estimated, in name order.
  std::vector<std::string> camera_names;
  if (focal) {
    focal->estimates.clear();
    std::map<std::string, int> numbered;
    for (AdjustedView& v : views) {
      const auto it = focal->camera.find(v.id);
      if (it == focal->camera.end()) continue;
      numbered.emplace(it->second, 0);
    }
    for (auto& [name, number] : numbered) {
      number = static_cast<int>(camera_names.size());
      camera_names.push_back(name);
    }
    for (AdjustedView& v : views) {
      const auto it = focal->camera.find(v.id);
      if (it != focal->camera.end()) v.camera = numbered.at(it->second);
    }
  }
  std::vector<double> focal_scales(camera_names.size(), 1.0);
  std::vector<Track> tracks = BuildTracks(used, index, options, summary);
  std::string message;
  if (!PlaceCentres(used, index, options, start_centres, &views, summary, &message)) return finish(false, "centres: " + message);
  const double min_parallax = options.min_parallax_deg * M_PI / 180.0;
  TriangulateAll(views, min_parallax, &tracks, summary);
  if (tracks.empty()) return finish(false, "no track could be triangulated");
  summary->initial_rms_sigmas = RmsSigmas(views, tracks);

  // Reprojection errors: the first stage holds the orientations (the centres
  // are rough), under Huber's loss.
  const double scale = options.loss_scale_sigmas > 0.0 ? options.loss_scale_sigmas : 3.0;
  ceres::HuberLoss huber(scale);
  ceres::Solver::Summary first;
  if (!Adjust(true, &huber, options, &views, &tracks, &focal_scales, summary, &first)) {
    return finish(false, "centres and points: " + first.message);
  }
  // Points the first stage took behind a camera or onto its centre start
  // the next from the midpoint of their rays (adjustment_tracks.h).
  summary->tracks_unconstrained += adjustment::RetriangulateStrayPoints(views, min_parallax, &tracks);
  if (tracks.empty()) return finish(false, "no track left after placing the centres");
  // Then everything: with the orientations held, their errors (a tenth of a
  // degree is tens of sigma at a tenth of a pixel) are in every residual,
  // and only once they are adjusted do the residuals say which observations
  // are wrong. Cauchy's loss: under Huber's linear tail, wrong matches that
  // fit their pair (a window matched to the next one) keep their pull, and
  // the adjustment kept the averaging's errors on a courtyard of repeated
  // windows.
  ceres::CauchyLoss cauchy(scale);
  if (!Adjust(false, &cauchy, options, &views, &tracks, &focal_scales, summary, &first)) {
    return finish(false, "everything: " + first.message);
  }
  // Drop the observations the first stages could not fit, and triangulate
  // again from the adjusted views.
  DropOutlierObservations(views, options, &tracks, summary);
  TriangulateAll(views, min_parallax, &tracks, summary);
  if (tracks.empty()) return finish(false, "no track left after the first stage");

  ceres::Solver::Summary second;
  if (!Adjust(false, &cauchy, options, &views, &tracks, &focal_scales, summary, &second)) {
    return finish(false, "orientations: " + second.message);
  }
  for (const AdjustedView& v : views) {
    if (!v.rotation.allFinite() || !v.centre.allFinite() || !std::isfinite(v.focal_scale) || !(v.focal_scale > 0.0)) {
      return finish(false, "non-finite result: orientations kept");
    }
  }
  summary->final_rms_sigmas = RmsSigmas(views, tracks);
  summary->tracks = static_cast<int>(tracks.size());
  summary->views = static_cast<int>(views.size());
  summary->views_held = static_cast<int>(
      std::count_if(views.begin(), views.end(), [](const AdjustedView& v) { return v.orientation_held; }));
  summary->edges_used = static_cast<int>(used.size());
  summary->converged =
      second.termination_type == ceres::CONVERGENCE || second.termination_type == ceres::USER_SUCCESS;
  // (A held view keeps the very matrix it was given, not its round trip
  // through the angle-axis block.)
  for (const AdjustedView& v : views) {
    if (!v.orientation_held) (*orientations)[v.id] = v.rotation;
  }
  if (rig) {
    // A rig camera without a usable edge turns with its capture's cameras
    // that have one.
    std::map<std::int64_t, const AdjustedView*> adjusted_capture;
    for (const AdjustedView& v : views) {
      const auto it = rig->views.find(v.id);
      if (it != rig->views.end() && it->second.camera_from_rig.allFinite()) {
        adjusted_capture.emplace(it->second.capture, &v);
      }
    }
    for (const auto& [id, member] : rig->views) {
      const auto it = adjusted_capture.find(member.capture);
      if (index.count(id) || it == adjusted_capture.end() || !member.camera_from_rig.allFinite() ||
          !orientations->count(id)) {
        continue;
      }
      const AdjustedView& v = *it->second;
      (*orientations)[id] = ProjectToSO3(member.camera_from_rig) *
                            ProjectToSO3(rig->views.at(v.id).camera_from_rig).transpose() * v.rotation;
    }
  }
  if (centres) {
    centres->clear();
    for (const AdjustedView& v : views) (*centres)[v.id] = v.centre;
  }
  std::vector<BundleAdjustmentFocal::Estimate> estimates(camera_names.size());
  for (std::size_t c = 0; c < camera_names.size(); ++c) estimates[c].scale = focal_scales[c];
  for (const Track& t : tracks) {
    for (const Observation& o : t.observations) {
      if (views[o.view].camera >= 0) ++estimates[views[o.view].camera].observations;
    }
  }
  if (covariance || !camera_names.empty()) {
    const auto covariance_start = std::chrono::steady_clock::now();
    BundleAdjustmentCovariance own;
    BundleAdjustmentCovariance* out = covariance ? covariance : &own;
    *out = BundleAdjustmentCovariance();
    // (The held views turn in the covariance's problem, which does not read
    // orientation_held: their orientations are estimates, a window's older
    // neighbours, and a covariance that took them as exact would be as much
    // too narrow as they are off.)
    std::vector<AdjustedView> alone;
    if (rig && !rig->joint_covariance) {
      alone = views;
      for (AdjustedView& v : alone) v.capture = -1;
    }
    if (!ComputeCovariance(alone.empty() ? views : alone, tracks, scale, options.covariance_cell_grid,
                           options.covariance_track_clusters,
                           focal ? focal->principal_point_sigma : 0.0, out, focal ? &estimates : nullptr)) {
      *out = BundleAdjustmentCovariance();
      for (BundleAdjustmentFocal::Estimate& e : estimates) e.determined = false;
    }
    summary->covariance_time_s =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - covariance_start).count();
  }
  if (focal) {
    for (const AdjustedView& v : views) {
      if (v.camera >= 0) ++estimates[v.camera].views;
    }
    for (std::size_t c = 0; c < camera_names.size(); ++c) {
      if (estimates[c].observations > 0) focal->estimates[camera_names[c]] = estimates[c];
    }
  }
  return finish(true, summary->converged ? "" : second.message);
}

}  // namespace rotation_averaging
