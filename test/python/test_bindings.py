"""Tests of the Python bindings (run by ctest through the devel space's env.sh)."""
import os
import subprocess
import threading

import numpy as np
import pytest

import rotation_averaging as ra

DATA = os.environ.get("ROTAVG_DATA_DIR", os.path.join(os.path.dirname(__file__), "..", "..", "..", "shared", "data"))
ROTAVG = os.environ.get("ROTAVG_BINARY", "")


def rotation_error_deg(a, b):
    return np.degrees(np.linalg.norm(ra.log_so3(a.T @ b)))


@pytest.fixture(scope="module")
def synthetic():
    return ra.synthetic_graph(num_views=60, mean_degree=8, noise_deg=1.0, noise_spread=3.0, anisotropic=True,
                              outlier_ratio=0.15, seed=7)


def test_arrays_as_matrices_or_quaternions_give_the_same_graph_and_solution(synthetic):
    graph, truth, _ = synthetic
    views = graph.edge_views
    rotations = graph.edge_rotations
    covariances = graph.edge_covariances
    assert views.shape == (graph.num_edges, 2) and rotations.shape == (graph.num_edges, 3, 3)
    # (w, x, y, z) quaternions of the same rotations.
    quaternions = []
    for r in rotations:
        w = np.sqrt(max(0.0, 1.0 + np.trace(r))) / 2.0
        x = np.copysign(np.sqrt(max(0.0, 1.0 + r[0, 0] - r[1, 1] - r[2, 2])) / 2.0, r[2, 1] - r[1, 2])
        y = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] + r[1, 1] - r[2, 2])) / 2.0, r[0, 2] - r[2, 0])
        z = np.copysign(np.sqrt(max(0.0, 1.0 - r[0, 0] - r[1, 1] + r[2, 2])) / 2.0, r[1, 0] - r[0, 1])
        quaternions.append([w, x, y, z])
    quaternions = np.array(quaternions)
    quaternions /= np.linalg.norm(quaternions, axis=1, keepdims=True)
    from_matrices = ra.ViewGraph.from_arrays(views[:, 0], views[:, 1], rotations, covariances=covariances)
    from_quaternions = ra.ViewGraph.from_arrays(views[:, 0], views[:, 1], quaternions, covariances=covariances)
    assert from_matrices.num_edges == from_quaternions.num_edges == graph.num_edges
    a, b = ra.solve(from_matrices), ra.solve(from_quaternions)
    assert a.success and b.success
    np.testing.assert_array_equal(a.ids, b.ids)
    assert max(rotation_error_deg(x, y) for x, y in zip(a.rotations, b.rotations)) < 1e-6
    scores = ra.evaluate(a.named(), truth)
    assert scores["views_common"] == 60
    assert scores["median_error_deg"] < 1.0, scores["median_error_deg"]
    assert set(scores["auc"]) == {2.0, 5.0, 10.0, 20.0}


def test_per_edge_results_match_the_graph_and_outliers_lose_their_weight(synthetic):
    graph, _, is_outlier = synthetic
    s = ra.solve(graph)
    for field in (s.edge_residuals_rad, s.edge_whitened_squared, s.edge_weights, s.edge_solved):
        assert field.shape == (graph.num_edges,)
    assert s.edge_solved.all()
    assert ((s.edge_weights >= 0.0) & (s.edge_weights <= 1.0)).all()
    assert np.median(s.edge_weights[is_outlier]) < 0.01
    assert np.median(s.edge_weights[~is_outlier]) > 0.5
    assert s.num_outlier_edges >= 0.8 * is_outlier.sum()
    component = s.components[0]
    assert component["num_views"] == 60 and component["final_cost"] > 0 and component["status"]
    assert "components solved" in s.report()


