"""Tests of the two-view estimation from Python: relative_pose() on matches the
caller brings, its conventions as a view-graph edge, and its errors."""
import concurrent.futures

import numpy as np
import pytest

import rotation_averaging as ra

K = np.array([[500.0, 0.0, 320.0], [0.0, 500.0, 240.0], [0.0, 0.0, 1.0]])


def rotation_about(axis, degrees):
    axis = np.asarray(axis, dtype=float)
    return ra.exp_so3(np.radians(degrees) * axis / np.linalg.norm(axis))


def make_rig(rng, num_views, baseline):
    """World-to-camera rotations and centres of cameras on an arc, all looking at the points."""
    rotations, centres = [], []
    for v in range(num_views):
        yaw = 6.0 * (v - (num_views - 1) / 2.0)
        rotations.append(rotation_about([0, 1, 0], -yaw) @ rotation_about(rng.normal(size=3), 1.5))
        centres.append(baseline * np.array([np.sin(np.radians(yaw)), 0.1 * rng.normal(), 0.0]) * 3.0)
    points = np.column_stack([rng.uniform(-3, 3, 2000), rng.uniform(-2, 2, 2000), rng.uniform(5, 10, 2000)])
    return rotations, centres, points


def project(rotation, centre, points, rng, sigma_px):
    camera = (points - centre) @ rotation.T
    pixels = (camera @ K.T)[:, :2] / camera[:, 2:3]
    visible = (camera[:, 2] > 0) & (pixels[:, 0] >= 0) & (pixels[:, 0] < 640) & (pixels[:, 1] >= 0) & (pixels[:, 1] < 480)
    return pixels + sigma_px * rng.normal(size=pixels.shape), visible


def matches(rig, i, j, rng, sigma_px=0.5, outlier_ratio=0.1):
    rotations, centres, points = rig
    p1, seen1 = project(rotations[i], centres[i], points, rng, sigma_px)
    p2, seen2 = project(rotations[j], centres[j], points, rng, sigma_px)
    both = seen1 & seen2
    p1, p2 = p1[both][:400], p2[both][:400]
    wrong = rng.random(len(p2)) < outlier_ratio
    p2[wrong] = rng.uniform([0, 0], [640, 480], size=(wrong.sum(), 2))
    return p1, p2, wrong


def angle_deg(r):
    return np.degrees(np.linalg.norm(ra.log_so3(r)))


def test_a_pair_with_outliers_gives_its_pose_in_the_documented_convention():
    rng = np.random.default_rng(1)
    rig = make_rig(rng, 2, baseline=1.0)
    p1, p2, wrong = matches(rig, 0, 1, rng)
    pose = ra.relative_pose(p1, p2, K)
    assert pose.success and pose.failure == "none" and pose.model == "essential", pose
    rotations, centres, _ = rig
    truth_21 = rotations[1] @ rotations[0].T
    assert angle_deg(truth_21.T @ pose.rotation) < 0.2
    np.testing.assert_allclose(pose.edge_rotation, pose.rotation.T)
    # x2 = R x1 + t with t = -R_2 (c_2 - c_1), up to scale.
    t_true = -rotations[1] @ (centres[1] - centres[0])
    assert np.degrees(np.arccos(np.clip(pose.translation @ t_true / np.linalg.norm(t_true), -1, 1))) < 3.0
    inliers = set(pose.inliers.tolist())
    assert len(inliers & set(np.flatnonzero(wrong).tolist())) <= 2
    assert len(inliers) >= 0.85 * (~wrong).sum()
    assert 0.3 < pose.sigma_px < 0.8
    for c in (pose.covariance, pose.covariance_marginal, pose.covariance_conditional):
        assert np.all(np.linalg.eigvalsh(0.5 * (c + c.T)) > 0)
    np.testing.assert_array_equal(pose.covariance, pose.covariance_marginal)
    # The conditional covariance (t held fixed) is never wider than the marginal one.
    assert np.trace(pose.covariance_conditional) <= np.trace(pose.covariance_marginal)
    conditional = ra.relative_pose(p1, p2, K, covariance_model="conditional")
    np.testing.assert_array_equal(conditional.covariance, conditional.covariance_conditional)
    assert "essential" in repr(pose)


