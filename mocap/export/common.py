"""Conventions shared by the trajectory writers: axis frames and label checks."""

from __future__ import annotations

import os

import numpy as np

from mocap.errors import MocapError

__all__ = ["z_up_to_y_up", "y_up_to_z_up", "check_labels", "identity_colors"]


def z_up_to_y_up(points: np.ndarray) -> np.ndarray:
    """(..., 3) z-up world points -> OpenSim/Motive's y-up frame: (x, y, z) -> (x, z, -y).

    A +90 degree rotation about x; exact (a permutation and a sign change).
    """
    out = np.asarray(points, dtype=np.float64)[..., [0, 2, 1]]
    out[..., 2] *= -1.0
    return out


def y_up_to_z_up(points: np.ndarray) -> np.ndarray:
    """(..., 3) y-up points -> z-up: the inverse of :func:`z_up_to_y_up`, (X, Y, Z) -> (X, -Z, Y)."""
    out = np.asarray(points, dtype=np.float64)[..., [0, 2, 1]]
    out[..., 1] *= -1.0
    return out


def check_labels(labels: list[str], path: str | os.PathLike, fmt: str, forbidden: str = "") -> None:
    """Raise :class:`MocapError` unless every label is non-empty printable ASCII without ``forbidden`` characters.

    C3D, TRC and CSV readers in other programs expect ASCII marker names; the message names the
    first offending label and says how to fix it.
    """
    for i, label in enumerate(labels):
        bad = not label or not label.isascii() or not label.isprintable() or any(ch in label for ch in forbidden)
        if bad:
            shown = "".join(forbidden).replace("\t", "\\t")
            raise MocapError(
                f"{path}: marker {i} label {label!r} cannot be written to {fmt}: labels must be non-empty printable "
                f"ASCII{' without ' + repr(shown) if forbidden else ''}; rename the marker (for example "
                f"{label.encode('ascii', 'replace').decode().replace('?', '_') or f'M{i:03d}'!r})"
            )


def identity_colors(ids: np.ndarray) -> np.ndarray:
    """(K,) integer identities -> (K, 4) RGBA in [0, 1]: hues spread by the golden ratio, full alpha."""
    hue = (np.asarray(ids, dtype=np.float64) * 0.618033988749895) % 1.0
    sector = hue * 6.0
    rgb = np.clip(np.abs((sector[:, None] + np.array([0.0, 4.0, 2.0])) % 6.0 - 3.0) - 1.0, 0.0, 1.0)
    rgb = 1.0 - 0.8 * (1.0 - rgb)  # saturation 0.8, value 1
    return np.column_stack([rgb, np.ones(len(hue))])