def test_every_loss_and_weighting_runs_and_options_are_checked(synthetic):
    graph, truth, _ = synthetic
    assert "magsac" in ra.loss_names() and "covariance" in ra.weighting_names()
    for loss in ra.loss_names():
        for weighting in ra.weighting_names():
            s = ra.solve(graph, loss=loss, weighting=weighting)
            assert s.ids.shape == (60,), (loss, weighting)
    for solver in ("ceres", "l1_irls"):
        s = ra.solve(graph, solver=solver, max_iterations=20)
        assert ra.evaluate(s.named(), truth)["median_error_deg"] < 5.0, solver
    with pytest.raises(ValueError, match="unknown loss 'l3'.*magsac"):
        ra.solve(graph, loss="l3")
    with pytest.raises(TypeError, match="unknown solve option 'sigma'"):
        ra.solve(graph, sigma=3.0)
    options = ra.make_options(loss="cauchy", loss_scale=0.05)
    assert options.loss == "cauchy" and options.loss_scale == 0.05
    derived = ra.make_options(options, weighting="trace")
    assert options.weighting == "covariance" and derived.weighting == "trace" and derived.loss == "cauchy"
    assert ra.SolveOptions().default_loss_scale() == 3.0
    assert ra.SolveOptions().self_calibration == "loss_scale"
    with pytest.raises(ValueError, match="loss_scale, floor"):
        ra.make_options(self_calibration="scale")
    # Values out of range are refused before anything runs, naming the field.
    with pytest.raises(ValueError, match=r"options: max_iterations must be at least 0 \(got -1\)"):
        ra.solve(graph, max_iterations=-1)
    with pytest.raises(ValueError, match="linear_solve_tolerance must be in"):
        ra.make_options(linear_solve_tolerance=2.0).validate()
    ra.SolveOptions().validate()


def test_covariance_floor_from_python():
    # Covariances that claim 0.01 deg for errors of 1 deg: the floor takes up
    # the difference and the loss keeps its scale.
    graph, truth, _ = ra.synthetic_graph(num_views=60, mean_degree=8, noise_deg=1.0, seed=3)
    views = graph.edge_views
    optimistic = np.tile(np.eye(3) * np.radians(0.01) ** 2, (len(views), 1, 1))
    g = ra.ViewGraph.from_arrays(views[:, 0], views[:, 1], graph.edge_rotations, covariances=optimistic)
    floor = ra.solve(g, self_calibration="floor")
    widened = ra.solve(g)
    c = floor.components[0]
    assert 0.5 < np.degrees(c["covariance_floor_rad"]) < 1.5
    assert c["loss_scale"] == 3.0 and widened.components[0]["loss_scale"] > 3.0
    assert widened.components[0]["covariance_floor_rad"] == 0.0
    assert ra.evaluate(floor.named(), truth)["median_error_deg"] < 1.0


def test_warm_start_continues_from_a_solution_and_posterior_covariances(synthetic):
    graph, _, _ = synthetic
    first = ra.solve(graph, posterior_covariance_max_views=1000)
    again = ra.solve(graph, initial=first.as_dict())
    assert again.components[0]["iterations"] <= 3
    assert max(rotation_error_deg(x, y) for x, y in zip(first.rotations, again.rotations)) < 1e-3
    covariances = first.view_covariances
    assert len(covariances) == 60
    gauge = first.components[0]["gauge_view"]
    assert np.allclose(covariances[gauge], 0.0)
    others = [c for view, c in covariances.items() if view != gauge]
    assert all(np.all(np.linalg.eigvalsh(c) > 0) for c in others)
    with pytest.raises(ValueError, match="unknown view 999"):
        ra.solve(graph, initial={999: np.eye(3)})
    with pytest.raises(ValueError, match="not a rotation"):
        ra.solve(graph, initial={0: 2.0 * np.eye(3)})


