"""A marker partly hidden by an edge: a blurred disc cut by a straight blurred edge, fitted to its blob.

A limb, a prop or another body part passing in front of a marker hides part of its disc: the blob is the disc
minus everything beyond an edge, and its centroid (and a whole disc fitted to it) lies up to 0.42 radius toward the
part still seen, 1-2 px on a marker a few pixels across. The curved part of the disc's edge still fixes its centre.
Detection (:mod:`mocap.detect`) refits the blobs a single disc misfits with this model::

    I(x) = b + A * Phi((r - |x - c|) / s) * Phi((d - n(theta) . (x - c)) / s)

a disc of radius ``r`` (px) whose edge is blurred by a Gaussian of std ``s`` (optics and pixel area), cut at ``d``
px from its centre along the unit normal ``n(theta)`` (the hidden side), with the same blur. Levenberg–Marquardt
from both ends of the blob's shortest axis (a straight cut's normal), vectorised over blobs and starts (the
windows' pixels one after another in flat arrays, as the disc fit's; with :data:`mocap.kernels.HAVE_NUMBA` blob
by blob in :func:`mocap.detect_kernels.fit_cut_discs`); the better start of each blob is kept. On rendered discs
of 2.5-4 px radius cut half a radius out or through their centre the centre comes out 0.007-0.03 px rms off
(0.2-0.42 radius before), with a covariance from the fit that matches those errors and grows as less of the disc
is seen.
"""

from __future__ import annotations

import math

import numpy as np
from scipy import special

from mocap import detect_kernels, kernels

__all__ = ["N_PAR", "fit_cut_discs", "visible_fraction"]

STARTS = 2  # edge directions each blob's fit starts from: either way along its shortest axis
ITERATIONS = 10  # Levenberg–Marquardt steps from each start
N_PAR = 8  # b, cx, cy, A, r, s, theta, d
_START_SHIFT = 0.25  # radii: the centre's start, from the whole disc's fit toward the edge's (hidden) side
_START_EDGE = 0.25  # radii: the edge's start distance from that centre
_NO_CUT = 1e6  # px: an edge this far out hides nothing and its parameters get no gradient (the whole disc's fit)
_LOW = np.array([-np.inf, -np.inf, -np.inf, 1.0, 0.3, 0.15, -np.inf, -np.inf])
_HIGH = np.array([np.inf, np.inf, np.inf, np.inf, 100.0, 5.0, np.inf, np.inf])
_MAX_STEP_PX = 1.0  # a centre, radius or edge moves at most this far per step, px (the edge's normal 0.5 rad)
_BOUND = np.array([np.inf, _MAX_STEP_PX, _MAX_STEP_PX, np.inf, _MAX_STEP_PX, np.inf, 0.5, _MAX_STEP_PX])
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)


def _model_and_jacobian(params: np.ndarray, ox: np.ndarray, oy: np.ndarray, seg: np.ndarray, jacobian: bool = True
                        ) -> tuple[np.ndarray, np.ndarray | None]:
    """The model (T,) at the pixels ``ox, oy`` (T,) of problems ``seg`` (T,) with ``params`` (P, 8), and its
    Jacobian (T, 8) (None unless asked)."""
    b, cx, cy, amp, r, s, theta, d = params.take(seg, axis=0).T
    dx, dy = ox - cx, oy - cy
    rho = np.sqrt(dx * dx + dy * dy)
    cos, sin = np.cos(theta), np.sin(theta)
    along = dx * cos + dy * sin
    inv_s = 1.0 / s
    u, v = (r - rho) * inv_s, (d - along) * inv_s
    disc, cut = special.ndtr(u), special.ndtr(v)
    model = b + amp * disc * cut
    if not jacobian:
        return model, None
    disc_slope = np.exp(-0.5 * u * u) * _INV_SQRT_2PI * inv_s
    cut_slope = np.exp(-0.5 * v * v) * _INV_SQRT_2PI * inv_s
    radial = amp * disc_slope * cut / np.maximum(rho, 1e-9)
    edge = amp * disc * cut_slope
    jac = np.empty((len(seg), N_PAR))
    jac[:, 0] = 1.0
    jac[:, 1] = radial * dx + edge * cos
    jac[:, 2] = radial * dy + edge * sin
    jac[:, 3] = disc * cut
    jac[:, 4] = amp * disc_slope * cut
    jac[:, 5] = -(amp * disc_slope * cut * u + edge * v)
    jac[:, 6] = edge * (dx * sin - dy * cos)
    jac[:, 7] = edge
    return model, jac


