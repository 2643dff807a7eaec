"""Compiled kernels of the tracker's hot per-frame loops (numba, optional), and the switch that
selects them.

The numpy functions (:mod:`mocap.fusion`, :mod:`mocap.ekf`, :mod:`mocap.stereo`, the tracker's stages) are
the reference; each kernel here computes the same numbers with one loop over the points, tracks or filters
(one call per stage and frame instead of dozens of numpy calls on small arrays) and the callers switch to it
where :data:`HAVE_NUMBA` is true. The same arithmetic in the same order, so results agree to rounding
(BLAS sums products in its own order: ~1e-16 relative). The detector's kernels are in :mod:`mocap.detect_kernels`.
Install with ``pip install 'mocap[fast]'``.

:data:`HAVE_NUMBA` is false when numba cannot be imported or the environment variable ``MOCAP_NO_NUMBA`` is
set to anything but ``0`` (tests and benchmarks use it to run the numpy path). Kernels are compiled on first
use and cached on disk next to this file (or in numba's user cache folder when that is read-only; without
any writable folder they are compiled in every process, which is only slower).
"""

from __future__ import annotations

import functools
import logging
import math
import os

import numpy as np

__all__ = ["HAVE_NUMBA", "REASON", "announce", "contiguous", "robust_triangulate", "gauss_newton", "update_position",
           "repick", "predict", "update_tracks", "epipolar_consistency", "gate", "search_regions", "crowded",
           "undistort_points", "near_any", "assign_unambiguous", "frame_record", "frame_detections", "attached_learn",
           "attached_fill", "pair_distance_statistics", "measure_views", "match_free_pairs",
           "triangulate_two_views", "prepare_frame", "measured_points", "explained_elsewhere"]

_log = logging.getLogger("mocap")


def _load_numba():
    """(numba module or None, why)."""
    if os.environ.get("MOCAP_NO_NUMBA", "0") not in ("", "0"):
        return None, "MOCAP_NO_NUMBA is set"
    try:
        import numba
    except ImportError:
        return None, "numba is not installed (pip install 'mocap[fast]')"
    return numba, f"numba {numba.__version__}"


_numba, REASON = _load_numba()
HAVE_NUMBA: bool = _numba is not None  # the switch the callers read (``kernels.HAVE_NUMBA``, at call time)


def _jit(function):
    """``numba.njit`` with an on-disk cache (without, where no cache folder is writable); IEEE division
    (x / 0 is inf or NaN, as in numpy). Without numba the plain function (never called by the callers)."""
    if _numba is None:
        return function
    try:
        return _numba.njit(cache=True, error_model="numpy")(function)
    except RuntimeError:  # "cannot cache function ...: no locator available": no writable folder
        return _numba.njit(error_model="numpy")(function)


def contiguous(a: np.ndarray, dtype: type = np.float64) -> np.ndarray:
    """``a`` as a C-contiguous array of ``dtype`` (no copy if it is one): one compiled version of each kernel."""
    return np.ascontiguousarray(a, dtype=dtype)


@functools.cache
def announce() -> None:
    """Log once which path the tracker runs (called when a tracker is made): the compiled one quietly (debug),
    the numpy one with how to get the other (info)."""
    if HAVE_NUMBA:
        _log.debug("tracking kernels: compiled (%s)", REASON)
    else:
        _log.info("tracking kernels: numpy (%s)", REASON)


# ---------------------------------------------------------------------------------------------- small algebra
@_jit
def _inv2x2(a, b, c, d):
    """Inverse of [[a, b], [c, d]] as :func:`mocap.geometry.inv2x2` computes it: (d, -b, -c, a) / det."""
    det = a * d - b * c
    return d / det, -b / det, -c / det, a / det


@_jit
def _inv3x3(A, out):
    """``out`` (3, 3) = inverse of ``A`` (3, 3) as :func:`mocap.geometry.inv3x3` computes it (adjugate / det)."""
    for i in range(3):
        i1, i2 = (i + 1) % 3, (i + 2) % 3
        for j in range(3):
            j1, j2 = (j + 1) % 3, (j + 2) % 3
            out[i, j] = A[j1, i1] * A[j2, i2] - A[j1, i2] * A[j2, i1]
    det = A[0, 0] * out[0, 0] + A[0, 1] * out[1, 0] + A[0, 2] * out[2, 0]
    for i in range(3):
        for j in range(3):
            out[i, j] /= det


# ---------------------------------------------------------------------------------------------- cameras
@_jit
def undistort_points(uv, camera, K, dist, distorted, max_steps, eps_px):
    """``cv2.undistortPoints(uv, K, dist, P=K)`` (OpenCV 5) with criteria (COUNT | EPS, ``max_steps``, ``eps_px``)
    for the standard lens model, the same steps: per point (``uv`` (N, 2) px of ``camera`` (N,) int), damped
    fixed-point steps of the normalised coordinates until the point distorted again lies within ``eps_px`` of the
    observed pixel (a step that moves it farther is rejected and the damping halved); ``K`` (C, 3, 3), ``dist``
    (C, 8) ``k1, k2, p1, p2, k3, k4, k5, k6``; the points of a camera not ``distorted`` (C,) are copied. Returns
    (N, 2) ideal px; NaN stays NaN."""
    out = np.empty_like(uv)
    for i in range(uv.shape[0]):
        c = camera[i]
        if not distorted[c]:
            out[i, 0], out[i, 1] = uv[i, 0], uv[i, 1]
            continue
        fx, fy, cx, cy = K[c, 0, 0], K[c, 1, 1], K[c, 0, 2], K[c, 1, 2]
        k1, k2, p1, p2 = dist[c, 0], dist[c, 1], dist[c, 2], dist[c, 3]
        k3, k4, k5, k6 = dist[c, 4], dist[c, 5], dist[c, 6], dist[c, 7]
        u, v = uv[i, 0], uv[i, 1]
        x0 = x = (u - cx) * (1.0 / fx)
        y0 = y = (v - cy) * (1.0 / fy)
        error = previous = np.inf
        alpha = 1.0
        for _ in range(max_steps):
            if error < eps_px:
                break
            r2 = x * x + y * y
            icdist = (1 + ((k6 * r2 + k5) * r2 + k4) * r2) / (1 + ((k3 * r2 + k2) * r2 + k1) * r2)
            if icdist < 0:  # (far outside the lens model's valid field: OpenCV's answer, the distorted point)
                x, y = x0, y0
                break
            delta_x = 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
            delta_y = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
            new_x = (1.0 - alpha) * x + alpha * (x0 - delta_x) * icdist
            new_y = (1.0 - alpha) * y + alpha * (y0 - delta_y) * icdist
            r2 = new_x * new_x + new_y * new_y
            r4 = r2 * r2
            r6 = r4 * r2
            cdist = (1 + k1 * r2 + k2 * r4 + k3 * r6) * (1.0 / (1 + k4 * r2 + k5 * r4 + k6 * r6))
            xd = new_x * cdist + p1 * (2 * new_x * new_y) + p2 * (r2 + 2 * new_x * new_x)
            yd = new_y * cdist + p1 * (r2 + 2 * new_y * new_y) + p2 * (2 * new_x * new_y)
            error = math.sqrt((xd * fx + cx - u) ** 2 + (yd * fy + cy - v) ** 2)
            if error > previous:
                alpha *= 0.5
            else:
                x, y = new_x, new_y
            previous = error
        out[i, 0] = fx * x + K[c, 0, 1] * y + cx
        out[i, 1] = fy * y + cy
    return out


