"""Multi-view fusion: one 3D point per track from all its cameras, new markers, re-identification.

Paper 004 fuses the pairs' 3D results by averaging (case 1) and builds ad-hoc pairs from single
cameras of different pairs (case 2). Here both are one step: every camera that holds a detection for
the track, from whichever pair, enters a covariance-weighted multi-view triangulation (the maximum
likelihood point, better than averaging pair results), with per-camera outlier rejection so that a
merged blob or a ghost in one camera cannot drag the point (:func:`robust_triangulate`). Cameras
without a detection are then offered the free detection nearest to the point's reprojection
(:func:`repick`), which is the candidate closest to all the partners' epipolar lines at once.

"New markers" (case 3) come from the detections no track used: all-pairs epipolar matching,
triangulation, and a multi-view consistency test — a point must be supported (reprojection within a
few pixels of a free detection) by ``min_views`` cameras, or by every camera whose image it falls in
when fewer do (:func:`new_points`). Their identities are decided by :func:`reidentify`.
"""

from __future__ import annotations

import functools
import heapq
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap import kernels
from mocap.geometry import inv2x2, inv3x3, reprojection_jacobians
from mocap.pairs import CameraPairs
from mocap.stereo import dist2, match_pairs, triangulate_matches

__all__ = ["Triangulated", "robust_triangulate", "repick", "new_points", "distance_to_lost", "reidentify"]


@dataclass
class Triangulated:
    """Multi-view points of K tracks.

    Attributes:
        X: (K, 3) m; NaN where fewer than two cameras agree.
        cov: (K, 3, 3) m^2 (inverse Fisher information of the used cameras).
        rms_px: (K,) RMS reprojection error over the used cameras, pixels.
        used: (K, C) bool, cameras that entered the point.
        proj: (C, K, 2) reprojection of X, ideal pixels.
        depth: (C, K) depth of X in each camera, m.
    """

    X: np.ndarray
    cov: np.ndarray
    rms_px: np.ndarray
    used: np.ndarray
    proj: np.ndarray
    depth: np.ndarray


GAUSS_NEWTON_STEPS = 3  # largest number of Gauss-Newton steps per solve of a robust triangulation