def _normal_equations(jac: np.ndarray, resid: np.ndarray, starts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per problem ``J^T J`` (P, 8, 8) and ``J^T resid`` (P, 8) from the pixels' Jacobian (T, 8) and residuals (T,)
    (problem ``p``'s pixels from ``starts[p]``)."""
    outer = (jac[:, :, None] * jac[:, None, :]).reshape(len(jac), -1)
    jtj = np.add.reduceat(outer, starts, axis=0).reshape(-1, N_PAR, N_PAR)
    return jtj, np.add.reduceat(jac * resid[:, None], starts, axis=0)


def _starts(disc: np.ndarray, axis: np.ndarray, cut: bool) -> np.ndarray:
    """(N * S, 8) starting parameters from the whole-disc fits ``disc`` (N, 6) ``b, cx, cy, A, r, s``: with a
    ``cut``, S = STARTS, the edge's normal at STARTS directions from ``axis`` (N,) rad on and the centre moved toward
    it; without, S = 1, the edge ``_NO_CUT`` px out (the whole disc in the same model)."""
    starts = STARTS if cut else 1
    theta = (axis[:, None] + 2.0 * np.pi * np.arange(starts) / starts).ravel()
    start = np.repeat(disc, starts, axis=0)
    r = start[:, 4]
    shift = _START_SHIFT if cut else 0.0
    params = np.empty((len(start), N_PAR))
    params[:, 0] = start[:, 0]
    params[:, 1] = start[:, 1] + shift * r * np.cos(theta)
    params[:, 2] = start[:, 2] + shift * r * np.sin(theta)
    params[:, 3] = start[:, 3]
    params[:, 4] = r * (1.0 + shift)
    params[:, 5] = start[:, 5]
    params[:, 6] = theta
    params[:, 7] = _START_EDGE * r if cut else _NO_CUT
    return params


def fit_cut_discs(values: np.ndarray, ox: np.ndarray, oy: np.ndarray, seg: np.ndarray, disc: np.ndarray,
                  axis: np.ndarray, cut: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit a disc cut by an edge (or, without ``cut``, the same model's whole disc) to each of N blobs' windows.

    Args:
        values: (T,) grey levels minus the frame's background level; ox, oy: (T,) pixel offsets from each window's
            origin, px; seg: (T,) the blob (0..N-1) of each pixel, non-decreasing, every blob with some pixels.
        disc: (N, 6) the blobs' whole-disc fits ``b, cx, cy, A, r, s`` (centres relative to the window origin).
        axis: (N,) the blobs' shortest axis (of their second moments), rad: a cut's normal lies along it.
        cut: fit the edge; False: keep it out of reach (its parameters get no gradient and stay), a whole disc.

    Returns:
        params (N, 8) ``b, cx, cy, A, r, s, theta, d`` of each blob's best start, the unscaled covariance
        ``(J^T J)^-1`` (N, 8, 8) there (NaN where singular: always without ``cut``) and the residuals' sum of
        squares (N,), grey levels^2.
    """
    n = len(disc)
    count = np.bincount(seg, minlength=n)
    first = np.cumsum(count) - count
    starts = STARTS if cut else 1
    params = _starts(np.asarray(disc, dtype=np.float64), np.asarray(axis, dtype=np.float64), cut)
    if kernels.HAVE_NUMBA:
        return detect_kernels.fit_cut_discs(values.astype(np.float64), ox.astype(np.float64), oy.astype(np.float64),
                                            np.append(first, len(seg)), params, starts, ITERATIONS, _LOW, _HIGH,
                                            _BOUND)
    problem_count = np.repeat(count, starts)  # problem p = blob * starts + start
    problem_first = np.cumsum(problem_count) - problem_count
    pixel = np.repeat(np.repeat(first, starts) - problem_first, problem_count) + np.arange(problem_count.sum())
    pseg = np.repeat(np.arange(n * starts), problem_count)
    px, py, pv = ox.take(pixel).astype(np.float64), oy.take(pixel).astype(np.float64), values.take(pixel)
    model, jac = _model_and_jacobian(params, px, py, pseg)
    resid = pv - model
    cost = np.add.reduceat(resid * resid, problem_first)
    damping = np.full(len(params), 1e-2)
    diag = np.arange(N_PAR)
    for _ in range(ITERATIONS):
        jtj, grad = _normal_equations(jac, resid, problem_first)
        lhs = jtj.copy()
        lhs[:, diag, diag] = jtj[:, diag, diag] * (1.0 + damping[:, None]) + 1e-9
        try:
            step = np.linalg.solve(lhs, grad[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:  # (a degenerate window somewhere)
            step = np.matmul(np.linalg.pinv(lhs), grad[:, :, None])[:, :, 0]
        trial = np.clip(params + np.clip(step, -_BOUND, _BOUND), _LOW, _HIGH)
        trial_model, _ = _model_and_jacobian(trial, px, py, pseg, jacobian=False)
        trial_resid = pv - trial_model
        trial_cost = np.add.reduceat(trial_resid * trial_resid, problem_first)
        better = trial_cost < cost
        params = np.where(better[:, None], trial, params)
        cost = np.where(better, trial_cost, cost)
        damping = np.where(better, np.maximum(damping / 3.0, 1e-6), np.minimum(damping * 4.0, 1e6))
        if better.any():
            model, jac = _model_and_jacobian(params, px, py, pseg)
            resid = pv - model
    best = np.nanargmin(np.where(np.isfinite(cost), cost, np.inf).reshape(n, starts), axis=1) + starts * np.arange(n)
    jtj, _ = _normal_equations(jac, resid, problem_first)
    jtj = jtj[best]
    cov = np.full_like(jtj, np.nan)
    regular = np.linalg.cond(jtj) < 1e12
    cov[regular] = np.linalg.inv(jtj[regular])
    return params[best], cov, cost[best]


def visible_fraction(r: np.ndarray, d: np.ndarray) -> np.ndarray:
    """(N,) the share of a disc of radius ``r`` (N,) px left in view by an edge ``d`` (N,) px from its centre (the
    part beyond it hidden): 1 for d >= r, 0 for d <= -r."""
    x = np.clip(d / np.maximum(r, 1e-9), -1.0, 1.0)
    hidden = np.arccos(x) - x * np.sqrt(1.0 - x * x)  # the cap beyond the edge, in units of r^2
    return 1.0 - hidden / np.pi
