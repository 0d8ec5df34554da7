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

Conventions: R_i world-to-camera; an edge (i, j) holds R_ij = R_i R_j^T; a
covariance (rad^2) is that of a right perturbation in camera j's frame;
quaternions are (w, x, y, z). Errors are exceptions with the C++ message
(ValueError; FileNotFoundError for files that cannot be opened).

The ROS messages of the package are rotation_averaging.msg and .srv.
"""

from rotation_averaging._core import (  # noqa: F401
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
    "Solution", "SolveOptions", "ViewGraph", "evaluate", "exp_so3", "log_so3", "loss_names", "make_options",
    "read_graph", "read_ground_truth", "read_orientations", "solve", "synthetic_graph", "weighting_names",
    "write_graph", "write_orientations",
]


def make_options(options=None, **settings):
    """A SolveOptions: a copy of `options` (or the defaults) with `settings` applied.

    Every field of SolveOptions may be given, e.g. loss="cauchy", weighting="trace",
    solver="ceres", loss_scale=0.1, posterior_covariance_max_views=1000.
    """
    result = options.copy() if options is not None else SolveOptions()
    for name, value in settings.items():
        if name.startswith("_") or not hasattr(result, name):
            raise TypeError(f"unknown solve option '{name}'")
        setattr(result, name, value)
    return result


def solve(graph, options=None, initial=None, **settings):
    """Rotation averaging of every connected component of `graph`.

    options: a SolveOptions (defaults: MAGSAC++ loss, covariance weighting, IRLS);
    settings: fields of SolveOptions to override, e.g. solve(g, loss="huber").
    initial: {view id: 3x3} warm-start orientations (used when warm_start is on).
    Returns a Solution.
    """
    return _core.solve(graph, make_options(options, **settings), initial)
