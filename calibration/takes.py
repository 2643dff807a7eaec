"""Reading calibration takes (wand wave, L-frame, floor markers) as blobs per frame per camera.

A calibration take is an ordinary take (DESIGN.md sec. 1): images are read with
:func:`mocap.take.open_take` and their blobs found by the engine's detector
(:func:`mocap.detect.detect`); a centroid take gives its blobs directly. Only the intrinsics of
the take's ``calibration.toml`` are used. ``take.toml`` may state the wand (``wand_m``, marker
positions along it, m) and the L-frame (``lframe_m``, marker coordinates, m).
"""

from __future__ import annotations

import os
import tomllib
from pathlib import Path
from typing import Any

from tqdm import tqdm

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.errors import MocapError

__all__ = ["read_blobs", "take_facts"]


def take_facts(path: str | os.PathLike) -> dict[str, Any]:
    """The take's ``take.toml`` as a dict (empty when absent)."""
    file = Path(path) / "take.toml"
    if not file.exists():
        return {}
    try:
        return tomllib.loads(file.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise MocapError(f"{file}: not valid TOML ({exc}); fix or remove it") from None


def read_blobs(path: str | os.PathLike, every: int = 1, progress: bool = True
               ) -> tuple[Rig, list[list[Detections]]]:
    """The blobs of every ``every``-th frame of a take.

    Returns:
        ``(rig, frames)``: the take's cameras (intrinsics), and per frame one :class:`Detections`
        per camera in rig order (empty where a frame could not be decoded).
    """
    from mocap.take import open_take

    take = open_take(path)
    frames: list[list[Detections]] = []
    stop = take.n_frames
    with tqdm(total=stop, desc=f"reading {Path(path).name}", unit="frame", disable=None if progress else True) as bar:
        if take.kind == "centroids":
            for index, dets in take.centroids(0, stop):
                if index % every == 0:
                    frames.append(list(dets))
                bar.update(1)
        else:
            from mocap.detect import detect

            for index, images in take.images(0, stop):
                if index % every == 0:
                    frames.append([detect(im) if im is not None else Detections.empty() for im in images])
                bar.update(1)
    if not frames:
        raise MocapError(f"{path}: the take has no frames")
    return take.rig, frames