# ---------------------------------------------------------------------------------------------- fusion
@_jit
def gauss_newton(P, uv, Winv, mask, point, X, iterations, tol_m, cov, proj, res, depth):
    """:func:`mocap.fusion._gauss_newton` for L problems solved together (one stopping test for all).

    Problem l is point ``point[l]`` seen by the cameras ``mask[:, l]`` (C, L) bool, weights ``Winv`` (C, K, 2, 2)
    times the mask, detections ``uv`` (C, K, 2) zero where unseen. ``X`` (L, 3) start, refined in place;
    fills ``cov`` (L, 3, 3), ``proj`` and ``res`` (C, L, 2) (first order after the last step), ``depth`` (C, L).
    """
    C = P.shape[0]
    L = point.shape[0]
    J = np.empty((L, 2, C, 3))  # the last linearisation
    WJ = np.empty((2, C, 3))
    H = np.empty((3, 3))
    g = np.empty(3)
    dx = np.zeros((L, 3))
    few = np.zeros(L, dtype=np.bool_)
    for lo in range(L):
        n = 0
        for c in range(C):
            n += Winv[c, point[lo], 0, 0] * (1.0 if mask[c, lo] else 0.0) > 0
        few[lo] = n < 2
    for it in range(iterations):
        converged = True
        for lo in range(L):
            k = point[lo]
            x0, x1, x2 = X[lo, 0], X[lo, 1], X[lo, 2]
            for c in range(C):
                m = 1.0 if mask[c, lo] else 0.0
                w = x0 * P[c, 2, 0] + x1 * P[c, 2, 1] + x2 * P[c, 2, 2] + P[c, 2, 3]
                for a in range(2):
                    p = (x0 * P[c, a, 0] + x1 * P[c, a, 1] + x2 * P[c, a, 2] + P[c, a, 3]) / w
                    proj[c, lo, a] = p
                    res[c, lo, a] = uv[c, k, a] - p
                    for i in range(3):
                        J[lo, a, c, i] = (P[c, a, i] - p * P[c, 2, i]) / w
                w00, w01 = Winv[c, k, 0, 0] * m, Winv[c, k, 0, 1] * m
                w10, w11 = Winv[c, k, 1, 0] * m, Winv[c, k, 1, 1] * m
                for i in range(3):
                    WJ[0, c, i] = w00 * J[lo, 0, c, i] + w01 * J[lo, 1, c, i]
                    WJ[1, c, i] = w10 * J[lo, 0, c, i] + w11 * J[lo, 1, c, i]
            H[:] = 0.0
            g[:] = 0.0
            for a in range(2):  # J^T W J and J^T W r, summed over (a, c) in numpy's order
                for c in range(C):
                    r = res[c, lo, a]
                    for i in range(3):
                        w = WJ[a, c, i]
                        g[i] += w * r
                        for j in range(3):
                            H[i, j] += w * J[lo, a, c, j]
            if few[lo]:
                H[:] = 0.0
                for i in range(3):
                    H[i, i] = 1.0
            _inv3x3(H, cov[lo])
            for i in range(3):
                d = cov[lo, i, 0] * g[0] + cov[lo, i, 1] * g[1] + cov[lo, i, 2] * g[2]
                dx[lo, i] = d
                X[lo, i] += d
                converged &= abs(d) < tol_m
        if it == iterations - 1 or converged:
            break
    for lo in range(L):
        for c in range(C):
            for a in range(2):
                step = dx[lo, 0] * J[lo, a, c, 0] + dx[lo, 1] * J[lo, a, c, 1] + dx[lo, 2] * J[lo, a, c, 2]
                proj[c, lo, a] += step
                res[c, lo, a] -= step
            depth[c, lo] = X[lo, 0] * P[c, 2, 0] + X[lo, 1] * P[c, 2, 1] + X[lo, 2] * P[c, 2, 2] + P[c, 2, 3]


@_jit
def _solve(P, uvz, Winv, used, point, X, iterations, cov3, proj, res, depth, err):
    """Gauss-Newton of the points ``point`` over their ``used`` cameras, written back at those points."""
    C = P.shape[0]
    L = point.shape[0]
    mask = np.empty((C, L), dtype=np.bool_)
    for lo in range(L):
        for c in range(C):
            mask[c, lo] = used[c, point[lo]]
    Xs = np.empty((L, 3))
    for lo in range(L):
        for i in range(3):
            Xs[lo, i] = X[point[lo], i]
    cs, ps, rs, ds = np.empty((L, 3, 3)), np.empty((C, L, 2)), np.empty((C, L, 2)), np.empty((C, L))
    gauss_newton(P, uvz, Winv, mask, point, Xs, iterations, 1e-6, cs, ps, rs, ds)
    for lo in range(L):  # (element by element: array-slice assignments are slow to compile)
        k = point[lo]
        for i in range(3):
            X[k, i] = Xs[lo, i]
            for j in range(3):
                cov3[k, i, j] = cs[lo, i, j]
        for c in range(C):
            for a in range(2):
                proj[c, k, a] = ps[c, lo, a]
                res[c, k, a] = rs[c, lo, a]
            depth[c, k] = ds[c, lo]
            err[c, k] = math.hypot(rs[c, lo, 0], rs[c, lo, 1]) if mask[c, lo] else 0.0


@_jit
def _consensus(P, uvz, Winv, used, X, limit, todo, iterations):
    """:func:`mocap.fusion._consensus` of the points ``todo``: their ``used`` (C, K) columns set in place to the
    cameras agreeing with the best camera pair (the first pair of the lowest truncated cost)."""
    C = P.shape[0]
    T = todo.shape[0]
    n_pairs = C * (C - 1) // 2
    pi = np.empty(n_pairs, dtype=np.intp)
    pj = np.empty(n_pairs, dtype=np.intp)
    q = 0
    for i in range(C):  # np.triu_indices(C, 1) order
        for j in range(i + 1, C):
            pi[q], pj[q] = i, j
            q += 1
    L = 0
    for q in range(n_pairs):
        for t in range(T):
            L += used[pi[q], todo[t]] and used[pj[q], todo[t]]
    point = np.empty(L, dtype=np.intp)
    mask = np.zeros((C, L), dtype=np.bool_)
    Xs = np.empty((L, 3))
    lo = 0
    for q in range(n_pairs):  # (pair, point) problems, pair-major as np.nonzero gives them
        for t in range(T):
            k = todo[t]
            if used[pi[q], k] and used[pj[q], k]:
                point[lo] = k
                mask[pi[q], lo] = mask[pj[q], lo] = True
                for i in range(3):
                    Xs[lo, i] = X[k, i]
                lo += 1
    if L == 0:
        return
    cs, ps, rs, ds = np.empty((L, 3, 3)), np.empty((C, L, 2)), np.empty((C, L, 2)), np.empty((C, L))
    gauss_newton(P, uvz, Winv, mask, point, Xs, iterations, 1e-6, cs, ps, rs, ds)
    e2 = np.empty((C, L))
    best_cost = np.full(X.shape[0], np.inf)
    best = np.full(X.shape[0], -1, dtype=np.intp)
    for lo in range(L):
        k = point[lo]
        cost = 0.0
        for c in range(C):
            e = math.hypot(rs[c, lo, 0], rs[c, lo, 1]) / limit[c, k]
            e = e * e
            e2[c, lo] = e
            cost += (e if (e < 1.0 or e != e) else 1.0) * (1.0 if used[c, k] else 0.0)
        if cost < best_cost[k]:  # NaN never wins
            best_cost[k] = cost
            best[k] = lo
    for t in range(T):
        k = todo[t]
        if best[k] >= 0:
            for c in range(C):
                used[c, k] = used[c, k] and e2[c, best[k]] < 1.0


@_jit
def robust_triangulate(P, uv, cov, start, outlier_sigma, outlier_min_px, iterations):
    """:func:`mocap.fusion.robust_triangulate` in one call: returns X (K, 3), cov (K, 3, 3), rms_px (K,),
    used (K, C), proj (C, K, 2), depth (C, K) (the fields of :class:`mocap.fusion.Triangulated`)."""
    C, K = uv.shape[0], uv.shape[1]
    used = np.empty((C, K), dtype=np.bool_)
    limit = np.empty((C, K))
    uvz = np.zeros((C, K, 2))
    Winv = np.empty((C, K, 2, 2))
    for c in range(C):
        for k in range(K):
            used[c, k] = math.isfinite(uv[c, k, 0])
            v = outlier_sigma * math.sqrt(0.5 * (cov[c, k, 0, 0] + cov[c, k, 1, 1]))
            limit[c, k] = v if (v >= outlier_min_px or v != v) else outlier_min_px
            if used[c, k]:
                uvz[c, k, 0], uvz[c, k, 1] = uv[c, k, 0], uv[c, k, 1]
                a, b, cc, d = _inv2x2(cov[c, k, 0, 0], cov[c, k, 0, 1], cov[c, k, 1, 0], cov[c, k, 1, 1])
            else:
                a, b, cc, d = _inv2x2(1.0, 0.0, 0.0, 1.0)
            Winv[c, k, 0, 0], Winv[c, k, 0, 1], Winv[c, k, 1, 0], Winv[c, k, 1, 1] = a, b, cc, d
    X = start.copy()
    cov3, proj, res = np.empty((K, 3, 3)), np.empty((C, K, 2)), np.empty((C, K, 2))
    depth, err = np.empty((C, K)), np.empty((C, K))
    _solve(P, uvz, Winv, used, np.arange(K), X, iterations, cov3, proj, res, depth, err)
    todo = np.arange(K)
    ratio = np.empty((C, K))
    for rnd in range(C - 1):
        keep = np.zeros(todo.shape[0], dtype=np.bool_)
        for t in range(todo.shape[0]):
            k = todo[t]
            top, n, nan = -np.inf, 0, False
            for c in range(C):
                r = err[c, k] / limit[c, k] if used[c, k] else -1.0
                ratio[c, k] = r
                nan |= r != r
                top = max(top, r)
                n += used[c, k]
            keep[t] = not nan and top > 1.0 and n >= 3
        if not keep.any():
            break
        todo = todo[keep]
        if rnd == 0:
            _consensus(P, uvz, Winv, used, X, limit, todo, iterations)
        else:  # the consensus refit still leaves a camera out of bounds: drop the worst (the first of the largest)
            for k in todo:
                worst = 0
                for c in range(1, C):
                    if ratio[c, k] > ratio[worst, k]:
                        worst = c
                used[worst, k] = False
        _solve(P, uvz, Winv, used, todo, X, iterations, cov3, proj, res, depth, err)
    rms = np.empty(K)
    for k in range(K):
        n, out, s = 0, False, 0.0
        for c in range(C):
            n += used[c, k]
            out |= err[c, k] > limit[c, k] and used[c, k]
            s += err[c, k] * err[c, k] * (1.0 if used[c, k] else 0.0)
        rms[k] = math.sqrt(s / n)
        fail = n < 2 or (out and n < 3) or not (math.isfinite(X[k, 0]) and math.isfinite(X[k, 1])
                                                 and math.isfinite(X[k, 2]))
        if fail:
            rms[k] = np.nan
            for c in range(C):
                used[c, k] = False
            for i in range(3):
                X[k, i] = np.nan
                for j in range(3):
                    cov3[k, i, j] = np.nan
    return X, cov3, rms, used.T.copy(), proj, depth


