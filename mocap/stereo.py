"""Per-camera-pair stage of the tracker: 2D gating, assignment, epipolar pruning, pair matching.

Everything is vectorised over tracks, cameras and pairs and works on ideal (undistorted) pixels.
Detections of one frame are held padded as ``D`` (C, N, 2) with NaN rows beyond each camera's count.

* :func:`gate` — distance of every track's 2D prediction to every detection of the same camera,
  normalised by the track's search radius there (paper 004: a region sized by the running
  prediction errors); in the gate when < 1.
* :func:`assign` — one detection per (track, camera) and one track per detection: unambiguous gates
  are taken directly, the rest per camera by optimal assignment (``linear_sum_assignment``).
* :func:`epipolar_consistency` — paper 004's epipolar pruning over the stereo pairs: a camera's
  choice for a track must lie on the epipolar line of the track's point in a partner camera
  (``l2 = F p1``); choices no partner supports are dropped (the fusion stage re-picks them from the
  multi-view point, i.e. the candidate nearest to all partners' epipolar lines).
* :func:`match_pairs` — all-pairs epipolar matching of leftover detections (the start of "new
  markers"), and :func:`triangulate_matches` their two-view triangulation with covariance.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap import kernels
from mocap.geometry import triangulate_weighted
from mocap.pairs import CameraPairs

__all__ = ["dist2", "gate", "assign", "epipolar_distance", "epipolar_consistency", "match_pairs", "triangulate_matches"]

_FORBIDDEN = 1e6
_MATCH_STEPS = 3  # Gauss-Newton steps of the two-view triangulation of matches


def gate(pred: np.ndarray, radius: np.ndarray, D: np.ndarray) -> np.ndarray:
    """Normalised squared distances of predictions to detections.

    Args:
        pred: (K, C, 2) predicted ideal pixels of K tracks in C cameras (NaN: no prediction).
        radius: (K, C) search radius, pixels.
        D: (C, N, 2) padded detections, ideal pixels (NaN rows are padding).

    Returns:
        (K, C, N) ``|pred - det|^2 / radius^2``; inf where undefined. In the gate when < 1.
    """
    if kernels.HAVE_NUMBA:
        return kernels.gate(kernels.contiguous(pred), kernels.contiguous(radius), kernels.contiguous(D))
    q = dist2(pred[:, :, None, :], D[None]) / (radius * radius)[..., None]
    return np.where(np.isnan(q), np.inf, q)


def dist2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Squared distance of broadcast 2D points (component-wise: much faster than a sum over a size-2 axis)."""
    dx = a[..., 0] - b[..., 0]
    dy = a[..., 1] - b[..., 1]
    return dx * dx + dy * dy


def assign(q: np.ndarray, eligible: np.ndarray | None = None) -> np.ndarray:
    """One-to-one assignment of detections to tracks in every camera.

    Unambiguous gates (a track's only candidate, and that detection's only track) are taken directly; the
    contested rows of all cameras are solved together by one ``linear_sum_assignment`` (pairs across
    cameras are forbidden, so its optimum is each camera's own).

    Args:
        q: (K, C, N) normalised costs from :func:`gate` (entries >= 1 are out of the gate).
        eligible: (C, N) bool, detections still available (default: all).

    Returns:
        (K, C) detection index per track and camera, -1 where none.
    """
    K, C, N = q.shape
    if eligible is None:
        eligible = np.ones((C, N), dtype=bool)
    if K == 0 or N == 0:
        return np.full((K, C), -1, dtype=np.intp)
    if kernels.HAVE_NUMBA:
        out, contested = kernels.assign_unambiguous(kernels.contiguous(q), kernels.contiguous(eligible, bool))
    else:
        out, contested = _assign_unambiguous(q, eligible)
    kk, cc = np.nonzero(contested)
    if kk.size:  # the rest: one optimal assignment over all cameras' contested rows (no gate spans two cameras)
        rows_q = q[kk, cc]  # (R, N)
        rows_in = (rows_q < 1.0) & eligible[cc]
        wanted = np.zeros((C, N), dtype=bool)
        r, n = np.nonzero(rows_in)
        wanted[cc[r], n] = True
        wc, wn = np.nonzero(wanted)  # the contested detections (L,)
        ok = rows_in[:, wn] & (cc[:, None] == wc[None, :])
        sub = np.where(ok, rows_q[:, wn], _FORBIDDEN)
        r, k = linear_sum_assignment(sub)
        ok = ok[r, k]
        out[kk[r[ok]], cc[r[ok]]] = wn[k[ok]]
    return out


