"""Self-occlusion: a body made of capsules hides the markers behind it.

A capsule is a segment (two end points per frame) with a radius. The line of sight from a
camera centre to a marker is blocked when it passes closer than ``radius`` to the axis of a
capsule. A marker lying INSIDE a capsule (closer to its axis than the radius: the capsule is a
rough approximation there, or the capsule was built through that marker) is never hidden by that
capsule; markers sit on the skin, so a marker on the far side of its own body part is still
hidden by it, while one facing the camera is not.

Two body models:

* the built-in marching body (:mod:`mocap.synth.body`) has true segment capsules;
* recorded motion gets :func:`capsules_from_markers`, an approximation from the markers alone
  (see its docstring).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

__all__ = ["Capsules", "capsules_from_markers", "occluded", "segment_distance", "point_segment_distance"]

_EPS = 1e-12
_CHUNK_ELEMENTS = 600_000  # (frames x markers x capsules) per batch


@dataclass(eq=False)
class Capsules:
    """Body capsules over time.

    Attributes:
        a: (F, K, 3) first end of each capsule axis, m (NaN: capsule absent that frame).
        b: (F, K, 3) second end, m.
        radius: (K,) radii, m.
        names: (K,) names, for the record.
    """

    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray
    names: list[str]

    def __len__(self) -> int:
        return len(self.radius)

    def window(self, start: int, stop: int) -> Capsules:
        """The frames ``start:stop``."""
        return Capsules(self.a[start:stop], self.b[start:stop], self.radius, self.names)


def point_segment_distance(p: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance from points to segments; (..., 3) arrays broadcast -> (...,) m."""
    d = b - a
    t = np.clip(np.einsum("...i,...i", p - a, d) / np.maximum(np.einsum("...i,...i", d, d), _EPS), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * d), axis=-1)


