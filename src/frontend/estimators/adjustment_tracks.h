// Internal to the front end: the bundle adjustment's views, tracks and
// their triangulation (bundle_adjustment.cpp), apart so that tests can
// reach them.
#ifndef ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_ADJUSTMENT_TRACKS_H_
#define ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_ADJUSTMENT_TRACKS_H_

#include <Eigen/Core>
#include <vector>

#include "rotation_averaging/core/scene/view_graph.h"

namespace rotation_averaging {
namespace adjustment {

struct Observation {
  int view = 0;  // index into the views
  Eigen::Vector2d x;
};

struct Track {
  std::vector<Observation> observations;
  Eigen::Vector3d point = Eigen::Vector3d::Zero();
};

struct AdjustedView {
  ViewId id = 0;
  Eigen::Matrix3d rotation;
  Eigen::Vector3d angle_axis = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
  double sigma = 0.0;  // pixel noise over the focal length
  // The camera whose focal length is estimated (an index into the focal
  // scales; -1: none) and that scale (BundleAdjustmentFocal; exactly 1
  // where none is, so that the arithmetic is what it is without it).
  int camera = -1;
  double focal_scale = 1.0;
  bool centre_given = false;  // its centre from an earlier adjustment (start_centres)
  bool orientation_held = false;  // held where it was given, in every stage (held_orientations)
  // A rig camera (BundleAdjustmentRig): the view that holds its capture's
  // rotation (the capture's first; -1: it turns alone, by angle_axis), and
  // its camera_from_rig E, so that rotation = E Exp(that view's rig_angle_axis).
  int capture = -1;
  Eigen::Matrix3d from_rig = Eigen::Matrix3d::Identity();
  Eigen::Vector3d rig_angle_axis = Eigen::Vector3d::Zero();  // the capture's, on the view that holds it
};

// The unit ray of image point x (over the focal length) in the world frame.
Eigen::Vector3d Ray(const AdjustedView& v, const Eigen::Vector2d& x);

// Midpoint of the track's rays: the point nearest to all of them. False if
// the rays are nearly parallel or the point is behind a camera.
bool Triangulate(const std::vector<AdjustedView>& views, double min_parallax_rad, Track* track);

// The depth, as a fraction of the median depth of all observations, below
// which a track's point counts as having run onto a camera.
constexpr double kStrayDepthFraction = 1e-3;

// Triangulates again, from the views as they stand, each track whose point
// has gone behind one of its cameras or onto its centre (a depth below
// kStrayDepthFraction of the median), and leaves out those that then fail;
// returns how many it left out. The other tracks keep their points.
int RetriangulateStrayPoints(const std::vector<AdjustedView>& views, double min_parallax_rad,
                             std::vector<Track>* tracks);

}  // namespace adjustment
}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_ADJUSTMENT_TRACKS_H_