def _assign_unambiguous(q: np.ndarray, eligible: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, C) the detection of every (track, camera) whose gate in ``q`` (K, C, N) holds one ``eligible`` (C, N)
    detection that no other track's gate holds, else -1; (K, C) bool, the other gates holding any."""
    inside = (q < 1.0) & eligible[None]
    per_row = inside.sum(axis=2)  # (K, C)
    per_col = inside.sum(axis=0)  # (C, N)
    first = np.argmax(inside, axis=2)  # (K, C)
    simple = (per_row == 1) & (per_col[np.arange(q.shape[1])[None, :], first] == 1)
    return np.where(simple, first, -1), (per_row > 0) & ~simple


def epipolar_distance(F: np.ndarray, p1: np.ndarray, p2: np.ndarray) -> np.ndarray:
    """Symmetric point-to-epipolar-line distance, pixels, of matched points.

    ``max(dist(p2, F p1), dist(p1, F^T p2))`` with ``dist(p, (a, b, c)) = |a u + b v + c| / sqrt(a^2 + b^2)``.

    Args:
        F: (..., 3, 3) fundamental matrices (image 1 -> image 2), broadcast against the points.
        p1: (..., 2) ideal pixels in image 1.
        p2: (..., 2) ideal pixels in image 2.

    Returns:
        (...) distances; NaN where a point is NaN.
    """
    h1 = np.concatenate([p1, np.ones(p1.shape[:-1] + (1,))], axis=-1)
    h2 = np.concatenate([p2, np.ones(p2.shape[:-1] + (1,))], axis=-1)
    l2 = (F @ h1[..., None])[..., 0]  # lines in image 2
    l1 = (np.swapaxes(F, -1, -2) @ h2[..., None])[..., 0]  # lines in image 1
    alg = np.abs(p2[..., 0] * l2[..., 0] + p2[..., 1] * l2[..., 1] + l2[..., 2])
    return np.maximum(alg / np.hypot(l2[..., 0], l2[..., 1]), alg / np.hypot(l1[..., 0], l1[..., 1]))


def epipolar_consistency(pairs: CameraPairs, uv: np.ndarray, tol_px: float, sigma: np.ndarray | None = None,
                         n_sigma: float = 4.0) -> tuple[np.ndarray, np.ndarray]:
    """Which cameras' choices for each track agree with a partner camera's.

    Args:
        pairs: the stereo pairs.
        uv: (K, C, 2) each track's chosen detection per camera, ideal pixels (NaN: none).
        tol_px: largest symmetric epipolar distance of an agreeing pair, pixels ...
        sigma: (K, C) centroid std of each point, pixels (optional) ...
        n_sigma: ... or ``n_sigma * hypot(sigma_1, sigma_2)`` if larger (small, far markers are noisier).

    Returns:
        ``supported`` (K, C) bool: the camera's point agrees with at least one partner's; and
        ``tested`` (K, C) bool: the camera had a partner with a point to test against.
    """
    K, C = uv.shape[:2]
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        return kernels.epipolar_consistency(c(pairs.index, np.intp), c(pairs.F), c(uv), float(tol_px),
                                            c(np.zeros((K, C)) if sigma is None else sigma), float(n_sigma))
    if len(pairs) == 0 or K == 0:
        return np.zeros((K, C), dtype=bool), np.zeros((K, C), dtype=bool)
    i, j = pairs.index[:, 0], pairs.index[:, 1]
    # Homogeneous points (C, 3, K): every pair's epipolar lines in one (P, 3, 3) @ (P, 3, K) product.
    h = np.empty((C, 3, K))
    h[:, :2] = uv.transpose(1, 2, 0)
    h[:, 2] = 1.0
    h2 = h[j]
    l2 = pairs.F @ h[i]  # lines in image j of the points in image i
    l1 = pairs.F_t @ h2  # lines in image i of the points in image j
    # max(alg / |l2|, alg / |l1|) as alg / min(|l2|, |l1|): the same number
    e = np.abs((l2 * h2).sum(axis=1)) / np.minimum(np.hypot(l2[:, 0], l2[:, 1]), np.hypot(l1[:, 0], l1[:, 1]))
    have = np.isfinite(e)  # (P, K)
    tol = tol_px
    if sigma is not None:
        tol = np.maximum(tol_px, n_sigma * np.hypot(sigma[:, i], sigma[:, j]).T)
    good = e < tol  # False where NaN
    incidence = pairs.incidence(C)
    return good.T @ incidence, have.T @ incidence