def _gauss_newton(P: np.ndarray, uv: np.ndarray, W: np.ndarray, X: np.ndarray, iterations: int,
                  tol_m: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Weighted Gauss-Newton refinement of K points from a start ``X`` (K, 3).

    ``uv`` (C, K, 2) is zero where unseen and ``W`` (C, K, 2, 2) zero there. Stops after ``iterations``
    steps or when no point moves more than ``tol_m``. Returns X, cov (K, 3, 3) (inverse information at
    the last linearisation), reprojection (C, K, 2) and residual vectors (C, K, 2) (both updated to
    first order by the last step) and depth (C, K).

    Inside, the cameras' u and v rows are stacked per point, (K, 2, C) projections and (K, 3, 2 C) transposed
    Jacobians with the cameras innermost, so that ``J^T W J`` and ``J^T W r`` summed over cameras are one
    (3, 2C) x (2C, .) product per point. The element-wise products that build ``J^T`` and ``(W J)^T`` run with the
    points innermost ((3, 2, C, K): long inner loops; ``(W J)^T`` 8.5 -> 4 us at K = 40) and are copied into that
    layout (the same numbers, ~4 % less per solve).
    """
    C, K = uv.shape[:2]
    Wf = W.transpose(3, 2, 0, 1).copy()  # (2, 2, C, K): Wf[b, a, c, k] = W[c, k, a, b]
    W0, W1 = Wf[0:1], Wf[1:2]  # (1, 2, C, K): the columns of each camera's weight
    few = (Wf[0, 0] > 0).sum(axis=0) < 2
    few = few if few.any() else None
    uvk = uv.transpose(1, 2, 0)  # (K, 2, C)
    Pm = P[:, :, :3].transpose(1, 0, 2).reshape(3 * C, 3).T  # (3, 3C): u rows, v rows, w rows
    pt = P[:, :, 3].T.reshape(3 * C)
    P01 = P[:, :2, :3].transpose(2, 1, 0)[..., None].copy()  # (3, 2, C, 1)
    P2 = P[:, 2, :3].T[:, None, :, None].copy()  # (3, 1, C, 1)
    for it in range(iterations):
        h = X @ Pm + pt  # (K, 3C)
        w = h[:, None, 2 * C:]  # (K, 1, C)
        proj = h[:, :2 * C].reshape(K, 2, C) / w
        Jf = (P01 - proj.transpose(1, 2, 0) * P2) / w[:, 0].T  # (3, 2, C, K): J^T, points innermost
        WJf = W0 * Jf[:, 0:1] + W1 * Jf[:, 1:2]  # (W J)^T
        Jt = np.ascontiguousarray(Jf.transpose(3, 0, 1, 2)).reshape(K, 3, 2 * C)
        WJt = np.ascontiguousarray(WJf.transpose(3, 0, 1, 2)).reshape(K, 3, 2 * C)
        r = uvk - proj
        H = WJt @ Jt.transpose(0, 2, 1)
        if few is not None:
            H[few] = np.eye(3)
        cov = inv3x3(H)  # the last one is the point's covariance
        dx = (cov @ (WJt @ r.reshape(K, 2 * C, 1)))[..., 0]
        X = X + dx
        if it == iterations - 1 or np.abs(dx).max(initial=0.0) < tol_m:
            break
    step = (dx[:, None, :] @ Jt).reshape(K, 2, C)  # first order, for the returned values
    proj = proj + step
    r = r - step
    depth = X @ P[:, 2, :3].T + P[:, 2, 3]  # (K, C)
    return X, cov, proj.transpose(2, 0, 1), r.transpose(2, 0, 1), depth.T


@functools.cache
def _camera_pairs(C: int) -> tuple[np.ndarray, np.ndarray]:
    """(C (C - 1) / 2,) first and second cameras of every pair i < j (np.triu_indices, cached: it is slow)."""
    i, j = np.triu_indices(C, 1)
    i.setflags(write=False)
    j.setflags(write=False)
    return i, j


def _consensus(P: np.ndarray, uv: np.ndarray, Winv: np.ndarray, used: np.ndarray, X: np.ndarray,
               limit: np.ndarray, iterations: int) -> np.ndarray:
    """(C, K) the cameras of each point that agree with its best two-camera hypothesis.

    Every pair of the point's cameras is triangulated on its own and scored by the truncated squared
    errors of all its cameras, ``sum(min((err / limit)^2, 1))`` (MSAC); the best pair's inliers are
    returned. Dropping the worst-fitting camera one at a time instead fails when a precise wrong
    detection (a neighbour's, or a second marker on the same epipolar line) pulls the weighted point
    towards itself: the right cameras then look like the outliers.

    Args: ``uv`` (C, K, 2) zero where unused, ``Winv`` (C, K, 2, 2) inverse covariances, ``used`` (C, K),
    ``X`` (K, 3) start, m, ``limit`` (C, K) pixels.
    """
    C, K = used.shape
    best = used.copy()
    i, j = _camera_pairs(C)  # every camera pair, all solved in one batch of (pair, point) problems
    q, rows = np.nonzero(used[i] & used[j])
    if q.size == 0:
        return best
    L = q.size
    pair = np.zeros((C, L), dtype=bool)
    pair[i[q], np.arange(L)] = True
    pair[j[q], np.arange(L)] = True
    _, _, _, r, _ = _gauss_newton(P, uv[:, rows], Winv[:, rows] * pair[..., None, None], X[rows], iterations)
    e2 = (np.hypot(r[..., 0], r[..., 1]) / limit[:, rows]) ** 2  # (C, L)
    cost = (np.minimum(e2, 1.0) * used[:, rows]).sum(axis=0)
    table = np.full((len(i), K), np.inf)  # (pairs, K) cost; the first pair of the lowest cost wins
    table[q, rows] = np.where(np.isnan(cost), np.inf, cost)
    win = np.argmin(table, axis=0)
    combo = np.full((len(i), K), -1)
    combo[q, rows] = np.arange(L)
    done = np.flatnonzero(np.isfinite(table[win, np.arange(K)]))
    best[:, done] = used[:, done] & (e2[:, combo[win[done], done]] < 1.0)
    return best


def robust_triangulate(P: np.ndarray, uv: np.ndarray, cov: np.ndarray, start: np.ndarray,
                       outlier_sigma: float, outlier_min_px: float, iterations: int = GAUSS_NEWTON_STEPS
                       ) -> Triangulated:
    """Covariance-weighted triangulation with per-camera outlier rejection.

    Starting from ``start`` (the tracks' predictions), Gauss-Newton over the cameras that hold a
    detection. Where some camera's reprojection error exceeds ``max(outlier_sigma * sigma_c,
    outlier_min_px)`` and at least three cameras hold one, the point is recomputed from the cameras that
    agree with its best camera pair (:func:`_consensus`); a camera still out of bounds after that is
    dropped, worst first, while three remain. A two-camera point whose cameras disagree is dropped (NaN).

    Args:
        P: (C, 3, 4) ideal-pixel projection matrices.
        uv: (C, K, 2) detections per camera and track, ideal pixels; NaN where none.
        cov: (C, K, 2, 2) their covariances, px^2.
        start: (K, 3) starting points, m (finite).
        outlier_sigma: rejection threshold in centroid standard deviations.
        outlier_min_px: rejection threshold floor, pixels.
        iterations: largest number of Gauss-Newton steps per solve (it stops when converged).
    """
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        return Triangulated(*kernels.robust_triangulate(c(P), c(uv), c(cov), c(start), float(outlier_sigma),
                                                        float(outlier_min_px), int(iterations)))
    C, K = uv.shape[:2]
    used = np.isfinite(uv[..., 0])  # (C, K)
    limit = np.maximum(outlier_sigma * np.sqrt(0.5 * (cov[..., 0, 0] + cov[..., 1, 1])), outlier_min_px)
    uvz = np.where(used[..., None], uv, 0.0)
    Winv = inv2x2(np.where(used[..., None, None], cov, np.eye(2)))
    X, cov3, proj, r, depth = _gauss_newton(P, uvz, Winv * used[..., None, None], start, iterations)
    err = np.where(used, np.hypot(r[..., 0], r[..., 1]), 0.0)
    todo = slice(None)  # the points still examined: all at first (views, not copies), then an index array
    for rnd in range(C - 1):
        ratio = np.where(used[:, todo], err[:, todo] / limit[:, todo], -1.0)
        drop = (ratio.max(axis=0) > 1.0) & (used[:, todo].sum(axis=0) >= 3)
        if not drop.any():
            break
        todo = np.flatnonzero(drop) if rnd == 0 else todo[drop]
        if rnd == 0:
            used[:, todo] = _consensus(P, uvz[:, todo], Winv[:, todo], used[:, todo], X[todo], limit[:, todo],
                                       iterations)
        else:  # the consensus refit still leaves a camera out of bounds: drop the worst
            used[np.argmax(ratio[:, drop], axis=0), todo] = False
        W = Winv[:, todo] * used[:, todo, None, None]
        X[todo], cov3[todo], proj[:, todo], r[:, todo], depth[:, todo] = _gauss_newton(
            P, uvz[:, todo], W, X[todo], iterations)
        err[:, todo] = np.where(used[:, todo], np.hypot(r[:, todo, 0], r[:, todo, 1]), 0.0)
    n = used.sum(axis=0)
    fail = (n < 2) | ((err > limit) & used).any(axis=0) & (n < 3) | ~np.isfinite(X).all(axis=1)
    used[:, fail] = False
    with np.errstate(invalid="ignore", divide="ignore"):  # (n differs from used's count only where failed)
        rms = np.sqrt((err**2 * used).sum(axis=0) / n)
    X[fail] = np.nan
    cov3[fail] = np.nan
    rms[fail] = np.nan
    return Triangulated(X, cov3, rms, used.T.copy(), proj, depth)


def repick(tri: Triangulated, D: np.ndarray, free: np.ndarray, limit_px: np.ndarray | float
           ) -> np.ndarray:
    """Offer each track's unused cameras the free detection nearest to its reprojection.

    Args:
        tri: the tracks' points (tracks with NaN X get nothing).
        D: (C, N, 2) padded detections, ideal pixels.
        free: (C, N) bool, detections no track holds (and not flagged merged).
        limit_px: largest distance, pixels (scalar or (C, N) per detection).

    Returns:
        (K, C) detection index picked (each detection at most once: the nearest track wins), -1: none.
    """
    K, C = tri.used.shape
    if kernels.HAVE_NUMBA:
        c = kernels.contiguous
        return kernels.repick(c(tri.used, bool), c(tri.X), c(tri.proj), c(D), c(free, bool),
                              c(np.broadcast_to(np.asarray(limit_px, dtype=float), free.shape)))
    out = np.full((K, C), -1, dtype=np.intp)
    cols = np.flatnonzero(free.any(axis=0))  # only detection slots free in some camera can be picked (a few)
    if K == 0 or cols.size == 0:
        return out
    want = ~tri.used.T & np.isfinite(tri.X[:, 0])[None, :]  # (C, K)
    d = np.sqrt(dist2(tri.proj[:, :, None, :], D[:, None, cols, :]))  # (C, K, n)
    limit = np.asarray(limit_px, dtype=float)
    limit = limit[:, None, cols] if limit.ndim else limit
    ok = want[..., None] & free[:, None, cols] & (d < limit)
    d = np.where(ok, d, np.inf)
    best = np.argmin(d, axis=2)  # (C, K)
    # A detection wanted by several tracks goes to the nearest one.
    nearest_track = np.argmin(d, axis=1)  # (C, n)
    won = nearest_track[np.arange(C)[:, None], best] == np.arange(K)[None, :]
    take = ok.any(axis=2) & won  # (d is finite exactly where ok)
    out.T[take] = cols[best[take]]
    return out


@dataclass
class NewPoints:
    """Candidate new markers: ``X`` (L, 3) m, ``cov`` (L, 3, 3), ``rms_px`` (L,), ``det`` (L, C) index or -1,
    ``strong`` (L,) bool: supported by enough cameras to start a new track (weak points may only
    re-acquire a known identity)."""

    X: np.ndarray
    cov: np.ndarray
    rms_px: np.ndarray
    det: np.ndarray
    strong: np.ndarray

    @classmethod
    def none(cls, n_cameras: int) -> NewPoints:
        """No points (a rig of ``n_cameras``)."""
        return cls(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0), np.zeros((0, n_cameras), dtype=np.intp),
                   np.zeros(0, dtype=bool))

    def subset(self, index: np.ndarray) -> NewPoints:
        return NewPoints(self.X[index], self.cov[index], self.rms_px[index], self.det[index], self.strong[index])


def _views(D: np.ndarray, cov: np.ndarray, det: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(C, L, 2) positions and (C, L, 2, 2) covariances of the detections ``det`` (L, C) (-1: none) of ``D``
    (C, N, 2) and ``cov`` (C, N, 2, 2): NaN and the identity where a point has none, as triangulation takes them."""
    cams = np.arange(D.shape[0])[None, :]
    have = det >= 0
    uv = np.where(have[..., None], D[cams, np.maximum(det, 0)], np.nan).swapaxes(0, 1)
    S = np.where(have[..., None, None], cov[cams, np.maximum(det, 0)], np.eye(2)).swapaxes(0, 1)
    return uv, S


def _greedy_by_support(support: np.ndarray, nearest: np.ndarray, dist: np.ndarray, shape: tuple[int, int]
                       ) -> list[int]:
    """Candidates accepted greedily, most supporting cameras first, then smallest epipolar distance; each
    detection once. A detection claimed by a better candidate leaves a later one's support, not the candidate
    itself (a marker hidden in one camera lands within support_px of its neighbour's blob there), and the
    candidate then queues again with the views it has left: a ghost that lost its third view to a real marker
    must not outrank a real two-view point. ``support`` (C, L) is updated in place.

    Returns: the accepted candidates' indices, in acceptance order.
    """
    queue = list(zip((-support.sum(axis=0)).tolist(), dist.tolist(), range(len(dist)), strict=True))
    heapq.heapify(queue)
    used = np.zeros(shape, dtype=bool)
    chosen = []
    while queue:  # over the (few) candidates
        key, d, idx = heapq.heappop(queue)
        cams = np.flatnonzero(support[:, idx])
        taken = used[cams, nearest[cams, idx]]
        left = int((~taken).sum())
        if left < 2:
            continue
        if left < -key:
            heapq.heappush(queue, (-left, d, idx))
            continue
        support[cams[taken], idx] = False
        used[cams[~taken], nearest[cams[~taken], idx]] = True
        chosen.append(idx)
    return chosen


def new_points(P: np.ndarray, pairs: CameraPairs, D: np.ndarray, cov: np.ndarray, free: np.ndarray,
               sizes: np.ndarray, epipolar_px: float, support_px: float, min_views: int,
               outlier_sigma: float, outlier_min_px: float, fresh: np.ndarray | None = None,
               n_sigma: float = 4.0) -> NewPoints:
    """3D points explained by free detections in several cameras (multi-view consistent).

    All-pairs epipolar matching gives candidate correspondences; each is triangulated and projected
    into every camera; a camera supports it when a free detection lies within ``support_px``.
    Candidates are accepted greedily (most supporting cameras, then smallest epipolar distance),
    each detection used once (a candidate keeps those of its detections no better one took, if two or
    more, and queues again with that many); a candidate's support is what a robust fit over its supporting
    detections keeps (a merged blob's offset centroid, a hidden marker's neighbour near its projection do not
    count, nor are they claimed); a point is ``strong`` when supported by ``min_views`` cameras, or by
    every camera whose image it falls in when fewer than ``min_views`` do (cameras that saw nothing at all
    this frame do not count), but never by two alone when the rig has three or more: two fixed reflections
    that happen to match make a point only those two cameras frame just as well. The accepted point is
    re-triangulated over its supporting detections with outlier rejection.

    Args:
        P: (C, 3, 4) ideal-pixel projection matrices.
        pairs: the stereo pairs.
        D: (C, N, 2) padded detections, ideal pixels.  cov: (C, N, 2, 2) their covariances.
        free: (C, N) bool, detections to use.
        sizes: (C, 2) image width, height, pixels.
        epipolar_px, support_px: matching tolerances, pixels.
        min_views: supporting cameras required where that many cameras frame the point.
        outlier_sigma, outlier_min_px: see :func:`robust_triangulate`.
        fresh: (C, N) bool, see :func:`mocap.stereo.match_pairs`.
        n_sigma: tolerances widen to ``n_sigma`` centroid stds where that is larger.
    """
    C = len(P)
    empty = NewPoints.none(C)
    sigma = np.sqrt(0.5 * (cov[..., 0, 0] + cov[..., 1, 1]))  # (C, N)
    pair, n1, n2, dist = match_pairs(pairs, D, free, epipolar_px, fresh, sigma, n_sigma)
    if pair.size == 0:
        return empty
    X, _, _ = triangulate_matches(P, pairs, D, cov, pair, n1, n2)
    ok = np.isfinite(X).all(axis=1)
    pair, n1, n2, dist, X = pair[ok], n1[ok], n2[ok], dist[ok], X[ok]
    if pair.size == 0:
        return empty
    proj, _ = reprojection_jacobians(P, X)  # (C, L, 2)
    depth = np.einsum("cj,lj->cl", P[:, 2, :3], X) + P[:, 2, 3][:, None]
    framed = (depth > 0) & (proj >= 0).all(axis=2) & (proj < sizes[:, None, :]).all(axis=2)  # (C, L)
    framed &= np.isfinite(D).all(axis=2).any(axis=1)[:, None]  # a camera that saw nothing cannot object
    d = np.where(free[:, None, :], np.sqrt(dist2(proj[:, :, None, :], D[:, None, :, :])), np.inf)  # (C, L, N)
    nearest = np.argmin(d, axis=2)
    near_d = np.take_along_axis(d, nearest[..., None], axis=2)[..., 0]
    support = near_d < np.maximum(support_px, n_sigma * np.take_along_axis(sigma, nearest, axis=1))  # (C, L)
    rows = np.arange(len(pair))
    for side, n in ((0, n1), (1, n2)):  # the pair's own detections support it by construction
        cams = pairs.index[pair, side]
        nearest[cams, rows] = n
        support[cams, rows] = True
    need = np.maximum(np.minimum(min_views, framed.sum(axis=0)), min(3, C))  # two views: never strong, if 3+ exist
    # A candidate's support is what a robust fit over it keeps: a blob near its projection that the fit rejects (a
    # merged blob's offset centroid, a ghost's chance neighbour) neither ranks it nor is claimed by it.
    support &= robust_triangulate(P, *_views(D, cov, np.where(support, nearest, -1).T), X, outlier_sigma,
                                  outlier_min_px).used.T
    chosen = _greedy_by_support(support, nearest, dist, free.shape)
    if not chosen:
        return empty
    sel = np.array(chosen)
    det = np.where(support[:, sel], nearest[:, sel], -1).T  # (L', C)
    tri = robust_triangulate(P, *_views(D, cov, det), X[sel], outlier_sigma, outlier_min_px)
    keep = np.isfinite(tri.X).all(axis=1) & (tri.used.sum(axis=1) >= 2)
    det = np.where(tri.used, det, -1)
    strong = tri.used.sum(axis=1) >= need[sel]
    return NewPoints(tri.X[keep], tri.cov[keep], tri.rms_px[keep], det[keep], strong[keep])


def distance_to_lost(points: np.ndarray, predicted: np.ndarray, last_seen: np.ndarray | None = None) -> np.ndarray:
    """(L, T) distance, m, of each point (L, 3) to each lost track: the smaller of its distances to the track's
    prediction (T, 3) and, if given, to where the track was last seen (T, 3) (paper 004: "position or prediction";
    a long extrapolation can run away)."""
    d = np.linalg.norm(points[:, None, :] - predicted[None, :, :], axis=2)
    if last_seen is not None:
        d = np.fmin(d, np.linalg.norm(points[:, None, :] - last_seen[None, :, :], axis=2))
    return d


def reidentify(points: np.ndarray, predicted: np.ndarray, radius: np.ndarray, last_seen: np.ndarray | None = None,
               allowed: np.ndarray | None = None) -> np.ndarray:
    """Match new points to lost tracks inside each track's own (variable) search radius.

    The distance of a point to a track is the smaller of its distances to the track's prediction and
    to where the track was last seen (paper 004: "position or prediction"; a long extrapolation can
    run away). Optimal assignment (``linear_sum_assignment``) of distance / radius; a pair is
    allowed only when the point lies inside the track's radius.

    Args:
        points: (L, 3) new points, m.
        predicted: (T, 3) the lost tracks' predicted positions, m.
        radius: (T,) their search radii, m.
        last_seen: (T, 3) their last measured positions, m (optional).
        allowed: (L, T) bool, the pairs other evidence allows (optional; the rest are never matched).

    Returns:
        (L,) index of the lost track each point re-identifies, -1 for none.
    """
    out = np.full(len(points), -1, dtype=np.intp)
    if len(points) == 0 or len(predicted) == 0:
        return out
    q = distance_to_lost(points, predicted, last_seen) / radius[None, :]
    inside = q < 1.0
    if allowed is not None:
        inside &= allowed
    if not inside.any():
        return out
    r, c = linear_sum_assignment(np.where(inside, q, 1e6))
    ok = inside[r, c]
    out[r[ok]] = c[ok]
    return out
