"""Camera pairs and the per-pair stage: gating, assignment, epipolar pruning, pair matching."""

from __future__ import annotations

import cv2
import numpy as np
from conftest import ring_rig
from scipy.optimize import linear_sum_assignment

from mocap.geometry import epipolar_distance_matrix, fundamental_from_cameras
from mocap.pairs import camera_pairs, volume_of_interest
from mocap.stereo import (
    assign,
    epipolar_consistency,
    epipolar_distance,
    gate,
    match_pairs,
    triangulate_matches,
)
from mocap.synth import walkway_rig


def _ideal(rig, X):
    """(C, N, 2) ideal pixels of world points X (N, 3)."""
    P = rig.projection_matrices()
    Xh = np.concatenate([X, np.ones((len(X), 1))], axis=1)
    h = np.einsum("cij,nj->cni", P, Xh)
    return h[..., :2] / h[..., 2:]


def test_pairs_of_a_ring_follow_the_angle_rule():
    rig = ring_rig(6)
    pairs = camera_pairs(rig)
    centre, _ = volume_of_interest(rig)
    np.testing.assert_allclose(centre, [0, 0, 1], atol=1e-6)
    # 60 and 120 degree neighbours qualify; facing cameras of this ring are 147 degrees apart (<= 150).
    assert len(pairs) == 15
    assert pairs.neighbour.sum() == 6
    assert (pairs.angle_deg >= 15).all() and (pairs.angle_deg <= 150).all()
    strict = camera_pairs(rig, max_angle_deg=130)
    assert len(strict) == 12 and set(map(tuple, strict.index)) <= set(map(tuple, pairs.index))
    for (i, j), F in zip(pairs.index, pairs.F, strict=True):
        np.testing.assert_allclose(F, fundamental_from_cameras(rig[i], rig[j]))


def test_pairs_scale_to_other_rigs():
    rig = ring_rig(10, radius=6.0)
    pairs = camera_pairs(rig)
    assert len(pairs) > 10 and pairs.neighbour.sum() == 10
    assert len(camera_pairs(ring_rig(2))) == 1


def test_pairs_of_a_walkway_cover_every_stretch_of_it():
    """Two rows of cameras along a 14 m walkway, each seeing a stretch: every point two cameras see has a
    pair among them, and every camera is in a pair (one central volume left the end cameras out)."""
    rig = walkway_rig(12, length=14.0, standoff=5.0, seed=1)
    pairs = camera_pairs(rig)
    assert set(pairs.index.ravel()) == set(range(12))
    assert (pairs.angle_deg >= 15).all() and (pairs.angle_deg <= 150).all()
    rng = np.random.default_rng(2)
    X = rng.uniform([-6.0, -1.0, 0.1], [6.0, 1.0, 1.8], (2000, 3))
    seen = np.stack([cam.in_image(cam.project(X), 10.0) for cam in rig.cameras])  # (C, N)
    paired = np.zeros(len(X), dtype=bool)
    for i, j in pairs.index:
        paired |= seen[i] & seen[j]
    two_views = seen.sum(axis=0) >= 2
    assert two_views.mean() > 0.95
    assert paired[two_views].mean() > 0.99

def test_epipolar_distance_agrees_with_geometry_and_opencv(rig):
    rng = np.random.default_rng(0)
    X = rng.normal(scale=0.4, size=(7, 3)) + [0, 0, 1]
    uv = _ideal(rig, X)
    F = fundamental_from_cameras(rig[0], rig[2])
    p1 = uv[0] + rng.normal(scale=2.0, size=uv[0].shape)
    p2 = uv[2]
    d = epipolar_distance(F, p1[:, None, :], p2[None, :, :])
    np.testing.assert_allclose(d, epipolar_distance_matrix(F, p1, p2), rtol=1e-10)
    l2 = cv2.computeCorrespondEpilines(p1.reshape(-1, 1, 2), 1, F).reshape(-1, 3)  # a^2 + b^2 = 1
    l1 = cv2.computeCorrespondEpilines(p2.reshape(-1, 1, 2), 2, F).reshape(-1, 3)
    d12 = np.abs((l2[:, :2] * p2).sum(axis=1) + l2[:, 2])
    d21 = np.abs((l1[:, :2] * p1).sum(axis=1) + l1[:, 2])
    np.testing.assert_allclose(d.diagonal(), np.maximum(d12, d21), rtol=1e-6)


