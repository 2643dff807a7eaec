"""Ground truth of a synthetic take: what was really there, for scoring.

Stored as one ``.npz`` file (plain arrays and a JSON string; no pickle), kept outside
the take directory so the engine can never read it by accident.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError

__all__ = ["Truth", "save_truth", "load_truth"]


@dataclass(eq=False)
class Truth:
    """Ground truth of a rendered take.

    Attributes:
        labels: (M,) marker names.
        fps: frame rate, Hz.
        positions: (F, M, 3) world positions, metres; NaN where the source motion has a gap.
        camera_names: (C,) camera names, in calibration order.
        uv: (F, C, M, 2) true centroid of each marker's blob in each image, distorted pixels;
            NaN where the marker is not in front of / inside that camera.
        visible: (F, C, M) bool: the marker was drawn, unoccluded, in that camera's image.
        sigma_px: (F, C, M) Cramer-Rao standard deviation (pixels, per axis) of that blob's
            centroid given the rendered profile and sensor noise; NaN where not visible.
        settings: every rendering setting, for the record.
    """

    labels: list[str]
    fps: float
    positions: np.ndarray
    camera_names: list[str]
    uv: np.ndarray
    visible: np.ndarray
    sigma_px: np.ndarray
    settings: dict[str, Any] = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return self.positions.shape[0]

    @property
    def views(self) -> np.ndarray:
        """(F, M) number of cameras that saw each marker."""
        return self.visible.sum(axis=1)


def save_truth(truth: Truth, path: str | os.PathLike) -> None:
    """Write ``truth`` as a compressed ``.npz`` atomically."""
    buf = io.BytesIO()
    np.savez_compressed(
        buf,
        labels=np.array(truth.labels, dtype=str),
        fps=np.float64(truth.fps),
        positions=truth.positions.astype(np.float64),
        camera_names=np.array(truth.camera_names, dtype=str),
        uv=truth.uv.astype(np.float32),
        visible=truth.visible.astype(bool),
        sigma_px=truth.sigma_px.astype(np.float32),
        settings=np.array(json.dumps(truth.settings, default=str)),
    )
    atomic_write_bytes(path, buf.getvalue())


def load_truth(path: str | os.PathLike) -> Truth:
    """Read a truth file written by :func:`save_truth`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return Truth(
                labels=[str(s) for s in z["labels"]],
                fps=float(z["fps"]),
                positions=z["positions"].astype(np.float64),
                camera_names=[str(s) for s in z["camera_names"]],
                uv=z["uv"].astype(np.float64),
                visible=z["visible"].astype(bool),
                sigma_px=z["sigma_px"].astype(np.float64),
                settings=json.loads(str(z["settings"])),
            )
    except FileNotFoundError:
        raise MocapError(
            f"{path}: truth file not found (mocap synth writes it beside the take, as TAKE.truth.npz)"
        ) from None
    except (KeyError, ValueError, OSError) as exc:
        raise MocapError(f"{path}: not a mocap truth file ({exc})") from None