def test_bad_input_is_refused_with_the_reason():
    g = ra.ViewGraph()
    g.add_edge(1, 2, ra.exp_so3(np.array([0.0, 0.1, 0.0])), covariance=1e-4 * np.eye(3), inliers=50)
    g.add_edge(2, 3, np.array([1.0, 0.0, 0.0, 0.0]))  # quaternion
    assert (g.num_views, g.num_edges) == (3, 2)
    with pytest.raises(ValueError, match="self"):
        g.add_edge(3, 3, np.eye(3))
    with pytest.raises(ValueError, match="rotation"):
        g.add_edge(1, 3, np.full((3, 3), np.nan))
    with pytest.raises(ValueError, match="covariance"):
        g.add_edge(1, 3, np.eye(3), covariance=np.full((3, 3), np.inf))
    with pytest.raises(ValueError, match="3x3"):
        g.add_edge(1, 3, np.eye(2))
    with pytest.raises(ValueError, match="unknown edge source"):
        g.add_edge(1, 3, np.eye(3), source="odometry")
    assert g.num_edges == 2
    rotations = np.stack([np.eye(3), np.full((3, 3), np.nan), np.eye(3)])
    built = ra.ViewGraph.from_arrays([0, 1, 2], [1, 2, 2], rotations)
    assert built.num_edges == 1 and len(built.warnings) == 2
    assert "edge 1" in built.warnings[0] and "edge 2" in built.warnings[1]
    with pytest.raises(ValueError, match=r"shape \(3, 3, 3\) or \(3, 4\)"):
        ra.ViewGraph.from_arrays([0, 1, 2], [1, 2, 0], np.zeros((3, 2)))
    with pytest.raises(ValueError, match="same length"):
        ra.ViewGraph.from_arrays([0, 1], [1], np.zeros((2, 3, 3)))


def test_files_round_trip_and_read_errors_carry_the_message(tmp_path, synthetic):
    graph, truth, _ = synthetic
    path = str(tmp_path / "graph.txt")
    ra.write_graph(path, graph)
    back = ra.read_graph(path)
    assert (back.num_views, back.num_edges) == (graph.num_views, graph.num_edges)
    # Rotations are stored as quaternions, covariances as their upper triangle: equal to rounding.
    np.testing.assert_allclose(back.edge_rotations, graph.edge_rotations, rtol=0, atol=1e-14)
    np.testing.assert_allclose(back.edge_covariances, graph.edge_covariances, rtol=1e-13, atol=0)
    csv = str(tmp_path / "truth.csv")
    ra.write_orientations(csv, truth)
    read = ra.read_orientations(csv)
    assert read.keys() == truth.keys()
    assert max(np.abs(read[k] - truth[k]).max() for k in truth) < 1e-14  # quaternions, written exactly
    assert ra.read_ground_truth(csv).keys() == truth.keys()
    with pytest.raises(FileNotFoundError, match="cannot open"):
        ra.read_graph(str(tmp_path / "missing.g2o"))
    (tmp_path / "bad.g2o").write_text("VERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\nEDGE_SE3:QUAT 0 1 oops\n")
    with pytest.raises(ValueError, match=r"bad.g2o:2: expected 'EDGE_SE3:QUAT"):
        ra.read_graph(str(tmp_path / "bad.g2o"))
    with pytest.raises(ValueError, match="unknown format"):
        ra.read_graph(path, format="bundler")
    with pytest.raises(ValueError, match="folder without ground truth"):
        ra.read_ground_truth(str(tmp_path))


@pytest.mark.skipif(not ROTAVG, reason="ROTAVG_BINARY not set")
def test_python_and_the_command_line_give_the_same_orientations(tmp_path, synthetic):
    graph, _, _ = synthetic
    path = str(tmp_path / "graph.txt")
    ra.write_graph(path, graph)
    out = str(tmp_path / "cli.csv")
    subprocess.run([ROTAVG, "solve", path, "--output", out], check=True, capture_output=True)
    cli = ra.read_orientations(out)
    py = ra.solve(ra.read_graph(path)).named()
    assert cli.keys() == py.keys()
    assert max(np.abs(cli[k] - py[k]).max() for k in cli) < 1e-12


def quaternion_wxyz(r):
    """Unit quaternion (w, x, y, z) of a rotation matrix (COLMAP's order)."""
    k = np.array([[r[0, 0] - r[1, 1] - r[2, 2], r[1, 0] + r[0, 1], r[2, 0] + r[0, 2], r[2, 1] - r[1, 2]],
                  [r[1, 0] + r[0, 1], r[1, 1] - r[0, 0] - r[2, 2], r[2, 1] + r[1, 2], r[0, 2] - r[2, 0]],
                  [r[2, 0] + r[0, 2], r[2, 1] + r[1, 2], r[2, 2] - r[0, 0] - r[1, 1], r[1, 0] - r[0, 1]],
                  [r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1], r[0, 0] + r[1, 1] + r[2, 2]]]) / 3.0
    values, vectors = np.linalg.eigh(k)
    x, y, z, w = vectors[:, np.argmax(values)]
    return np.array([w, x, y, z])


