#!/usr/bin/env python3
"""Rotation averaging with uncertainties on the matches of a COLMAP database.

Reads the keypoints and matches that COLMAP (feature_extractor and one of its
matchers, or hloc and other tools that write COLMAP databases) stored in
`database.db`, estimates every pair's relative pose and rotation covariance
with the package's two-view estimation, averages the rotations (MAGSAC++ loss,
covariance weighting) and bundle adjusts them as `rotavg images` does; writes
the world-to-camera orientations by image name and, given a ground truth,
scores them.

    python3 colmap_database.py database.db --output orientations.csv
    python3 colmap_database.py database.db --gt sparse/0/images.txt   # any ground truth rotavg reads
    python3 colmap_database.py database.db --matches raw --no-bundle-adjustment

By default the pairs are the inlier matches of COLMAP's geometric verification
(two_view_geometries); `--matches raw` takes every match (matches table) and
leaves the outliers to the package's own robust estimation. Keypoints are
undistorted with their camera's model (SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL,
RADIAL, OPENCV). Run it after sourcing the workspace (source devel/setup.bash).
"""
import argparse
import concurrent.futures
import os
import sqlite3
import sys

import numpy as np

import rotation_averaging as ra

# COLMAP's pair id: image ids (smaller first) packed into one integer.
MAX_IMAGE_ID = 2147483647

# COLMAP camera model id: (name, parameter count).
CAMERA_MODELS = {0: ("SIMPLE_PINHOLE", 3), 1: ("PINHOLE", 4), 2: ("SIMPLE_RADIAL", 4), 3: ("RADIAL", 5),
                 4: ("OPENCV", 8)}


class DatabaseError(Exception):
    pass


def camera_from_row(camera_id, model, params_blob):
    if model not in CAMERA_MODELS:
        raise DatabaseError(f"camera {camera_id}: model {model} is not supported (supported: "
                            + ", ".join(name for name, _ in CAMERA_MODELS.values()) + ")")
    name, count = CAMERA_MODELS[model]
    params = np.frombuffer(params_blob, dtype=np.float64)
    if len(params) != count or not np.all(np.isfinite(params)):
        raise DatabaseError(f"camera {camera_id} ({name}): expected {count} finite parameters, got {params}")
    if name in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = params[0]
        cx, cy = params[1], params[2]
    else:
        fx, fy, cx, cy = params[:4]
    distortion = np.zeros(4)  # k1, k2, p1, p2
    if name == "SIMPLE_RADIAL":
        distortion[0] = params[3]
    elif name == "RADIAL":
        distortion[:2] = params[3:5]
    elif name == "OPENCV":
        distortion[:] = params[4:8]
    if not (fx > 0 and fy > 0):
        raise DatabaseError(f"camera {camera_id}: focal lengths must be positive")
    return np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]]), distortion


def undistort(pixels, k, distortion, iterations=20):
    """Pixels of the camera's distortion model to those of the pinhole K (fixed point, as COLMAP's own)."""
    if not np.any(distortion):
        return pixels
    k1, k2, p1, p2 = distortion
    distorted = (pixels - k[:2, 2]) / np.array([k[0, 0], k[1, 1]])
    x = distorted.copy()
    for _ in range(iterations):
        u, v = x[:, 0], x[:, 1]
        r2 = u * u + v * v
        radial = 1.0 + k1 * r2 + k2 * r2 * r2
        tangential = np.column_stack([2 * p1 * u * v + p2 * (r2 + 2 * u * u), p1 * (r2 + 2 * v * v) + 2 * p2 * u * v])
        x = (distorted - tangential) / radial[:, None]
    return x * np.array([k[0, 0], k[1, 1]]) + k[:2, 2]


