#pragma once
// Synthetic pairs of views for the focal-length estimator
// (EstimateFocalScale) and the radial distortion check (EstimateRadialDistortion): a cloud of points seen by cameras of a known
// pinhole matrix, matched with pixel noise and wrong matches, every pair's
// pose estimated with the intrinsics the user would give. Used by its tests
// and by rotavg_frontend_eval's focal-calibration table.
#include <Eigen/Core>
#include <vector>

#include "rotation_averaging/frontend/controllers/image_pipeline.h"
#include "rotation_averaging/frontend/estimators/relative_pose.h"

namespace rotation_averaging {

enum class FocalSceneGeometry {
  // Eight cameras along a path, turning a little, looking into a cloud in
  // front of them: general motion, where two views determine the focal length.
  kPath,
  // 24 cameras on a circle around an object, each looking at its centre
  // (pairs up to three steps apart, 45 deg): the critical configuration of
  // focal self-calibration, broken only by `ring_jitter` (camera heights and
  // aim points scattered by 0.2 ring_jitter object radii).
  kRing,
};

struct FocalSceneOptions {
  FocalSceneGeometry geometry = FocalSceneGeometry::kPath;
  double ring_jitter = 0.3;
  double noise_px = 0.3;
  double wrong_match_fraction = 0.1;
  // Radial distortion of the lens (k1 of x (1 + k1 |x|^2), x in the
  // normalised coordinates of k_true): the pixels are where that lens puts
  // them, and the poses are estimated without knowing it.
  double lens_k1 = 0.0;
  unsigned seed = 5;
};

struct FocalScene {
  std::vector<std::vector<Eigen::Vector2d>> points1, points2;
  std::vector<RelativePoseResult> poses;  // estimated with k_given
  std::vector<FocalPair> Pairs() const;
};

// Images of 640 x 480 pixels taken with k_true; poses estimated with k_given.
FocalScene MakeFocalScene(const Eigen::Matrix3d& k_true, const Eigen::Matrix3d& k_given,
                          const FocalSceneOptions& options = FocalSceneOptions());

}  // namespace rotation_averaging
