// Internal to the front end: what the two models of a pair's estimation
// share (relative_pose.cpp: the essential matrix and model selection;
// rotation_only_model.cpp: the rotation-only model).
#ifndef ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_TWO_VIEW_INTERNAL_H_
#define ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_TWO_VIEW_INTERNAL_H_

#include <Eigen/Core>
#include <string>
#include <vector>

#include "rotation_averaging/frontend/estimators/relative_pose.h"

namespace rotation_averaging {

// Rounds of inlier re-selection after a refinement, at most.
constexpr int kMaxReselectionRounds = 4;

// A failed estimation: `failure` with its message.
RelativePoseResult TwoViewFail(TwoViewFailure failure, const std::string& message);

// Transfer error of the rotation-only model in image 2, pixels: K2 R b1
// projected minus p2; false if R b1 points behind camera 2.
bool TransferError(const Eigen::Matrix3d& k2, const Eigen::Matrix3d& rotation, const Eigen::Vector3d& b1,
                   const Eigen::Vector2d& p2, Eigen::Vector2d* error);

// The rotation-only model x2 ~ K2 R K1^-1 x1 (see relative_pose.h): 2-point
// RANSAC with local optimisation, then Gauss-Newton on the transfer errors of
// the inliers, re-selected at the 99% radius of their measured noise. A
// rotation explaining fewer than `min_support` correspondences cannot win
// the model selection, so the sampling stops once such a rotation would
// have been found with the RANSAC confidence.
RelativePoseResult EstimateRotationOnly(const std::vector<Eigen::Vector2d>& points1,
                                        const std::vector<Eigen::Vector2d>& points2, const Eigen::Matrix3d& k1,
                                        const Eigen::Matrix3d& k2, const RelativePoseOptions& options,
                                        int min_support);

}  // namespace rotation_averaging

#endif  // ROTATION_AVERAGING_SRC_FRONTEND_ESTIMATORS_TWO_VIEW_INTERNAL_H_