def test_edges_from_relative_poses_average_to_the_truth_with_calibrated_covariances():
    """Every pair of six views, added as edges: the averaged orientations match the
    truth, and each edge's error against the truth is what its covariance says
    (median whitened squared error near chi-square(3)'s 2.37; read in the
    other convention, R_21, it is in the thousands)."""
    rng = np.random.default_rng(2)
    rig = make_rig(rng, 6, baseline=1.0)
    rotations = rig[0]
    graph = ra.ViewGraph()
    nees = []
    for i in range(6):
        for j in range(i + 1, 6):
            p1, p2, _ = matches(rig, i, j, rng, outlier_ratio=0.05)
            pose = ra.relative_pose(p1, p2, K)
            if not pose.success:
                continue
            graph.add_relative_pose(i, j, pose, source="other")
            # The edge's right perturbation: R_ij = R_ij_true Exp(eta).
            eta = ra.log_so3((rotations[i] @ rotations[j].T).T @ pose.edge_rotation)
            nees.append(eta @ np.linalg.solve(pose.covariance, eta))
    assert graph.num_edges >= 12
    np.testing.assert_array_equal(graph.edge_inliers > 100, True)
    assert 1.0 < np.median(nees) < 5.0, nees
    solution = ra.solve(graph)
    truth = {str(v): r for v, r in enumerate(rotations)}
    scores = ra.evaluate(solution.named(), truth)
    assert scores["views_common"] == 6
    assert scores["median_error_deg"] < 0.05, scores


def test_a_camera_that_only_turned_is_estimated_by_the_rotation_model():
    rng = np.random.default_rng(3)
    rig = make_rig(rng, 2, baseline=0.0)
    p1, p2, _ = matches(rig, 0, 1, rng, outlier_ratio=0.0)
    pose = ra.relative_pose(p1, p2, K)
    assert pose.success and pose.model == "rotation", pose
    np.testing.assert_array_equal(pose.translation, 0.0)
    rotations = rig[0]
    assert angle_deg((rotations[1] @ rotations[0].T).T @ pose.rotation) < 0.1
    # Without the rotation model, the pair has no pose, and says why.
    essential_only = ra.relative_pose(p1, p2, K, rotation_model=False)
    assert not essential_only.success and essential_only.failure != "none" and essential_only.message
    g = ra.ViewGraph()
    with pytest.raises(ValueError, match="has no pose"):
        g.add_relative_pose(0, 1, essential_only)
    assert g.num_edges == 0


def test_bad_input_raises_and_a_pair_without_a_pose_does_not():
    rng = np.random.default_rng(4)
    p1, p2, _ = matches(make_rig(rng, 2, baseline=1.0), 0, 1, rng)
    with pytest.raises(ValueError, match="differ in length"):
        ra.relative_pose(p1, p2[:-1], K)
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        ra.relative_pose(np.column_stack([p1, np.ones(len(p1))]), p2, K)
    with pytest.raises(ValueError, match="3x3"):
        ra.relative_pose(p1, p2, K[:2])
    bad = p2.copy()
    bad[5, 1] = np.nan
    with pytest.raises(ValueError, match="correspondence 5 is not finite"):
        ra.relative_pose(p1, bad, K)
    with pytest.raises(ValueError, match="K2 is not intrinsics"):
        ra.relative_pose(p1, p2, K, np.diag([500.0, -500.0, 1.0]))
    with pytest.raises(ValueError, match="unknown covariance_model 'full'"):
        ra.relative_pose(p1, p2, K, covariance_model="full")
    with pytest.raises(TypeError, match="unknown relative pose option 'threshold'"):
        ra.relative_pose(p1, p2, K, threshold=2.0)
    with pytest.raises(ValueError, match=r"options: ransac_threshold_px must be above 0 \(got -1\)"):
        ra.relative_pose(p1, p2, K, ransac_threshold_px=-1.0)
    with pytest.raises(ValueError, match="jackknife_grid must be in"):
        ra.make_relative_pose_options(jackknife_grid=40).validate()
    few = ra.relative_pose(p1[:10], p2[:10], K)
    assert not few.success and few.failure == "too_few_matches" and "10 correspondences" in few.message
    noise = ra.relative_pose(p1, rng.uniform([0, 0], [640, 480], size=p2.shape), K)
    assert not noise.success
    # Options are copied, never changed in place.
    options = ra.make_relative_pose_options(min_inliers=30)
    again = ra.make_relative_pose_options(options, min_inliers=40)
    assert (options.min_inliers, again.min_inliers) == (30, 40)


