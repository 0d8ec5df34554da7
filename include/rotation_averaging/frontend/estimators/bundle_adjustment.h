// Public header of rotation_averaging::frontend (docs/embedding.md).
// Bundle adjustment started from averaged orientations: the refinement that
// gives the averaging what incremental SfM has and pairwise summaries lack,
// points seen in three or more views.
//
// A pair's relative rotation, however it is summarised (a covariance, or its
// Sampson cost as in correspondence_refinement.h), only knows that pair's
// matches. A wrong match that lies near its pair's epipolar line (a window
// matched to the next one along a façade) fits that pair, but the 3D point
// it implies does not project onto the same feature in the other views of
// its track; and each pair's translation direction is free there, while here
// every pair's baseline comes from the same camera centres. So the rotation
// is pinned by every view that sees a point, as in SfM's bundle adjustment:
//
//   1. Tracks: the inlier correspondences of the edges are linked through
//      the keypoints they share (a keypoint is its coordinates in its view);
//      a track holding two keypoints of one view is inconsistent and dropped,
//      and so is one seen in fewer than `min_track_views` views.
//   2. Camera centres with the orientations held: c_j - c_i = s_ij d_ij,
//      s_ij >= 1, d_ij the direction the edge's matches give under the
//      averaged orientations (least unsquared deviations, Ozyesil & Singer,
//      CVPR 2015: convex, so no start is needed). A pair of the rotation-only
//      model (zero translation: the camera turned in place) gives no
//      direction; its matches join the tracks, and a view only it links to
//      the others starts at its partner's centre.
//   3. Points by the midpoint of their rays; tracks behind a camera or with
//      too little parallax are left out.
//   4. Reprojection errors, each whitened by its view's pixel noise (the
//      median of its edges' Sampson noise), minimised over centres and
//      points with the orientations held under Huber's loss (the centres of
//      step 2 are rough), then over everything under Cauchy's; then
//      observations beyond `outlier_sigmas` are dropped and everything is
//      adjusted again under Cauchy's loss.
#ifndef ROTATION_AVERAGING_FRONTEND_ESTIMATORS_BUNDLE_ADJUSTMENT_H_
#define ROTATION_AVERAGING_FRONTEND_ESTIMATORS_BUNDLE_ADJUSTMENT_H_

#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <set>
#include <string>
#include <unordered_map>
#include <vector>

#include "rotation_averaging/frontend/estimators/correspondence_refinement.h"
#include "rotation_averaging/core/estimators/rotation_averaging.h"