@_jit
def repick(used, X, proj, D, free, limit):
    """:func:`mocap.fusion.repick`: ``used`` (K, C), ``X`` (K, 3), ``proj`` (C, K, 2), ``D`` (C, N, 2), ``free``
    and ``limit`` (C, N) -> (K, C) detection index, -1: none. A track gets its nearest eligible free detection
    (the first of equals) when it is also that detection's nearest track (the first of equals)."""
    K, C = used.shape
    N = D.shape[1]
    out = np.full((K, C), -1, dtype=np.intp)
    d = np.empty((K, N))
    best = np.empty(K, dtype=np.intp)
    for c in range(C):
        for k in range(K):
            want = not used[k, c] and math.isfinite(X[k, 0])
            b, bd = -1, np.inf
            for n in range(N):
                e = np.inf
                if want and free[c, n]:
                    du, dv = proj[c, k, 0] - D[c, n, 0], proj[c, k, 1] - D[c, n, 1]
                    s = math.sqrt(du * du + dv * dv)
                    if s < limit[c, n]:
                        e = s
                d[k, n] = e
                if e < bd:
                    b, bd = n, e
            best[k] = b
        for k in range(K):
            n = best[k]
            if n < 0:
                continue
            nearest = 0
            for j in range(1, K):
                if d[j, n] < d[nearest, n]:
                    nearest = j
            if nearest == k:
                out[k, c] = n
    return out


@_jit
def measure_views(D, S, merged, valid, asg, crowded, index, F, P, start, tol_px, n_sigma, suspect_scale,
                  outlier_sigma, outlier_min_px, iterations, repick_px):
    """The tracker's measurement of its assigned detections in one call (``Tracker._measure``'s numpy steps up to
    the re-pick): epipolar pruning (:func:`epipolar_consistency`), the robust triangulation (:func:`robust_triangulate`;
    a view of a crowded track on a blob not flagged merged has its covariance scaled by ``suspect_scale``) and
    the re-pick of free detections (:func:`repick`).

    ``D`` (C, N, 2), ``S`` (C, N, 2, 2), ``merged`` and ``valid`` (C, N) the frame's detections; ``asg`` (K, C) the
    tracks' detection per camera (-1: none), views dropped set to -1 in place; ``crowded`` (K, C); ``index`` (P, 2)
    and ``F`` (P, 3, 3) the camera pairs; ``P`` (C, 3, 4); ``start`` (K, 3) m. Returns the fields of
    :class:`mocap.fusion.Triangulated` (X, cov, rms_px, used, proj, depth), the re-picked detections (K, C) and the
    detections' centroid std (C, N) px."""
    C, N, K = D.shape[0], D.shape[1], asg.shape[0]
    sigma = np.empty((C, N))
    for c in range(C):
        for n in range(N):
            sigma[c, n] = math.sqrt(0.5 * (S[c, n, 0, 0] + S[c, n, 1, 1]))
    uv = np.full((K, C, 2), np.nan)
    sig = np.full((K, C), np.nan)
    for k in range(K):
        for c in range(C):
            a = asg[k, c]
            if a >= 0:
                uv[k, c, 0], uv[k, c, 1] = D[c, a, 0], D[c, a, 1]
                sig[k, c] = sigma[c, a]
    supported, tested = epipolar_consistency(index, F, uv, tol_px, sig, n_sigma)
    uvt = np.full((C, K, 2), np.nan)
    cov = np.zeros((C, K, 2, 2))
    for k in range(K):
        for c in range(C):
            if tested[k, c] and not supported[k, c]:
                asg[k, c] = -1
            a = asg[k, c]
            if a >= 0:
                uvt[c, k, 0], uvt[c, k, 1] = uv[k, c, 0], uv[k, c, 1]
                scale = suspect_scale if crowded[k, c] and not merged[c, a] else 1.0
                for i in range(2):
                    for j in range(2):
                        cov[c, k, i, j] = S[c, a, i, j] * scale
            else:
                cov[c, k, 0, 0] = cov[c, k, 1, 1] = 1.0
    X, cov3, rms, used, proj, depth = robust_triangulate(P, uvt, cov, start, outlier_sigma, outlier_min_px, iterations)
    free = np.empty((C, N), dtype=np.bool_)
    for c in range(C):
        for n in range(N):
            free[c, n] = valid[c, n] and not merged[c, n]
    for k in range(K):
        for c in range(C):
            if not used[k, c]:
                asg[k, c] = -1
            elif asg[k, c] >= 0:
                free[c, asg[k, c]] = False
    limit = np.empty((C, N))
    for c in range(C):
        for n in range(N):
            limit[c, n] = max(repick_px, n_sigma * sigma[c, n])
    extra = repick(used, X, proj, D, free, limit)
    return X, cov3, rms, used, proj, depth, extra, sigma


# ---------------------------------------------------------------------------------------------- filters
@_jit
def predict(x, P, F, Q):
    """:func:`mocap.ekf.predict` of K filters: ``x`` (K, n), ``P`` (K, n, n), ``F`` (n, n), ``Q`` (1 or K, n, n)
    -> ``x'``, ``P'``. Only the non-zero entries of ``F`` enter the sums (a few per row)."""
    K, n = x.shape
    cols = np.zeros((n, n), dtype=np.intp)  # per row of F, its non-zero columns
    nnz = np.zeros(n, dtype=np.intp)
    for i in range(n):
        for j in range(n):
            if F[i, j] != 0.0:
                cols[i, nnz[i]] = j
                nnz[i] += 1
    x_new = np.empty((K, n))
    P_new = np.empty((K, n, n))
    FP = np.empty((n, n))
    one_q = Q.shape[0] == 1
    PF = np.empty((n, n))
    for k in range(K):  # (each sum in the order of F's columns, as written out: the innermost loops run along rows)
        q = 0 if one_q else k
        for i in range(n):
            s = 0.0
            for m in range(nnz[i]):
                s += F[i, cols[i, m]] * x[k, cols[i, m]]
            x_new[k, i] = s
            for j in range(n):
                FP[i, j] = 0.0
            for m in range(nnz[i]):
                f, c = F[i, cols[i, m]], cols[i, m]
                for j in range(n):
                    FP[i, j] += f * P[k, c, j]
        for j in range(n):  # PF[j, i] = (F P F^T)[i, j]
            for i in range(n):
                PF[j, i] = 0.0
            for m in range(nnz[j]):
                f, c = F[j, cols[j, m]], cols[j, m]
                for i in range(n):
                    PF[j, i] += FP[i, c] * f
        for i in range(n):
            for j in range(n):
                P_new[k, i, j] = PF[j, i] + Q[q, i, j]
    return x_new, P_new