def test_pairs_in_a_thread_pool_give_the_same_poses_as_one_by_one():
    rng = np.random.default_rng(5)
    rig = make_rig(rng, 5, baseline=1.0)
    pairs = [matches(rig, i, i + 1, rng)[:2] for i in range(4)]
    expected = [ra.relative_pose(p1, p2, K) for p1, p2 in pairs]
    with concurrent.futures.ThreadPoolExecutor(max_workers=4) as pool:
        results = list(pool.map(lambda pair: ra.relative_pose(pair[0], pair[1], K), pairs * 2))
    for k, result in enumerate(results):
        reference = expected[k % len(pairs)]
        np.testing.assert_array_equal(result.rotation, reference.rotation)
        np.testing.assert_array_equal(result.covariance, reference.covariance)
        np.testing.assert_array_equal(result.inliers, reference.inliers)


def pairs_of_a_rig(rig, rng, outlier_ratio=0.05):
    """Every pair of views, each view's keypoints observed once (the same pixels in
    every pair, as a feature detector gives them), with wrong matches."""
    rotations, centres, points = rig
    observed = [project(r, c, points, rng, 0.5) for r, c in zip(rotations, centres)]
    graph, pairs = ra.ViewGraph(), []
    for i in range(len(rotations)):
        for j in range(i + 1, len(rotations)):
            common = np.flatnonzero(observed[i][1] & observed[j][1])[:600]
            p1, p2 = observed[i][0][common], observed[j][0][common].copy()
            wrong = rng.random(len(p2)) < outlier_ratio
            p2[wrong] = rng.uniform([0, 0], [640, 480], size=(wrong.sum(), 2))
            pose = ra.relative_pose(p1, p2, K)
            if pose.success:
                graph.add_relative_pose(i, j, pose)
                pairs.append((i, j, p1, p2, pose))
    return graph, pairs


def test_bundle_adjustment_of_the_averaged_orientations_on_the_pairs_matches():
    rng = np.random.default_rng(6)
    rig = make_rig(rng, 6, baseline=1.0)
    rotations, centres, _ = rig
    graph, pairs = pairs_of_a_rig(rig, rng)
    assert graph.num_edges == 15
    solution = ra.solve(graph)
    adjusted = ra.bundle_adjust(solution, pairs, K)
    assert adjusted.success, adjusted.report()
    s = adjusted.summary
    assert s["edges_used"] == 15 and s["edges_skipped"] == 0
    assert s["tracks"] > 300 and s["observations"] > 3 * s["tracks"]
    assert 0.5 < s["final_rms_sigmas"] < 1.5, adjusted.report()
    truth = {str(v): r for v, r in enumerate(rotations)}
    assert ra.evaluate(adjusted.named(), truth)["median_error_deg"] < 0.1
    # The orientations come from the matches, not from the start: started 0.5
    # deg off in every view, the adjustment reaches the same solution (up to
    # the gauge, which holds view 0 where it starts).
    directions = np.random.default_rng(0).normal(size=(6, 3))
    off = {v: ra.exp_so3(np.radians(0.5) * directions[v] / np.linalg.norm(directions[v])) @ r
           for v, r in solution.as_dict().items()}
    assert ra.evaluate({str(v): r for v, r in off.items()}, truth)["median_error_deg"] > 0.2
    again = ra.bundle_adjust(off, pairs, K)
    assert ra.evaluate(again.named(), adjusted.named())["median_error_deg"] < 0.005
    # The centres, up to the gauge's similarity: distances from view 0 in the
    # ratios of the truth's.
    estimated = np.array([np.linalg.norm(adjusted.centres[v] - adjusted.centres[0]) for v in range(1, 6)])
    true = np.array([np.linalg.norm(centres[v] - centres[0]) for v in range(1, 6)])
    np.testing.assert_allclose(estimated / estimated[-1], true / true[-1], rtol=0.03)
    # Intrinsics per view give the same adjustment as one K for all.
    per_view = ra.bundle_adjust(solution.as_dict(), pairs, {v: K for v in range(6)})
    for v in range(6):
        np.testing.assert_array_equal(per_view.orientations[v], adjusted.orientations[v])
    named = adjusted.named({v: f"cam{v}" for v in range(6)})
    assert sorted(named) == [f"cam{v}" for v in range(6)]


