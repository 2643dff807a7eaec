"""Multi-view fusion: robust triangulation, re-pick, new markers, variable-radius re-identification."""

from __future__ import annotations

import numpy as np

from mocap.fusion import _greedy_by_support, new_points, reidentify, repick, robust_triangulate
from mocap.geometry import triangulate_weighted
from mocap.pairs import camera_pairs


def _ideal(rig, X):
    P = rig.projection_matrices()
    h = np.einsum("cij,nj->cni", P, np.concatenate([X, np.ones((len(X), 1))], axis=1))
    return h[..., :2] / h[..., 2:]


def test_robust_triangulation_rejects_a_dragged_camera_and_matches_the_clean_solution(rig):
    rng = np.random.default_rng(0)
    P = rig.projection_matrices()
    X = rng.normal(scale=0.3, size=(4, 3)) + [0, 0, 1]
    uv = _ideal(rig, X) + rng.normal(scale=0.05, size=(len(rig), 4, 2))
    cov = np.broadcast_to(np.eye(2) * 0.05**2, uv.shape[:2] + (2, 2)).copy()
    uv[2, 0] += [3.0, -2.0]  # a merged blob / ghost in camera 2 for point 0
    uv[4:, 1] = np.nan  # point 1 seen by four cameras only
    start = X + rng.normal(scale=0.01, size=X.shape)
    tri = robust_triangulate(P, uv, cov, start, outlier_sigma=5.0, outlier_min_px=0.3)
    assert not tri.used[0, 2] and tri.used[0].sum() == 5
    assert tri.used[1].tolist() == [True] * 4 + [False] * 2
    clean = uv.copy()
    clean[2, 0] = np.nan
    ref, ref_cov, ref_rms = triangulate_weighted(P, clean, cov)
    np.testing.assert_allclose(tri.X, ref, atol=1e-9)
    np.testing.assert_allclose(tri.cov, ref_cov, rtol=1e-6)
    np.testing.assert_allclose(tri.rms_px, ref_rms, rtol=1e-6)
    assert np.linalg.norm(tri.X - X, axis=1).max() < 1e-3


def test_a_precise_wrong_camera_is_rejected_by_the_pair_consensus(rig):
    """A wrong detection 100x more precise than the others pulls the weighted point onto itself, so that the
    right cameras look like outliers; the best camera pair's consensus still finds and drops it, for many
    points at once (each with its own wrong camera, some seen by four cameras only)."""
    rng = np.random.default_rng(6)
    P = rig.projection_matrices()
    K = 12
    X = rng.normal(scale=0.3, size=(K, 3)) + [0, 0, 1]
    uv = _ideal(rig, X) + rng.normal(scale=0.05, size=(len(rig), K, 2))
    cov = np.broadcast_to(np.eye(2) * 0.05**2, uv.shape[:2] + (2, 2)).copy()
    wrong = np.arange(K) % len(rig)
    uv[wrong, np.arange(K)] += rng.choice([-1.0, 1.0], size=(K, 2)) * [4.0, 3.0]
    cov[wrong, np.arange(K)] /= 100.0
    four = np.arange(K) >= K - 3
    uv[(wrong[four] + 1) % len(rig), np.flatnonzero(four)] = np.nan
    uv[(wrong[four] + 2) % len(rig), np.flatnonzero(four)] = np.nan
    tri = robust_triangulate(P, uv, cov, X + rng.normal(scale=0.005, size=X.shape), 5.0, 0.3)
    want = np.isfinite(uv[..., 0]).T
    want[np.arange(K), wrong] = False
    np.testing.assert_array_equal(tri.used, want)
    clean = np.where(want.T[..., None], uv, np.nan)
    ref, _, _ = triangulate_weighted(P, clean, cov)
    np.testing.assert_allclose(tri.X, ref, atol=1e-9)


def test_two_disagreeing_cameras_give_no_point(rig):
    P = rig.projection_matrices()
    X = np.array([[0.0, 0.1, 1.0]])
    uv = np.full((len(rig), 1, 2), np.nan)
    uv[:2] = _ideal(rig, X)[:2]
    uv[1, 0, 1] += 5.0
    cov = np.broadcast_to(np.eye(2) * 0.01, uv.shape[:2] + (2, 2))
    tri = robust_triangulate(P, uv, cov, X, 5.0, 0.3)
    assert np.isnan(tri.X).all() and not tri.used.any()


def test_repick_takes_the_free_detection_at_the_reprojection(rig):
    P = rig.projection_matrices()
    X = np.array([[0.0, 0.0, 1.0], [0.3, 0.0, 1.0]])
    truth = _ideal(rig, X)  # (C, 2, 2)
    uv = truth.copy()
    uv[3:, :] = np.nan  # cameras 3.. not assigned yet
    cov = np.broadcast_to(np.eye(2) * 0.01, uv.shape[:2] + (2, 2))
    tri = robust_triangulate(P, uv, cov, X, 5.0, 0.3)
    D = np.concatenate([truth[:, ::-1], truth[:, :1] + [4.0, 0.0]], axis=1)  # (C, 3, 2): swapped order + decoy
    free = np.ones(D.shape[:2], dtype=bool)
    free[4, 0] = False  # camera 4's blob of point 1 is taken by someone else
    got = repick(tri, D, free, 1.0)
    assert (got[:, :3] == -1).all()  # assigned cameras are not offered anything
    assert got[0, 3:].tolist() == [1, 1, 1]
    assert got[1, 3:].tolist() == [0, -1, 0]


