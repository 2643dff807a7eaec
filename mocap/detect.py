"""Blob detection: bright markers on a dark grey image -> sub-pixel centroids, at the Cramér–Rao bound.

Stages, all vectorised over the blobs of a frame (no per-blob Python loop):

1. **Background and noise** (:func:`background_level`): the median of a 1-in-16 pixel subsample and
   the robust std ``median - 15.87th percentile`` (both interpolated within integer grey levels, and
   taken from the lower half so bright blobs do not inflate them).
2. **Coarse search**: 4x4 max-pooling (``cv2.dilate`` + stride) and a threshold
   ``level + max(6 sigma, 8)`` give candidate cells; their 8-connected groups (a 16x smaller image)
   give one patch per group, margin 4 px.
3. **Blobs**: the patches, thresholded and restricted to their own cells, are stacked in one
   small mosaic and labelled once (8-connectivity). Area, intensity-weighted centroid and second
   moments (roundness) come from ``bincount`` over the labelled pixels.
4. **Sub-pixel fit**: maximum-likelihood (Levenberg–Marquardt) fit of a blurred-disc model to the
   blob's window (blob bounding box + 3 px of skirt), saturated pixels and other blobs' pixels left
   out::

       I(x) = level + b + sum_k A_k * erfc((|x - c_k| - r_k) / (sqrt(2) s_k)) / 2

   The fit's ``sigma^2 (J^T J)^-1`` is the reported centroid covariance; on synthetic blurred discs the
   fit is unbiased (< 0.005 px) and its std is within a few % of the Cramér–Rao bound (tests), where a
   thresholded intensity-weighted centroid is 2-3x above it. A fit that fails falls back to the
   intensity-weighted centroid.
5. **Merged markers**: a blob with two or more local maxima separated by a clear saddle is split and
   fitted as that many discs jointly; a blob that is elongated (roundness below 0.7) or much larger than
   its neighbours is flagged ``merged`` but kept whole. Limits: two markers closer than about their
   radius (no saddle) stay one blob; two saturated markers joined by a saturated bridge are flagged, not
   split.

ROI mode (``rois``): only blobs whose centroid lies in one of the given boxes are measured and
reported; the coarse 4x4 pass still covers the frame (it is ~5 % of the cost) so that a blob crossing a
box edge is measured whole, exactly as a full scan measures it. Callers that track markers pass
predicted boxes and do a full scan every few frames to pick up new markers.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from scipy.spatial import cKDTree

from mocap.detections import Detections

__all__ = ["background_level", "detect", "K_SIGMA", "MIN_CONTRAST"]

K_SIGMA = 6.0  # detection threshold above the background, in noise std
MIN_CONTRAST = 8.0  # ... and never fewer grey levels than this (noise-free or black images)
CELL = 4  # coarse search cell, px
MARGIN = 4  # patch margin around a group of cells, px (the blob's skirt lies inside)
SKIRT = 2.0  # fit window reach beyond a blob's thresholded pixels, px
ROUND_MERGED = 0.7  # roundness below this (and area >= MIN_SHAPE_AREA): flagged as merged
MIN_SHAPE_AREA = 9  # px: smaller blobs are too pixelated and noisy for a shape judgement
ROUND_SPLIT = 0.85  # roundness below this: searched for two or more peaks (one round disc is ~1)
AREA_MERGED = 2.5  # area above this many times the neighbours' median: flagged as merged
MAX_DISCS = 4  # a blob is split into at most this many markers
FIT_MAX_AREA = 1000  # px: larger blobs (with a raised max_area) get the weighted centroid, not a fit
FIT_ITERATIONS = 8
STEP_TOL = 2e-4  # px: a fit stops when its centres move less (the Cramer-Rao bound is >= 0.003 px)
_SATURATED = 255
_SQRT2 = math.sqrt(2.0)
_SQRTPI = math.sqrt(math.pi)
_KERNEL = np.ones((CELL, CELL), np.uint8)
_WINDOW_HALVES = 6 * 2 ** np.arange(12)  # fit window sizes, px: few, so that few vectorised fits run


# --------------------------------------------------------------------------- background
def _quantile_from_histogram(cum: np.ndarray, q: float) -> float:
    """Quantile of integer samples treating level k as uniform on [k - 0.5, k + 0.5); ``cum``: (256,) CDF."""
    k = int(np.searchsorted(cum, q, side="right"))
    below = cum[k - 1] if k > 0 else 0.0
    width = cum[k] - below
    return k - 0.5 + (q - below) / width if width > 0 else float(k)


def background_level(image: np.ndarray) -> tuple[float, float]:
    """Robust background level and noise std of an 8-bit image.

    Args:
        image: (H, W) uint8.

    Returns:
        (level, sigma), grey levels: the median and ``median - 15.87th percentile`` of every 4th pixel
        of every 4th row, interpolated within integer levels (sigma includes the 8-bit rounding).
    """
    hist = np.bincount(image[::4, ::4].ravel(), minlength=256).astype(np.float64)
    cum = np.cumsum(hist) / hist.sum()
    level = _quantile_from_histogram(cum, 0.5)
    return level, level - _quantile_from_histogram(cum, 0.15866)


# --------------------------------------------------------------------------- coarse search
def _groups(cells: np.ndarray, roi_cells: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """8-connected groups of candidate cells.

    Returns:
        labels: (Hc, Wc) int32 group label per cell (0: none).
        boxes: (G, 5) int ``label, cx0, cy0, cx1, cy1`` inclusive cell bounds of each kept group.
    """
    n, labels = cv2.connectedComponents(cells, connectivity=8, ltype=cv2.CV_32S)
    if n <= 1:
        return labels, np.zeros((0, 5), np.int64)
    cy, cx = np.nonzero(labels)
    lab = labels[cy, cx]
    order = np.argsort(lab, kind="stable")
    lab, cy, cx = lab[order], cy[order], cx[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])
    boxes = np.stack([lab[starts], np.minimum.reduceat(cx, starts), np.minimum.reduceat(cy, starts),
                      np.maximum.reduceat(cx, starts), np.maximum.reduceat(cy, starts)], axis=1).astype(np.int64)
    if roi_cells is not None:
        boxes = boxes[np.add.reduceat(roi_cells[cy, cx].astype(np.int64), starts) > 0]
    return labels, boxes


def _roi_cells(rois: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(Hc, Wc) bool: cells touched by any box ``x0, y0, x1, y1`` (inclusive px)."""
    mask = np.zeros(shape, bool)
    for x0, y0, x1, y1 in np.asarray(rois, dtype=np.int64).reshape(-1, 4):
        mask[max(y0, 0) // CELL: max(y1, -1) // CELL + 1, max(x0, 0) // CELL: max(x1, -1) // CELL + 1] = True
    return mask


# --------------------------------------------------------------------------- labelling
class _Pixels:
    """Above-threshold pixels of every blob: blob id, x, y, grey level (sorted by blob)."""

    def __init__(self, blob: np.ndarray, x: np.ndarray, y: np.ndarray, grey: np.ndarray) -> None:
        order = np.argsort(blob, kind="stable")
        self.blob, self.x, self.y, self.grey = blob[order], x[order], y[order], grey[order]


def _label_blobs(image: np.ndarray, t: int, cell_labels: np.ndarray, boxes: np.ndarray
                 ) -> tuple[_Pixels, np.ndarray]:
    """Label the blobs of each group of cells in a stacked mosaic of patches.

    Returns:
        pixels: every blob pixel (blob ids 0..N-1); label image (H, W) int32 (blob id + 1 on blob
        pixels, 0 elsewhere).
    """
    h, w = image.shape
    side = CELL * (np.maximum(boxes[:, 3] - boxes[:, 1], boxes[:, 4] - boxes[:, 2]) + 1) + 2 * MARGIN
    bucket = np.maximum(16, 2 ** np.ceil(np.log2(side))).astype(np.int64)  # few distinct patch sizes
    label_image = np.zeros((h, w), np.int32)
    parts = []
    n_blobs = 0
    for size in np.unique(bucket):
        sel = boxes[bucket == size]
        ys = (CELL * sel[:, 2] - MARGIN)[:, None] + np.arange(size)  # (n, S)
        xs = (CELL * sel[:, 1] - MARGIN)[:, None] + np.arange(size)
        yc, xc = np.clip(ys, 0, h - 1), np.clip(xs, 0, w - 1)
        inside = ((ys >= 0) & (ys < h))[:, :, None] & ((xs >= 0) & (xs < w))[:, None, :]
        grey = image.ravel().take(yc[:, :, None] * w + xc[:, None, :])
        own = cell_labels.ravel().take((yc // CELL)[:, :, None] * cell_labels.shape[1] + (xc // CELL)[:, None, :]
                                       ) == sel[:, 0, None, None]
        mosaic = np.zeros((len(sel), size + 1, size), np.uint8)  # a blank row between patches
        mosaic[:, :size] = (grey > t) & own & inside
        n, labels = cv2.connectedComponents(mosaic.reshape(-1, size), connectivity=8, ltype=cv2.CV_32S)
        p, i, j = np.nonzero(labels.reshape(len(sel), size + 1, size))
        blob = labels.reshape(len(sel), size + 1, size)[p, i, j] - 1 + n_blobs
        parts.append((blob, xs[p, j], ys[p, i], grey[p, i, j]))
        n_blobs += n - 1
    pixels = _Pixels(*(np.concatenate(a) for a in zip(*parts, strict=True)))
    label_image[pixels.y, pixels.x] = pixels.blob + 1
    return pixels, label_image


# --------------------------------------------------------------------------- blob model fit
def _half_erfc(z: np.ndarray, e: np.ndarray) -> np.ndarray:
    """``erfc(z) / 2`` given ``e = exp(-z^2)``: Abramowitz & Stegun 7.1.26 (abs. error < 1e-7), 4x faster
    than ``scipy.special.erfc`` and reusing the exponential the Jacobian needs anyway."""
    t = 1.0 / (1.0 + 0.3275911 * np.abs(z))
    q = 0.5 * e * t * (0.254829592 + t * (-0.284496736 + t * (1.421413741 + t * (-1.453152027 + t * 1.061405429))))
    return np.where(z >= 0, q, 1.0 - q)


def _disc_model(params: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sum of blurred discs plus an offset, and its Jacobian.

    Args:
        params: (N, 1 + 5K) ``b, (cx, cy, A, r, s) * K``.
        x, y: (N, P) pixel coordinates.

    Returns:
        model (N, P) and Jacobian (N, 1 + 5K, P).
    """
    n, n_par = params.shape
    disc = params[:, 1:].reshape(n, -1, 5)  # (N, K, 5)
    cx, cy, amp, r, s = (disc[:, :, i, None] for i in range(5))  # (N, K, 1)
    dx = x[:, None, :] - cx
    dy = y[:, None, :] - cy
    rho = np.sqrt(dx * dx + dy * dy)
    z = (rho - r) * (1.0 / (_SQRT2 * s))
    e = np.exp(-z * z)
    f = _half_erfc(z, e)
    slope = (amp / (_SQRT2 * _SQRTPI * s)) * e  # -dM/drho
    unit = slope / np.maximum(rho, 1e-9)
    jac = np.empty((n, n_par, x.shape[1]))
    jac[:, 0] = 1.0
    jd = jac[:, 1:].reshape(n, -1, 5, x.shape[1])  # (N, K, 5, P) view
    np.multiply(unit, dx, out=jd[:, :, 0])
    np.multiply(unit, dy, out=jd[:, :, 1])
    jd[:, :, 2] = f
    jd[:, :, 3] = slope
    np.multiply(slope * _SQRT2, z, out=jd[:, :, 4])
    return params[:, :1] + (amp * f).sum(axis=1), jac


def _fit_discs(values: np.ndarray, x: np.ndarray, y: np.ndarray, weight: np.ndarray, saturated: np.ndarray,
               params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg–Marquardt least squares of :func:`_disc_model`, vectorised over blobs.

    Saturated pixels are censored: they only say the model reaches their value, so they pull the model
    up where it is below and count for nothing where it is above (this keeps a saturated blob's fit from
    drifting along the height/radius/blur valley that its unsaturated skirt alone leaves open).

    Args:
        values: (N, P) grey levels minus the frame's background level.
        x, y: (N, P) pixel coordinates.
        weight: (N, P) 1 for pixels in the fit, 0 for the rest.
        saturated: (N, P) bool, pixels at full scale.
        params: (N, 1 + 5K) starting parameters.

    Returns:
        params (N, 1 + 5K) and the unscaled parameter covariance ``(J^T W J)^-1`` (N, 1 + 5K, 1 + 5K).
    """
    params = params.copy()
    n, n_par = params.shape
    eye = np.eye(n_par)
    diag = np.arange(n_par)
    damping = np.full(n, 1e-3)

    def evaluate(p: np.ndarray, rows: np.ndarray | slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        model, jac = _disc_model(p, x[rows], y[rows])
        w = np.where(saturated[rows] & (model >= values[rows]), 0.0, weight[rows])
        resid = (values[rows] - model) * w
        jac *= w[:, None, :]
        return resid, jac, (resid * resid).sum(axis=1)

    resid, jac, cost = evaluate(params, slice(None))
    active = np.arange(n)  # blobs whose centre still moves by more than STEP_TOL
    for _ in range(FIT_ITERATIONS):
        j = jac[active]
        jtj = np.matmul(j, j.transpose(0, 2, 1))
        grad = np.matmul(j, resid[active][:, :, None])
        lhs = jtj + eye * (damping[active, None] * jtj[:, diag, diag] + 1e-9)[:, :, None]
        step = np.linalg.solve(lhs, grad)[:, :, 0]
        trial = params[active] + step
        trial[:, 3::5] = np.maximum(trial[:, 3::5], 1.0)  # heights
        trial[:, 4::5] = np.clip(trial[:, 4::5], 0.2, 100.0)  # radii
        trial[:, 5::5] = np.clip(trial[:, 5::5], 0.25, 5.0)  # blur
        t_resid, t_jac, t_cost = evaluate(trial, active)
        better = t_cost <= cost[active]
        upd = active[better]
        params[upd], resid[upd], jac[upd], cost[upd] = trial[better], t_resid[better], t_jac[better], t_cost[better]
        damping[active] = np.where(better, damping[active] * 0.3, damping[active] * 10.0)
        moving = np.abs(step[:, 1:].reshape(len(step), -1, 5)[:, :, :2]).max(axis=(1, 2)) > STEP_TOL
        active = active[moving | ~better]
        if len(active) == 0:
            break
    jtj = np.matmul(jac, jac.transpose(0, 2, 1))
    try:
        cov = np.linalg.inv(jtj)
    except np.linalg.LinAlgError:  # a degenerate window somewhere (e.g. every pixel saturated)
        cov = np.linalg.pinv(jtj)
    return params, cov


# --------------------------------------------------------------------------- peaks (merged markers)
def _box_mean3(image: np.ndarray, x: np.ndarray, y: np.ndarray, reach: int) -> np.ndarray:
    """3x3 box means of ``image`` on the (2 reach + 1)^2 grid around each (x, y): (N, 2 reach + 1, 2 reach + 1)."""
    h, w = image.shape
    offs = np.arange(-reach - 1, reach + 2)
    patch = image[np.clip(y[:, None, None] + offs[None, :, None], 0, h - 1),
                  np.clip(x[:, None, None] + offs[None, None, :], 0, w - 1)].astype(np.float64)
    return np.lib.stride_tricks.sliding_window_view(patch, (3, 3), axis=(1, 2)).mean(axis=(3, 4))


def _peaks(image: np.ndarray, pixels: _Pixels, level: float, sigma: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Significant local maxima of each blob's 3x3-smoothed profile.

    The highest maximum of a blob always counts; another counts when, towards every higher maximum of
    its blob, it lies 2 px or more away and the smoothed profile on the straight path dips below the
    lower of the two by more than ``max(4 sigma, 10 % of its height above the background)`` (plateaus
    and noise bumps do not count).

    Returns:
        blob (M,), x (M,), y (M,): peak positions (px), sorted by blob, highest first within a blob.
    """
    if len(pixels.blob) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    grid = _box_mean3(image, pixels.x, pixels.y, 1)  # (P, 3, 3)
    value = grid[:, 1, 1]
    idx = np.flatnonzero(value >= grid.reshape(len(value), 9).max(axis=1))
    blob, px, py, pv = pixels.blob[idx], pixels.x[idx], pixels.y[idx], value[idx]
    order = np.lexsort((-pv, blob))
    blob, px, py, pv = blob[order], px[order], py[order], pv[order]
    start = np.flatnonzero(np.r_[True, blob[1:] != blob[:-1]])
    rank = np.arange(len(blob)) - np.repeat(start, np.diff(np.r_[start, len(blob)]))  # 0: the blob's highest
    top = rank < 2 * MAX_DISCS  # the highest few maxima are enough to find up to MAX_DISCS markers
    blob, px, py, pv, rank = blob[top], px[top], py[top], pv[top], rank[top]
    # every maximum against every higher one of its blob: (i, j) pairs with rank(j) < rank(i)
    i = np.repeat(np.arange(len(blob)), rank)
    j = np.repeat(np.arange(len(blob)) - rank, rank) + (np.arange(len(i)) - np.repeat(np.cumsum(rank) - rank, rank))
    dist = np.hypot(px[i] - px[j], py[i] - py[j])
    failed = np.zeros(len(blob), bool)
    if len(i):
        steps = np.linspace(0.0, 1.0, 2 * int(np.ceil(dist.max())) + 1)
        sx = np.rint(px[i, None] + (px[j] - px[i])[:, None] * steps).astype(np.int64)
        sy = np.rint(py[i, None] + (py[j] - py[i])[:, None] * steps).astype(np.int64)
        path = _box_mean3(image, sx.ravel(), sy.ravel(), 0).reshape(sx.shape)
        dip = np.minimum(pv[i], pv[j]) - path.min(axis=1)
        bad = (dip <= np.maximum(4.0 * sigma, 0.1 * (pv[i] - level))) | (dist < 2.0)
        failed = np.bincount(i[bad], minlength=len(blob)) > 0
    significant = ~failed
    return blob[significant], px[significant].astype(np.float64), py[significant].astype(np.float64)


# --------------------------------------------------------------------------- main entry
class _Blobs:
    """Per-blob sums over the thresholded pixels (blob ids 0..N-1, each with at least one pixel).

    Attributes:
        area: (N,) pixel count; centroid: (N, 2) intensity-weighted, px; second: (N, 2, 2) weighted
        second moments, px^2; centroid_cov: (N, 2, 2) noise covariance of that centroid per unit noise
        variance; peak: (N,) highest grey level; radius: (N,) radius of the area above half the peak, px;
        reach: (N,) farthest pixel from the centroid, px.
    """

    def __init__(self, pixels: _Pixels, level: float) -> None:
        b = pixels.blob
        starts = np.flatnonzero(np.r_[True, b[1:] != b[:-1]])
        x, y = pixels.x.astype(np.float64), pixels.y.astype(np.float64)
        wgt = np.maximum(pixels.grey - level, 1e-6)
        self.area = np.diff(np.r_[starts, len(b)]).astype(np.float64)
        m0 = np.add.reduceat(wgt, starts)
        self.centroid = np.stack([np.add.reduceat(wgt * x, starts), np.add.reduceat(wgt * y, starts)], 1) / m0[:, None]
        dx, dy = x - self.centroid[b, 0], y - self.centroid[b, 1]
        sums = np.stack([np.add.reduceat(v, starts) for v in (wgt * dx * dx, wgt * dx * dy, wgt * dy * dy,
                                                               dx * dx, dx * dy, dy * dy)], axis=1)
        self.second = sums[:, [0, 1, 1, 2]].reshape(-1, 2, 2) / m0[:, None, None]
        self.centroid_cov = sums[:, [3, 4, 4, 5]].reshape(-1, 2, 2) / (m0**2)[:, None, None]
        self.peak = np.maximum.reduceat(pixels.grey, starts).astype(np.float64)
        half_max = np.add.reduceat((pixels.grey - level > 0.5 * (self.peak - level)[b]).astype(np.float64), starts)
        self.radius = np.sqrt(half_max / np.pi)
        self.reach = np.sqrt(np.maximum.reduceat(dx * dx + dy * dy, starts))


def _neighbour_median_area(xy: np.ndarray, area: np.ndarray, k: int = 5) -> np.ndarray:
    """(N,) median area of each blob's k nearest other blobs (inf with fewer than 2 others)."""
    if len(xy) < 3:
        return np.full(len(xy), np.inf)
    k = min(k, len(xy) - 1)
    _, nn = cKDTree(xy).query(xy, k + 1)
    return np.median(area[nn[:, 1:]], axis=1)


def _window(centre: np.ndarray, radius: np.ndarray, half: int, image: np.ndarray, label_image: np.ndarray,
            own: np.ndarray, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Round fit windows: pixels within ``radius`` (N,) px of each ``centre`` (N, 2), padded to ``half`` px.

    Returns:
        x, y, grey, weight, saturated, each (N, P). Weight is 0 beyond the radius, off the image and on
        other blobs' above-threshold pixels.
    """
    h, w = image.shape
    dy, dx = np.mgrid[-half: half + 1, -half: half + 1].reshape(2, -1)
    round_ = dx * dx + dy * dy <= (half + 0.5) ** 2
    dx, dy = dx[round_], dy[round_]
    xs = np.rint(centre[:, 0]).astype(np.int64)[:, None] + dx
    ys = np.rint(centre[:, 1]).astype(np.int64)[:, None] + dy
    xc, yc = np.clip(xs, 0, w - 1), np.clip(ys, 0, h - 1)
    flat = yc * w + xc
    grey = image.ravel().take(flat)
    x, y = xs.astype(np.float64), ys.astype(np.float64)
    usable = ((xs == xc) & (ys == yc) & ((grey <= t) | (label_image.ravel().take(flat) == own[:, None] + 1))
              & ((x - centre[:, :1]) ** 2 + (y - centre[:, 1:]) ** 2 <= (radius * radius)[:, None]))
    return x, y, grey.astype(np.float64), usable.astype(np.float64), grey >= _SATURATED


def _disc_starts(blobs: np.ndarray, k: int, peaks: tuple[np.ndarray, np.ndarray, np.ndarray], stats: _Blobs,
                 level: float) -> np.ndarray:
    """(N, 1 + 5k) starting parameters: offset 0; per disc: centre, height, radius, blur 0.6 px."""
    n = len(blobs)
    start = np.zeros((n, 1 + 5 * k))
    disc = start[:, 1:].reshape(n, k, 5)
    if k == 1:
        disc[:, 0, :2] = stats.centroid[blobs]
    else:
        pk_blob, pk_x, pk_y = peaks
        take = np.searchsorted(pk_blob, blobs)[:, None] + np.arange(k)
        disc[:, :, 0] = pk_x[take]
        disc[:, :, 1] = pk_y[take]
    height = stats.peak[blobs] - level
    disc[:, :, 2] = np.where(stats.peak[blobs] >= _SATURATED, 1.3 * height, np.maximum(height, 1.0))[:, None]
    disc[:, :, 3] = np.maximum(stats.radius[blobs] / math.sqrt(k), 0.5)[:, None]
    disc[:, :, 4] = 0.6
    return start


def _measure(image: np.ndarray, label_image: np.ndarray, blobs: np.ndarray, k: int, radius: np.ndarray, half: int,
             peaks: tuple[np.ndarray, np.ndarray, np.ndarray], stats: _Blobs, level: float, sigma: float, t: int
             ) -> tuple[np.ndarray, np.ndarray]:
    """Fit ``k`` discs to each blob in ``blobs`` (N,) on the pixels within ``radius`` (N,) px of its
    centroid (``half`` >= every radius).

    Returns:
        centres (N, k, 2) px and their covariances (N, k, 2, 2) px^2. A fit that fails (not finite, or a
        centre that wandered more than max(1.5 px, its radius) from its start) falls back to the start:
        the weighted centroid (k = 1) or the peaks (k > 1), with the centroid's noise covariance.
    """
    n = len(blobs)
    x, y, grey, weight, saturated = _window(stats.centroid[blobs], radius, half, image, label_image, blobs, t)
    start = _disc_starts(blobs, k, peaks, stats, level)
    params, pcov = _fit_discs(grey - level, x, y, weight, saturated, start)
    disc = params[:, 1:].reshape(n, k, 5)
    centres = disc[:, :, :2]
    pos = 1 + 5 * np.arange(k)[:, None] + np.arange(2)  # (k, 2) parameter indices of each centre
    cov = pcov[np.arange(n)[:, None, None, None], pos[None, :, :, None], pos[None, :, None, :]] * sigma**2
    start_xy = start[:, 1:].reshape(n, k, 5)[:, :, :2]
    bad = (~np.isfinite(centres).all(axis=2) | ~np.isfinite(cov).all(axis=(2, 3))
           | (np.hypot(*(centres - start_xy).transpose(2, 0, 1)) > np.maximum(1.5, disc[:, :, 3])))
    fallback_cov = stats.centroid_cov[blobs][:, None] * sigma**2 + np.eye(2) * (0.25 if k > 1 else 0.0)
    return (np.where(bad[:, :, None], start_xy, centres),
            np.where(bad[:, :, None, None], fallback_cov, cov))


def detect(image: np.ndarray, *, threshold: float | None = None, min_area: int = 2, max_area: int = 1000,
           rois: np.ndarray | None = None, noise_sigma: float | None = None, refine: str = "fit") -> Detections:
    """Find bright blobs and measure their sub-pixel centres.

    Args:
        image: (H, W) uint8 grey image (bright markers, dark background).
        threshold: grey level a blob pixel must exceed; default ``level + max(6 sigma, 8)`` from
            :func:`background_level`.
        min_area: fewest pixels above the threshold for a blob (2 rejects single hot pixels).
        max_area: most pixels above the threshold (larger blobs are reflections or lamps, dropped).
        rois: optional (K, 4) int boxes ``x0, y0, x1, y1`` (px, inclusive): report only blobs whose
            centroid lies in a box.
        noise_sigma: the image noise std, grey levels, if known (else estimated from the image).
        refine: "fit" (maximum-likelihood disc fit, at the Cramér–Rao bound, splits merged markers) or
            "centroid" (the intensity-weighted centroid of the thresholded pixels: several times faster,
            2-3x the noise of the fit, merged blobs flagged but not split). Blobs larger than
            ``FIT_MAX_AREA`` always get the centroid.

    Returns:
        :class:`Detections`: centroids (distorted px), area (px above threshold; the parts of a split
        blob share it equally), roundness, centroid covariance (px^2) and the merged flag.
    """
    image = np.ascontiguousarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"detect needs an (H, W) uint8 image, got {image.dtype} {image.shape}")
    level, sigma = background_level(image)
    if noise_sigma is not None:
        sigma = float(noise_sigma)
    t = max(0, math.floor(threshold if threshold is not None else level + max(K_SIGMA * sigma, MIN_CONTRAST)))
    if t >= _SATURATED or (rois is not None and len(rois) == 0):
        return Detections.empty()
    cells = (cv2.dilate(image, _KERNEL, anchor=(0, 0))[::CELL, ::CELL] > t).astype(np.uint8)
    cell_labels, boxes = _groups(cells, None if rois is None else _roi_cells(rois, cells.shape))
    if len(boxes) == 0:
        return Detections.empty()
    pixels, label_image = _label_blobs(image, t, cell_labels, boxes)
    stats = _Blobs(pixels, level)
    keep = (stats.area >= min_area) & (stats.area <= max_area)
    if rois is not None:
        r = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
        c = stats.centroid[:, None, :]
        keep &= ((c[..., 0] >= r[:, 0]) & (c[..., 0] <= r[:, 2]) & (c[..., 1] >= r[:, 1])
                 & (c[..., 1] <= r[:, 3])).any(axis=1)
    ids = np.flatnonzero(keep)
    if len(ids) == 0:
        return Detections.empty()
    evals = np.linalg.eigvalsh(stats.second[ids])
    roundness = np.sqrt(np.clip(evals[:, 0], 0, None) / np.maximum(evals[:, 1], 1e-12))
    too_big = stats.area[ids] > AREA_MERGED * _neighbour_median_area(stats.centroid[ids], stats.area[ids])
    elongated = roundness < ROUND_SPLIT
    flagged = too_big | ((roundness < ROUND_MERGED) & (stats.area[ids] >= MIN_SHAPE_AREA))
    if refine not in ("fit", "centroid"):
        raise ValueError(f"refine must be 'fit' or 'centroid', got {refine!r}")
    fit = stats.area[ids] <= FIT_MAX_AREA if refine == "fit" else np.zeros(len(ids), bool)
    xy, cov, part = [stats.centroid[ids[~fit]]], [stats.centroid_cov[ids[~fit]] * sigma**2], [np.flatnonzero(~fit)]

    # two markers side by side make an elongated (or oversized) blob: look for their peaks there
    candidates = ids[fit & (elongated | too_big)]
    sel = np.isin(pixels.blob, candidates)
    peaks = _peaks(image, _Pixels(pixels.blob[sel], pixels.x[sel], pixels.y[sel], pixels.grey[sel]), level, sigma)
    n_discs = np.clip(np.bincount(peaks[0], minlength=len(stats.area))[ids], 1, MAX_DISCS)
    radius = stats.reach[ids] + SKIRT
    half = _WINDOW_HALVES[np.searchsorted(_WINDOW_HALVES, radius)]  # a few window sizes
    for k in np.unique(n_discs[fit]):
        for hh in np.unique(half[fit & (n_discs == k)]):
            group = np.flatnonzero(fit & (n_discs == k) & (half == hh))
            centres, covs = _measure(image, label_image, ids[group], int(k), radius[group], int(hh), peaks, stats,
                                     level, sigma, t)
            xy.append(centres.reshape(-1, 2))
            cov.append(covs.reshape(-1, 2, 2))
            part.append(np.repeat(group, k))
    part = np.concatenate(part)
    return Detections(np.concatenate(xy), stats.area[ids][part] / n_discs[part], roundness[part],
                      np.concatenate(cov), flagged[part] | (n_discs[part] > 1))