def test_bundle_adjustment_refuses_pairs_it_cannot_use():
    rng = np.random.default_rng(7)
    rig = make_rig(rng, 4, baseline=1.0)
    graph, pairs = pairs_of_a_rig(rig, rng)
    start = ra.solve(graph).as_dict()
    i, j, p1, p2, pose = pairs[0]
    with pytest.raises(ValueError, match="beyond the 10 points"):
        ra.bundle_adjust(start, [(i, j, p1[:10], p2[:10], pose)], K)
    failed = ra.relative_pose(p1[:10], p2[:10], K)
    with pytest.raises(ValueError, match=r"pairs\[0\]: the pair has no pose"):
        ra.bundle_adjust(start, [(i, j, p1, p2, failed)], K)
    with pytest.raises(ValueError, match="no intrinsics for view 1"):
        ra.bundle_adjust(start, pairs, {0: K})
    with pytest.raises(ValueError, match=r"\(view1, view2, points1, points2, pose\)"):
        ra.bundle_adjust(start, [(i, j, p1, p2)], K)
    with pytest.raises(ValueError, match="not a rotation"):
        ra.bundle_adjust({0: 2.0 * np.eye(3)}, pairs, K)
    with pytest.raises(TypeError, match="unknown bundle adjustment option 'sigmas'"):
        ra.bundle_adjust(start, pairs, K, sigmas=2.0)
    # Views without an orientation leave their pairs out; the rest is adjusted.
    partial = ra.bundle_adjust({v: r for v, r in start.items() if v != 3}, pairs, K)
    assert partial.success and partial.summary["edges_used"] == 3 and 3 not in partial.orientations


@pytest.mark.parametrize("seed, view", [(116, 1), (119, 0), (122, 4), (138, 4), (150, 0)])
def test_a_robust_model_with_the_mirrored_translation_still_gives_the_pose(seed, view):
    """Pairs whose robust model lies off along the rotation-translation valley,
    with its points in front only under the mirrored translation: the Sampson
    refinement brings R back but cannot tell t from -t (they failed with every
    point behind the cameras); cheirality picks the sign."""
    rng = np.random.default_rng(seed)
    rig = make_rig(rng, 6, baseline=1.0)
    for k in range(view + 1):
        p1, p2, _ = matches(rig, k, k + 1, rng, outlier_ratio=0.1)
    pose = ra.relative_pose(p1, p2, K)
    assert pose.success, pose
    rotations, centres, _ = rig
    eta = ra.log_so3((rotations[view + 1] @ rotations[view].T).T @ pose.rotation)
    assert np.degrees(np.linalg.norm(eta)) < 0.5
    assert eta @ np.linalg.solve(pose.covariance, eta) < 16.3  # chi-square(3) 99.9 %
    t_true = -rotations[view + 1] @ (centres[view + 1] - centres[view])
    assert pose.translation @ t_true / np.linalg.norm(t_true) > 0.999


def test_the_cell_jackknife_only_widens_the_marginal_covariance():
    rng = np.random.default_rng(5)
    rig = make_rig(rng, 2, baseline=1.0)
    p1, p2, _ = matches(rig, 0, 1, rng)
    pixel = ra.relative_pose(p1, p2, K)  # the library's default: the pixel model alone
    jackknife = ra.relative_pose(p1, p2, K, jackknife_grid=4)
    assert pixel.success and jackknife.success
    np.testing.assert_allclose(jackknife.rotation, pixel.rotation, atol=1e-12)
    np.testing.assert_allclose(jackknife.covariance_conditional, pixel.covariance_conditional)
    np.testing.assert_allclose(jackknife.covariance_marginal_pixel, pixel.covariance)
    np.testing.assert_allclose(pixel.covariance_marginal_pixel, pixel.covariance)
    # At least as large in every direction, and larger in some.
    assert np.linalg.eigvalsh(jackknife.covariance - pixel.covariance).min() > -1e-12 * np.trace(pixel.covariance)
    assert np.trace(jackknife.covariance) > np.trace(pixel.covariance)
