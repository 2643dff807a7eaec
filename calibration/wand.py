"""The calibration wand, and finding its markers among the blobs of one camera image.

A wand carries K = 2 or 3 markers on a straight line at known distances. A 3-marker wand must
be asymmetric (middle marker off centre): the image ratio of the two gaps then tells which end
is which, so every camera numbers the markers alike. With 2 markers the order in each image is
arbitrary; :func:`calibration.initial.order_two_marker_wand` settles it with epipolar geometry.

Blobs that stay at one place through the wave (reflections, stray lights) are removed first
(:func:`static_blobs`). In an image the 3 wand blobs are the triple that is collinear (middle blob within
``line_tol_px`` of the line through the ends) and whose gap ratio is the wand's within
``ratio_tol`` (perspective changes it a little). Frames where no triple fits, or two different
triples fit about equally well, count as "wand not seen" in that camera.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import permutations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from mocap.detections import Detections
from mocap.errors import MocapError

__all__ = ["Wand", "parse_wand", "find_wand", "wand_observations"]

MAX_BLOBS = 12  # images with more blobs than this are skipped (a wand frame shows a few blobs)


@dataclass(frozen=True)
class Wand:
    """A wand: marker positions along its axis.

    Attributes:
        offsets: (K,) distance of each marker from marker 0, metres, increasing (``offsets[0] == 0``).
    """

    offsets: tuple[float, ...]

    def __post_init__(self) -> None:
        o = np.asarray(self.offsets, dtype=np.float64)
        if o.ndim != 1 or len(o) not in (2, 3) or o[0] != 0 or not (np.diff(o) > 0).all():
            raise MocapError(f"--wand {self.describe()}: give 2 or 3 increasing marker positions along the wand in "
                             "metres starting at 0, e.g. 0,0.15,0.5 (or one length, e.g. 0.5, for 2 markers)")
        if len(o) == 3 and abs(o[1] / o[2] - 0.5) < 0.1:
            raise MocapError(f"--wand {self.describe()}: the middle marker is too close to the centre to tell the "
                             "ends apart; a 3-marker wand needs gaps in a ratio of at most 0.4 : 0.6")

    def describe(self) -> str:
        return ",".join(f"{v:g}" for v in self.offsets)

    @property
    def array(self) -> np.ndarray:
        """(K,) offsets, metres."""
        return np.asarray(self.offsets, dtype=np.float64)

    @property
    def n_markers(self) -> int:
        return len(self.offsets)

    @property
    def length(self) -> float:
        """Distance between the end markers, metres."""
        return float(self.offsets[-1])

    @property
    def ratio(self) -> float:
        """Position of the middle marker as a fraction of the length (3 markers), else NaN."""
        return self.offsets[1] / self.offsets[2] if self.n_markers == 3 else float("nan")


def parse_wand(text: str) -> Wand:
    """``"0,0.15,0.5"`` (marker positions, m) or ``"0.5"`` (a 2-marker wand's length, m) -> :class:`Wand`."""
    try:
        values = [float(v) for v in text.replace(" ", "").split(",") if v]
    except ValueError:
        raise MocapError(f"--wand {text!r}: give marker positions in metres, e.g. 0,0.15,0.5") from None
    if len(values) == 1:
        values = [0.0, values[0]]
    return Wand(tuple(values))


_TRIPLES = {n: np.array(list(permutations(range(n), 3)), dtype=np.intp) for n in range(3, MAX_BLOBS + 1)}


def find_wand(xy: np.ndarray, wand: Wand, line_tol_px: float = 1.5, ratio_tol: float = 0.08) -> np.ndarray | None:
    """The wand's markers among one image's blobs.

    Args:
        xy: (N, 2) blob centroids, pixels.
        wand: the wand.
        line_tol_px: largest distance of the middle blob from the line through the ends, pixels.
        ratio_tol: largest difference between the image gap ratio and the wand's.

    Returns:
        (K, 2) the markers' blobs in wand order, or None (not found, or ambiguous).
    """
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    n = len(xy)
    if wand.n_markers == 2:
        return xy.copy() if n == 2 else None
    if n < 3 or n > MAX_BLOBS:
        return None
    t = _TRIPLES[n]
    a, m, b = xy[t[:, 0]], xy[t[:, 1]], xy[t[:, 2]]
    ab = b - a
    length = np.linalg.norm(ab, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        along = ((m - a) * ab).sum(axis=1) / length**2
        off_line = np.abs(ab[:, 0] * (m - a)[:, 1] - ab[:, 1] * (m - a)[:, 0]) / length
    # A triple and its reverse are the same candidate: keep the order whose ratio matches the wand's.
    score = np.abs(along - wand.ratio) / ratio_tol + off_line / line_tol_px
    ok = (length > 4 * line_tol_px) & (off_line < line_tol_px) & (np.abs(along - wand.ratio) < ratio_tol)
    if not ok.any():
        return None
    good = np.flatnonzero(ok)
    order = good[np.argsort(score[good])]
    best = t[order[0]]
    for other in order[1:]:
        if set(t[other]) != set(best) and score[other] < 2 * score[order[0]] + 1:
            return None  # two different triples fit: ambiguous
    return xy[best]


def static_blobs(xy: Sequence[np.ndarray], radius_px: float = 0.5, min_fraction: float = 0.1) -> list[np.ndarray]:
    """Which blobs of one camera stay put across a wave: reflections and stray lights, not the wand.

    Args:
        xy: per frame, (N_f, 2) blob centroids of one camera.
        radius_px: how far a still blob may wander, pixels.
        min_fraction: a place occupied in at least this fraction of the frames (and 10 frames) is static.

    Returns:
        Per frame, (N_f,) bool: the blob sits on a static place.
    """
    counts = [len(p) for p in xy]
    points = np.concatenate([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in xy]) if xy else np.zeros((0, 2))
    static = np.zeros(len(points), dtype=bool)
    if len(points):
        pairs = cKDTree(points).query_pairs(radius_px, output_type="ndarray")
        graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(points), len(points)))
        _, label = connected_components(graph, directed=False)
        size = np.bincount(label)
        static = size[label] >= max(10, min_fraction * len(xy))
    return np.split(static, np.cumsum(counts)[:-1])


def wand_observations(frames: Sequence[Sequence[Detections | np.ndarray]], wand: Wand) -> np.ndarray:
    """Find the wand in every camera of every frame, after removing each camera's static blobs.

    Args:
        frames: per frame, one :class:`Detections` (or (N, 2) array of centroids) per camera.
        wand: the wand.

    Returns:
        (F, C, K, 2) the wand markers' distorted pixels; NaN where that camera did not see the wand.
    """
    n_frames = len(frames)
    n_cams = len(frames[0]) if n_frames else 0
    out = np.full((n_frames, n_cams, wand.n_markers, 2), np.nan)
    for c in range(n_cams):
        xy = [row[c].xy if isinstance(row[c], Detections) else np.asarray(row[c]) for row in frames]
        for f, (blobs, still) in enumerate(zip(xy, static_blobs(xy), strict=True)):
            found = find_wand(blobs[~still], wand)
            if found is not None:
                out[f, c] = found
    return out