@_jit
def _update_one(x, P, z, R, d, x_new, P_new, y, S, Si, gain, M, A):
    """One filter's position update (``d`` a constant, so its loops unroll); ``Si``, ``gain``, ``M``, ``A`` are
    work arrays (3, 3), (n, d), (n, n), (n, d). ``x_new`` and ``P_new`` may be ``x`` and ``P`` (each element is
    read before it is written)."""
    n = x.shape[0]
    for i in range(d):
        for j in range(d):
            S[i, j] = P[i, j] + R[i, j]
    if d == 2:
        Si[0, 0], Si[0, 1], Si[1, 0], Si[1, 1] = _inv2x2(S[0, 0], S[0, 1], S[1, 0], S[1, 1])
    else:
        _inv3x3(S, Si)
    for i in range(n):
        for j in range(d):
            s = 0.0
            for m in range(d):
                s += P[i, m] * Si[m, j]
            gain[i, j] = s
    for i in range(d):
        y[i] = z[i] - x[i]
    for i in range(n):
        s = 0.0
        for m in range(d):
            s += gain[i, m] * y[m]
        x_new[i] = x[i] + s
    for i in range(n):
        for j in range(n):
            s = 0.0
            for m in range(d):
                s += gain[i, m] * P[m, j]
            M[i, j] = P[i, j] - s
    for i in range(n):
        for j in range(d):
            s = 0.0
            for m in range(d):
                s += gain[i, m] * R[m, j]
            A[i, j] = s - M[i, j]
    for i in range(n):
        for j in range(n):
            s = 0.0
            for m in range(d):
                s += A[i, m] * gain[j, m]
            P_new[i, j] = M[i, j] + s


@_jit
def _update_all(x, P, z, R, d):
    K, n = x.shape
    x_new, P_new, y, S = np.empty((K, n)), np.empty((K, n, n)), np.empty((K, d)), np.empty((K, d, d))
    Si, gain, M, A = np.empty((3, 3)), np.empty((n, d)), np.empty((n, n)), np.empty((n, d))
    for k in range(K):
        _update_one(x[k], P[k], z[k], R[k], d, x_new[k], P_new[k], y[k], S[k], Si, gain, M, A)
    return x_new, P_new, y, S


@_jit
def update_position(x, P, z, R):
    """:func:`mocap.ekf.update_position` (Joseph form, d = 2 or 3) of K filters: ``x`` (K, n), ``P`` (K, n, n),
    ``z`` (K, d), ``R`` (K, d, d) -> ``x'``, ``P'``, innovation ``y`` (K, d), its covariance ``S`` (K, d, d)."""
    if z.shape[1] == 2:  # a constant d: the compiler unrolls the loops over it (2x faster)
        return _update_all(x, P, z, R, 2)
    return _update_all(x, P, z, R, 3)


@_jit
def update_tracks(idx, X, cov, asg, D, S, P, focal, dt, alpha, velocity_std, accel_std,
                  since, hits, x3, P3, e3, last_X, last_v, noise, x2, P2, e2, last_uv, last_uvv, lock2, unseen2):
    """The tracker's ``_update`` of tracks ``idx`` in place: 3D filters and running errors from this frame's points
    ``X`` (K, 3), ``cov`` (K, 3, 3); then the image filters of the cameras used (``asg`` (K, C) into ``D``
    (C, N, 2), ``S`` (C, N, 2, 2)): updated where locked, else restarted from the projected 3D state."""
    C = asg.shape[1]
    y3, S3, y2, S2 = np.empty(3), np.empty((3, 3)), np.empty(2), np.empty((2, 2))
    Si, R = np.empty((3, 3)), np.empty((3, 3))
    gain3, M3, A3 = np.empty((9, 3)), np.empty((9, 9)), np.empty((9, 3))
    gain2, M2, A2 = np.empty((6, 2)), np.empty((6, 6)), np.empty((6, 2))
    meas = np.empty(9)
    for k in idx:
        consecutive = since[k] == 1
        for i in range(3):
            for j in range(3):
                R[i, j] = cov[k, i, j] + (1e-12 if i == j else 0.0)
        for i in range(3):  # measured position, velocity, acceleration (finite differences)
            v = (X[k, i] - last_X[k, i]) / dt
            meas[i], meas[3 + i], meas[6 + i] = X[k, i], v, (v - last_v[k, i]) / dt
        for g in range(3):  # running prediction errors, from consecutive frames only
            b = 3 * g
            d0, d1, d2 = meas[b] - x3[k, b], meas[b + 1] - x3[k, b + 1], meas[b + 2] - x3[k, b + 2]
            err = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
            if consecutive:
                e3[k, g] = alpha * (err if math.isfinite(err) else e3[k, g]) + (1.0 - alpha) * e3[k, g]
        _update_one(x3[k], P3[k], X[k], R, 3, x3[k], P3[k], y3, S3, Si, gain3, M3, A3)  # in place (see _update_one)
        for i in range(3):
            last_v[k, i] = meas[3 + i] if consecutive else np.nan
            last_X[k, i] = X[k, i]
        noise[k] = math.sqrt((cov[k, 0, 0] + cov[k, 1, 1] + cov[k, 2, 2]) / 3.0)
        hits[k] = hits[k] + 1 if consecutive else 1
        since[k] = 0
    for k in idx:  # the image filters, from the updated 3D states
        for c in range(C):
            n = asg[k, c]
            if n < 0:
                lock2[k, c] = False
                continue
            z = D[c, n]
            locked = lock2[k, c]
            uvv0, uvv1 = (z[0] - last_uv[k, c, 0]) / dt, (z[1] - last_uv[k, c, 1]) / dt
            if locked:
                meas[0], meas[1], meas[2], meas[3] = z[0], z[1], uvv0, uvv1
                meas[4], meas[5] = (uvv0 - last_uvv[k, c, 0]) / dt, (uvv1 - last_uvv[k, c, 1]) / dt
                for g in range(3):
                    d0, d1 = meas[2 * g] - x2[k, c, 2 * g], meas[2 * g + 1] - x2[k, c, 2 * g + 1]
                    err = math.sqrt(d0 * d0 + d1 * d1)
                    if math.isfinite(err):
                        e2[k, c, g] = alpha * err + (1.0 - alpha) * e2[k, c, g]
                _update_one(x2[k, c], P2[k, c], z, S[c, n], 2, x2[k, c], P2[k, c], y2, S2, Si, gain2, M2, A2)
                last_uvv[k, c, 0], last_uvv[k, c, 1] = uvv0, uvv1
            else:  # (re)start from the projected 3D state (mocap.ekf.init_state), errors seeded from the 3D ones
                X0, X1, X2 = x3[k, 0], x3[k, 1], x3[k, 2]
                w = X0 * P[c, 2, 0] + X1 * P[c, 2, 1] + X2 * P[c, 2, 2] + P[c, 2, 3]
                for i in range(6):
                    x2[k, c, i] = 0.0
                    for j in range(6):
                        P2[k, c, i, j] = 0.0
                for a in range(2):
                    u = (X0 * P[c, a, 0] + X1 * P[c, a, 1] + X2 * P[c, a, 2] + P[c, a, 3]) / w
                    vel = 0.0
                    for i in range(3):
                        vel += (P[c, a, i] - u * P[c, 2, i]) / w * x3[k, 3 + i]
                    x2[k, c, a], x2[k, c, 2 + a] = z[a], vel
                    P2[k, c, a, 0], P2[k, c, a, 1] = S[c, n, a, 0], S[c, n, a, 1]
                    P2[k, c, 2 + a, 2 + a] = velocity_std**2
                    P2[k, c, 4 + a, 4 + a] = accel_std**2
                depth = P[c, 2, 0] * X0 + P[c, 2, 1] * X1 + P[c, 2, 2] * X2 + P[c, 2, 3]
                scale = focal[c] / (depth if (depth >= 1e-6 or depth != depth) else 1e-6)
                for g in range(3):
                    e2[k, c, g] = e3[k, g] * scale
                last_uvv[k, c, 0] = last_uvv[k, c, 1] = 0.0
            last_uv[k, c, 0], last_uv[k, c, 1] = z[0], z[1]
            lock2[k, c] = True
            unseen2[k, c] = 0


# ---------------------------------------------------------------------------------------------- stereo
@_jit
def gate(pred, radius, D):
    """:func:`mocap.stereo.gate`: (K, C, N) ``|pred - det|^2 / radius^2``, inf where undefined."""
    K, C = radius.shape
    N = D.shape[1]
    q = np.empty((K, C, N))
    for k in range(K):
        for c in range(C):
            r2 = radius[k, c] * radius[k, c]
            for n in range(N):
                du, dv = pred[k, c, 0] - D[c, n, 0], pred[k, c, 1] - D[c, n, 1]
                v = (du * du + dv * dv) / r2
                q[k, c, n] = np.inf if v != v else v
    return q


@_jit
def assign_unambiguous(q, eligible):
    """The first pass of :func:`mocap.stereo.assign`: -> (out (K, C) the detection of every (track, camera)
    whose gate holds one eligible detection that no other track's gate holds, else -1; contested (K, C) bool,
    the other gates holding any)."""
    K, C, N = q.shape
    per_col = np.zeros((C, N), dtype=np.intp)
    for k in range(K):
        for c in range(C):
            for n in range(N):
                if q[k, c, n] < 1.0 and eligible[c, n]:
                    per_col[c, n] += 1
    out = np.full((K, C), -1, dtype=np.intp)
    contested = np.zeros((K, C), dtype=np.bool_)
    for k in range(K):
        for c in range(C):
            count, first = 0, -1
            for n in range(N):
                if q[k, c, n] < 1.0 and eligible[c, n]:
                    count += 1
                    if first < 0:
                        first = n
            if count == 1 and per_col[c, first] == 1:
                out[k, c] = first
            elif count > 0:
                contested[k, c] = True
    return out, contested