def test_assign_is_optimal_and_one_to_one():
    rng = np.random.default_rng(1)
    K, C, N = 6, 3, 8
    pred = rng.uniform(0, 40, size=(K, C, 2))
    D = rng.uniform(0, 40, size=(C, N, 2))
    radius = np.full((K, C), 12.0)
    q = gate(pred, radius, D)
    asg = assign(q)
    for c in range(C):
        got = asg[:, c]
        chosen = got[got >= 0]
        assert len(set(chosen)) == len(chosen)  # one track per detection
        assert (q[got >= 0, c, chosen] < 1).all()  # all inside their gates
        # optimality: maximum number of pairs, then least total cost (brute force via an augmented matrix)
        inside = q[:, c] < 1
        big = np.where(inside, q[:, c], 1e6)
        r, k = linear_sum_assignment(big)
        ok = inside[r, k]
        assert ok.sum() == len(chosen)
        assert np.isclose(big[r[ok], k[ok]].sum(), q[got >= 0, c, chosen].sum())


def test_assign_respects_eligibility_and_empty_inputs():
    q = np.array([[[0.1, 0.2]]])
    assert assign(q, np.array([[False, True]]))[0, 0] == 1
    assert assign(np.zeros((0, 2, 3))).shape == (0, 2)
    assert (assign(np.zeros((2, 2, 0))) == -1).all()


def test_epipolar_consistency_flags_the_odd_camera(rig):
    pairs = camera_pairs(rig)
    X = np.array([[0.1, 0.2, 1.1], [-0.3, 0.1, 0.8]])
    uv = _ideal(rig, X).swapaxes(0, 1).copy()  # (K, C, 2)
    uv[0, 3] += [0.0, 25.0]  # track 0: camera 3 picked the wrong blob
    uv[1, 1:] = np.nan  # track 1 seen by camera 0 only: nothing to test against
    supported, tested = epipolar_consistency(pairs, uv, tol_px=2.0)
    assert supported[0].tolist() == [True, True, True, False, True, True]
    assert tested[0].all()
    assert not tested[1].any() and not supported[1].any()


def test_epipolar_consistency_equals_a_loop_over_pairs(rig):
    """The batched test gives, track by track, what epipolar_distance over each pair says (sigma tolerance too)."""
    rng = np.random.default_rng(4)
    pairs = camera_pairs(rig)
    X = rng.uniform(-0.5, 0.5, size=(30, 3)) + [0.0, 0.0, 1.0]
    uv = _ideal(rig, X).swapaxes(0, 1).copy()
    uv += rng.normal(scale=1.5, size=uv.shape)  # some pairs within 2 px, some not
    uv[rng.random(uv.shape[:2]) < 0.3] = np.nan
    sigma = rng.uniform(0.05, 0.8, size=uv.shape[:2])
    supported, tested = epipolar_consistency(pairs, uv, 2.0, sigma, 4.0)
    want_s, want_t = np.zeros_like(supported), np.zeros_like(tested)
    for k in range(len(X)):
        for (a, b), F in zip(pairs.index, pairs.F, strict=True):
            e = epipolar_distance(F, uv[k, a], uv[k, b])
            if np.isfinite(e):
                want_t[k, [a, b]] = True
                if e < max(2.0, 4.0 * np.hypot(sigma[k, a], sigma[k, b])):
                    want_s[k, [a, b]] = True
    assert want_t.any() and want_s.any() and (want_t & ~want_s).any()
    np.testing.assert_array_equal(supported, want_s)
    np.testing.assert_array_equal(tested, want_t)


def test_match_pairs_finds_the_true_correspondences_and_triangulates_them(rig):
    rng = np.random.default_rng(2)
    pairs = camera_pairs(rig)
    X = rng.normal(scale=0.3, size=(5, 3)) + [0, 0, 1]
    uv = _ideal(rig, X)  # (C, 5, 2): detection n of every camera is marker n
    free = np.ones(uv.shape[:2], dtype=bool)
    pair, n1, n2, dist = match_pairs(pairs, uv, free, tol_px=0.5)
    true = n1 == n2
    assert true.sum() == 5 * len(pairs)  # every marker matched in every pair
    assert (dist[true] < 1e-6).all()
    cov = np.broadcast_to(np.eye(2) * 0.01, uv.shape[:2] + (2, 2))
    Xt, cov3, rms = triangulate_matches(rig.projection_matrices(), pairs, uv, cov, pair[true], n1[true], n2[true])
    np.testing.assert_allclose(Xt, X[n1[true]], atol=1e-9)
    assert np.all(np.linalg.eigvalsh(cov3) > 0)
    # with 'fresh' flags, detections that are all old are not paired again
    fresh = np.zeros_like(free)
    assert match_pairs(pairs, uv, free, 0.5, fresh)[0].size == 0
    fresh[0, 2] = True
    got = match_pairs(pairs, uv, free, 0.5, fresh)
    assert set(got[0]) == {p for p, (i, j) in enumerate(pairs.index) if 0 in (i, j)}
    assert ((got[1] == 2) | (got[2] == 2)).all()


def test_match_pairs_handles_no_detections(rig):
    pairs = camera_pairs(rig)
    D = np.zeros((len(rig), 0, 2))
    assert match_pairs(pairs, D, np.zeros((len(rig), 0), dtype=bool), 1.0)[0].size == 0
