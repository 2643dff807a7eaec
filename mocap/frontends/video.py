"""Reading a colour take for the front ends: the take layout of DESIGN.md, but frames stay BGR colour.

Per camera of ``calibration.toml``: a video ``<name>.avi|.mp4|.mkv`` or a folder ``<name>/`` of numbered
PNG frames. Frames are streamed one camera at a time (the front ends track each camera on its own), so
memory stays flat. The frame rate comes from the command line, else ``take.toml``, else the first video.
"""

from __future__ import annotations

import re
import tomllib
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from mocap.camera import Rig, load_rig
from mocap.errors import MocapError

__all__ = ["ColourTake", "open_colour_take"]

_VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv")


def _natural_key(path: Path) -> list[int | str]:
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


class ColourTake:
    """A take folder opened for colour reading.

    Attributes:
        folder: the take folder.
        rig: its calibration.
        fps: frame rate, Hz.
        sources: per camera (rig order), its video file or PNG folder.
    """

    def __init__(self, folder: Path, rig: Rig, fps: float, sources: list[Path]) -> None:
        self.folder, self.rig, self.fps, self.sources = folder, rig, fps, sources

    def frames(self, camera: int) -> Iterator[np.ndarray]:
        """Yield camera ``camera``'s frames as (H, W, 3) uint8 BGR (grey files come back as 3 equal channels).

        Raises:
            MocapError: a frame cannot be decoded or its size differs from the calibration's.
        """
        src = self.sources[camera]
        size = self.rig[camera].size
        if src.is_dir():
            items: Iterator[tuple[str, np.ndarray | None]] = (
                (str(p), cv2.imread(str(p), cv2.IMREAD_COLOR)) for p in sorted(src.glob("*.png"), key=_natural_key))
        else:
            items = self._video(src)
        for k, (where, frame) in enumerate(items):
            if frame is None:
                raise MocapError(f"{where}: cannot decode frame {k}; re-export the recording")
            if (frame.shape[1], frame.shape[0]) != size:
                raise MocapError(f"{where}: frame {k} is {frame.shape[1]}x{frame.shape[0]} but calibration.toml "
                                 f"says camera {self.rig[camera].name!r} is {size[0]}x{size[1]}")
            yield frame

    @staticmethod
    def _video(path: Path) -> Iterator[tuple[str, np.ndarray | None]]:
        cap = cv2.VideoCapture(str(path))
        if not cap.isOpened():
            raise MocapError(f"{path}: OpenCV cannot open this video; convert it to FFV1 .mkv or PNG frames")
        try:
            while True:
                ok, frame = cap.read()
                if not ok:
                    return
                yield str(path), frame
        finally:
            cap.release()


def open_colour_take(folder: str | Path, fps: float | None = None) -> ColourTake:
    """Open a take folder: calibration, one colour recording per camera, frame rate.

    Raises:
        MocapError: missing folder, calibration or recording, or no frame rate anywhere.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise MocapError(f"{folder}: take folder not found")
    rig = load_rig(folder / "calibration.toml")
    sources = []
    for cam in rig.cameras:
        found = [folder / f"{cam.name}{s}" for s in _VIDEO_SUFFIXES if (folder / f"{cam.name}{s}").is_file()]
        if (folder / cam.name).is_dir():
            found.append(folder / cam.name)
        if not found:
            raise MocapError(f"{folder}: no recording for camera {cam.name!r}; expected {cam.name}.mkv (or .avi, "
                             f".mp4) or a folder {cam.name}/ of PNG frames")
        sources.append(found[0])
    if fps is None and (folder / "take.toml").is_file():
        try:
            fps = tomllib.loads((folder / "take.toml").read_text(encoding="utf-8")).get("fps")
        except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
            raise MocapError(f"{folder / 'take.toml'}: not valid TOML ({exc})") from None
    if fps is None and sources[0].is_file():
        cap = cv2.VideoCapture(str(sources[0]))
        fps = cap.get(cv2.CAP_PROP_FPS) or None
        cap.release()
    if fps is None or not np.isfinite(float(fps)) or float(fps) <= 0:
        raise MocapError(f"{folder}: frame rate unknown; put 'fps = 30.0' in take.toml or pass --fps")
    return ColourTake(folder, rig, float(fps), sources)