@_jit
def _epipolar_distance(f, u1, v1, u2, v2):
    """Symmetric epipolar distance, px, of ``(u1, v1)`` in image i and ``(u2, v2)`` in image j under the pair's
    fundamental matrix ``f`` (3, 3): |l2 . x2| over the shorter of the two lines' normals (NaN for NaN input)."""
    a2 = f[0, 0] * u1 + f[0, 1] * v1 + f[0, 2]  # line in image j of the point in image i
    b2 = f[1, 0] * u1 + f[1, 1] * v1 + f[1, 2]
    c2 = f[2, 0] * u1 + f[2, 1] * v1 + f[2, 2]
    a1 = f[0, 0] * u2 + f[1, 0] * v2 + f[2, 0]  # line in image i of the point in image j
    b1 = f[0, 1] * u2 + f[1, 1] * v2 + f[2, 1]
    return abs(a2 * u2 + b2 * v2 + c2) / min(math.hypot(a2, b2), math.hypot(a1, b1))


@_jit
def epipolar_consistency(index, F, uv, tol_px, sigma, n_sigma):
    """:func:`mocap.stereo.epipolar_consistency` with ``sigma`` (K, C): ``supported`` and ``tested`` (K, C).
    ``index`` (P, 2) the pairs' cameras, ``F`` (P, 3, 3) their fundamental matrices."""
    K, C = uv.shape[0], uv.shape[1]
    supported = np.zeros((K, C), dtype=np.bool_)
    tested = np.zeros((K, C), dtype=np.bool_)
    for p in range(index.shape[0]):
        i, j = index[p, 0], index[p, 1]
        f = F[p]
        for k in range(K):
            u1, v1, u2, v2 = uv[k, i, 0], uv[k, i, 1], uv[k, j, 0], uv[k, j, 1]
            e = _epipolar_distance(f, u1, v1, u2, v2)
            if not math.isfinite(e):
                continue
            tested[k, i] = tested[k, j] = True
            tol = max(tol_px, n_sigma * math.hypot(sigma[k, i], sigma[k, j]))
            if e < tol:
                supported[k, i] = supported[k, j] = True
    return supported, tested


@_jit
def match_free_pairs(index, F, D, free, fresh, use_fresh, sigma, tol_px, n_sigma):
    """:func:`mocap.stereo.match_pairs`: ``pair``, ``n1``, ``n2`` (L,) and ``dist`` (L,) px of every pair of free
    detections ``free`` (C, N) of ``D`` (C, N, 2) within the pair's epipolar tolerance, in the numpy path's order
    (pair, then first camera's detection, then second's); with ``use_fresh``, one of the two must be ``fresh``."""
    counted = 0
    for second_pass in range(2):
        if second_pass:
            pair = np.empty(counted, dtype=np.intp)
            n1 = np.empty(counted, dtype=np.intp)
            n2 = np.empty(counted, dtype=np.intp)
            dist = np.empty(counted)
        k = 0
        for p in range(index.shape[0]):
            i, j = index[p, 0], index[p, 1]
            for a in range(D.shape[1]):
                if not free[i, a]:
                    continue
                for b in range(D.shape[1]):
                    if not free[j, b] or (use_fresh and not (fresh[i, a] or fresh[j, b])):
                        continue
                    e = _epipolar_distance(F[p], D[i, a, 0], D[i, a, 1], D[j, b, 0], D[j, b, 1])
                    if e < max(tol_px, n_sigma * math.hypot(sigma[i, a], sigma[j, b])):
                        if second_pass:
                            pair[k], n1[k], n2[k], dist[k] = p, a, b, e
                        k += 1
        counted = k
    return pair, n1, n2, dist


@_jit
def _well_conditioned(H):
    """:func:`mocap.geometry._well_conditioned` of one (3, 3) normal matrix."""
    for i in range(3):
        for j in range(3):
            if not math.isfinite(H[i, j]):
                return False
    scale = ((H[0, 0] + H[1, 1] + H[2, 2]) / 3.0) ** 3
    det = (H[0, 0] * (H[1, 1] * H[2, 2] - H[1, 2] * H[2, 1]) - H[0, 1] * (H[1, 0] * H[2, 2] - H[1, 2] * H[2, 0])
           + H[0, 2] * (H[1, 0] * H[2, 1] - H[1, 1] * H[2, 0]))
    return det > 1e-12 * scale and scale > 0


@_jit
def triangulate_two_views(P, D, cov, cam1, n1, cam2, n2, iterations):
    """:func:`mocap.stereo.triangulate_matches`: match l is detection ``n1[l]`` of camera ``cam1[l]`` and ``n2[l]``
    of ``cam2[l]`` (``D`` (C, N, 2) px, ``cov`` (C, N, 2, 2) px^2); the DLT, then ``iterations`` Gauss-Newton steps
    weighted by the inverse covariances, as :func:`mocap.geometry.triangulate_weighted`. ``X`` (L, 3) m, ``cov3``
    (L, 3, 3) m^2, ``rms`` (L,) px; NaN where the normal matrix is singular."""
    L = cam1.shape[0]
    X = np.full((L, 3), np.nan)
    cov3 = np.full((L, 3, 3), np.nan)
    rms = np.full(L, np.nan)
    A = np.empty((4, 4))
    uv = np.empty((2, 2))
    W = np.empty((2, 2, 2))
    J = np.empty((2, 2, 3))
    r = np.empty((2, 2))
    H = np.empty((3, 3))
    g = np.empty(3)
    step = np.empty(3)
    Hinv = np.empty((3, 3))
    for lo in range(L):
        cams = (cam1[lo], cam2[lo])
        dets = (n1[lo], n2[lo])
        for v in range(2):
            c, n = cams[v], dets[v]
            uv[v, 0], uv[v, 1] = D[c, n, 0], D[c, n, 1]
            W[v, 0, 0], W[v, 0, 1], W[v, 1, 0], W[v, 1, 1] = _inv2x2(cov[c, n, 0, 0], cov[c, n, 0, 1],
                                                                     cov[c, n, 1, 0], cov[c, n, 1, 1])
            for a in range(2):  # rows u P2 - P0 and v P2 - P1, scaled to unit length
                norm = 0.0
                for q in range(4):
                    A[2 * v + a, q] = uv[v, a] * P[c, 2, q] - P[c, a, q]
                    norm += A[2 * v + a, q] * A[2 * v + a, q]
                norm = math.sqrt(norm)
                if norm > 0:
                    for q in range(4):
                        A[2 * v + a, q] /= norm
        if not np.isfinite(A).all():
            continue
        _, _, vt = np.linalg.svd(A)
        x = np.empty(3)
        good = True
        for i in range(3):
            x[i] = vt[3, i] / vt[3, 3]
            good &= math.isfinite(x[i])
        if not good:
            continue
        for it in range(iterations + 1):
            H[:] = 0.0
            g[:] = 0.0
            for v in range(2):
                c = cams[v]
                w = x[0] * P[c, 2, 0] + x[1] * P[c, 2, 1] + x[2] * P[c, 2, 2] + P[c, 2, 3]
                for a in range(2):
                    p = (x[0] * P[c, a, 0] + x[1] * P[c, a, 1] + x[2] * P[c, a, 2] + P[c, a, 3]) / w
                    r[v, a] = uv[v, a] - p
                    for i in range(3):
                        J[v, a, i] = (P[c, a, i] - p * P[c, 2, i]) / w
                for i in range(3):
                    wj0 = J[v, 0, i] * W[v, 0, 0] + J[v, 1, i] * W[v, 1, 0]  # (J^T W)[i, :]
                    wj1 = J[v, 0, i] * W[v, 0, 1] + J[v, 1, i] * W[v, 1, 1]
                    g[i] += wj0 * r[v, 0] + wj1 * r[v, 1]
                    for j in range(3):
                        H[i, j] += wj0 * J[v, 0, j] + wj1 * J[v, 1, j]
            good = _well_conditioned(H)
            if not good:
                break
            _inv3x3(H, Hinv)
            if it == iterations:
                break
            for i in range(3):
                step[i] = Hinv[i, 0] * g[0] + Hinv[i, 1] * g[1] + Hinv[i, 2] * g[2]
            for i in range(3):
                x[i] += step[i]
        if not good:
            continue
        for i in range(3):
            X[lo, i] = x[i]
            for j in range(3):
                cov3[lo, i, j] = Hinv[i, j]
        rms[lo] = math.sqrt((r[0, 0] ** 2 + r[0, 1] ** 2 + r[1, 0] ** 2 + r[1, 1] ** 2) / 2.0)
    return X, cov3, rms


