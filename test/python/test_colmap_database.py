"""Tests of examples/python/colmap_database.py on COLMAP databases written here
(the schema's tables and blobs as COLMAP writes them) from a synthetic scene."""
import importlib.util
import os
import sqlite3

import numpy as np
import pytest

import rotation_averaging as ra
from test_relative_pose import K, make_rig, project

SCRIPT = os.path.join(os.path.dirname(__file__), "..", "..", "examples", "python", "colmap_database.py")
spec = importlib.util.spec_from_file_location("colmap_database", SCRIPT)
colmap_database = importlib.util.module_from_spec(spec)
spec.loader.exec_module(colmap_database)

K1 = -0.08  # SIMPLE_RADIAL distortion of the synthetic camera


def distort(pixels, k1=K1):
    x = (pixels - K[:2, 2]) / K[0, 0]
    r2 = (x * x).sum(axis=1, keepdims=True)
    return x * (1.0 + k1 * r2) * K[0, 0] + K[:2, 2]


def write_database(path, rig, rng, camera_model=2, camera_params=None, outlier_ratio=0.1):
    """COLMAP's tables (the columns the script reads) for the views of `rig`:
    keypoints with 6 columns (x, y and an affine shape, as COLMAP's SIFT),
    every match in `matches`, the true ones in `two_view_geometries`."""
    rotations, centres, points = rig
    db = sqlite3.connect(path)
    db.execute("CREATE TABLE cameras (camera_id INTEGER PRIMARY KEY, model INTEGER, width INTEGER, height INTEGER, "
               "params BLOB, prior_focal_length INTEGER)")
    db.execute("CREATE TABLE images (image_id INTEGER PRIMARY KEY, name TEXT, camera_id INTEGER)")
    db.execute("CREATE TABLE keypoints (image_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB)")
    db.execute("CREATE TABLE matches (pair_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB)")
    db.execute("CREATE TABLE two_view_geometries (pair_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, "
               "data BLOB, config INTEGER)")
    params = camera_params if camera_params is not None else np.array([K[0, 0], K[0, 2], K[1, 2], K1])
    db.execute("INSERT INTO cameras VALUES (1, ?, 640, 480, ?, 0)", (camera_model, params.astype(np.float64).tobytes()))
    point_index = []  # per image: keypoint row of each scene point (-1: not seen)
    for v, (r, c) in enumerate(zip(rotations, centres)):
        image_id = v + 1
        pixels, visible = project(r, c, points, rng, 0.5)
        seen = np.flatnonzero(visible)
        keypoints = np.zeros((len(seen), 6), dtype=np.float32)
        keypoints[:, :2] = distort(pixels[seen])
        keypoints[:, 2] = keypoints[:, 5] = 2.0
        index = np.full(len(points), -1)
        index[seen] = np.arange(len(seen))
        point_index.append(index)
        db.execute("INSERT INTO images VALUES (?, ?, 1)", (image_id, f"img_{v:03d}.jpg"))
        db.execute("INSERT INTO keypoints VALUES (?, ?, 6, ?)", (image_id, len(seen), keypoints.tobytes()))
    for i in range(len(rotations)):
        for j in range(i + 1, len(rotations)):
            common = np.flatnonzero((point_index[i] >= 0) & (point_index[j] >= 0))[:500]
            true = np.column_stack([point_index[i][common], point_index[j][common]]).astype(np.uint32)
            wrong = np.column_stack([rng.integers(0, point_index[i].max() + 1, int(outlier_ratio * len(true))),
                                     rng.integers(0, point_index[j].max() + 1, int(outlier_ratio * len(true)))])
            every = np.vstack([true, wrong.astype(np.uint32)])
            pair_id = (i + 1) * colmap_database.MAX_IMAGE_ID + (j + 1)
            db.execute("INSERT INTO matches VALUES (?, ?, 2, ?)", (pair_id, len(every), every.tobytes()))
            db.execute("INSERT INTO two_view_geometries VALUES (?, ?, 2, ?, 2)", (pair_id, len(true), true.tobytes()))
    db.commit()
    db.close()


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    rng = np.random.default_rng(11)
    rig = make_rig(rng, 6, baseline=1.0)
    folder = tmp_path_factory.mktemp("colmap")
    database = str(folder / "database.db")
    write_database(database, rig, rng)
    truth = str(folder / "truth.csv")
    ra.write_orientations(truth, {f"img_{v:03d}.jpg": r for v, r in enumerate(rig[0])})
    return folder, database, truth