@pytest.mark.skipif(not ROTAVG, reason="ROTAVG_BINARY not set")
def test_command_line_scores_a_colmap_model_as_it_scores_our_csv(tmp_path, synthetic):
    _, truth, _ = synthetic
    truth_csv = str(tmp_path / "truth.csv")
    ra.write_orientations(truth_csv, truth)
    # Another frame (one rotation away from the truth's) and one view 2 degrees off.
    frame = ra.exp_so3(np.array([0.3, -1.1, 0.4]))
    off = sorted(truth)[5]
    estimate = {name: r @ frame for name, r in truth.items()}
    estimate[off] = ra.exp_so3(np.radians(2.0) * np.array([0.0, 0.6, 0.8])) @ estimate[off]
    estimate_csv = str(tmp_path / "estimate.csv")
    ra.write_orientations(estimate_csv, estimate)
    lines = ["# Image list with two lines of data per image:"]
    for index, (name, r) in enumerate(sorted(estimate.items())):
        w, x, y, z = quaternion_wxyz(r)
        lines += [f"{index + 1} {w!r} {x!r} {y!r} {z!r} 0.5 -0.25 2 1 {name}", ""]
    (tmp_path / "images.txt").write_text("\n".join(lines) + "\n")

    def scores(*arguments):
        run = subprocess.run([ROTAVG, "eval", "--gt", truth_csv, "--per-view", *arguments], check=True,
                             capture_output=True, text=True)
        return {line.split()[1]: float(line.split()[2]) for line in run.stdout.splitlines() if line.startswith("view ")}

    ours = scores("--estimate", estimate_csv)
    colmap = scores("--estimate", str(tmp_path / "images.txt"), "--estimate-format", "colmap")
    assert ours.keys() == colmap.keys() == truth.keys()
    assert abs(colmap[off] - 2.0) < 1e-6
    assert max(abs(colmap[name] - ours[name]) for name in ours) < 1e-9
    assert max(error for name, error in colmap.items() if name != off) < 1e-9
    bad = subprocess.run([ROTAVG, "eval", "--gt", truth_csv, "--estimate", estimate_csv, "--estimate-format", "bundler"],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "unknown --estimate-format bundler" in bad.stderr


@pytest.mark.skipif(not ROTAVG, reason="ROTAVG_BINARY not set")
def test_command_line_scores_the_edges_covariances_against_ground_truth(tmp_path, synthetic):
    graph, truth, _ = synthetic
    graph_path, truth_csv = str(tmp_path / "graph.txt"), str(tmp_path / "truth.csv")
    ra.write_graph(graph_path, graph)
    ra.write_orientations(truth_csv, truth)

    def per_edge(*arguments):
        run = subprocess.run([ROTAVG, "eval", "--graph", graph_path, "--gt", truth_csv, "--per-edge", *arguments],
                             check=True, capture_output=True, text=True)
        assert "NEES median" in run.stdout
        return {tuple(line.split()[1:3]): [float(v) for v in line.split()[3:]]
                for line in run.stdout.splitlines() if line.startswith("edge ")}

    given = per_edge("--floor-deg", "0")
    names = dict(zip(graph.view_ids, graph.view_names))
    assert len(given) == graph.num_edges
    # Every view's offset, as a rotation vector whose norm is the offset.
    run = subprocess.run([ROTAVG, "eval", "--graph", graph_path, "--gt", truth_csv, "--per-edge"],
                         check=True, capture_output=True, text=True)
    offsets = {line.split()[1]: [float(v) for v in line.split()[2:]]
               for line in run.stdout.splitlines() if line.startswith("view ")}
    assert sorted(offsets) == sorted(graph.view_names)
    assert all(abs(o[0] - np.linalg.norm(o[1:])) < 1e-6 * max(1.0, o[0]) for o in offsets.values())
    assert "NEES median after per-view offsets" in run.stdout
    # Each edge's error in its right perturbation, where its covariance lives.
    for (i, j), r, c in zip(graph.edge_views, graph.edge_rotations, graph.edge_covariances):
        a, b = names[i], names[j]
        eta = ra.log_so3((truth[a] @ truth[b].T).T @ r)
        error_deg, nees, nees_floor = given[(a, b)]
        assert abs(error_deg - np.degrees(np.linalg.norm(eta))) < 1e-6 * max(1.0, error_deg)
        assert abs(nees - eta @ np.linalg.solve(c, eta)) < 1e-6 * max(1.0, nees)
        assert nees_floor == nees
    floor = np.radians(0.5)
    floored = per_edge("--floor-deg", "0.5")
    for (i, j), r, c in zip(graph.edge_views, graph.edge_rotations, graph.edge_covariances):
        a, b = names[i], names[j]
        eta = ra.log_so3((truth[a] @ truth[b].T).T @ r)
        expected = eta @ np.linalg.solve(c + floor * floor * np.eye(3), eta)
        assert abs(floored[(a, b)][2] - expected) < 1e-6 * max(1.0, expected)
    # Without --floor-deg, the floor the averaging estimates: never a larger NEES.
    estimated = per_edge()
    assert all(estimated[k][2] <= given[k][1] * (1 + 1e-9) for k in given)
    bad = subprocess.run([ROTAVG, "eval", "--graph", graph_path, "--gt", truth_csv, "--floor-deg", "-1"],
                         capture_output=True, text=True)
    assert bad.returncode != 0 and "--floor-deg must be a finite number >= 0" in bad.stderr
    # The view term from the offsets against an adjustment (here the truth,
    # floor 0: the offsets --per-edge prints): sqrt(median |d|^2 / 2.366).
    run = subprocess.run([ROTAVG, "eval", "--graph", graph_path, "--gt", truth_csv, "--floor-deg", "0", "--per-edge",
                          "--view-term-from", truth_csv], check=True, capture_output=True, text=True)
    offsets = [float(line.split()[2]) for line in run.stdout.splitlines() if line.startswith("view ")]
    block = run.stdout.split("covariances with the floor and the view term (")[1]
    view_deg = float(block.split()[0])
    assert abs(view_deg - np.sqrt(np.median(np.square(offsets)) / 2.366)) < 1e-4 * max(1.0, view_deg) + 5e-5
    floor_line = next(line for line in block.splitlines() if line.startswith("covariance floor:"))
    assert abs(float(floor_line.split()[2]) - np.sqrt(2.0) * view_deg) < 2e-4
    missing = subprocess.run([ROTAVG, "eval", "--graph", graph_path, "--gt", truth_csv,
                              "--view-term-from", str(tmp_path / "none.csv")], capture_output=True, text=True)
    assert missing.returncode != 0 and "none.csv" in missing.stderr and missing.stdout == ""
    usage = subprocess.run([ROTAVG, "eval", "--help"], capture_output=True, text=True)
    assert usage.returncode == 0 and "rotavg eval --graph" in usage.stdout


def test_solves_in_threads_agree_with_sequential_ones(synthetic):
    graph, _, _ = synthetic
    expected = ra.solve(graph).rotations
    results = [None] * 4

    def work(k):
        results[k] = ra.solve(graph).rotations

    threads = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for r in results:
        np.testing.assert_array_equal(r, expected)


def test_shared_pose_graph_with_ground_truth():
    garage = os.path.join(DATA, "pose_graphs", "sphere2500.g2o")
    chain = os.path.join(DATA, "pose_graphs", "sphere2500_groundtruth.txt")
    if not (os.path.exists(garage) and os.path.exists(chain)):
        if os.environ.get("ROTAVG_REQUIRE_DATA") == "1":
            pytest.fail(f"shared data not found under {DATA} (ROTAVG_REQUIRE_DATA=1; set ROTAVG_DATA_DIR)")
        pytest.skip(f"shared data not found under {DATA} (set ROTAVG_DATA_DIR)")
    graph = ra.read_graph(garage)
    assert (graph.num_views, graph.num_edges) == (2500, 4949)
    assert not np.isnan(graph.edge_covariances).any()
    s = ra.solve(graph)
    scores = ra.evaluate(s.named(), ra.read_ground_truth(chain))
    assert scores["views_common"] == 2500
    assert scores["median_error_deg"] < 2.0