namespace rotation_averaging {

struct BundleAdjustmentOptions {
  // Loss scale in standard deviations of an observation's pixel noise, for
  // the Huber stage and the two Cauchy ones.
  double loss_scale_sigmas = 3.0;
  // Before the last stage, observations whose whitened reprojection error
  // exceeds this are dropped (and tracks left in fewer than min_track_views).
  double outlier_sigmas = 6.0;
  // Tracks seen in fewer views are left out. A track of two views says what
  // its pair's epipolar geometry says and nothing more: a wrong match in it
  // (a window matched to the next one, near its epipolar line) fits any pose
  // by moving its point, so it pulls as it pulled the pair, and no third view
  // can contradict it: a view all of whose pairs carry such matches stays as
  // far off as the averaging left it (results/colmap.md, per view).
  int min_track_views = 3;
  // Tracks whose rays meet at less than this angle (degrees) are left out:
  // their depth, and with it their pull on the orientations, is undetermined.
  double min_parallax_deg = 1.0;
  int max_iterations = 200;  // per stage
  // A stage ends once two successful steps in a row turn no view by more
  // than settled_rotation_rad, move no centre by more than
  // settled_centre_fraction of the map's extent (a hundred times that in
  // the first stage, which only places centres and points for the next) and
  // change no focal scale by more than settled_focal; or by Ceres' own
  // tests. 1e-6 rad is a hundredth of the orientations' errors on the best
  // inputs (0.006 deg on the rendered rig, results/self_calibration.md).
  double settled_rotation_rad = 1e-6;
  double settled_centre_fraction = 1e-5;
  double settled_focal = 1e-6;
  int min_correspondences = 8;  // edges with fewer are left out
  // The orientations' covariance (when asked for): the pixel model's, at
  // least in every direction the delete-one-cell jackknife's over a grid x
  // grid partition of each view's observations (0: the pixel model alone).
  // Errors a region of an image shares (keypoints biased alike, a repeated
  // structure matched to its neighbour) move the orientations together, where
  // the pixel model counts them as independent: as the two-view covariances'
  // jackknife (RelativePoseOptions::jackknife_grid) does for a pair. 3:
  // with the cells alone, 2, 3 and 4 give the pixel model's NEES within 10%
  // on every input with a reference but one, whose errors a region shares
  // are not what it misses; with the track clusters below, whose size the
  // grid sets, each meets the NEES target on the same four inputs
  // (results/posterior.md, "The jackknife's grid"); 3 keeps the guard where
  // such errors are (docs/decisions.md, "Grid 3").
  int covariance_cell_grid = 3;
  // And at least the jackknife's over clusters of whole tracks, the tracks
  // that start in one cell of that grid: errors a feature carries along its
  // track (a tracker's drift, a point matched a little off in every view)
  // move the orientations together across the views that see it, where the
  // pixel model and the cells count each observation on its own.
  bool covariance_track_clusters = true;
};

// The adjusted orientations' covariance: left perturbations of the
// world-to-camera rotations, R = Exp(d) R_hat (d in the camera's frame), over
// the adjustment's normal equations with the points and centres eliminated.
// In each group of views the tracks (or a rig's captures) connect, one view is held (the gauge):
// the covariance of a view relative to another of its group is what it
// describes, and that is the same whichever view the adjustment held.
struct BundleAdjustmentCovariance {
  std::map<ViewId, int> index;                // view -> block
  std::vector<Eigen::Matrix3d> orientations;  // adjusted, by block
  std::vector<int> group;                     // by block
  // Joint covariances (rad^2) of the blocks' d, 3 rows per block: the pixel
  // model's (scaled by the variance factor), the cell jackknife's and the
  // track clusters' jackknife's (empty when not asked for).
  Eigen::MatrixXd pixel_model, jackknife, track_jackknife;
  double variance_factor = 1.0;  // weighted mean squared whitened residual over the redundancy
  // What the jackknives' moves are scaled by: sum w / sum w^2 of Cauchy's
  // weights, the normal equations' information over the robust cost's
  // expected Hessian (ComputeCovariance); 1 without the loss' effect.
  double jackknife_bread = 1.0;
  int cells = 0;                 // non-empty cells of the jackknife
  int track_clusters = 0;        // non-empty clusters of the track jackknife
  // Covariance of view's orientation relative to reference's, of
  // d = Log(R_hat_v R_hat_r^T R_r R_v^T) (what the published covariances
  // describe): the largest of the three in every direction. False if
  // either view is not adjusted or they are in different groups.
  bool Relative(ViewId view, ViewId reference, Eigen::Matrix3d* covariance) const;
};

// Self-calibration: one focal length per camera estimated with everything
// else, for the views of `camera`. A view's normalised observations x were
// taken with the focal length in use f (x = (u - c) / f), so with the true
// one a f the model is x = a proj(R (X - c)); a is estimated in the last two
// stages (the first, with the orientations held, holds it at 1). Views not
// listed keep their focal length (a = 1, exactly as without this).
//
// Its deviation has two parts, as the two-view focal check's
// (FocalCalibrationOptions): the matches' (the pixel model's variance, at
// least the jackknives', as the orientations' covariance) and the
// principal point's, the variance the focal length gains when each camera's
// principal point is a further unknown with a prior of
// `principal_point_sigma` of the width its observations span. Where the
// views' axes meet near one point (an arc around an object: the critical
// configuration of focal self-calibration) a principal point error explains
// the observations as well as a focal length error does, and that part is
// large: what says the motion cannot tell.
struct BundleAdjustmentFocal {
  std::map<ViewId, std::string> camera;  // in: the camera of each view whose focal length is estimated
  double principal_point_sigma = 0.007;  // in: of the observations' width (FocalCalibrationOptions' default)
  struct Estimate {
    double scale = 1.0;  // true over in use: the focal length to use is scale times the one in use
    // Standard deviation of scale: sqrt(matches^2 + principal_point^2).
    double sigma = 0.0, sigma_matches = 0.0, sigma_principal_point = 0.0;
    int views = 0;
    std::size_t observations = 0;
    bool determined = false;  // false: no deviation (the covariance failed), so no evidence
  };
  std::map<std::string, Estimate> estimates;  // out: by camera, those with adjusted views
};

// Cameras of a rig whose extrinsics are known: each view's orientation is
// its camera_from_rig rotation E times its capture's, R_view = E R_capture,
// and the adjustment turns the capture, so that every camera's tracks hold
// all of them (each camera's centre stays its own). Without it the rig's
// cameras meet only through the few tracks two of them see, and the
// adjustment of each is as good as that camera's tracks alone.
struct BundleAdjustmentRig {
  struct Member {
    std::int64_t capture = 0;  // views of one capture share its rotation
    Eigen::Matrix3d camera_from_rig = Eigen::Matrix3d::Identity();
  };
  std::map<ViewId, Member> views;  // views that are not here turn alone
  // The covariance (RefineRotationsWithBundleAdjustment's `covariance`) of
  // the problem the rig makes, every camera's tracks holding each capture;
  // false: each view's as if it turned alone (at the rig's solution), what
  // its own camera's tracks determine.
  bool joint_covariance = true;
};

struct BundleAdjustmentSummary {
  int views = 0;
  int views_held = 0;           // of views, held where they were given (held_orientations)
  int edges_used = 0;
  int edges_rotation_only = 0;  // of edges_used: in the tracks, not in the centres (step 2)
  int edges_skipped = 0;        // too few correspondences, unknown views, bad numbers
  int tracks = 0;               // triangulated and adjusted (final stage)
  int tracks_inconsistent = 0;  // holding two keypoints of one view
  int tracks_short = 0;         // seen in fewer than min_track_views views
  int tracks_unconstrained = 0; // behind a camera or below min_parallax_deg
  std::size_t observations = 0; // final stage
  std::size_t observations_dropped = 0;  // beyond outlier_sigmas before the last stage
  // Root mean square of the whitened reprojection errors, per coordinate:
  // after triangulation, and of the kept observations at the end.
  double initial_rms_sigmas = 0.0;
  double final_rms_sigmas = 0.0;
  int iterations = 0;           // of every stage
  // Of iterations, the steps whose linear system could not be solved (its
  // factorisation failed) or whose cost could not be evaluated: many of
  // them mean a stage spent its iterations stalled.
  int failed_steps = 0;
  double time_s = 0.0;
  double covariance_time_s = 0.0;  // of it, the covariance's (when asked for)
  bool converged = false;
  std::string status;
  std::string Report() const;   // one line for logs and the CLI
};

// Refines `orientations` (world-to-camera, as SolveRotationAveraging gives
// them) in place and, if `centres` is given, fills it with the adjusted
// camera centres (in the frame of the orientations, up to one scale per
// component). Views without an orientation and edges touching one are left
// out. The gauge: in each group of views the tracks connect, the first view
// keeps its orientation and centre, and one coordinate of a second view's
// centre keeps the scale of step 2 (s_ij >= 1). Returns false, leaving
// `orientations` as they were, if nothing could be adjusted or a solve failed.
// With `covariance`, also the adjusted orientations' covariance; it is left
// empty (index empty) if the normal equations are singular. With `focal`,
// its cameras' focal lengths are estimated too (BundleAdjustmentFocal), and
// the orientations and their covariance are those of that adjustment.
// With `start_centres` (an earlier adjustment's `centres`, in the frame of
// orientations near these), step 2 holds the views it gives at those centres
// and places only the others among them: an adjustment of a map that has
// grown since the last one starts near its minimum and needs a fraction of
// the iterations (the node's background refinement, keyframe_refiner.h).
// With `rig`, the views of each of its captures (two or more adjusted) turn
// together (BundleAdjustmentRig), starting from the chordal mean of their
// orientations in the rig's frame, and their covariance is of that problem;
// a view of `orientations` that no usable edge reaches turns with its
// capture's adjusted cameras. With `held_orientations`, those views keep
// the orientations given (a rig capture one of whose views is held turns as
// that view has it): they take part with their centres and tracks, and hold
// the frame of every group the tracks tie to them, in place of the first
// view's orientation. The covariance does not take their orientations as
// exact (they are estimates too): it is of the problem in which they turn.
bool RefineRotationsWithBundleAdjustment(const std::vector<EdgeCorrespondences>& edges,
                                         const BundleAdjustmentOptions& options, ViewOrientations* orientations,
                                         BundleAdjustmentSummary* summary,
                                         std::unordered_map<ViewId, Eigen::Vector3d>* centres = nullptr,
                                         BundleAdjustmentCovariance* covariance = nullptr,
                                         BundleAdjustmentFocal* focal = nullptr,
                                         const std::unordered_map<ViewId, Eigen::Vector3d>* start_centres = nullptr,
                                         const BundleAdjustmentRig* rig = nullptr,
                                         const std::set<ViewId>* held_orientations = nullptr);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_FRONTEND_ESTIMATORS_BUNDLE_ADJUSTMENT_H_