@pytest.mark.parametrize("matches", ["verified", "raw"])
def test_a_database_gives_orientations_by_image_name(scene, matches, capsys):
    folder, database, truth = scene
    output = str(folder / f"orientations_{matches}.csv")
    assert colmap_database.main([database, "--matches", matches, "--output", output, "--gt", truth,
                                 "--threads", "3"]) == 0
    printed = capsys.readouterr().out
    assert "6 images, 15 pairs with matches" in printed and "relative poses: 15 of 15 pairs" in printed
    assert "bundle adjustment: 6 views, 15 edges" in printed
    scores = ra.evaluate(ra.read_orientations(output), ra.read_ground_truth(truth))
    assert scores["views_common"] == 6
    assert scores["median_error_deg"] < 0.1, scores


def test_without_undistortion_the_same_matches_are_worse(scene, monkeypatch, capsys):
    """The camera's distortion is what the undistortion removes: the same database
    read as if the camera were a pinhole gives orientations several times further
    off (the distortion moves the image corners by 20 px)."""
    folder, database, truth = scene
    with_model = str(folder / "with_model.csv")
    assert colmap_database.main([database, "--output", with_model, "--no-bundle-adjustment"]) == 0
    monkeypatch.setattr(colmap_database, "undistort", lambda pixels, k, distortion: pixels)
    without_model = str(folder / "without_model.csv")
    assert colmap_database.main([database, "--output", without_model, "--no-bundle-adjustment"]) == 0
    capsys.readouterr()
    gt = ra.read_ground_truth(truth)
    good = ra.evaluate(ra.read_orientations(with_model), gt)["median_error_deg"]
    bad = ra.evaluate(ra.read_orientations(without_model), gt)["median_error_deg"]
    assert bad > 3 * good, (good, bad)


def test_undistortion_inverts_each_supported_model():
    rng = np.random.default_rng(12)
    pixels = rng.uniform([0, 0], [640, 480], size=(200, 2))
    k = np.array([[480.0, 0, 330.0], [0, 510.0, 235.0], [0, 0, 1]])
    for distortion in ([-0.1, 0, 0, 0], [-0.1, 0.02, 0, 0], [-0.1, 0.02, 1e-3, -2e-3]):
        k1, k2, p1, p2 = distortion
        x = (pixels - k[:2, 2]) / [k[0, 0], k[1, 1]]
        u, v = x[:, 0], x[:, 1]
        r2 = u * u + v * v
        radial = (1 + k1 * r2 + k2 * r2 * r2)[:, None]
        tangential = np.column_stack([2 * p1 * u * v + p2 * (r2 + 2 * u * u), p1 * (r2 + 2 * v * v) + 2 * p2 * u * v])
        distorted = (x * radial + tangential) * [k[0, 0], k[1, 1]] + k[:2, 2]
        np.testing.assert_allclose(colmap_database.undistort(distorted, k, np.array(distortion)), pixels, atol=1e-6)


def test_malformed_databases_are_refused_with_the_reason(tmp_path, capsys):
    rng = np.random.default_rng(13)
    rig = make_rig(rng, 3, baseline=1.0)
    first_pair = 1 * colmap_database.MAX_IMAGE_ID + 2

    def database(name, *statements, **written):
        """A database of the rig, then changed by the SQL statements (with their parameters)."""
        write_database(str(tmp_path / name), rig, rng, **written)
        db = sqlite3.connect(str(tmp_path / name))
        for statement in statements:
            db.execute(*statement)
        db.commit()
        db.close()
        return name

    with open(tmp_path / "not_a_database.db", "w") as f:
        f.write("not sqlite")
    cases = {
        "missing.db": "cannot open",
        "not_a_database.db": "file is not a database",
        database("fisheye.db", camera_model=5, camera_params=np.array([500.0, 320, 240, 0.1, 0.01])):
            "model 5 is not supported",
        database("short_params.db", camera_params=np.array([500.0, 320, 240])): "expected 4 finite parameters",
        database("cut_keypoints.db", ("UPDATE keypoints SET data = substr(data, 1, 100) WHERE image_id = 2",)):
            "keypoints of image 2",
        database("beyond.db", ("UPDATE two_view_geometries SET rows = 3, data = ? WHERE pair_id = ?",
                               (np.array([[0, 10 ** 6]] * 3, dtype=np.uint32).tobytes(), first_pair))):
            "refer to keypoints that are not stored",
        database("no_table.db", ("DROP TABLE two_view_geometries",)): "no such table: two_view_geometries",
    }
    for name, reason in cases.items():
        assert colmap_database.main([str(tmp_path / name)]) == 2, name
        error = capsys.readouterr().err
        assert error.startswith("error: ") and reason in error, (name, error)
