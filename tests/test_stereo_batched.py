"""The batched per-pair computations give what the plain per-pair / per-camera definitions give."""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap.geometry import epipolar_distance_matrix
from mocap.pairs import camera_pairs
from mocap.stereo import assign, match_pairs


def test_match_pairs_is_every_pair_of_free_detections_within_tolerance(rig):
    """Every (pair, detection, detection) with a symmetric epipolar distance below the tolerance, and no other,
    with that distance (H&Z point-line distances per pair as the reference), including padding and used slots."""
    rng = np.random.default_rng(7)
    pairs = camera_pairs(rig)
    P = rig.projection_matrices()
    X = rng.uniform(-0.6, 0.6, size=(12, 3)) + [0.0, 0.0, 1.0]
    Xh = np.concatenate([X, np.ones((len(X), 1))], axis=1)
    h = np.einsum("cij,nj->cni", P, Xh)
    D = h[..., :2] / h[..., 2:] + rng.normal(scale=0.8, size=(len(rig), len(X), 2))  # some within 2 px, some not
    D = D[:, rng.permutation(len(X))]  # detection order differs per camera
    D[1, 9:] = np.nan  # camera 1 saw fewer blobs (padding)
    free = np.isfinite(D[..., 0]) & (rng.random(D.shape[:2]) < 0.8)
    sigma = rng.uniform(0.05, 0.6, size=D.shape[:2])
    pair, n1, n2, dist = match_pairs(pairs, D, free, 2.0, None, sigma, 4.0)
    got = {(p, a, b): d for p, a, b, d in zip(pair, n1, n2, dist, strict=True)}
    want = {}
    for p, ((i, j), F) in enumerate(zip(pairs.index, pairs.F, strict=True)):
        a, b = np.flatnonzero(free[i]), np.flatnonzero(free[j])
        e = epipolar_distance_matrix(F, D[i, a], D[j, b])
        tol = np.maximum(2.0, 4.0 * np.hypot(sigma[i, a][:, None], sigma[j, b][None, :]))
        for r, s in zip(*np.nonzero(e < tol), strict=True):
            want[(p, a[r], b[s])] = e[r, s]
    assert len(want) > len(pairs) and set(got) == set(want)
    np.testing.assert_allclose([got[k] for k in want], list(want.values()), rtol=1e-9, atol=1e-9)


def test_assign_equals_one_optimal_assignment_per_camera():
    """Contested gates of all cameras solved together give each camera's own optimum (random crowded scenes)."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        K, C, N = 9, 4, 7
        q = rng.uniform(0.0, 1.6, size=(K, C, N))  # about 60 % of the gates inside: many contested
        eligible = rng.random((C, N)) < 0.9
        asg = assign(q, eligible)
        inside = (q < 1.0) & eligible[None]
        for c in range(C):
            got = asg[:, c]
            chosen = got[got >= 0]
            assert len(set(chosen)) == len(chosen) and inside[got >= 0, c, chosen].all()
            big = np.where(inside[:, c], q[:, c], 1e6)
            r, k = linear_sum_assignment(big)
            ok = inside[:, c][r, k]
            assert ok.sum() == len(chosen)
            np.testing.assert_allclose(q[got >= 0, c, chosen].sum(), big[r[ok], k[ok]].sum(), rtol=1e-12)


def test_pair_incidence_marks_each_pairs_two_cameras(rig):
    pairs = camera_pairs(rig)
    inc = pairs.incidence(len(rig) + 1)  # a camera in no pair keeps an empty column
    assert inc.shape == (len(pairs), len(rig) + 1)
    assert (inc.sum(axis=1) == 2).all() and not inc[:, -1].any()
    np.testing.assert_array_equal(np.nonzero(inc)[1].reshape(-1, 2), pairs.index)
    np.testing.assert_array_equal(pairs.F_t, pairs.F.transpose(0, 2, 1))