def test_new_points_recover_markers_and_reject_ghost_pairs(rig):
    rng = np.random.default_rng(4)
    P = rig.projection_matrices()
    pairs = camera_pairs(rig)
    X = rng.normal(scale=0.3, size=(6, 3)) + [0, 0, 1]
    uv = _ideal(rig, X) + rng.normal(scale=0.05, size=(len(rig), 6, 2))
    uv[0, 5] = np.nan  # marker 5 only in cameras 1..5
    ghosts = rng.uniform([0, 0], [1024, 768], size=(len(rig), 4, 2))
    D = np.concatenate([uv, ghosts], axis=1)
    order = rng.permutation(D.shape[1])
    D = D[:, order]
    free = np.isfinite(D).all(axis=2)
    cov = np.broadcast_to(np.eye(2) * 0.05**2, D.shape[:2] + (2, 2))
    sizes = np.array([c.size for c in rig.cameras], dtype=float)
    pts = new_points(P, pairs, D, cov, free, sizes, 1.5, 1.5, 3, 5.0, 0.3)
    strong = pts.X[pts.strong]
    assert len(strong) == 6
    d = np.linalg.norm(strong[:, None] - X[None], axis=2)
    assert (d.min(axis=0) < 2e-3).all()
    assert (pts.det[pts.strong] >= 0).sum(axis=1).min() >= 5
    for c in range(len(rig)):  # every detection is used at most once
        used = pts.det[:, c][pts.det[:, c] >= 0]
        assert len(np.unique(used)) == len(used)
    assert not any(order[d] >= 6 for d in pts.det[pts.strong].ravel() if d >= 0)  # no ghost blob in a marker


def test_a_candidate_that_lost_a_view_queues_again_with_the_views_it_has_left():
    """Detection 0 of every camera. A real marker (cameras 2, 3, 4) is accepted first and takes camera 2's blob from
    a ghost (cameras 0, 1, 2): the ghost, two views left, must not then outrank the real two-view point (cameras
    0, 5, epipolar distance 0.004 px) that its camera-0 blob belongs to."""
    support = np.zeros((6, 3), dtype=bool)
    support[[2, 3, 4], 0] = True  # the marker
    support[[0, 1, 2], 1] = True  # the ghost
    support[[0, 5], 2] = True  # the two-view marker
    nearest = np.zeros((6, 3), dtype=np.intp)
    chosen = _greedy_by_support(support, nearest, np.array([0.1, 0.9, 0.004]), (6, 1))
    assert chosen == [0, 2]
    assert support[:, 0].sum() == 3 and support[:, 2].sum() == 2


def test_new_points_free_a_blob_that_a_hidden_markers_point_claimed_and_rejected(rig):
    """Marker 1 is hidden from camera 2, where its projection lands 1 px from marker 0's blob: within the support
    tolerance, so the candidates of marker 1 (five views) would claim that blob before marker 0's (two views:
    cameras 1 and 2 alone see it). A robust fit over marker 1's candidates rejects the blob; marker 0 gets it."""
    P = rig.projection_matrices()
    pairs = camera_pairs(rig)
    X1 = np.array([[0.1, 0.2, 1.0]])
    uv1 = _ideal(rig, X1)[:, 0]
    # marker 0: on camera 2's ray through uv1 + 1 px, 0.3 m nearer the camera: seen by cameras 1 and 2 only
    target = uv1[2] + [1.0, 0.0]
    M = P[2][:, :3]
    ray = np.linalg.solve(M, np.r_[target, 1.0])
    centre = -np.linalg.solve(M, P[2][:, 3])
    X0 = centre + ray / np.linalg.norm(ray) * (np.linalg.norm(X1[0] - centre) - 0.3)
    uv0 = _ideal(rig, X0[None])[:, 0]
    D = np.full((len(rig), 2, 2), np.nan)
    D[:, 0] = uv1
    D[2, 0] = np.nan  # marker 1 hidden from camera 2
    D[[1, 2], 1] = uv0[[1, 2]]
    free = np.isfinite(D).all(axis=2)
    cov = np.broadcast_to(np.eye(2) * 0.01**2, D.shape[:2] + (2, 2))
    sizes = np.array([c.size for c in rig.cameras], dtype=float)
    pts = new_points(P, pairs, D, cov, free, sizes, 1.5, 2.0, 3, 5.0, 0.3)
    d = np.linalg.norm(pts.X[:, None] - np.array([X0, X1[0]])[None], axis=2)
    assert len(pts.X) == 2 and (d.min(axis=0) < 1e-3).all()
    assert pts.det[np.argmin(d[:, 0]), 2] == 1  # camera 2's blob is marker 0's


def test_reidentify_follows_each_tracks_own_radius():
    predicted = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    points = np.array([[0.15, 0.0, 1.0], [1.05, 0.0, 1.0], [3.0, 0.0, 1.0]])
    narrow = reidentify(points, predicted, np.array([0.05, 0.1]))
    assert narrow.tolist() == [-1, 1, -1]
    wide = reidentify(points, predicted, np.array([0.3, 0.1]))  # track 0 unseen longer: wider radius
    assert wide.tolist() == [0, 1, -1]
    # the last seen position counts as well as the (possibly runaway) prediction
    far = np.array([[5.0, 0.0, 1.0], [1.0, 0.0, 1.0]])
    assert reidentify(points, far, np.array([0.3, 0.1]), last_seen=predicted).tolist() == [0, 1, -1]
    # optimal, not greedy: point 0 is nearer to both, but the joint optimum gives each its own
    both = reidentify(np.array([[0.5, 0, 1.0], [0.05, 0, 1.0]]), np.array([[0.0, 0, 1.0], [0.55, 0, 1.0]]),
                      np.array([1.0, 1.0]))
    assert both.tolist() == [1, 0]
