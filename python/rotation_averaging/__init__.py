"""Uncertainty-aware robust rotation averaging from Python.

Bindings of the package's C++ core (Zhang, Larsson, Barath, "Revisiting
Rotation Averaging: Uncertainties and Robust Losses", CVPR 2023)::

    import numpy as np
    import rotation_averaging as ra

    graph = ra.ViewGraph.from_arrays(i, j, rotations, covariances=cov)  # (m,), (m,), (m,3,3) or (m,4), (m,3,3)
    solution = ra.solve(graph, loss="magsac", weighting="covariance")
    solution.ids, solution.rotations            # (n,), (n, 3, 3) world-to-camera
    solution.edge_residuals_rad, solution.edge_weights
    scores = ra.evaluate(solution.named(), ra.read_ground_truth("gt.csv"))

The rotations and covariances can come from your own matches: relative_pose()
estimates a pair's pose and the covariance of its rotation from corresponding
pixels, and ViewGraph.add_relative_pose() adds it as an edge::

    pose = ra.relative_pose(pixels_i, pixels_j, K)       # (n, 2), (n, 2) matched pixels, undistorted
    if pose.success:
        graph.add_relative_pose(i, j, pose)             # R_ij = pose.rotation^T, pose.covariance
    adjusted = ra.bundle_adjust(ra.solve(graph), [(i, j, pixels_i, pixels_j, pose), ...], K)

Conventions: R_i world-to-camera; an edge (i, j) holds R_ij = R_i R_j^T; a
covariance (rad^2) is that of a right perturbation in camera j's frame;
quaternions are (w, x, y, z). Errors are exceptions with the C++ message
(ValueError; FileNotFoundError for files that cannot be opened).

The ROS messages of the package are rotation_averaging.msg and .srv.
"""

from rotation_averaging._core import (  # noqa: F401
    BundleAdjustment,
    BundleAdjustmentOptions,
    RelativePose,
    RelativePoseOptions,
    Solution,
    SolveOptions,
    ViewGraph,
    evaluate,
    exp_so3,
    log_so3,
    loss_names,
    read_graph,
    read_ground_truth,
    read_orientations,
    synthetic_graph,
    weighting_names,
    write_graph,
    write_orientations,
)
from rotation_averaging import _core

__all__ = [
    "BundleAdjustment", "BundleAdjustmentOptions", "bundle_adjust", "make_bundle_adjustment_options",
    "RelativePose", "RelativePoseOptions", "Solution", "SolveOptions", "ViewGraph", "evaluate", "exp_so3", "log_so3",
    "loss_names", "make_options", "make_relative_pose_options", "read_graph", "read_ground_truth", "read_orientations",
    "relative_pose", "solve", "synthetic_graph", "weighting_names", "write_graph", "write_orientations",
]


def _with_settings(options, defaults, settings, what):
    result = options.copy() if options is not None else defaults()
    for name, value in settings.items():
        if name.startswith("_") or not hasattr(result, name):
            raise TypeError(f"unknown {what} option '{name}'")
        setattr(result, name, value)
    return result


def make_options(options=None, **settings):
    """A SolveOptions: a copy of `options` (or the defaults) with `settings` applied.

    Every field of SolveOptions may be given, e.g. loss="cauchy", weighting="trace",
    solver="ceres", loss_scale=0.1, posterior_covariance_max_views=1000.
    """
    return _with_settings(options, SolveOptions, settings, "solve")


def make_relative_pose_options(options=None, **settings):
    """A RelativePoseOptions: a copy of `options` (or the defaults) with `settings` applied.

    Every field of RelativePoseOptions may be given, e.g. ransac_threshold_px=2.0,
    covariance_model="conditional", rotation_model=False.
    """
    return _with_settings(options, RelativePoseOptions, settings, "relative pose")


def relative_pose(points1, points2, K1, K2=None, options=None, **settings):
    """The relative pose of two views and the covariance of its rotation.

    points1, points2: (n, 2) corresponding pixels of undistorted images with
    intrinsics K1 and K2 (3x3; K2 defaults to K1). The pipeline of the package's
    front end: MAGSAC++ essential matrix, Sampson refinement, covariance from its
    Jacobian scaled by the measured pixel noise; a camera that only turned is
    estimated by the rotation-only model. settings: fields of RelativePoseOptions.
    Returns a RelativePose (success False with `failure` and `message` when the
    pair has no pose); raises ValueError for input that cannot be two views
    (shapes, non-finite points, intrinsics). Releases the GIL, so pairs can be
    estimated in a thread pool.
    """
    return _core.relative_pose(points1, points2, K1, K2, make_relative_pose_options(options, **settings))


def solve(graph, options=None, initial=None, **settings):
    """Rotation averaging of every connected component of `graph`.

    options: a SolveOptions (defaults: MAGSAC++ loss, covariance weighting, IRLS);
    settings: fields of SolveOptions to override, e.g. solve(g, loss="huber").
    initial: {view id: 3x3} warm-start orientations (used when warm_start is on).
    Returns a Solution.
    """
    return _core.solve(graph, make_options(options, **settings), initial)


def make_bundle_adjustment_options(options=None, **settings):
    """A BundleAdjustmentOptions: a copy of `options` (or the defaults) with `settings` applied."""
    return _with_settings(options, BundleAdjustmentOptions, settings, "bundle adjustment")


def bundle_adjust(orientations, pairs, intrinsics, options=None, **settings):
    """Bundle adjustment from averaged orientations, as `rotavg images` runs it.

    orientations: a Solution or {view id: 3x3 world-to-camera}.
    pairs: (view1, view2, points1, points2, pose) with pose = relative_pose(points1,
    points2, ...); the pose's inliers are linked into tracks through the keypoints
    they share, a keypoint being its pixel coordinates in its view (so each view's
    keypoints must have the same coordinates in every pair).
    intrinsics: one 3x3 K, or {view id: K}. settings: fields of BundleAdjustmentOptions.
    Returns a BundleAdjustment: orientations, centres, summary, report().
    """
    if hasattr(orientations, "as_dict"):
        orientations = orientations.as_dict()
    return _core.bundle_adjust(orientations, list(pairs), intrinsics, make_bundle_adjustment_options(options, **settings))