def segment_distance(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Shortest distance between segments p0-p1 and q0-q1; (..., 3) arrays broadcast -> (...,).

    Closest points of two segments (Ericson, Real-Time Collision Detection, sec. 5.1.9), vectorised;
    degenerate segments (points) are handled.
    """
    d1 = p1 - p0
    d2 = q1 - q0
    r = p0 - q0
    a = np.einsum("...i,...i", d1, d1)
    e = np.einsum("...i,...i", d2, d2)
    f = np.einsum("...i,...i", d2, r)
    c = np.einsum("...i,...i", d1, r)
    b = np.einsum("...i,...i", d1, d2)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s_lo = np.where(a > _EPS, np.clip(-c / a, 0.0, 1.0), 0.0)  # closest to q0 (also: q is a point)
        s_hi = np.where(a > _EPS, np.clip((b - c) / a, 0.0, 1.0), 0.0)  # closest to q1
        s = np.where(denom > _EPS * np.maximum(a * e, _EPS), np.clip((b * f - c * e) / denom, 0.0, 1.0), 0.0)
        s = np.where(e > _EPS, s, s_lo)
        t = np.where(e > _EPS, (b * s + f) / e, 0.0)
    s = np.where(t < 0, s_lo, np.where(t > 1, s_hi, s))
    t = np.clip(t, 0.0, 1.0)
    return np.linalg.norm(p0 + s[..., None] * d1 - q0 - t[..., None] * d2, axis=-1)


def occluded(center: np.ndarray, points: np.ndarray, capsules: Capsules) -> np.ndarray:
    """Which markers a camera cannot see because a capsule is in the way.

    Args:
        center: (3,) camera centre, m.
        points: (F, M, 3) marker positions, m (NaN: no sample).
        capsules: the body, over the same F frames.

    Returns:
        (F, M) bool, True where the line of sight crosses a capsule the marker is not inside.
    """
    points = np.asarray(points, dtype=np.float64)
    F, M = points.shape[:2]
    out = np.zeros((F, M), dtype=bool)
    K = len(capsules)
    if K == 0 or M == 0:
        return out
    center = np.asarray(center, dtype=np.float64)
    step = max(1, _CHUNK_ELEMENTS // (M * K))
    radius = capsules.radius[None, None, :]
    for start in range(0, F, step):
        sl = slice(start, start + step)
        x = points[sl][:, :, None, :]  # (f, M, 1, 3)
        a = capsules.a[sl][:, None, :, :]  # (f, 1, K, 3)
        b = capsules.b[sl][:, None, :, :]
        with np.errstate(invalid="ignore"):
            inside = point_segment_distance(x, a, b) < radius
            blocked = segment_distance(center, x, a, b) < radius
        out[sl] = (blocked & ~inside).any(axis=2)
    return out


def _subject_groups(labels: list[str]) -> dict[str, np.ndarray]:
    """Marker indices per subject, from ``Subject:Marker`` label prefixes (one group if none)."""
    groups: dict[str, list[int]] = {}
    for i, label in enumerate(labels):
        groups.setdefault(label.split(":", 1)[0] if ":" in label else "", []).append(i)
    return {name: np.array(idx) for name, idx in groups.items()}


def capsules_from_markers(labels: list[str], positions: np.ndarray, limb_radius: float = 0.035,
                          max_links: int = 2) -> Capsules:
    """An approximate capsule body built from recorded markers alone.

    The approximation (per subject, subjects told apart by ``Subject:`` label prefixes):

    * limbs: markers that keep a steady distance (std < 8 % of the mean, mean 5-45 cm; so they sit
      on one body segment or one rigid cluster) are linked to their ``max_links`` nearest such
      partners by a capsule of radius ``limb_radius`` through the two markers;
    * torso: if the subject's markers span a standing person (median height span > 1.2 m), one
      vertical-ish capsule from the median position of the markers at the 40th height percentile
      to that of the markers at the 80th (per frame), radius 0.6 x the median distance of the
      markers between those heights from the axis, clipped to 8-16 cm.

    A marker is never hidden by a capsule that contains it (see the module docstring), so the
    capsules through a marker never hide it.

    Args:
        labels: (M,) marker labels.
        positions: (F, M, 3) z-up positions, m, NaN in gaps.
        limb_radius: radius of the marker-to-marker capsules, m.
        max_links: links per marker.
    """
    positions = np.asarray(positions, dtype=np.float64)
    F = positions.shape[0]
    ends_a: list[np.ndarray] = []
    ends_b: list[np.ndarray] = []
    radii: list[float] = []
    names: list[str] = []
    for subject, idx in _subject_groups(labels).items():
        p = positions[:, idx]
        diff = p[:, :, None, :] - p[:, None, :, :]
        with np.errstate(invalid="ignore"):
            dist = np.linalg.norm(diff, axis=-1)  # (F, m, m)
        enough = np.isfinite(dist).sum(axis=0) >= max(2, F // 4)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            mean = np.nanmean(dist, axis=0)
            std = np.nanstd(dist, axis=0)
        steady = enough & (mean >= 0.05) & (mean <= 0.45) & (std < 0.08 * mean)
        np.fill_diagonal(steady, False)
        cost = np.where(steady, mean, np.inf)
        links = set()
        for i in range(len(idx)):
            for j in np.argsort(cost[i])[:max_links]:
                if np.isfinite(cost[i, j]):
                    links.add((min(i, int(j)), max(i, int(j))))
        for i, j in sorted(links):
            ends_a.append(p[:, i])
            ends_b.append(p[:, j])
            radii.append(limb_radius)
            names.append(f"{labels[idx[i]]}-{labels[idx[j]]}")
        torso = _torso_capsule(p)
        if torso is not None:
            ends_a.append(torso[0])
            ends_b.append(torso[1])
            radii.append(torso[2])
            names.append(f"{subject or 'subject'} torso")
    if not radii:
        empty = np.zeros((F, 0, 3))
        return Capsules(empty, empty.copy(), np.zeros(0), [])
    return Capsules(np.stack(ends_a, axis=1), np.stack(ends_b, axis=1), np.array(radii), names)


def _torso_capsule(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, float] | None:
    """(F, 3) lower and upper axis ends and a radius for one subject's markers (F, m, 3), or None."""
    z = p[..., 2]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        span = np.nanpercentile(z, 95, axis=1) - np.nanpercentile(z, 5, axis=1)
        if not np.isfinite(span).any() or np.nanmedian(span) < 1.2:
            return None
        ends = []
        for q in (40, 80):
            level = np.nanpercentile(z, q, axis=1)[:, None]
            band = np.abs(z - level) < 0.12
            xy = np.where(band[..., None], p[..., :2], np.nan)
            ends.append(np.column_stack([np.nanmedian(xy, axis=1), level[:, 0]]))
        lower, upper = ends
        band = (z >= np.nanpercentile(z, 40, axis=1)[:, None]) & (z <= np.nanpercentile(z, 80, axis=1)[:, None])
        axis_dist = point_segment_distance(p, lower[:, None], upper[:, None])
        radius = 0.6 * np.nanmedian(np.where(band, axis_dist, np.nan))
    if not np.isfinite(radius):
        return None
    return lower, upper, float(np.clip(radius, 0.08, 0.16))