# ---------------------------------------------------------------------------------------------- tracker
@_jit
def frame_detections(D, S, merged, round_, cov, flagged, area, roundness, counts, min_shape_area, min_std_px,
                     default_sigma_px, centre, focal_xy, round_merged):
    """The tracker's frame of detections, camera by camera into the (C, N) slots (the rest stay as given: D NaN,
    S identity, merged False, round 1): ``D`` (C, N, 2) holds the ideal px already; ``cov`` (T, 2, 2), ``flagged``,
    ``area``, ``roundness`` (T,) are all cameras' detections one after another (``counts`` (C,)). Covariances get
    their smallest eigenvalue raised to ``min_std_px``^2 (non-finite ones: ``default_sigma_px``^2 I), as
    :func:`mocap.detections.floored_covariance` does; blobs of at
    least ``min_shape_area`` px flatter than ``round_merged`` x a sphere's image at their field angle are marked
    merged. Returns (C, N) the mean variance of each slot, px^2."""
    C, N = D.shape[0], D.shape[1]
    var = np.empty((C, N))
    floor = min_std_px * min_std_px
    i = 0
    for c in range(C):
        for n in range(N):
            if n < counts[c]:
                a, b, d = cov[i, 0, 0], 0.5 * (cov[i, 0, 1] + cov[i, 1, 0]), cov[i, 1, 1]
                smallest = 0.5 * (a + d) - math.sqrt((0.5 * (a - d)) ** 2 + b * b)
                lift = max(floor - smallest, 0.0)
                S[c, n, 0, 0], S[c, n, 0, 1] = cov[i, 0, 0] + lift, cov[i, 0, 1]
                S[c, n, 1, 0], S[c, n, 1, 1] = cov[i, 1, 0], cov[i, 1, 1] + lift
                if not (np.isfinite(S[c, n, 0, 0]) and np.isfinite(S[c, n, 0, 1]) and np.isfinite(S[c, n, 1, 0])
                        and np.isfinite(S[c, n, 1, 1])):
                    S[c, n, 0, 0], S[c, n, 1, 1] = default_sigma_px**2, default_sigma_px**2
                    S[c, n, 0, 1], S[c, n, 1, 0] = 0.0, 0.0
                merged[c, n] = flagged[i]
                round_[c, n] = roundness[i] if area[i] >= min_shape_area else 1.0
                rx = (D[c, n, 0] - centre[c, 0]) / focal_xy[c, 0]
                ry = (D[c, n, 1] - centre[c, 1]) / focal_xy[c, 1]
                if round_[c, n] < round_merged / math.sqrt(1.0 + (rx * rx + ry * ry)):
                    merged[c, n] = True
                i += 1
            var[c, n] = 0.5 * (S[c, n, 0, 0] + S[c, n, 1, 1])
    return var