def read_database(path, matches_table):
    """Images {id: (name, K, undistorted keypoints)} and pairs [(id1, id2, (m, 2) keypoint indices)]."""
    if not os.path.isfile(path):
        raise DatabaseError(f"cannot open {path}")
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
        cameras = {cid: camera_from_row(cid, model, params)
                   for cid, model, params in db.execute("SELECT camera_id, model, params FROM cameras")}
        images = {}
        for image_id, name, camera_id in db.execute("SELECT image_id, name, camera_id FROM images"):
            if camera_id not in cameras:
                raise DatabaseError(f"image {name}: unknown camera {camera_id}")
            images[image_id] = [name, camera_id, np.zeros((0, 2))]
        for image_id, rows, cols, data in db.execute("SELECT image_id, rows, cols, data FROM keypoints"):
            if image_id not in images or data is None or rows == 0:
                continue
            if cols < 2 or len(data) != 4 * rows * cols:
                raise DatabaseError(f"keypoints of image {image_id}: {len(data)} bytes for {rows}x{cols} float32")
            points = np.frombuffer(data, dtype=np.float32).reshape(rows, cols)[:, :2].astype(np.float64)
            k, distortion = cameras[images[image_id][1]]
            images[image_id][2] = undistort(points, k, distortion)
        pairs = []
        for pair_id, rows, cols, data in db.execute(f"SELECT pair_id, rows, cols, data FROM {matches_table}"):
            if data is None or rows == 0:
                continue
            id2 = pair_id % MAX_IMAGE_ID
            id1 = (pair_id - id2) // MAX_IMAGE_ID
            if id1 not in images or id2 not in images:
                raise DatabaseError(f"pair {pair_id}: unknown image {id1 if id1 not in images else id2}")
            if cols != 2 or len(data) != 4 * rows * cols:
                raise DatabaseError(f"matches of pair {id1}-{id2}: {len(data)} bytes for {rows}x{cols} uint32")
            indices = np.frombuffer(data, dtype=np.uint32).reshape(rows, 2).astype(np.int64)
            if (indices[:, 0] >= len(images[id1][2])).any() or (indices[:, 1] >= len(images[id2][2])).any():
                raise DatabaseError(f"matches of pair {id1}-{id2} refer to keypoints that are not stored")
            pairs.append((id1, id2, indices))
        db.close()
    except sqlite3.Error as e:
        raise DatabaseError(f"{path}: {e}") from e
    return ({image_id: (name, cameras[camera_id][0], keypoints)
             for image_id, (name, camera_id, keypoints) in images.items()}, sorted(pairs, key=lambda p: p[:2]))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("database", help="COLMAP database.db")
    parser.add_argument("--matches", choices=["verified", "raw"], default="verified",
                        help="COLMAP's verified inlier matches (default) or every match")
    parser.add_argument("--output", help="write the orientations here (CSV: name,qw,qx,qy,qz, world-to-camera)")
    parser.add_argument("--graph-out", help="write the view graph (relative rotations and covariances) here")
    parser.add_argument("--gt", help="score against this ground truth (COLMAP images.txt, Strecha folder, CSV)")
    parser.add_argument("--no-bundle-adjustment", action="store_true", help="stop after the averaging")
    parser.add_argument("--threads", type=int, default=os.cpu_count() or 1,
                        help="pairs estimated at a time (default: the machine's cores; same results for any)")
    args = parser.parse_args(argv)

    try:
        images, pairs = read_database(args.database,
                                      "two_view_geometries" if args.matches == "verified" else "matches")
    except DatabaseError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"{len(images)} images, {len(pairs)} pairs with matches ({args.matches})")

    def estimate(pair):
        id1, id2, indices = pair
        points1, points2 = images[id1][2][indices[:, 0]], images[id2][2][indices[:, 1]]
        # The cell jackknife as rotavg images uses it on photographs.
        return points1, points2, ra.relative_pose(points1, points2, images[id1][1], images[id2][1], jackknife_grid=4)

    with concurrent.futures.ThreadPoolExecutor(max_workers=max(1, args.threads)) as pool:
        estimates = list(pool.map(estimate, pairs))
    graph = ra.ViewGraph()
    for image_id in sorted(images):
        graph.add_view(image_id, images[image_id][0])
    adjusted_pairs, failures = [], {}
    for (id1, id2, _), (points1, points2, pose) in zip(pairs, estimates):
        if not pose.success:
            failures[pose.failure] = failures.get(pose.failure, 0) + 1
            continue
        graph.add_relative_pose(id1, id2, pose)
        adjusted_pairs.append((id1, id2, points1, points2, pose))
    print(f"relative poses: {graph.num_edges} of {len(pairs)} pairs"
          + (" (failed: " + ", ".join(f"{k} {v}" for k, v in sorted(failures.items())) + ")" if failures else ""))
    if graph.num_edges == 0:
        print("error: no pair has a relative pose", file=sys.stderr)
        return 1
    if args.graph_out:
        ra.write_graph(args.graph_out, graph)

    solution = ra.solve(graph)
    print(solution.report())
    named = solution.named()
    if not args.no_bundle_adjustment:
        adjusted = ra.bundle_adjust(solution, adjusted_pairs, {i: images[i][1] for i in images})
        print(adjusted.report())
        if adjusted.success:
            named = adjusted.named({i: images[i][0] for i in images})
    if args.output:
        ra.write_orientations(args.output, named)
        print(f"orientations of {len(named)} images written to {args.output}")
    if args.gt:
        scores = ra.evaluate(named, ra.read_ground_truth(args.gt))
        print(f"views common with the ground truth: {scores['views_common']}")
        print(f"median error: {scores['median_error_deg']:.4f} deg, mean {scores['mean_error_deg']:.4f} deg")
        print("AUC: " + ", ".join(f"@{t:g} deg {100 * a:.2f} %" for t, a in sorted(scores["auc"].items())))
    return 0


if __name__ == "__main__":
    sys.exit(main())