def match_pairs(pairs: CameraPairs, D: np.ndarray, free: np.ndarray, tol_px: float,
                fresh: np.ndarray | None = None, sigma: np.ndarray | None = None, n_sigma: float = 4.0
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """All-pairs epipolar matching of the free detections (all pairs in one vectorised pass).

    Args:
        pairs: the stereo pairs.
        D: (C, N, 2) padded detections, ideal pixels.
        free: (C, N) bool, detections to consider.
        tol_px: largest symmetric epipolar distance of a match, pixels.
        fresh: (C, N) bool; if given, a match needs a fresh detection on at least one side (so
            clutter already examined in earlier frames is not paired with itself again).
        sigma, n_sigma: (C, N) centroid stds, pixels: the tolerance widens to ``n_sigma * hypot(s1, s2)``.

    Returns:
        ``pair`` (L,) pair index, ``n1`` (L,) detection index in the pair's first camera, ``n2`` (L,)
        in its second, ``dist`` (L,) epipolar distance, pixels.
    """
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        free = c(free, bool)
        return kernels.match_free_pairs(c(pairs.index, np.intp), c(pairs.F), c(D), free,
                                        free if fresh is None else c(fresh, bool), fresh is not None,
                                        c(np.zeros(free.shape) if sigma is None else sigma), float(tol_px),
                                        float(n_sigma))
    empty = np.zeros(0, dtype=np.intp)
    counts = free.sum(axis=1)
    if len(pairs) == 0 or counts.max(initial=0) == 0:
        return empty, empty, empty, np.zeros(0)
    # Compact the free detections of every camera into (C, M) slots.
    M = int(counts.max())
    slot = np.cumsum(free, axis=1) - 1
    cam, det = np.nonzero(free)
    index = np.full((free.shape[0], M), -1, dtype=np.intp)
    index[cam, slot[cam, det]] = det
    h = np.ones((free.shape[0], M, 3))  # homogeneous slots, NaN where empty
    h[..., :2] = np.where((index >= 0)[..., None], D[np.arange(free.shape[0])[:, None], np.maximum(index, 0)], np.nan)
    i, j = pairs.index[:, 0], pairs.index[:, 1]
    hj = h[j]
    # epipolar_distance of every slot pair: lines per slot (P, M, 3), then all |l2 . x_j| in one (M, 3) x (3, M)
    l2 = h[i] @ pairs.F_t  # lines in image j of the points of image i
    l1 = hj @ pairs.F  # lines in image i of the points of image j
    alg = np.abs(l2 @ hj.transpose(0, 2, 1))  # (P, M, M)
    e = alg / np.minimum(np.hypot(l2[..., 0], l2[..., 1])[:, :, None], np.hypot(l1[..., 0], l1[..., 1])[:, None, :])
    rows = np.arange(free.shape[0])[:, None]
    tol = tol_px
    if sigma is not None:
        s = np.where(index >= 0, sigma[rows, np.maximum(index, 0)], 0.0)
        tol = np.maximum(tol_px, n_sigma * np.hypot(s[i][:, :, None], s[j][:, None, :]))
    ok = e < tol
    if fresh is not None:
        fr = np.where(index >= 0, fresh[rows, np.maximum(index, 0)], False)
        ok &= fr[i][:, :, None] | fr[j][:, None, :]
    p, a, b = np.nonzero(ok)
    return p, index[i[p], a], index[j[p], b], e[p, a, b]


def triangulate_matches(projections: np.ndarray, pairs: CameraPairs, D: np.ndarray, cov: np.ndarray,
                        pair: np.ndarray, n1: np.ndarray, n2: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two-view weighted triangulation of matches from :func:`match_pairs`.

    Args:
        projections: (C, 3, 4) ideal-pixel projection matrices.
        pairs: the stereo pairs.
        D: (C, N, 2) padded detections, ideal pixels.  cov: (C, N, 2, 2) their covariances, px^2.
        pair, n1, n2: (L,) the matches.

    Returns:
        ``X`` (L, 3) m, ``cov3`` (L, 3, 3) m^2, ``rms`` (L,) reprojection RMS, pixels.
    """
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        return kernels.triangulate_two_views(c(projections), c(D), c(cov), c(pairs.index[pair, 0], np.intp),
                                             c(n1, np.intp), c(pairs.index[pair, 1], np.intp), c(n2, np.intp),
                                             _MATCH_STEPS)
    C = len(projections)
    L = len(pair)
    uv = np.full((C, L, 2), np.nan)
    S = np.broadcast_to(np.eye(2), (C, L, 2, 2)).copy()
    rows = np.arange(L)
    for side, n in ((0, n1), (1, n2)):
        cams = pairs.index[pair, side]
        uv[cams, rows] = D[cams, n]
        S[cams, rows] = cov[cams, n]
    return triangulate_weighted(projections, uv, S, _MATCH_STEPS)