@_jit
def prepare_frame(xy, counts, K, dist, distorted, max_steps, eps_px, cov, flagged, area, roundness, min_shape_area,
                  min_std_px, default_sigma_px, centre, focal_xy, round_merged, vague2, vague_typical2, merged_scale):
    """The tracker's ``_prepare`` in one call: all cameras' detections one after another (``xy`` (T, 2) distorted
    px, ``cov`` (T, 2, 2), ``flagged``, ``area``, ``roundness`` (T,), ``counts`` (C,)) undistorted
    (:func:`undistort_points` with the lenses ``K``, ``dist``, ``distorted``, ``max_steps``, ``eps_px``) into the
    padded (C, N) slots and prepared by :func:`frame_detections`; slots whose mean variance exceeds ``vague2`` px^2
    and ``vague_typical2`` x the median of the valid ones are merged too, and merged slots' covariances are
    multiplied by ``merged_scale``. Returns ``D`` (C, N, 2), ``S`` (C, N, 2, 2), ``valid``, ``merged`` (C, N)
    bool and ``round_`` (C, N)."""
    C = counts.shape[0]
    N = 0
    for c in range(C):
        N = max(N, counts[c])
    camera = np.empty(xy.shape[0], dtype=np.intp)
    i = 0
    for c in range(C):
        for _ in range(counts[c]):
            camera[i] = c
            i += 1
    ideal = undistort_points(xy, camera, K, dist, distorted, max_steps, eps_px)
    D = np.full((C, N, 2), np.nan)
    S = np.zeros((C, N, 2, 2))
    merged = np.zeros((C, N), dtype=np.bool_)
    round_ = np.ones((C, N))
    i = 0
    for c in range(C):
        for n in range(N):
            S[c, n, 0, 0] = S[c, n, 1, 1] = 1.0
            if n < counts[c]:
                D[c, n, 0], D[c, n, 1] = ideal[i, 0], ideal[i, 1]
                i += 1
    var = frame_detections(D, S, merged, round_, cov, flagged, area, roundness, counts, min_shape_area, min_std_px,
                           default_sigma_px, centre, focal_xy, round_merged)
    valid = np.empty((C, N), dtype=np.bool_)
    values = np.empty(C * N)
    m = 0
    for c in range(C):
        for n in range(N):
            valid[c, n] = math.isfinite(D[c, n, 0]) and math.isfinite(D[c, n, 1])
            if valid[c, n]:
                values[m] = var[c, n]
                m += 1
    if m:  # quick_median of the valid slots' variances
        ordered = np.sort(values[:m])
        limit = max(vague2, vague_typical2 * (0.5 * (ordered[(m - 1) // 2] + ordered[m // 2])))
        for c in range(C):
            for n in range(N):
                merged[c, n] |= var[c, n] > limit
    for c in range(C):
        for n in range(N):
            if merged[c, n]:
                for a in range(2):
                    for b in range(2):
                        S[c, n, a, b] *= merged_scale
    return D, S, valid, merged, round_


@_jit
def measured_points(X, used, crowded, split, merged, sigma, asg, depth, focal, x3, e3, gate_scale, suspect_lo,
                    suspect_hi, n_sigma):
    """The tracker's verdicts on its measured points ``X`` (K, 3) m: ``ok`` (K,) finite; ``clean`` (K, C) its
    ``used`` views whose blob (``asg`` (K, C) into the (C, N) ``merged`` flags) is not merged and whose track is
    not ``crowded`` there, or whose blob was ``split``; ``out`` (K,): two clean views, or one that lies within
    ``gate_scale`` x the running error ``e3[:, 0]`` (clipped to ``suspect_lo`` and the larger of ``suspect_hi`` and
    ``n_sigma`` x the point's noise, the clean views' mean ``sigma`` (C, N) px x ``depth`` (C, K) m / ``focal``
    (C,) px) of the prediction ``x3`` (K, >= 3)."""
    K, C = used.shape
    ok = np.empty(K, dtype=np.bool_)
    clean = np.zeros((K, C), dtype=np.bool_)
    out = np.empty(K, dtype=np.bool_)
    for k in range(K):
        ok[k] = math.isfinite(X[k, 0]) and math.isfinite(X[k, 1]) and math.isfinite(X[k, 2])
        n = 0
        total = 0.0
        for c in range(C):
            j = asg[k, c]
            clean[k, c] = used[k, c] and ((not crowded[k, c] and not merged[c, max(j, 0)]) or split[k, c])
            if clean[k, c]:
                n += 1
                total += sigma[c, max(j, 0)] * depth[c, k] / focal[c]
        high = suspect_hi
        if n:
            high = max(high, n_sigma * (total / n))
        d0, d1, d2 = X[k, 0] - x3[k, 0], X[k, 1] - x3[k, 1], X[k, 2] - x3[k, 2]
        agree = math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) < min(max(gate_scale * e3[k, 0], suspect_lo), high)
        out[k] = ok[k] and (n >= 2 or (agree and n == 1))
    return ok, clean, out


@_jit
def explained_elsewhere(asg, ok, out, merged, D, S, P, X, reach_px, n_sigma, apart_m):
    """(K,) bool: the tracks whose measured point ``X`` (K, 3) m (``ok`` (K,)) rests on two views (``asg`` (K, C)
    into the (C, N) detections ``D`` ideal px, ``S`` px^2, ``merged``), one of them a clean blob that another
    output (``out``) point of two views or more, ``apart_m`` away at least, not seen in that camera and in front of
    it, projects onto within the larger of ``reach_px`` and ``n_sigma`` x the blob's std; not where the two explain a
    blob of each other (``mocap.tracker.Tracker._explained_elsewhere``). ``P`` (C, 3, 4)."""
    K, C = asg.shape
    views = np.zeros(K, np.int64)
    for k in range(K):
        for c in range(C):
            if asg[k, c] >= 0:
                views[k] += 1
    explains = np.zeros((K, K), dtype=np.bool_)
    found = False
    for p in range(K):
        if not ok[p] or views[p] != 2:
            continue
        for c in range(C):
            j = asg[p, c]
            if j < 0 or merged[c, j]:
                continue
            reach = max(reach_px, n_sigma * math.sqrt(0.5 * (S[c, j, 0, 0] + S[c, j, 1, 1])))
            for q in range(K):
                if q == p or not (ok[q] and out[q]) or views[q] < 2 or asg[q, c] >= 0:
                    continue
                d0, d1, d2 = X[q, 0] - X[p, 0], X[q, 1] - X[p, 1], X[q, 2] - X[p, 2]
                if not math.sqrt(d0 * d0 + d1 * d1 + d2 * d2) >= apart_m:
                    continue
                w = X[q, 0] * P[c, 2, 0] + X[q, 1] * P[c, 2, 1] + X[q, 2] * P[c, 2, 2] + P[c, 2, 3]
                if not w > 0:
                    continue
                u = (X[q, 0] * P[c, 0, 0] + X[q, 1] * P[c, 0, 1] + X[q, 2] * P[c, 0, 2] + P[c, 0, 3]) / w
                v = (X[q, 0] * P[c, 1, 0] + X[q, 1] * P[c, 1, 1] + X[q, 2] * P[c, 1, 2] + P[c, 1, 3]) / w
                if math.hypot(u - D[c, j, 0], v - D[c, j, 1]) < reach:
                    explains[p, q] = True
                    found = True
    loser = np.zeros(K, dtype=np.bool_)
    if not found:  # (most frames: no pair to weigh)
        return loser
    for p in range(K):
        for q in range(K):
            if explains[p, q] and not explains[q, p]:
                loser[p] = True
    return loser


@_jit
def frame_record(X, asg, rms_px, ident, P, focal, bounds):
    """The tracker's output of a frame for the measured points ``X`` (R, 3) m from the blobs ``asg`` (R, C) (-1:
    none) with reprojection RMS ``rms_px`` (R,) and identities ``ident`` (R,) (-1: tentative): residuals (R,) mm
    (the RMS times the mean depth / focal length over the cameras used), camera masks (R,) uint32 (bit c: camera c
    used) and, for the detections of all cameras one after another (camera c's from ``bounds[c]``), the identity
    each went to (-1: none or a tentative track)."""
    n, C = asg.shape
    res = np.empty(n)
    mask = np.zeros(n, np.uint32)
    flat = np.full(bounds[C], -1, np.intp)
    for r in range(n):
        total = 0.0
        used = 0
        for c in range(C):
            if asg[r, c] < 0:
                continue
            depth = X[r, 0] * P[c, 2, 0] + X[r, 1] * P[c, 2, 1] + X[r, 2] * P[c, 2, 2] + P[c, 2, 3]
            total += depth / focal[c]
            used += 1
            mask[r] |= np.uint32(1) << np.uint32(c)
            if ident[r] >= 0:
                flat[bounds[c] + asg[r, c]] = ident[r]
        res[r] = rms_px[r] * (total / max(used, 1)) * 1000.0
    return res, mask, flat


@_jit
def near_any(D, cc, nn, old, limit2):
    """The tracker's clutter test: (W,) bool, detection ``D[cc[i], nn[i]]`` (px) lies closer than ``sqrt(limit2)``
    to one of the points ``old[cc[i]]`` (C, M, 2) px (NaN: none there)."""
    out = np.zeros(cc.shape[0], np.bool_)
    for i in range(cc.shape[0]):
        c = cc[i]
        u, v = D[c, nn[i], 0], D[c, nn[i], 1]
        for m in range(old.shape[1]):
            du, dv = u - old[c, m, 0], v - old[c, m, 1]
            if du * du + dv * dv < limit2:
                out[i] = True
                break
    return out


@_jit
def search_regions(x3, e3, since, x2, e2, lock, P, focal, dt, scale, floor_m, reid_max_m, floor_px, max_px):
    """The tracker's ``_search_regions``: predicted ideal pixels (K, C, 2) (the locked image filter's, else the
    projected 3D prediction; NaN behind the camera), search radii (K, C), px, and depths (K, C), m."""
    K, C = lock.shape
    pred, radius, depth = np.empty((K, C, 2)), np.empty((K, C)), np.empty((K, C))
    for k in range(K):
        t = max(since[k] - 1, 0) * dt  # :meth:`mocap.ekf.RunningError.radius`, clipped to reid_max_m
        r3 = scale * (e3[k, 0] + e3[k, 1] * t + 0.5 * e3[k, 2] * t * t) + floor_m
        r3 = r3 if (r3 <= reid_max_m or r3 != r3) else reid_max_m
        X0, X1, X2 = x3[k, 0], x3[k, 1], x3[k, 2]
        for c in range(C):
            w = X0 * P[c, 2, 0] + X1 * P[c, 2, 1] + X2 * P[c, 2, 2] + P[c, 2, 3]
            depth[k, c] = w
            if lock[k, c]:
                pred[k, c, 0], pred[k, c, 1] = x2[k, c, 0], x2[k, c, 1]
                r = scale * (e2[k, c, 0] + e2[k, c, 1] * 0.0 + e2[k, c, 2] * 0.0) + floor_px
            else:
                for a in range(2):
                    pred[k, c, a] = (X0 * P[c, a, 0] + X1 * P[c, a, 1] + X2 * P[c, a, 2] + P[c, a, 3]) / w
                r = r3 * focal[c] / w
            r = r if (r >= floor_px or r != r) else floor_px  # np.clip: NaN stays NaN
            radius[k, c] = r if (r <= max_px or r != r) else max_px
            if w <= 0:
                pred[k, c, 0] = pred[k, c, 1] = np.nan
    return pred, radius, depth


@_jit
def crowded(pred, play, seen, depth, asg, focal, marker_mm, merge_px):
    """The tracker's ``_crowded``: (K, C) bool, another track in ``play`` (K,) and ``seen`` (K, C) by that camera
    lately is predicted (``pred`` (K, C, 2)) within the marker's image diameter + ``merge_px`` (depth (K, C) m,
    ``focal`` (C,) px) and did not take a blob of its own there (``asg`` (K, C))."""
    K, C = asg.shape
    out = np.zeros((K, C), dtype=np.bool_)
    for c in range(C):
        for k in range(K):
            if not play[k]:
                continue
            reach = focal[c] * marker_mm / 1000.0 / depth[k, c] + merge_px
            reach2 = reach * reach
            for j in range(K):
                if j == k or not play[j] or not seen[j, c]:
                    continue
                du, dv = pred[k, c, 0] - pred[j, c, 0], pred[k, c, 1] - pred[j, c, 1]
                if du * du + dv * dv < reach2:
                    own, other = asg[k, c], asg[j, c]
                    if own < 0 or other < 0 or own == other:
                        out[k, c] = True
    return out


@_jit
def attached_learn(ident, X, neighbour, distance, held, last, tries, frame, tol, alpha, forget):
    """:meth:`mocap.attached.AttachedDistances.learn`'s update of the slots (in place) for the identities ``ident``
    (n,) measured at ``X`` (n, 3) m; the memory's arrays (I, J) as there."""
    where = np.full(neighbour.shape[0], -1, np.intp)
    for i in range(ident.shape[0]):
        where[ident[i]] = i
    for i in range(ident.shape[0]):
        a = ident[i]
        for j in range(neighbour.shape[1]):
            nb = neighbour[a, j]
            if nb >= 0 and where[nb] >= 0:
                b = where[nb]
                dx, dy, dz = X[i, 0] - X[b, 0], X[i, 1] - X[b, 1], X[i, 2] - X[b, 2]
                d = math.sqrt(dx * dx + dy * dy + dz * dz)
                last[a, j] = frame
                if held[a, j] == 0:
                    distance[a, j] = d
                    held[a, j] = 1
                elif abs(d - distance[a, j]) <= tol:
                    distance[a, j] = distance[a, j] + alpha * (d - distance[a, j])
                    held[a, j] += 1
                else:
                    held[a, j] = held[a, j] // 2
                    if held[a, j] == 0:
                        nb = -1
            if nb >= 0 and frame - last[a, j] > forget:
                nb = -1
            if nb < 0:
                if neighbour[a, j] >= 0:
                    tries[a, j] += 1
                neighbour[a, j] = -1
                held[a, j] = 0


@_jit
def attached_fill(ident, X, rows, neighbour, tries, last, frame, reach2):
    """:meth:`mocap.attached.AttachedDistances._fill` (in place): every free slot of the identities ``ident[rows]``
    takes a measured identity (``ident`` (n,) at ``X`` (n, 3) m) within ``sqrt(reach2)`` m not yet held, the
    ``tries``-th nearest (cyclically) of those left."""
    n, J = ident.shape[0], neighbour.shape[1]
    d = np.empty(n)
    for r in range(rows.shape[0]):
        i = rows[r]
        a = ident[i]
        for m in range(n):
            dx, dy, dz = X[i, 0] - X[m, 0], X[i, 1] - X[m, 1], X[i, 2] - X[m, 2]
            d[m] = dx * dx + dy * dy + dz * dz
            if m == i or d[m] > reach2:
                d[m] = np.inf
            for j in range(J):
                if neighbour[a, j] == ident[m]:
                    d[m] = np.inf
        for j in range(J):
            if neighbour[a, j] >= 0:
                continue
            avail = 0
            for m in range(n):
                if d[m] < np.inf:
                    avail += 1
            if avail == 0:
                break
            pick = np.argsort(d)[tries[a, j] % avail]
            neighbour[a, j] = ident[pick]
            last[a, j] = frame
            d[pick] = np.inf


@_jit
def _partial_blob(area, roundness, merged, expected_area, expected_round, partial_area, partial_round, min_area):
    """:meth:`mocap.tracker.Tracker._partial` of one blob."""
    if merged or not expected_area >= min_area:  # (NaN: unknown)
        return False
    ratio = area / expected_area
    round_ratio = roundness / expected_round
    spread = 1.0 / math.sqrt(expected_area)
    return ((ratio < 1.0 - partial_area * spread and round_ratio < 1.0 + partial_round * spread)
            or (round_ratio < 1.0 - partial_round * spread and ratio < 1.0))


@_jit
def _blob_at_depth(blob, last_X, P, k, c, power):
    """Track ``k``'s depth in camera ``c`` (m, from ``last_X`` (K, 3) and ``P`` (C, 3, 4)) and its blob's area and
    light there (``blob`` (K, C, 7)) scaled to it: :func:`mocap.tracker._blob_at_depth` of one view."""
    depth = last_X[k, 0] * P[c, 2, 0] + last_X[k, 1] * P[c, 2, 1] + last_X[k, 2] * P[c, 2, 2] + P[c, 2, 3]
    ratio = blob[k, c, 2] / depth
    return depth, blob[k, c, 0] * ratio * ratio, blob[k, c, 3] * ratio**power


@_jit
def expected_blobs(blob, last_X, P, power):
    """:meth:`mocap.tracker.Tracker._expected_blobs`: ``blob`` (K, C, 7), ``last_X`` (K, 3) m, ``P`` (C, 3, 4), the
    light's depth ``power`` -> (K, C, 4)."""
    K, C = blob.shape[0], blob.shape[1]
    out = np.empty((K, C, 4))
    for k in range(K):
        for c in range(C):
            _, out[k, c, 0], out[k, c, 2] = _blob_at_depth(blob, last_X, P, k, c, power)
            out[k, c, 1] = blob[k, c, 1]
            out[k, c, 3] = blob[k, c, 4]
    return out


@_jit
def _dark_blob(flux, merged, expected_area, expected_flux, deviation, settings):
    """:meth:`mocap.tracker.Tracker._dark` of one blob (``settings`` (4,):
    :meth:`mocap.tracker.Tracker._dark_settings`)."""
    if merged or not expected_area >= settings[3]:  # (NaN: unknown)
        return False
    tolerance = settings[0]
    if settings[1] * deviation > tolerance:  # (NaN: no deviation known yet)
        tolerance = settings[1] * deviation
    tolerance = min(tolerance, settings[2])
    return flux / expected_flux < 1.0 - tolerance  # (NaN: no light known)


@_jit
def partly_hidden(expect, area, roundness, merged, tracks, cams, blobs, partial_area, partial_round, min_area):
    """:meth:`mocap.tracker.Tracker._partly_hidden`: ``expect`` (K, C, 2), the frame's ``area``, ``roundness`` and
    ``merged`` (C, N), the views ``tracks``, ``cams``, ``blobs`` (n,) -> (n,) bool."""
    out = np.zeros(tracks.shape[0], dtype=np.bool_)
    for i in range(tracks.shape[0]):
        k, c, j = tracks[i], cams[i], blobs[i]
        out[i] = _partial_blob(area[c, j], roundness[c, j], merged[c, j], expect[k, c, 0], expect[k, c, 1],
                               partial_area, partial_round, min_area)
    return out


@_jit
def follow_blobs(blob, cut_run, dark_run, last_X, P, area, roundness, flux, merged, tracks, cams, blobs, alpha,
                 partial_area, partial_round, min_area, partial_frames, dark_settings, power, step_clip, light_fit):
    """:meth:`mocap.tracker.Tracker._follow_blobs` in place on ``blob`` (K, C, 7), ``cut_run`` and ``dark_run``
    (K, C) and ``light_fit`` (2,): ``last_X`` (K, 3) m, ``P`` (C, 3, 4), the frame's ``area``, ``roundness``,
    ``flux`` and ``merged`` (C, N), the views ``tracks``, ``cams``, ``blobs`` (n,), ``dark_settings`` (4,), the
    light's depth ``power`` and the fit's ``step_clip``."""
    for i in range(tracks.shape[0]):
        k, c, j = tracks[i], cams[i], blobs[i]
        depth, expected, light = _blob_at_depth(blob, last_X, P, k, c, power)  # (at this depth)
        a, r, f = area[c, j], roundness[c, j], flux[c, j]
        dark = _dark_blob(f, merged[c, j], expected, light, blob[k, c, 4], dark_settings)
        run = dark_run[k, c] + 1 if dark else 0
        dark_lasting = run > partial_frames
        dark_run[k, c] = 0 if dark_lasting else run
        if not merged[c, j] and (not dark or dark_lasting) and math.isfinite(f) and math.isfinite(depth):
            x, y = math.log(depth / blob[k, c, 6]), math.log(f / blob[k, c, 5])  # (NaN: no view before)
            if not dark_lasting and math.isfinite(x) and math.isfinite(y):
                y = min(max(y + power * x, -step_clip), step_clip) - power * x
                light_fit[0] += x * x
                light_fit[1] += x * y
            blob[k, c, 5], blob[k, c, 6] = f, depth
            if math.isfinite(light) and not dark_lasting:
                off = abs(f / light - 1.0)
                blob[k, c, 4] = blob[k, c, 4] + alpha * (off - blob[k, c, 4]) if math.isfinite(blob[k, c, 4]) else off
                light += alpha * (f - light)
            else:
                light = f
        cut = _partial_blob(a, r, merged[c, j], expected, blob[k, c, 1], partial_area, partial_round, min_area)
        run = cut_run[k, c] + 1 if cut else 0
        lasting = run > partial_frames
        cut_run[k, c] = 0 if lasting else run
        if not (merged[c, j] or (cut and not lasting) or not math.isfinite(depth)):
            if lasting:
                expected = np.nan
            if math.isfinite(expected):
                blob[k, c, 0] = expected + alpha * (a - expected)
                blob[k, c, 1] = blob[k, c, 1] + alpha * (r - blob[k, c, 1])
            else:
                blob[k, c, 0], blob[k, c, 1] = a, r
            blob[k, c, 2] = depth
        if math.isfinite(light):  # (the light kept at the record's depth)
            if not math.isfinite(blob[k, c, 2]):
                blob[k, c, 2] = depth
            blob[k, c, 3] = light * (depth / blob[k, c, 2]) ** power


# ---------------------------------------------------------------------------------------------- identity repair
@_jit
def pair_distance_statistics(sample, count, min_frames):
    """:func:`mocap.rigid.pair_statistics`'s medians: per pair of identities of ``sample`` (F, M, 3) m whose
    co-seen count ``count`` (M, M) is ``min_frames`` or more, the median distance over the frames both are seen in
    and 1.4826 x the median absolute deviation from it -> (M, M) median m, (M, M) spread m (NaN elsewhere)."""
    F, M = sample.shape[0], sample.shape[1]
    median = np.full((M, M), np.nan)
    spread = np.full((M, M), np.nan)
    d = np.empty(F)
    for a in range(M):
        for b in range(a + 1, M):
            if count[a, b] < min_frames:
                continue
            n = 0
            for f in range(F):
                dx = sample[f, b, 0] - sample[f, a, 0]
                dy = sample[f, b, 1] - sample[f, a, 1]
                dz = sample[f, b, 2] - sample[f, a, 2]
                v = math.sqrt(dx * dx + dy * dy + dz * dz)
                if not math.isnan(v):
                    d[n] = v
                    n += 1
            if n == 0:
                continue
            med = np.median(d[:n])
            dev = np.abs(d[:n] - med)
            median[a, b] = median[b, a] = med
            spread[a, b] = spread[b, a] = 1.4826 * np.median(dev)
    return median, spread
