"""Blob detection: bright markers on a dark grey image -> sub-pixel centroids, at the Cramér–Rao bound.

Stages, all vectorised over the blobs of a frame (no per-blob Python loop); with numba installed
(:data:`mocap.kernels.HAVE_NUMBA`) each runs as one compiled call (:mod:`mocap.detect_kernels`: the coarse pass,
the labelling by flood fill in each group of cells, the per-blob sums, the peaks, the fit windows and the fit) with
the same blobs, pixels and order as the numpy path here, which stays the reference and the fallback:

1. **Background and noise** (:func:`background_level`): the median of a 1-in-16 pixel subsample and
   the robust std ``median - 15.87th percentile`` (both interpolated within integer grey levels, and
   taken from the lower half so bright blobs do not inflate them). A frame whose 64 px tiles disagree on the
   background level (ambient light) is made level by their medians first (:func:`flattened_background`).
2. **Coarse search**: 4x4 max-pooling (``cv2.dilate`` + stride) and a threshold
   ``level + max(6 sigma, 8)`` give candidate cells; their 8-connected groups (a 16x smaller image)
   give one patch per group, margin 4 px. Markers too faint for that threshold (heavy sensor noise, soft optics)
   are looked for the same way in the 3x3 mean image, whose noise is a third (measured on it), at its own
   ``level + max(6 sigma, 8)``; each pixel is held to its brightest neighbour's level first, so that a lone hot
   pixel adds nothing. A blob found there that holds no pixel of a blob found in the raw image is added, its
   pixels carrying their raw grey levels, its fit window a pixel wider, and a fallback to its thresholded centroid
   reported as known to its 3x3 box (9/12 px^2 per axis). At the default realism (noise 2, blur 0.5 px) it changed
   no figure of the rendered takes. Over a camera's stream (:class:`StreamDetector`, the reconstruction's) it runs
   only where it can find a marker: while it keeps finding some, where the raw threshold finds fewer blobs than in
   the frame before, and every 4th frame.
3. **Blobs**: the patches, thresholded and restricted to their own cells, are stacked in one
   small mosaic and labelled once (8-connectivity). Area, intensity-weighted centroid and second
   moments (roundness) come from ``bincount`` over the labelled pixels.
4. **Sub-pixel fit**: least-squares (maximum-likelihood under Gaussian noise) fit of a blurred-disc
   model to a round window around the blob (its farthest pixel + 2 px of skirt), saturated pixels and
   other blobs' pixels left out::

       I(x) = level + b + sum_k A_k * E(r_k - |x - c_k|; s_k, direction of x - c_k)

   ``E`` is the disc's edge as a square pixel sees it: a straight edge blurred by a Gaussian of std ``s``
   (the optics) and integrated over the pixel, whose footprint across the edge is a trapezoid that depends
   on the edge's direction (closed form from two tabulated antiderivatives of the Gaussian CDF). Two
   Gauss–Newton steps from the intensity-weighted centroid (six for split blobs); a saturated blob starts
   from the height and radius its half-height and saturated areas imply. All blobs with as many discs are
   fitted at once, their windows' usable pixels one after another in flat float32 arrays (no padding; the
   normal equations are segmented sums): the per-call overhead of numpy, not arithmetic, is what costs
   here. The last step's ``sigma^2 (J^T J)^-1`` is the reported centroid covariance. On rendered blurred
   discs the fit is unbiased (< 0.002 px) and its std is within ~10 % of the Cramér–Rao bound (tests),
   where a thresholded intensity-weighted centroid is 2-3x above it. Hard-edged discs (no optical blur,
   area-sampled: another renderer's) are measured as well as the least-squares fit allows, 1.4-2x closer
   than with a Gaussian edge (test). A fit that fails falls back to the intensity-weighted centroid.
5. **Merged markers**: a blob with two or more local maxima separated by a clear saddle is split and
   fitted as that many discs jointly; a blob that is elongated (roundness below 0.7) or much larger than
   its neighbours is flagged ``merged`` but kept whole. The parts of a split blob are not flagged (each is a
   fitted disc), unless a part holds more light than 1.25x the markers nearby (three markers found as two).
   Limits: two markers closer than about their radius (no saddle) stay one blob; two saturated markers joined
   by a saturated bridge are flagged, not split. A tracker that knows where its markers will be passes them as
   ``seeds``: a flagged blob holding two or more of them is fitted as that many discs started there (kept only
   if every disc's fit succeeds), so such a pair is measured after all.

6. **Partly hidden markers** (off by default: ``CUT_FIT``): a limb passing in front of a marker hides part of its
   disc, and the centroid (and a whole disc's fit) slides up to 0.42 radius toward the part in view. A single disc of
   ``CUT_MIN_AREA`` px or more whose fit misfits (reduced chi-square against the noise plus 1 % of its height, over
   the frame's median, above ``MISFIT_CUT``), or that is flagged merged for its shape, is fitted again as a disc cut
   by a straight edge (:mod:`mocap.cutdisc`). Where that fit explains the blob (its misfit within ``CUT_ACCEPT``
   times the frame's and ``CUT_GAIN`` times the same model's whole disc's, its blur within ``CUT_BLUR`` times the
   frame's discs', 0.3-0.88 of the disc in view, the centre known to ``CUT_MAX_STD`` px), the blob is reported at the
   cut disc's centre, with its covariance (x ``CUT_COV_SCALE``), flagged ``cut`` and not merged for its shape; its
   area, light and roundness stay those of the part in view. On rendered cut discs of 9 px or more the centres come
   out 0.02-0.06 px rms off (0.4-0.55 px as whole discs); blobs of 7-8 px get the cut disc's centre (0.13 px rms off,
   0.52 before, some to 1.2 px) but not the flag; on smaller ones the fit finds the cut's side too seldom. Two
   markers merged into one round blob are not taken for a cut one (too much blur, or too little of the disc in view),
   nor are a renderer's hard-edged whole discs, which a disc fit misfits (the cut would leave over 0.88 of them in
   view).

ROI mode (``rois``): only blobs whose centroid lies in one of the given boxes are measured and
reported; the coarse 4x4 pass still covers the frame (it is ~5 % of the cost) so that a blob crossing a
box edge is measured whole, exactly as a full scan measures it. Callers that track markers pass
predicted boxes and do a full scan every few frames to pick up new markers.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from scipy import special
from scipy.spatial import cKDTree

from mocap import cutdisc, detect_kernels, kernels
from mocap.detections import Detections, floored_covariance

__all__ = ["background_level", "detect", "flattened_background", "StreamDetector", "K_SIGMA", "MIN_CONTRAST"]

MIN_AREA = 2  # px above the threshold: fewer is a hot pixel (detect's default)
MAX_AREA = 1000  # px: more is a reflection or a lamp (detect's default)
K_SIGMA = 6.0  # detection threshold above the background, in noise std
MIN_CONTRAST = 8.0  # ... and never fewer grey levels than this (noise-free or black images)
CELL = 4  # coarse search cell, px
MARGIN = 4  # patch margin around a group of cells, px (the blob's skirt lies inside)
SKIRT = 2.0  # fit window reach beyond a blob's thresholded pixels, px
ROUND_MERGED = 0.7  # roundness below this (and area >= MIN_SHAPE_AREA): flagged as merged
MIN_SHAPE_AREA = 9  # px: smaller blobs are too pixelated and noisy for a shape judgement
ROUND_SPLIT = 0.85  # roundness below this: searched for two or more peaks (one round disc is ~1)
AREA_MERGED = 2.5  # area above this many times the neighbours' median: flagged as merged
MAX_DISCS = 8  # a blob is split into at most this many markers
SPLIT_PART_FLUX = 1.25  # a split blob's parts brighter (summed) than this times their neighbours' median: merged
CUT_FIT = False  # the cut disc refit below, off by default: on the whole sprint (seed 0) it doubled the switches
#   (36 -> 76) and made an 11.8 mm sample, not yet understood (docs/engine-log.md, eighty-first session)
MISFIT_CUT = 2.0  # a single disc whose fit misfits this many times the frame's median (floored at 1), or that is
#   flagged merged for its shape (not its size: a cut disc is smaller), is refitted as a disc cut by an edge
#   (:mod:`mocap.cutdisc`) ...
CUT_ACCEPT = 2.0  # ... and measured so where that fit misfits at most this many times the frame's median
CUT_GAIN = 0.6  # ... and at most this times as much as the same model's whole disc
CUT_MAX_STD = 0.5  # px: ... and places its centre to within this (std along the worst axis)
CUT_MIN_AREA = 7  # px: smaller blobs are not refitted (too few pixels to tell a cut's side); those under
#   MIN_SHAPE_AREA get the cut disc's centre but not the cut flag (0.13 px rms off, not trusted as a clean view)
CUT_COV_SCALE = 2.0  # the cut fit's covariance, scaled: its errors on rendered cut discs of 9 px or more are 1.3-1.5x
#   its std (the straight-edge model of the disc's rim, the cut's side and depth found from few pixels)
CUT_MIN_VISIBLE = 0.3  # ... and leaves at least this share of its disc in view (a bright disc's sliver, widely
#   blurred, can mimic two markers merged) and at most this (more: a whole disc, its fit kept)
CUT_MAX_VISIBLE = 0.88
CUT_BLUR = 1.35  # ... and blurs its edges at most this many times as much as the frame's whole discs' fits (two
#   markers merged into one round blob pass for a disc blurred more)
MISFIT_MODEL_ERROR = 0.01  # of a disc's height: the model error a disc fit's misfit allows per pixel
FIT_MAX_AREA = 1000  # px: larger blobs (with a raised max_area) get the weighted centroid, not a fit
FIT_ITERATIONS = 2  # Gauss-Newton steps for a single disc (from the weighted centroid)
SPLIT_ITERATIONS = 6  # ... for two or more discs fitted jointly (from the peaks)
DAMPING = 1e-2  # Levenberg-style relative damping of every Gauss-Newton step but the last
MAX_STEP = 1.0  # px: a centre moves at most this far per step
FIT_VAGUE = 3.0  # a fit whose std exceeds this many times the weighted centroid's, or whose covariance is
#   not positive semi-definite, is ill-posed: it falls back to the weighted centroid
FALLBACK_PIXEL_VAR = 1.0 / 12.0  # px^2 per axis in a single disc's weighted centroid's covariance besides its noise:
#   the thresholded centroid of a faint marker a few pixels across (in noise and blur) misses its sub-threshold
#   skirt, so it is known to about a pixel (uniform over one: 1/12 px^2). The vague test compares a fit with it,
#   and a fallback reports it
FAINT_PIXEL_VAR = 9.0 / 12.0  # px^2 per axis: ... and a faint blob's, thresholded in the 3x3 mean image, to its box
BACKGROUND_TILE = 64  # px: a frame whose tiles this size differ in background level is made level by their medians
_SATURATED = 255
_START_BLUR = 0.5  # px: the edge blur a fit starts from
# a saturated disc of height A: the gap between its half-full-scale and saturated edges, in units of the blur,
# is ndtri(F / A) - ndtri(F / 2A) (F = full scale above the background); tabulated against F / A
_HALF_RATIO = np.linspace(0.2, 0.999, 256)  # (a start at most 5x full scale: pixel counts are coarse)
_HALF_GAP = special.ndtri(_HALF_RATIO) - special.ndtri(0.5 * _HALF_RATIO)
_BRUTE_FORCE_NEIGHBOURS = 300  # blobs: up to this many, nearest neighbours from all pairwise distances
# bounds of each disc's (cx, cy, A, r, s) after every step, and of the step itself
_PARAM_LOW = np.array([-np.inf, -np.inf, 1.0, 0.2, 0.15], np.float32)
_PARAM_HIGH = np.array([np.inf, np.inf, np.inf, 100.0, 5.0], np.float32)
_STEP_BOUND = np.array([MAX_STEP, MAX_STEP, np.inf, np.inf, np.inf], np.float32)
_BOUNDS_F64 = tuple(b.astype(np.float64) for b in (_STEP_BOUND, _PARAM_LOW, _PARAM_HIGH))  # the compiled fit's
# The disc edge seen by a square pixel: a straight edge blurred by a Gaussian of std s, integrated over the
# pixel, whose footprint across the edge (normal (a, b) = |cos|, |sin| of its direction) is the trapezoid
# box(a) * box(b). With d = r - rho the pixel centre's depth inside the edge and p, q = (a + b) / 2, |a - b| / 2:
#     E(d) = [d > 0] + s^2 / (a b) * sum_i sign_i T(z_i),   z_i = (d + p, d + q, d - q, d - p) / s, signs + - - +
# where T is H(z) = ((z^2 + 1) Phi(z) + z phi(z)) / 2 (the second antiderivative of the Gaussian CDF) outside
# the edge and H(z) - (z^2 + 1) / 2 inside it (the same second difference, small numbers on both sides).
# Both halves are tabulated at z = -_Z_MAX ... _Z_MAX and read with linear interpolation; T' (the slope)
# is the table's difference quotient.
_Z_RES = 1024
_Z_MAX = 13.0  # >= 8 + max(p) / _PARAM_LOW[s]: a pixel's four z values never leave the table's live part
_Z_TABLE = np.arange(-_Z_MAX * _Z_RES, _Z_MAX * _Z_RES + 1) / _Z_RES
_H = 0.5 * ((_Z_TABLE**2 + 1) * special.ndtr(_Z_TABLE) + _Z_TABLE * np.exp(-0.5 * _Z_TABLE**2) / math.sqrt(2 * math.pi))
_EDGE_TABLES = np.concatenate([_H, _H - 0.5 * (_Z_TABLE**2 + 1)])  # outside, inside halves
_EDGE_STEPS = np.append(np.diff(_EDGE_TABLES), 0.0)  # T[i + 1] - T[i]
_EDGE_TABLES, _EDGE_STEPS = (np.where(np.abs(t) < 1e-12, 0.0, t).astype(np.float32)  # (tails that matter nowhere,
                             for t in (_EDGE_TABLES, _EDGE_STEPS))  # zeroed: no slow float32 denormals in products)
_Z_ORIGIN = _Z_MAX * _Z_RES  # table index of z = 0
_Z_LAST = 2 * _Z_ORIGIN - 0.01  # highest interpolation position inside one half
_MIN_FOOTPRINT = 0.1  # px: a and b are at least this (a box this narrow changes the edge by < 1e-3 px^2)
_ROW_KERNEL = np.ones((1, CELL), np.uint8)
_RING_3 = np.array([[1, 1, 1], [1, 0, 1], [1, 1, 1]], np.uint8)  # a pixel's 8 neighbours
_WINDOW_HALVES = 6 * 2 ** np.arange(12)  # sizes of the cached window templates, px


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
    if kernels.HAVE_NUMBA:
        hist = detect_kernels.subsampled_histogram(image, 4)
    else:
        hist = cv2.calcHist([np.ascontiguousarray(image[::4, ::4])], [0], None, [256], [0, 256]).ravel().astype(
            np.float64)
    cum = np.cumsum(hist) / hist.sum()
    level = _quantile_from_histogram(cum, 0.5)
    return level, level - _quantile_from_histogram(cum, 0.15866)


@functools.lru_cache(maxsize=8)
def _tile_index(shape: tuple[int, int], step: int) -> tuple[np.ndarray, int, int]:
    """Each pixel of a frame's subsample (every ``step``-th pixel of every ``step``-th row): its ``BACKGROUND_TILE``
    tile's index times 256, (h, w) int64; and the tiles down and across."""
    h, w = -(-shape[0] // step), -(-shape[1] // step)
    side = BACKGROUND_TILE // step
    ty, tx = -(-h // side), -(-w // side)
    return 256 * ((np.arange(h) // side)[:, None] * tx + (np.arange(w) // side)[None, :]), ty, tx


def _tile_medians(image: np.ndarray, step: int) -> tuple[np.ndarray, float]:
    """(ty, tx) float32 median of each ``BACKGROUND_TILE`` px tile's subsample (every ``step``-th pixel of every
    ``step``-th row), and the median over tiles of ``median - 15.87th percentile`` (the noise std, unswayed by a
    slope across the frame), grey levels."""
    if kernels.HAVE_NUMBA:
        medians, low = detect_kernels.tile_quantiles(image, step, BACKGROUND_TILE // step, 0.15866)
        return medians.astype(np.float32), float(np.median(medians - low))
    index, ty, tx = _tile_index(image.shape, step)
    cum = np.cumsum(np.bincount((index + image[::step, ::step]).ravel(), minlength=ty * tx * 256).reshape(-1, 256),
                    axis=1)
    medians = np.argmax(cum >= 0.5 * cum[:, -1:], axis=1)
    low = np.argmax(cum >= 0.15866 * cum[:, -1:], axis=1)
    return medians.astype(np.float32).reshape(ty, tx), float(np.median(medians - low))


def flattened_background(image: np.ndarray) -> np.ndarray | None:
    """The image with its background made level, or None when it is level already (its tiles' medians, from every
    8th pixel of every 8th row, within ``max(4 sigma, 8)`` grey levels of each other). Made level: minus the
    bilinear surface through the medians of its ``BACKGROUND_TILE`` px tiles (every 4th pixel of every 4th row),
    plus their median; saturated pixels stay saturated. For ambient light or a lit wall, where one threshold for
    the whole frame would swallow the bright side and miss markers on the dark one. (H, W) uint8 -> (H, W) uint8."""
    medians, sigma = _tile_medians(image, 8)
    if medians.max() - medians.min() <= max(4.0 * sigma, MIN_CONTRAST):
        return None
    medians = _tile_medians(image, 4)[0]
    surface = cv2.resize(medians, (image.shape[1], image.shape[0]), interpolation=cv2.INTER_LINEAR)
    flat = np.clip(np.rint(image - surface + np.median(medians)), 0, _SATURATED - 1).astype(np.uint8)
    return np.where(image >= _SATURATED, image, flat)


# --------------------------------------------------------------------------- coarse search
def _max_pool(image: np.ndarray) -> np.ndarray:
    """(ceil(H / CELL), W) uint8: the maximum over each cell's rows; column ``CELL * j`` of it holds the maximum of
    cell j (the rows' maxima ``CELL`` wide to the right). One pass over the frame, a quarter-size result."""
    rows = [image[i::CELL] for i in range(CELL)]
    rows = [r if len(r) == len(rows[0]) else np.vstack([r, rows[0][len(r):]]) for r in rows]  # H not a multiple
    pooled = functools.reduce(cv2.max, rows)
    return cv2.dilate(pooled, _ROW_KERNEL, anchor=(0, 0))


def _groups(image: np.ndarray, t: int, rois: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """8-connected groups of the cells holding a pixel brighter than ``t`` (those touching one of ``rois`` if given).

    Returns:
        labels: (Hc, Wc) int32 group label per cell (0: none).
        boxes: (G, 5) int ``label, cx0, cy0, cx1, cy1`` inclusive cell bounds of each kept group.
    """
    if kernels.HAVE_NUMBA:
        labels, boxes = detect_kernels.coarse_groups(image, t, CELL)
    else:  # Grana's algorithm: 3x faster here than OpenCV's default with statistics on one thread
        cells = (_max_pool(image)[:, ::CELL] > t).astype(np.uint8)
        n, labels, stats, _ = cv2.connectedComponentsWithStatsWithAlgorithm(cells, 8, cv2.CV_32S, cv2.CCL_GRANA)
        cy, cx = np.indices(labels.shape)
        labels, new = _renumbered(labels, n, (cy // 2) * labels.shape[1] + cx // 2)  # (OpenCV's order: threads')
        left, top, width, height = stats[1:, :4].astype(np.int64)[np.argsort(new[1:])].T
        boxes = np.stack([np.arange(1, n), left, top, left + width - 1, top + height - 1], axis=1)
    if rois is not None:
        boxes = boxes[np.bincount(labels[_roi_cells(rois, labels.shape)], minlength=len(boxes) + 1)[1:] > 0]
    return labels, boxes


def _renumbered(labels: np.ndarray, n: int, key: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Connected-component ``labels`` (H, W) (0 and 1..n-1) renumbered in the order of each label's smallest
    ``key`` (H, W) int (default: its first pixel in raster order), whatever order OpenCV's algorithm and threads
    gave; and the renumbering (n,) old -> new label."""
    flat = labels.ravel()
    at = np.flatnonzero(flat)
    if key is not None:
        at = at[np.argsort(key.ravel()[at], kind="stable")]
    _, first = np.unique(flat[at], return_index=True)  # labels 1..n-1: where each comes first in key order
    new = np.zeros(n, np.int32)
    new[1 + np.argsort(first, kind="stable")] = np.arange(1, n, dtype=np.int32)
    return new[labels], new


def _roi_cells(rois: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(Hc, Wc) bool: cells touched by any box ``x0, y0, x1, y1`` (inclusive px)."""
    mask = np.zeros(shape, bool)
    for x0, y0, x1, y1 in np.asarray(rois, dtype=np.int64).reshape(-1, 4):
        mask[max(y0, 0) // CELL: max(y1, -1) // CELL + 1, max(x0, 0) // CELL: max(x1, -1) // CELL + 1] = True
    return mask


# --------------------------------------------------------------------------- labelling
class _Pixels:
    """Above-threshold pixels of every blob: blob id, x, y, grey level (sorted by blob)."""

    def __init__(self, blob: np.ndarray, x: np.ndarray, y: np.ndarray, grey: np.ndarray, presorted: bool = False
                 ) -> None:
        order = slice(None) if presorted else np.argsort(blob, kind="stable")
        self.blob, self.x, self.y, self.grey = blob[order], x[order], y[order], grey[order]


class _Owners:
    """Which blob owns a pixel, from the labelled patches (no frame-sized label image).

    Attributes:
        labels: (L,) int32, every patch's labels (0: no blob), patches one after another; each blob's patch
        starts at ``base`` (N,), has its top-left pixel at ``x0``, ``y0`` (N,), ``width`` columns and ``height``
        rows (N,); ``local`` (N,) is the blob's label there.
    """

    def __init__(self, labels: np.ndarray, base: np.ndarray, x0: np.ndarray, y0: np.ndarray, width: np.ndarray,
                 height: np.ndarray, local: np.ndarray) -> None:
        self.labels, self.base, self.x0, self.y0, self.local = labels, base, x0, y0, local
        self.width, self.height = width, height

    def owns(self, blobs: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """(T,) bool: pixel (x, y) (T,) int belongs to blob ``blobs`` (T,)."""
        width, height = self.width[blobs], self.height[blobs]
        rx, ry = x - self.x0[blobs], y - self.y0[blobs]
        inside = (rx >= 0) & (ry >= 0) & (rx < width) & (ry < height)
        index = self.base[blobs] + np.minimum(np.maximum(ry, 0), height - 1) * width + np.minimum(
            np.maximum(rx, 0), width - 1)
        return inside & (self.labels.take(index) == self.local[blobs])


def _label_blobs(image: np.ndarray, t: int, cell_labels: np.ndarray, boxes: np.ndarray
                 ) -> tuple[_Pixels, _Owners, np.ndarray]:
    """Label the blobs of each group of cells in a stacked mosaic of patches (compiled: by flood fill in each
    group's box, the same blobs in the same order).

    Returns:
        pixels: every blob pixel (blob ids 0..N-1); owners: which blob owns a pixel; starts (N,): each blob's
        first pixel.
    """
    h, w = image.shape
    side = CELL * (np.maximum(boxes[:, 3] - boxes[:, 1], boxes[:, 4] - boxes[:, 2]) + 1) + 2 * MARGIN
    bucket = np.maximum(16, 2 ** np.ceil(np.log2(side))).astype(np.int64)  # few distinct patch sizes
    if kernels.HAVE_NUMBA:
        starts, x, y, grey, *owners = detect_kernels.label_blobs(
            image, t, kernels.contiguous(cell_labels, np.int32), kernels.contiguous(
                boxes[np.argsort(bucket, kind="stable")], np.int64), CELL)
        blob = np.repeat(np.arange(len(starts) - 1), np.diff(starts))
        return _Pixels(blob, x, y, grey, presorted=True), _Owners(*owners), starts[:-1]
    parts, owners = [], []
    n_blobs = n_labels = 0
    for size in np.unique(bucket):
        sel = boxes[bucket == size]
        ys = (CELL * sel[:, 2] - MARGIN)[:, None] + np.arange(size)  # (n, S)
        xs = (CELL * sel[:, 1] - MARGIN)[:, None] + np.arange(size)
        yc, xc = np.minimum(np.maximum(ys, 0), h - 1), np.minimum(np.maximum(xs, 0), w - 1)
        inside = ((ys >= 0) & (ys < h))[:, :, None] & ((xs >= 0) & (xs < w))[:, None, :]
        grey = image.ravel().take(yc[:, :, None] * w + xc[:, None, :])
        own = cell_labels.ravel().take((yc // CELL)[:, :, None] * cell_labels.shape[1] + (xc // CELL)[:, None, :]
                                       ) == sel[:, 0, None, None]
        mosaic = np.zeros((len(sel), size + 1, size), np.uint8)  # a blank row between patches
        mosaic[:, :size] = (grey > t) & own & inside
        n, labels = cv2.connectedComponents(mosaic.reshape(-1, size), connectivity=8, ltype=cv2.CV_32S)
        labels = _renumbered(labels, n)[0]  # each patch's blobs in raster order
        flat = np.flatnonzero(labels)
        local = labels.ravel()[flat]
        p, i = np.divmod(flat, (size + 1) * size)
        i, j = np.divmod(i, size)
        parts.append((local - 1 + n_blobs, xs[p, j], ys[p, i], grey[p, i, j]))
        patch = np.zeros(n - 1, np.int64)
        patch[local - 1] = p
        owners.append((labels.ravel(), n_labels + patch * ((size + 1) * size), xs[patch, 0], ys[patch, 0],
                       np.full(n - 1, size), np.full(n - 1, size), np.arange(1, n, dtype=np.int32)))
        n_blobs += n - 1
        n_labels += labels.size
    pixels = _Pixels(*(np.concatenate(a) for a in zip(*parts, strict=True)))
    return pixels, _Owners(*(np.concatenate(a) for a in zip(*owners, strict=True))), _runs(pixels.blob)[0]


def _blobs_above(image: np.ndarray, t: int, rois: np.ndarray | None) -> tuple[_Pixels, _Owners, np.ndarray] | None:
    """The blobs of pixels brighter than ``t`` (coarse search, then labelling; ``rois`` as :func:`detect`), or
    None when there are none."""
    cell_labels, boxes = _groups(image, t, rois)
    return _label_blobs(image, t, cell_labels, boxes) if len(boxes) else None


def _faint_blobs(image: np.ndarray, t: int, rois: np.ndarray | None, found: tuple[_Pixels, _Owners, np.ndarray] | None,
                 min_area: int) -> tuple[_Pixels, _Owners, np.ndarray] | None:
    """Markers too faint for the raw threshold ``t``: blobs of the 3x3 mean image (its noise a third of the raw
    image's, measured on it) above ``its level + max(6 sigma, 8)``, each holding no pixel of a blob ``found``
    (``_blobs_above(image, t, ...)``) of ``min_area`` or more. The mean is taken with every pixel held to its
    brightest neighbour's level, so that a lone hot pixel adds nothing (a marker's peak, spread by the optics,
    loses little; the border rows and columns are left out). The blobs' pixels (the mean image's above its
    threshold) carry the raw grey levels. ``image`` (H, W) uint8; returns the blobs as ``_blobs_above`` does, or
    None when there are none or when the mean image's threshold is not below ``t``."""
    smooth = cv2.blur(cv2.min(image, cv2.dilate(image, _RING_3)), (3, 3))
    level, sigma = background_level(smooth)
    ts = max(0, math.floor(level + max(K_SIGMA * sigma, MIN_CONTRAST)))
    if ts >= t:
        return None
    smooth[[0, -1], :] = smooth[:, [0, -1]] = 0  # (means over the border's reflected copies: noisier)
    faint = _blobs_above(smooth, ts, rois)
    if faint is None:
        return None
    pixels, owners, starts = faint
    pixels.grey = image[pixels.y, pixels.x]
    taken = np.zeros(image.shape, bool)
    if found is not None:
        area = np.diff(np.append(found[2], len(found[0].blob)))
        big = area[found[0].blob] >= min_area
        taken[found[0].y[big], found[0].x[big]] = True
    keep = np.bincount(pixels.blob, weights=taken[pixels.y, pixels.x], minlength=len(starts)) == 0
    if not keep.any():
        return None
    at = keep[pixels.blob]
    new_id = np.cumsum(keep) - 1
    pixels = _Pixels(new_id[pixels.blob[at]], pixels.x[at], pixels.y[at], pixels.grey[at], presorted=True)
    owners = _Owners(owners.labels, *(a[keep] for a in (owners.base, owners.x0, owners.y0, owners.width,
                                                        owners.height, owners.local)))
    return pixels, owners, _runs(pixels.blob)[0]


def _joined(a: tuple[_Pixels, _Owners, np.ndarray] | None, b: tuple[_Pixels, _Owners, np.ndarray] | None
            ) -> tuple[_Pixels, _Owners, np.ndarray] | None:
    """Two sets of labelled blobs as one, ``b``'s after ``a``'s."""
    if a is None or b is None:
        return a if b is None else b
    (pa, oa, sa), (pb, ob, sb) = a, b
    pixels = _Pixels(np.concatenate([pa.blob, pb.blob + len(sa)]), *(np.concatenate([getattr(pa, k), getattr(pb, k)])
                                                                      for k in ("x", "y", "grey")), presorted=True)
    owners = _Owners(np.concatenate([oa.labels, ob.labels]), np.concatenate([oa.base, ob.base + len(oa.labels)]),
                     *(np.concatenate([getattr(oa, k), getattr(ob, k)]) for k in ("x0", "y0", "width", "height",
                                                                                   "local")))
    return pixels, owners, np.concatenate([sa, sb + len(pa.blob)])


# --------------------------------------------------------------------------- blob model fit
def _fit_discs(values: np.ndarray, ox: np.ndarray, oy: np.ndarray, seg: np.ndarray, starts: np.ndarray,
               params: np.ndarray, iterations: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares fit of blurred discs plus an offset, vectorised over blobs: a fixed number of
    lightly damped Gauss–Newton steps.

    Model: ``b + sum_k A_k * E(r_k - |x - c_k|)``, a disc of radius ``r`` whose edge is blurred by a Gaussian
    of std ``s`` (px) and integrated over the pixel (``E``: see ``_EDGE_TABLES``). All but the last step are damped
    (``DAMPING``); a centre moves at most ``MAX_STEP`` px per step. Pixel arithmetic is float32 (centres are
    relative to the window, so float32 resolves 1e-6 px); the normal equations are solved in float64.
    The windows' pixels of all blobs lie one after another in flat (T,) arrays (no padding). With the compiled
    kernels on, :func:`mocap.detect_kernels.fit_discs` does the same blob by blob in float64.

    Args:
        values: (T,) grey levels minus the frame's background level.
        ox, oy: (T,) pixel offsets from the window's centre pixel, px.
        seg: (T,) the blob (0..N-1) of each pixel, non-decreasing; starts: (N,) each blob's first pixel
            (every blob has one or more).
        params: (N, 1 + 5K) starting ``b, (cx, cy, A, r, s) * K``, centres relative to the window centre.
        iterations: Gauss–Newton steps.

    Returns:
        params (N, 1 + 5K), the unscaled covariance ``(J^T J)^-1`` of the centres (N, 2K, 2K), from the
        Jacobian at the last step's start, and the residuals' sum of squares (N,) there, grey levels^2.
    """
    if kernels.HAVE_NUMBA:
        params = kernels.contiguous(params)
        cov, ss = detect_kernels.fit_discs(values, ox, oy, np.append(starts, len(seg)), params, iterations,
                                       _EDGE_TABLES, _EDGE_STEPS, float(_Z_RES), float(_Z_ORIGIN), float(_Z_LAST),
                                       _MIN_FOOTPRINT, DAMPING, *_BOUNDS_F64)
        pos = (1 + 5 * np.arange((params.shape[1] - 1) // 5)[:, None] + np.arange(2)).ravel()
        return params, cov[:, pos[:, None], pos], ss
    params = params.astype(np.float32)
    n, n_par = params.shape
    disc = params[:, 1:].reshape(n, -1, 5)  # (N, K, 5) view
    n_discs = disc.shape[1]
    jac = np.empty((n_par, len(seg)), np.float32)  # parameter-major: every product below runs along the pixels
    rows = jac[1:].reshape(n_discs, 5, len(seg))  # (K, 5, T) view: d model / d (cx, cy, A, r, s)
    jac[0] = 1.0
    upper, symmetric = _normal_index(n_par)
    half = len(_EDGE_TABLES) // 2
    pos = np.empty((4, n_discs, len(seg)), np.float32)
    for step_no in range(iterations):
        cx, cy, amp, r, s = disc.transpose(2, 1, 0)  # (K, N) each
        per_blob = np.concatenate([params[:, :1].T, cx, cy, amp, r, s])  # (1 + 5K, N): gathered in one go
        per_pixel = per_blob.take(seg, axis=1)
        cx, cy, amp, r, s = per_pixel[1:].reshape(5, n_discs, len(seg))
        dx, dy = ox - cx, oy - cy
        rho = np.sqrt(dx * dx + dy * dy)
        inv_rho = 1.0 / np.maximum(rho, 1e-6)
        a = np.maximum(np.abs(dx) * inv_rho, _MIN_FOOTPRINT)  # the pixel's footprint across the edge
        b = np.maximum(np.abs(dy) * inv_rho, _MIN_FOOTPRINT)
        inv_s = 1.0 / s
        depth = r - rho
        inside = depth > 0
        centre = depth * (_Z_RES * inv_s) + _Z_ORIGIN  # table position of z = depth / s
        half_sum, half_diff = (a + b) * (0.5 * _Z_RES * inv_s), np.abs(a - b) * (0.5 * _Z_RES * inv_s)
        np.add(centre, half_sum, out=pos[0])  # z_i = (d + p, d + q, d - q, d - p) / s, as table positions
        np.add(centre, half_diff, out=pos[1])
        np.subtract(centre, half_diff, out=pos[2])
        np.subtract(centre, half_sum, out=pos[3])
        np.minimum(np.maximum(pos, 0.0, out=pos), _Z_LAST, out=pos)
        cell = np.floor(pos)
        index = cell.astype(np.intp)
        index += inside * half
        pos -= cell  # the fraction within the cell
        t = _EDGE_TABLES.take(index)
        dt = _EDGE_STEPS.take(index)  # T'(z) / _Z_RES
        t += pos * dt
        pos += cell
        pos -= _Z_ORIGIN  # z * _Z_RES
        pos *= dt  # z T'(z)
        sum_t = (t[0] + t[3]) - (t[1] + t[2])
        scale = s / (a * b)
        f = sum_t * scale * s + inside
        slope = ((dt[0] + dt[3]) - (dt[1] + dt[2])) * (scale * _Z_RES)  # dE / d depth
        resid = values - per_pixel[0] - (amp * f).sum(axis=0)
        rows[:, 2] = f
        rows[:, 4] = amp * scale * (2.0 * sum_t - ((pos[0] + pos[3]) - (pos[1] + pos[2])))  # d model / d s
        slope *= amp
        rows[:, 3] = slope
        slope *= inv_rho
        np.multiply(slope, dx, out=rows[:, 0])
        np.multiply(slope, dy, out=rows[:, 1])
        jtj = np.add.reduceat(jac[upper[0]] * jac[upper[1]], starts, axis=1).T[:, symmetric].astype(np.float64)
        grad = np.add.reduceat(jac * resid, starts, axis=1).T.astype(np.float64)[:, :, None]  # (N, n_par, 1)
        if step_no < iterations - 1:
            lhs = jtj.copy()
            lhs.reshape(n, -1)[:, :: n_par + 1] *= 1.0 + DAMPING
            lhs.reshape(n, -1)[:, :: n_par + 1] += 1e-9
            step = np.linalg.solve(lhs, grad)[:, :, 0]
        else:  # the last step is undamped: its inverse is also the covariance
            ss = np.add.reduceat(resid.astype(np.float64) ** 2, starts)
            try:
                cov = np.linalg.inv(jtj)
            except np.linalg.LinAlgError:  # a degenerate window somewhere
                cov = np.linalg.pinv(jtj)
            step = np.matmul(cov, grad)[:, :, 0]
        params[:, 0] += step[:, 0]
        disc += np.minimum(np.maximum(step[:, 1:].reshape(disc.shape), -_STEP_BOUND), _STEP_BOUND)
        np.minimum(np.maximum(disc, _PARAM_LOW, out=disc), _PARAM_HIGH, out=disc)
    pos = (1 + 5 * np.arange(n_discs)[:, None] + np.arange(2)).ravel()
    return params.astype(np.float64), cov[:, pos[:, None], pos], ss


# --------------------------------------------------------------------------- peaks (merged markers)
def _runs(sorted_ids: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Runs of equal values in a sorted (M,) array: start index of each run (R,), and run index of each entry (M,)."""
    new = np.empty(len(sorted_ids), bool)
    new[:1] = True
    np.not_equal(sorted_ids[1:], sorted_ids[:-1], out=new[1:])
    return np.flatnonzero(new), np.cumsum(new) - 1


def _peaks(image: np.ndarray, pixels: _Pixels, starts: np.ndarray, blobs: np.ndarray, level: float, sigma: float
           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Significant local maxima of the 3x3-smoothed profile of each of the ``blobs`` (B,) (sorted ids; ``starts``
    (N,): each blob's first pixel in ``pixels``).

    The highest maximum of a blob always counts; another counts when, towards every higher maximum of
    its blob, it lies 2 px or more away and the smoothed profile on the straight path dips below the
    lower of the two by more than ``max(4 sigma, 10 % of its height above the background)`` (plateaus
    and noise bumps do not count). The blobs' bounding boxes are smoothed as one padded stack (pixels
    beyond the image border repeat the border).

    Returns:
        blob (M,), x (M,), y (M,): peak positions (px), sorted by blob, highest first within a blob.
    """
    if len(blobs) == 0:
        return np.zeros(0, np.int64), np.zeros(0), np.zeros(0)
    if kernels.HAVE_NUMBA:
        return detect_kernels.peaks(kernels.contiguous(blobs, np.int64), np.append(starts, len(pixels.blob)),
                                    kernels.contiguous(pixels.x, np.int64), kernels.contiguous(pixels.y, np.int64),
                                    image, level, sigma, 2 * MAX_DISCS)
    is_candidate = np.zeros(len(starts), bool)
    is_candidate[blobs] = True
    sel = is_candidate[pixels.blob]
    pixels = _Pixels(pixels.blob[sel], pixels.x[sel], pixels.y[sel], pixels.grey[sel], presorted=True)
    h, w = image.shape
    starts, b_of = _runs(pixels.blob)
    ids = pixels.blob[starts]
    x0, y0 = np.minimum.reduceat(pixels.x, starts) - 1, np.minimum.reduceat(pixels.y, starts) - 1
    bw = int((np.maximum.reduceat(pixels.x, starts) - x0).max()) + 2  # box with a 1 px margin
    bh = int((np.maximum.reduceat(pixels.y, starts) - y0).max()) + 2
    rows = np.minimum(np.maximum(y0[:, None] + np.arange(-1, bh + 1), 0), h - 1) * w
    cols = np.minimum(np.maximum(x0[:, None] + np.arange(-1, bw + 1), 0), w - 1)
    raw = image.ravel().take(rows[:, :, None] + cols[:, None, :]).astype(np.float32)  # (B, bh + 2, bw + 2)
    rsum = raw[:, :-2] + raw[:, 1:-1] + raw[:, 2:]
    smooth = (rsum[:, :, :-2] + rsum[:, :, 1:-1] + rsum[:, :, 2:]) * np.float32(1.0 / 9.0)  # (B, bh, bw)
    rmax = np.maximum(np.maximum(smooth[:, :-2], smooth[:, 1:-1]), smooth[:, 2:])
    nmax = np.maximum(np.maximum(rmax[:, :, :-2], rmax[:, :, 1:-1]), rmax[:, :, 2:])  # over 3x3, interior
    inner = smooth[:, 1:-1, 1:-1]
    own = np.zeros(inner.shape, bool)  # the blob's own pixels in its box
    own[b_of, pixels.y - y0[b_of] - 1, pixels.x - x0[b_of] - 1] = True
    b, i, j = np.nonzero(own & (inner >= nmax))
    blob, px, py, pv = ids[b], x0[b] + 1 + j, y0[b] + 1 + i, inner[b, i, j].astype(np.float64)
    order = np.lexsort((-pv, blob))
    b, blob, px, py, pv = b[order], blob[order], px[order], py[order], pv[order]
    start, run = _runs(blob)
    rank = np.arange(len(blob)) - start[run]  # 0: the blob's highest
    top = rank < 2 * MAX_DISCS  # the highest few maxima are enough to find up to MAX_DISCS markers
    b, blob, px, py, pv, rank = b[top], blob[top], px[top], py[top], pv[top], rank[top]
    # every maximum against every higher one of its blob: (i, j) pairs with rank(j) < rank(i)
    i = np.repeat(np.arange(len(blob)), rank)
    j = np.repeat(np.arange(len(blob)) - rank, rank) + (np.arange(len(i)) - np.repeat(np.cumsum(rank) - rank, rank))
    dist = np.hypot(px[i] - px[j], py[i] - py[j])
    failed = np.zeros(len(blob), bool)
    if len(i):
        n_steps = 2 * int(np.ceil(dist.max()))
        steps = np.arange(n_steps + 1) / n_steps
        sx = np.rint(px[i, None] + (px[j] - px[i])[:, None] * steps).astype(np.int64)  # inside the blob's box
        sy = np.rint(py[i, None] + (py[j] - py[i])[:, None] * steps).astype(np.int64)
        path = smooth.take((b[i, None] * bh + sy - y0[b[i], None]) * bw + sx - x0[b[i], None])
        dip = np.minimum(pv[i], pv[j]) - path.min(axis=1)
        bad = (dip <= np.maximum(4.0 * sigma, 0.1 * (pv[i] - level))) | (dist < 2.0)
        failed = np.bincount(i[bad], minlength=len(blob)) > 0
    significant = ~failed
    return blob[significant], px[significant].astype(np.float64), py[significant].astype(np.float64)


# --------------------------------------------------------------------------- main entry
class _Blobs:
    """Per-blob sums over the thresholded pixels (blob ids 0..N-1, each with at least one pixel).

    Attributes:
        area: (N,) pixel count; flux: (N,) grey levels above the background, summed; centroid: (N, 2)
        intensity-weighted, px; second: (N, 2, 2) weighted second moments, px^2; centroid_cov: (N, 2, 2) noise
        covariance of that centroid per unit noise variance; peak: (N,) highest grey level; radius: (N,) radius
        of the area above half the peak, px; reach: (N,) farthest pixel from the centroid, px;
        saturated_radius: (N,) radius of the saturated area, px.
    """

    def __init__(self, pixels: _Pixels, starts: np.ndarray, level: float) -> None:
        b = pixels.blob
        if kernels.HAVE_NUMBA:
            sums = detect_kernels.blob_sums(np.append(starts, len(b)), pixels.x, pixels.y, pixels.grey, level,
                                            _SATURATED)
            self.area, self.flux, self.peak, self.radius, self.saturated_radius, self.reach = sums[
                :, [0, 1, 10, 11, 12, 13]].T
            self.centroid = sums[:, 2:4]
            self.second = sums[:, [4, 5, 5, 6]].reshape(-1, 2, 2)
            self.centroid_cov = sums[:, [7, 8, 8, 9]].reshape(-1, 2, 2)
            return
        x, y = pixels.x.astype(np.float64), pixels.y.astype(np.float64)
        wgt = np.maximum(pixels.grey - level, 1e-6)
        self.area = np.diff(np.append(starts, len(b))).astype(np.float64)
        m0 = np.add.reduceat(wgt, starts)
        self.flux = m0
        self.centroid = np.stack([np.add.reduceat(wgt * x, starts), np.add.reduceat(wgt * y, starts)], 1) / m0[:, None]
        dx, dy = x - self.centroid[b, 0], y - self.centroid[b, 1]
        sums = np.stack([np.add.reduceat(v, starts) for v in (wgt * dx * dx, wgt * dx * dy, wgt * dy * dy,
                                                               dx * dx, dx * dy, dy * dy)], axis=1)
        self.second = sums[:, [0, 1, 1, 2]].reshape(-1, 2, 2) / m0[:, None, None]
        self.centroid_cov = sums[:, [3, 4, 4, 5]].reshape(-1, 2, 2) / (m0**2)[:, None, None]
        self.peak = np.maximum.reduceat(pixels.grey, starts).astype(np.float64)
        half_max = np.add.reduceat((pixels.grey - level > 0.5 * (self.peak - level)[b]).astype(np.float64), starts)
        self.radius = np.sqrt(half_max / np.pi)
        self.saturated_radius = np.sqrt(np.add.reduceat((pixels.grey >= _SATURATED).astype(np.float64), starts) / np.pi)
        self.reach = np.sqrt(np.maximum.reduceat(dx * dx + dy * dy, starts))


def _neighbour_medians(xy: np.ndarray, values: np.ndarray, k: int = 5) -> np.ndarray:
    """(N, V) median of each of the ``values`` (N, V) over each blob's k nearest other blobs (inf with fewer than 2
    others)."""
    if len(xy) < 3:
        return np.full(values.shape, np.inf)
    k = min(k, len(xy) - 1)
    if len(xy) <= _BRUTE_FORCE_NEIGHBOURS:
        if kernels.HAVE_NUMBA:
            return detect_kernels.neighbour_medians(kernels.contiguous(xy), kernels.contiguous(values), k)
        d2 = ((xy[:, None, :] - xy[None, :, :]) ** 2).sum(axis=2)
        np.fill_diagonal(d2, np.inf)
        nn = np.argsort(d2, axis=1, kind="stable")[:, :k]  # (ties to the lower index, as the kernel)
    else:
        nn = cKDTree(xy).query(xy, k + 1)[1][:, 1:]
    near = np.sort(values[nn], axis=1)  # (N, k, V)
    return 0.5 * (near[:, (k - 1) // 2] + near[:, k // 2])


def _window(centre: np.ndarray, radius: np.ndarray, image: np.ndarray, owners: _Owners, own: np.ndarray, t: int,
            level: float) -> tuple[np.ndarray, ...]:
    """Round fit windows: the usable pixels within ``radius`` (N,) px of each ``centre`` (N, 2), one window after
    another.

    Returns:
        origin (N, 2) int: each window's centre pixel; seg (T,) int: the window of each pixel, non-decreasing;
        count (N,): pixels per window; ox, oy (T,) float32: offsets from the window's origin, px; values (T,)
        float32: grey levels minus ``level``. Left out: pixels off the image, saturated pixels (their true
        level is unknown) and other blobs' above-threshold pixels.
    """
    h, w = image.shape
    origin = np.rint(centre).astype(np.int64)
    reach = radius + 0.7072  # a pixel within radius of the centre lies within this of the centre pixel
    half = _WINDOW_HALVES[np.searchsorted(_WINDOW_HALVES, reach.max())]
    all_ox, all_oy, all_r2 = _disc_offsets(int(half))
    count = np.searchsorted(all_r2, reach * reach, side="right")  # (N,) >= 1
    if kernels.HAVE_NUMBA:
        seg, ox, oy, values = detect_kernels.window(
            origin, kernels.contiguous(centre), kernels.contiguous(radius), count, all_ox, all_oy, image,
            kernels.contiguous(owners.labels, np.int32), *(kernels.contiguous(a, np.int64) for a in (
                owners.base, owners.x0, owners.y0, owners.width, owners.height)),
            kernels.contiguous(owners.local, np.int32), kernels.contiguous(own, np.int64), t, level, _SATURATED)
        return origin, seg, np.bincount(seg, minlength=len(count)), ox, oy, values
    starts = np.cumsum(count) - count
    seg = np.repeat(np.arange(len(count)), count)
    nearest = np.arange(len(seg)) - starts[seg]
    ox, oy = all_ox[nearest], all_oy[nearest]
    x0, y0 = origin.T
    xs, ys = x0.take(seg) + ox, y0.take(seg) + oy
    xc, yc = np.minimum(np.maximum(xs, 0), w - 1), np.minimum(np.maximum(ys, 0), h - 1)
    grey = image.ravel().take(yc * w + xc)
    fx, fy = (centre - origin).T
    usable = ((xs == xc) & (ys == yc) & ((ox - fx.take(seg)) ** 2 + (oy - fy.take(seg)) ** 2
                                          <= (radius * radius).take(seg)) & (grey < _SATURATED))
    above = np.flatnonzero(grey > t)  # blob pixels: usable if they are this blob's
    usable[above] &= owners.owns(own.take(seg.take(above)), xs.take(above), ys.take(above))
    kept = np.flatnonzero(usable)
    seg = seg.take(kept)
    return (origin, seg, np.bincount(seg, minlength=len(count)), ox.take(kept).astype(np.float32),
            oy.take(kept).astype(np.float32), (grey.take(kept) - np.float32(level)).astype(np.float32))


@functools.cache
def _normal_index(n_par: int) -> tuple[np.ndarray, np.ndarray]:
    """Row and column (U,) of the upper triangle of an (n_par, n_par) matrix, and (n_par, n_par) the position
    in that list of each entry (i, j) or (j, i)."""
    upper = np.triu_indices(n_par)
    symmetric = np.empty((n_par, n_par), np.intp)
    symmetric[upper] = symmetric[upper[::-1]] = np.arange(len(upper[0]))
    return upper, symmetric


@functools.cache
def _disc_offsets(half: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """x and y offsets (P,) int of the pixels within ``half`` px of a centre pixel, nearest first, and their
    squared distances (read-only)."""
    oy, ox = np.mgrid[-half: half + 1, -half: half + 1].reshape(2, -1)
    r2 = ox * ox + oy * oy
    order = np.argsort(r2, kind="stable")
    order = order[r2[order] <= half * half]
    out = ox[order], oy[order], r2[order]
    for a in out:
        a.setflags(write=False)
    return out


def _seeded_peaks(seeds: np.ndarray, ids: np.ndarray, eligible: np.ndarray, owners: _Owners, stats: _Blobs,
                  peaks: tuple[np.ndarray, np.ndarray, np.ndarray], n_discs: np.ndarray
                  ) -> tuple[tuple[np.ndarray, np.ndarray, np.ndarray], np.ndarray, np.ndarray]:
    """Seeds (S, 2) px as the peaks of the ``eligible`` blobs (of ``ids``) that own the pixels of two or more
    (up to ``MAX_DISCS``) of them. Returns the peaks (blob, x, y sorted by blob), ``n_discs`` and (len(ids),) bool:
    the blobs seeded."""
    seeded = np.zeros(len(ids), bool)
    cand = np.flatnonzero(eligible)
    if cand.size == 0:
        return peaks, n_discs, seeded
    reach = float(stats.reach[ids[cand]].max()) + 1.0
    dist, near = cKDTree(stats.centroid[ids[cand]]).query(seeds, distance_upper_bound=reach)
    hit = np.flatnonzero(np.isfinite(dist))
    hit = hit[owners.owns(ids[cand[near[hit]]], np.rint(seeds[hit, 0]).astype(np.int64),
                          np.rint(seeds[hit, 1]).astype(np.int64))]
    which = cand[near[hit]]  # index into ids
    count = np.bincount(which, minlength=len(ids))
    seeded = (count >= 2) & (count <= MAX_DISCS)
    if not seeded.any():
        return peaks, n_discs, seeded
    use = seeded[which]
    keep = ~np.isin(peaks[0], ids[seeded])
    blob = np.concatenate([peaks[0][keep], ids[which[use]]])
    order = np.argsort(blob, kind="stable")
    px = np.concatenate([peaks[1][keep], seeds[hit[use], 0]])
    py = np.concatenate([peaks[2][keep], seeds[hit[use], 1]])
    return (blob[order], px[order], py[order]), np.where(seeded, count, n_discs), seeded


def _disc_starts(blobs: np.ndarray, k: int, origin: np.ndarray, peaks: tuple[np.ndarray, np.ndarray, np.ndarray],
                 stats: _Blobs, level: float) -> np.ndarray:
    """(N, 1 + 5k) starting parameters: offset 0; per disc: centre (relative to ``origin`` (N, 2)), height,
    radius, blur 0.5 px."""
    n = len(blobs)
    start = np.zeros((n, 1 + 5 * k))
    disc = start[:, 1:].reshape(n, k, 5)
    if k == 1:
        disc[:, 0, :2] = stats.centroid[blobs] - origin
    else:
        pk_blob, pk_x, pk_y = peaks
        take = np.searchsorted(pk_blob, blobs)[:, None] + np.arange(k)
        disc[:, :, 0] = pk_x[take] - origin[:, :1]
        disc[:, :, 1] = pk_y[take] - origin[:, 1:]
    height = np.maximum(stats.peak[blobs] - level, 1.0)
    radius = stats.radius[blobs]
    saturated = stats.peak[blobs] >= _SATURATED
    if k == 1 and saturated.any():  # the height and radius that put the saturated and half-height edges where they are
        ratio = np.interp((radius - stats.saturated_radius[blobs]) / _START_BLUR, _HALF_GAP, _HALF_RATIO)
        height = np.where(saturated, height / ratio, height)
        radius = np.where(saturated, radius + _START_BLUR * special.ndtri(0.5 * ratio), radius)
    disc[:, :, 2] = np.where(saturated & (k > 1), 1.3 * height, height)[:, None]
    disc[:, :, 3] = np.maximum(radius / math.sqrt(k), 0.5)[:, None]
    disc[:, :, 4] = _START_BLUR
    return start


def _measure(image: np.ndarray, owners: _Owners, blobs: np.ndarray, k: int, radius: np.ndarray,
             peaks: tuple[np.ndarray, np.ndarray, np.ndarray], stats: _Blobs, level: float, sigma: float, t: int,
             pixel_var: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Fit ``k`` discs to each blob in ``blobs`` (N,) on the pixels within ``radius`` (N,) px of its
    centroid (``pixel_var`` (N,): px^2 per axis in a single disc's centroid besides its noise).

    Returns:
        centres (N, k, 2) px, their covariances (N, k, 2, 2) px^2, (N,) whether a disc's fit failed and (N, 2) the
        fit's misfit (:func:`_misfit`) and its discs' edge blur (px; k = 1), NaN where it failed. A fit that fails
        (no usable pixel, not finite, or a centre that wandered more than max(1.5 px, its radius) from its start)
        falls back to the start: the weighted centroid (k = 1) or the peaks (k > 1), with the centroid's noise
        covariance.
    """
    n = len(blobs)
    origin, seg, count, ox, oy, values = _window(stats.centroid[blobs], radius, image, owners, blobs, t, level)
    start = _disc_starts(blobs, k, origin, peaks, stats, level)
    params, pcov, ss = start.copy(), np.full((n, 2 * k, 2 * k), np.nan), np.full(n, np.nan)  # (NaN: the fallback)
    fitted = count > 0
    params[fitted], pcov[fitted], ss[fitted] = _fit_discs(values, ox, oy, (np.cumsum(fitted) - 1).take(seg),
                                                          np.cumsum(count[fitted]) - count[fitted], start[fitted],
                                                          FIT_ITERATIONS if k == 1 else SPLIT_ITERATIONS)
    centres, covs, failed = _fit_results(params, pcov, start, origin, stats.centroid_cov[blobs], float(sigma), k,
                                         pixel_var)
    peak = np.zeros(n)
    if fitted.any():
        peak[fitted] = np.maximum.reduceat(values, np.cumsum(count[fitted]) - count[fitted])
    quality = np.stack([_misfit(ss, count, params.shape[1], params[:, 3::5].sum(axis=1), peak, sigma),
                        params[:, 5]], axis=1)
    return centres, covs, failed, np.where(failed[:, None], np.nan, quality)


def _misfit(ss: np.ndarray, count: np.ndarray, n_par: int, height: np.ndarray, peak: np.ndarray, sigma: float
            ) -> np.ndarray:
    """(N,) reduced chi-square of fits: the residuals' sum of squares ``ss`` (N,) grey levels^2 over the ``count``
    (N,) pixels less the ``n_par`` parameters, against the noise ``sigma`` (grey levels) plus a model error of
    ``MISFIT_MODEL_ERROR`` times the fitted ``height`` (N,) or the window's ``peak`` (N,) grey levels above the
    background, the higher (a saturated or oddly blurred spot misfits in proportion to its height; a saturated
    disc's fitted height can run off where the clipped core leaves only its edge)."""
    scale = sigma**2 + (MISFIT_MODEL_ERROR * np.maximum(height, peak)) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        return ss / np.maximum(count - n_par, 1) / scale


def _fit_results(params: np.ndarray, pcov: np.ndarray, start: np.ndarray, origin: np.ndarray,
                 centroid_cov: np.ndarray, sigma: float, k: int, pixel_var: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The fitted discs checked: centres (N, k, 2) px, covariances (N, k, 2, 2) px^2 and (N,) whether a disc's fit
    failed, from the fit's ``params`` (N, 1 + 5k) and ``pcov`` (N, 2k, 2k), its ``start`` (centres relative to
    ``origin`` (N, 2)) and the blobs' ``centroid_cov`` (N, 2, 2) (unit noise; ``sigma`` grey levels). A disc whose
    offset or covariance is not finite, whose covariance is not positive or its std ``FIT_VAGUE`` times the
    centroid's, or whose centre wandered more than max(1.5 px, its radius) falls back to its start, with the
    centroid's covariance: its noise covariance + ``pixel_var`` (N,) px^2 per axis for k = 1 (0.25 for k > 1),
    also what the vague test compares with. With the kernels on,
    :func:`mocap.detect_kernels.fit_results` does the same disc by disc."""
    if kernels.HAVE_NUMBA:
        return detect_kernels.fit_results(params, pcov, start, kernels.contiguous(origin),
                                          kernels.contiguous(centroid_cov), sigma, k, FIT_VAGUE**2,
                                          kernels.contiguous(pixel_var))
    n = len(params)
    disc = params[:, 1:].reshape(n, k, 5)
    offset = disc[:, :, :2] - start[:, 1:].reshape(n, k, 5)[:, :, :2]
    pos = 2 * np.arange(k)[:, None] + np.arange(2)  # (k, 2) covariance rows of each centre
    cov = pcov[np.arange(n)[:, None, None, None], pos[None, :, :, None], pos[None, :, None, :]] * sigma**2
    fallback_cov = centroid_cov[:, None] * sigma**2 + np.eye(2) * (0.25 if k > 1 else pixel_var[:, None, None, None])
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    with np.errstate(invalid="ignore"):  # (NaN covariances are caught by the finiteness test)
        vague = (a < 0) | (a * d < b * b) | (a + d > FIT_VAGUE**2 * np.trace(fallback_cov, axis1=2, axis2=3))
    bad = (~np.isfinite(offset).all(axis=2) | ~np.isfinite(cov).all(axis=(2, 3)) | vague
           | (np.hypot(*offset.transpose(2, 0, 1)) > np.maximum(1.5, disc[:, :, 3])))
    start_xy = start[:, 1:].reshape(n, k, 5)[:, :, :2] + origin[:, None]
    return (start_xy + np.where(bad[:, :, None], 0.0, offset), np.where(bad[:, :, None, None], fallback_cov, cov),
            bad.any(axis=1))


def _usual_fit(quality: np.ndarray, flagged: np.ndarray) -> tuple[float, float]:
    """The median misfit (floored at 1) and edge blur (px) of the single disc fits ``quality`` (N, 2) (NaN: none) of
    the frame's blobs not ``flagged`` (N,) merged: what a whole marker's fit gives here (a renderer or lens whose
    spots are no blurred discs, a hard edge or a halo, misfits every blob alike). (1, inf) without such blobs."""
    usual = quality[~flagged & np.isfinite(quality).all(axis=1)]
    if not usual.size:
        return 1.0, math.inf
    misfit, blur = np.median(usual, axis=0)
    return max(1.0, float(misfit)), float(blur)


def _measure_cut(image: np.ndarray, owners: _Owners, blobs: np.ndarray, radius: np.ndarray, stats: _Blobs,
                 level: float, sigma: float, t: int, usual: tuple[float, float]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fit the single blobs ``blobs`` (N,) that a whole disc misfits as discs cut by an edge
    (:func:`mocap.cutdisc.fit_cut_discs`, on the pixels within ``radius`` (N,) px of their centroids).

    Returns:
        (N,) bool: measured so (the fit misfits at most ``CUT_ACCEPT`` times the frame's ``usual`` misfit (``usual``:
        that and the blur, :func:`_usual_fit`) and ``CUT_GAIN`` times the same model's whole disc's (a renderer's
        hard edges, which a disc fit misfits, are no cut), its edges are blurred at most
        ``CUT_BLUR`` times as much as the frame's discs, it leaves ``CUT_MIN_VISIBLE`` to ``CUT_MAX_VISIBLE`` of the
        disc in view, its centre is known to ``CUT_MAX_STD`` px and lies within its radius of the weighted
        centroid); their centres (N, 2) px and covariances (N, 2, 2) px^2 (NaN where not measured so).
    """
    n = len(blobs)
    accepted, centre, cov = np.zeros(n, bool), np.full((n, 2), np.nan), np.full((n, 2, 2), np.nan)
    if n == 0:
        return accepted, centre, cov
    origin, seg, count, ox, oy, values = _window(stats.centroid[blobs], radius, image, owners, blobs, t, level)
    start = _disc_starts(blobs, 1, origin, None, stats, level)
    sxx, sxy, syy = stats.second[blobs].reshape(-1, 4)[:, [0, 1, 3]].T
    minor_axis = 0.5 * np.arctan2(-2.0 * sxy, syy - sxx)  # (the normal of a straight cut: the blob's shortest axis)
    params, pcov, ss = cutdisc.fit_cut_discs(values, ox, oy, seg, start, minor_axis)
    peak = stats.peak[blobs] - level
    misfit = _misfit(ss, count, cutdisc.N_PAR, params[:, 3], peak, sigma)
    shown = cutdisc.visible_fraction(params[:, 4], params[:, 7])
    cov_xy = pcov[:, 1:3, 1:3] * sigma**2
    with np.errstate(invalid="ignore"):
        worst = np.linalg.eigvalsh(np.where(np.isfinite(cov_xy), cov_xy, 0.0))
        accepted = (np.isfinite(cov_xy).all(axis=(1, 2)) & (worst[:, 0] > 0) & (worst[:, 1] <= CUT_MAX_STD**2)
                    & (misfit <= CUT_ACCEPT * usual[0])
                    & (params[:, 5] <= CUT_BLUR * math.hypot(usual[1], math.sqrt(1 / 12)))  # (its blur: the pixel's)
                    & (shown >= CUT_MIN_VISIBLE) & (shown <= CUT_MAX_VISIBLE)
                    & (np.hypot(*(params[:, 1:3] + origin - stats.centroid[blobs]).T) <= params[:, 4]))
    if accepted.any():  # (the same model's whole disc, for the blobs that pass the rest)
        pixels = accepted.take(seg)
        whole, _, whole_ss = cutdisc.fit_cut_discs(values[pixels], ox[pixels], oy[pixels],
                                                   (np.cumsum(accepted) - 1).take(seg[pixels]), start[accepted],
                                                   minor_axis[accepted], cut=False)
        gain = misfit[accepted] <= CUT_GAIN * _misfit(whole_ss, count[accepted], cutdisc.N_PAR - 2, whole[:, 3],
                                                      peak[accepted], sigma)
        accepted[accepted] = gain
    centre[accepted] = params[accepted, 1:3] + origin[accepted]
    cov[accepted] = CUT_COV_SCALE * cov_xy[accepted]
    return accepted, centre, cov


def _refit_cut_blobs(image: np.ndarray, owners: _Owners, ids: np.ndarray, groups: list, quality: np.ndarray,
                     flagged: np.ndarray, too_big: np.ndarray, faint: np.ndarray, radius: np.ndarray, stats: _Blobs,
                     level: float, sigma: float, t: int) -> np.ndarray:
    """Refit as cut discs (:func:`_measure_cut`) the single discs of 7 px or more (``CUT_MIN_AREA``, not ``faint``
    (N,)) whose fit ``quality`` (N, 2) misfits ``MISFIT_CUT`` times the frame's usual (over the blobs not
    ``flagged`` (N,) merged) or that are flagged for their shape (not only ``too_big`` (N,)), and put the accepted
    fits' centres and covariances into the fitted ``groups`` (blobs (n,) of ``ids`` (N,), centres (n, k, 2),
    covariances (n, k, 2, 2)), in place. Returns the refitted blobs, sorted indices into ``ids``."""
    misfit = quality[:, 0]
    usual = _usual_fit(quality, flagged)
    with np.errstate(invalid="ignore"):
        candidates = np.flatnonzero(((misfit > MISFIT_CUT * usual[0]) | (flagged & ~too_big & np.isfinite(misfit)))
                                    & ~faint & (stats.area[ids] >= CUT_MIN_AREA))
    cut, cut_xy, cut_cov = _measure_cut(image, owners, ids[candidates], radius[candidates], stats, level, sigma, t,
                                        usual)
    candidates, cut_xy, cut_cov = candidates[cut], cut_xy[cut], cut_cov[cut]
    for group, centres, covs in groups:
        if centres.shape[1] == 1:  # (a single disc's blob is in one such group; groups are sorted)
            row = np.searchsorted(group, candidates)
            mine = row < len(group)
            mine[mine] = group[row[mine]] == candidates[mine]
            centres[row[mine], 0], covs[row[mine], 0] = cut_xy[mine], cut_cov[mine]
    return candidates


def detect(image: np.ndarray, *, threshold: float | None = None, min_area: int = MIN_AREA, max_area: int = MAX_AREA,
           rois: np.ndarray | None = None, noise_sigma: float | None = None, refine: str = "fit",
           seeds: np.ndarray | None = None, faint: bool = True) -> Detections:
    """Find bright blobs and measure their sub-pixel centres.

    Args:
        image: (H, W) uint8 grey image (bright markers, dark background).
        threshold: grey level a blob pixel must exceed; default ``level + max(6 sigma, 8)`` from
            :func:`background_level`, and markers too faint for it found in the 3x3 mean image (its noise a third).
        min_area: fewest pixels above the threshold for a blob (2 rejects single hot pixels).
        max_area: most pixels above the threshold (larger blobs are reflections or lamps, dropped).
        rois: optional (K, 4) int boxes ``x0, y0, x1, y1`` (px, inclusive): report only blobs whose
            centroid lies in a box.
        noise_sigma: the image noise std, grey levels, if known (else estimated from the image).
        refine: "fit" (maximum-likelihood disc fit, at the Cramér–Rao bound, splits merged markers) or
            "centroid" (the intensity-weighted centroid of the thresholded pixels: several times faster,
            2-3x the noise of the fit, merged blobs flagged but not split). Blobs larger than
            ``FIT_MAX_AREA`` always get the centroid.
        seeds: optional (S, 2) predicted marker positions (distorted px, e.g. a tracker's): a blob flagged merged
            with no saddle to split it at, holding two or more seeds (up to ``MAX_DISCS``), is fitted as that many
            discs started from them; if any of those fits fails it is measured whole, as without seeds.
        faint: with the default threshold, also look for markers too faint for it in the 3x3 mean image (about a
            third of the time on a 1024x768 frame; :class:`StreamDetector` runs it only where it can find some).

    Returns:
        :class:`Detections`: centroids (distorted px), area (px above threshold; the parts of a split
        blob share it equally), roundness, centroid covariance (px^2), the merged flag, flux (grey levels above
        the background summed over the thresholded pixels, shared as the area) and the cut flag (measured as a
        marker partly hidden by an edge; not merged then for its shape).
    """
    return _detect(image, threshold, min_area, max_area, rois, noise_sigma, refine, seeds, math.inf if faint else 0)[0]


def _detect(image: np.ndarray, threshold: float | None, min_area: int, max_area: int, rois: np.ndarray | None,
            noise_sigma: float | None, refine: str, seeds: np.ndarray | None, faint_below: float
            ) -> tuple[Detections, int, int]:
    """:func:`detect`, its faint pass run only where the raw threshold finds fewer than ``faint_below`` blobs of
    ``min_area`` to ``max_area`` pixels; also returns that number of blobs and how many blobs the faint pass
    added."""
    image = np.ascontiguousarray(image)
    if image.ndim != 2 or image.dtype != np.uint8:
        raise ValueError(f"detect needs an (H, W) uint8 image, got {image.dtype} {image.shape}")
    if threshold is None:
        flat = flattened_background(image)
        image = image if flat is None else flat
    level, sigma = background_level(image)
    if noise_sigma is not None:
        sigma = float(noise_sigma)
    t = max(0, math.floor(threshold if threshold is not None else level + max(K_SIGMA * sigma, MIN_CONTRAST)))
    if t >= _SATURATED or (rois is not None and len(rois) == 0):
        return Detections.empty(), 0, 0
    found = _blobs_above(image, t, rois)
    n_found, n_raw = 0, 0
    if found is not None:
        n_found = len(found[2])
        size = np.diff(np.append(found[2], len(found[0].blob)))
        n_raw = int(np.count_nonzero((size >= min_area) & (size <= max_area)))
    if threshold is None and n_raw < faint_below:  # (a threshold given is the one a blob pixel must exceed)
        found = _joined(found, _faint_blobs(image, t, rois, found, min_area))
    if found is None:
        return Detections.empty(), 0, 0
    pixels, owners, starts = found
    stats = _Blobs(pixels, starts, level)
    faint = np.arange(len(starts)) >= n_found  # (a faint blob's area is in the mean image: any is kept)
    keep = ((stats.area >= min_area) | faint) & (stats.area <= max_area)
    if rois is not None:
        r = np.asarray(rois, dtype=np.float64).reshape(-1, 4)
        c = stats.centroid[:, None, :]
        keep &= ((c[..., 0] >= r[:, 0]) & (c[..., 0] <= r[:, 2]) & (c[..., 1] >= r[:, 1])
                 & (c[..., 1] <= r[:, 3])).any(axis=1)
    ids = np.flatnonzero(keep)
    if len(ids) == 0:
        return Detections.empty(), n_raw, 0
    n_faint = int(np.count_nonzero(faint[ids]))
    sxx, sxy, syy = stats.second[ids].reshape(-1, 4)[:, [0, 1, 3]].T  # eigenvalues of the 2x2 moments:
    spread = np.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
    roundness = np.sqrt(np.maximum(0.5 * (sxx + syy) - spread, 0.0) / np.maximum(0.5 * (sxx + syy) + spread, 1e-12))
    typical_area, typical_flux = _neighbour_medians(stats.centroid[ids],
                                                    np.stack([stats.area[ids], stats.flux[ids]], axis=1)).T
    too_big = stats.area[ids] > AREA_MERGED * typical_area
    elongated = roundness < ROUND_SPLIT
    flagged = too_big | ((roundness < ROUND_MERGED) & (stats.area[ids] >= MIN_SHAPE_AREA))
    if refine not in ("fit", "centroid"):
        raise ValueError(f"refine must be 'fit' or 'centroid', got {refine!r}")
    fit = stats.area[ids] <= FIT_MAX_AREA if refine == "fit" else np.zeros(len(ids), bool)
    xy, part = [stats.centroid[ids[~fit]]], [np.flatnonzero(~fit)]
    box_var = np.where(faint[ids[~fit]], FAINT_PIXEL_VAR, 0.0)[:, None, None]  # (a faint blob's centroid: to its box)
    cov = [stats.centroid_cov[ids[~fit]] * sigma**2 + np.eye(2) * box_var]

    # two markers side by side make an elongated (or oversized) blob: look for their peaks there
    peaks = _peaks(image, pixels, starts, ids[fit & (elongated | too_big)], level, sigma)
    n_discs = np.minimum(np.maximum(np.bincount(peaks[0], minlength=len(stats.area))[ids], 1), MAX_DISCS)
    seeded = np.zeros(len(ids), bool)
    if seeds is not None and len(seeds):
        peaks, n_discs, seeded = _seeded_peaks(np.asarray(seeds, dtype=np.float64).reshape(-1, 2), ids,
                                               fit & flagged & (n_discs == 1), owners, stats, peaks, n_discs)
    radius = stats.reach[ids] + SKIRT + faint[ids]  # (a faint blob's pixels: where the 3x3 mean clears its threshold)
    pixel_var = np.where(faint[ids], FAINT_PIXEL_VAR, FALLBACK_PIXEL_VAR)
    groups = []  # (blobs (N,) of ids, centres (N, k, 2), covariances (N, k, 2, 2)) per fitted disc count
    quality = np.full((len(ids), 2), np.nan)  # single discs' misfit (:func:`_misfit`) and blur
    for k in np.unique(n_discs[fit]):
        group = np.flatnonzero(fit & (n_discs == k))
        centres, covs, failed, fit_quality = _measure(image, owners, ids[group], int(k), radius[group], peaks, stats,
                                                      level, sigma, t, pixel_var[group])
        whole = failed & seeded[group]  # a seeded split that failed: measured whole below
        n_discs[group[whole]] = 1
        groups.append((group[~whole], centres[~whole], covs[~whole]))
        if k == 1:
            quality[group] = fit_quality
    again = np.flatnonzero(seeded & (n_discs == 1))
    if again.size:
        centres, covs, _, quality[again] = _measure(image, owners, ids[again], 1, radius[again], peaks, stats, level,
                                                    sigma, t, pixel_var[again])
        groups.append((again, centres, covs))
    candidates = (_refit_cut_blobs(image, owners, ids, groups, quality, flagged, too_big, faint[ids], radius, stats,
                                   level, sigma, t) if CUT_FIT else np.zeros(0, np.intp))
    for group, centres, covs in groups:  # (N, k, ...) per group
        xy.append(centres.reshape(-1, 2))
        cov.append(covs.reshape(-1, 2, 2))
        part.append(np.repeat(group, centres.shape[1]))
    part = np.concatenate(part)
    # Each part of a split blob is fitted as a disc of its own: measured, not merged; unless the parts hold more light
    # than single markers nearby (three markers fitted as two discs: a centroid between two of them). (Light, not
    # area: where halos join, the area between two markers rises above the threshold, their light hardly.)
    area = stats.area[ids][part] / n_discs[part]
    split = (n_discs[part] > 1) & (stats.flux[ids][part] / n_discs[part] <= SPLIT_PART_FLUX * typical_flux[part])
    refit = np.zeros(len(ids), bool)
    refit[candidates] = stats.area[ids[candidates]] >= MIN_SHAPE_AREA  # (single discs: one part each)
    return Detections(np.concatenate(xy), area, np.where(split, 1.0, roundness[part]),
                      floored_covariance(np.concatenate(cov)),
                      ((too_big | flagged & ~refit)[part] | (n_discs[part] > 1)) & ~split,
                      stats.flux[ids][part] / n_discs[part], refit[part]), n_raw, n_faint


class StreamDetector:
    """:func:`detect` (default settings) over one camera's frames, its faint pass (markers too faint for the raw
    threshold, found in the 3x3 mean image: about a third of the detection time at 1024x768) run only where it can
    find some: in every frame up to ``hold`` frames after it last added a blob, in any frame whose raw threshold
    finds fewer blobs than in the frame before (a marker fading below it), and every ``check_every`` frames (a
    marker that enters the view too faint for the raw threshold is found within that many frames). Where the
    faint pass would add nothing, the detections are :func:`detect`'s."""

    def __init__(self, check_every: int = 4, hold: int = 30) -> None:
        if check_every < 1 or hold < 0:
            raise ValueError(f"StreamDetector needs check_every >= 1 and hold >= 0, got {check_every}, {hold}")
        self._check_every, self._hold = check_every, hold
        self._frames = 0  # frames detected so far
        self._since_faint = hold + 1  # frames since the faint pass last added a blob
        self._raw = 0  # blobs the raw threshold found in the previous frame

    def __call__(self, image: np.ndarray, *, rois: np.ndarray | None = None, seeds: np.ndarray | None = None
                 ) -> Detections:
        """The detections of the next frame ``image`` (H, W) uint8 (``rois``, ``seeds``: as :func:`detect`)."""
        due = self._frames % self._check_every == 0 or self._since_faint < self._hold
        dets, self._raw, added = _detect(image, None, MIN_AREA, MAX_AREA, rois, None, "fit", seeds,
                                         math.inf if due else self._raw)
        self._frames += 1
        self._since_faint = 0 if added else self._since_faint + 1
        return dets
