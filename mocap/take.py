"""Reading a take: a folder of calibration + one recording per camera, streamed frame by frame.

A take folder (DESIGN.md section 1, docs/take-format.md) holds ``calibration.toml``, an optional
``take.toml`` and, per camera (named as in the calibration), either a video ``<name>.avi|.mp4|.mkv``,
a folder ``<name>/`` of numbered 8-bit PNG frames, or a centroid file ``<name>.centroids.csv|.npz``
(:mod:`mocap.centroids`). Frame k of every camera is the same instant.

Problems are reported as :class:`MocapError` naming the file and the fix; two are documented
degradations with a logged warning instead: recordings that no camera of the calibration owns
are ignored, and cameras with different frame counts are read up to the shortest one. A frame
that cannot be decoded is returned as ``None`` (warning names the file and frame).
"""

from __future__ import annotations

import logging
import math
import os
import re
import tomllib
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from mocap.camera import Rig, load_rig
from mocap.centroids import CENTROID_SUFFIXES, open_centroids
from mocap.detections import Detections
from mocap.errors import MocapError

__all__ = ["Take", "open_take", "VIDEO_SUFFIXES"]

log = logging.getLogger(__name__)

VIDEO_SUFFIXES = (".avi", ".mp4", ".mkv")
DECODE_THREADS = 2  # cameras decoded at once, one frame ahead of the caller (0 or 1: in the caller's thread)
_GREY_FOURCC = cv2.VideoWriter_fourcc(*"Y800")  # FFmpeg's tag for 8-bit grey video (e.g. FFV1 gray)
MAX_LEAD_FRAMES = 10  # PNG numberings this close are one counter with files missing at the start
_MAX_FRAME_WARNINGS = 5  # per camera; later undecodable frames are counted, not each logged


def _natural_key(path: Path) -> list[Any]:
    """Sort key putting ``frame2.png`` before ``frame10.png``."""
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", path.name)]


def _numbered_frames(files: list[Path]) -> tuple[list[Path | None], tuple[int, int] | None]:
    """``files`` (sorted) placed by the number in their names (its last digits): a number missing from the run
    leaves a None in its place, so the frames after it are not moved up a frame; numbered in steps (every other
    frame exported), each step is one frame. Names without a number, with one twice, or whose numbers leave
    more than half the run empty (timestamps), keep their order. Also returns the first number and the step
    (None where the names are not frame numbers)."""
    numbers = []
    for f in files:
        digits = re.findall(r"\d+", f.stem)
        numbers.append(int(digits[-1]) if digits else None)
    if len(files) < 2 or None in numbers or len(set(numbers)) < len(numbers):
        return list(files), None
    first = min(numbers)
    step = math.gcd(*(n - first for n in numbers))
    if (max(numbers) - first) // step + 1 > 2 * len(files):  # half the run missing: timestamps, not frame numbers
        return list(files), None
    slots: list[Path | None] = [None] * ((max(numbers) - first) // step + 1)
    for f, n in zip(files, numbers, strict=True):
        slots[(n - first) // step] = f
    return slots, (first, step)


def _align_numbering(recordings: list[_Recording]) -> None:
    """PNG folders numbered alike whose first numbers differ by a few frames (``MAX_LEAD_FRAMES``): the first
    files of the later ones are missing, and their frames start blind instead of one camera running ahead of the
    others. Numbers further apart are independent counters: frames are matched by position."""
    numbering = [rec.numbering for rec in recordings]
    if not numbering or any(n is None for n in numbering) or len({step for _, step in numbering}) > 1:
        return
    step = numbering[0][1]
    origin = min(first for first, _ in numbering)
    if any((first - origin) % step for first, _ in numbering):
        return
    leads = [(first - origin) // step for first, _ in numbering]
    if not 0 < max(leads) <= MAX_LEAD_FRAMES:
        return
    for rec, lead in zip(recordings, leads, strict=True):
        if lead:
            rec.pad_front(lead)
            log.warning("%s: its PNG numbering starts %d frame(s) after the other cameras'; the camera is treated "
                        "as blind in frame(s) 0-%d", rec.path, lead, lead - 1)


def _to_grey(frame: np.ndarray) -> np.ndarray:
    """(H, W) or (H, W, 3|4) uint8 -> (H, W) uint8 grey (equal channels stay exact)."""
    if frame.ndim == 2:
        return frame
    if frame.shape[2] == 1:
        return frame[:, :, 0]
    return cv2.cvtColor(frame, cv2.COLOR_BGRA2GRAY if frame.shape[2] == 4 else cv2.COLOR_BGR2GRAY)


def _open_video(path: Path) -> cv2.VideoCapture:
    """A capture of ``path`` that hands out 8-bit grey videos as (H, W) frames without a BGR round trip."""
    cap = cv2.VideoCapture(str(path))
    if cap.isOpened() and int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)) == _GREY_FOURCC:
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0.0)
    return cap


class _Recording:
    """One camera's images: a video or a PNG folder, with a frame count and a decoder."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.fps: float | None = None
        self._warned = 0
        self._shift: int | None = None  # bits dropped from 16-bit PNGs (None: none seen yet)
        if path.is_dir():
            self._files, self.numbering = _numbered_frames(sorted(
                (p for p in path.iterdir() if p.suffix.lower() == ".png" and p.is_file()), key=_natural_key))
            self.n_frames = len(self._files)
            missing = [i for i, f in enumerate(self._files) if f is None]
            if missing:
                log.warning("%s: %d frame(s) missing from the files' numbering (first: frame %d); the camera is "
                            "treated as blind there and the other frames keep their place", path, len(missing),
                            missing[0])
            first = self._read_png(0) if self._files else None
            if self._files and first is None:
                raise MocapError(f"{self._files[0]}: cannot be read as an 8- or 16-bit PNG image; re-export the frames")
        else:
            self._files, self.numbering = [], None
            cap = _open_video(path)
            try:
                if not cap.isOpened():
                    raise MocapError(f"{path}: not a video OpenCV can read; re-encode it (e.g. ffmpeg -c:v ffv1) "
                                     "or replace it by a folder of PNG frames")
                self.n_frames = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
                fps = cap.get(cv2.CAP_PROP_FPS)
                self.fps = float(fps) if np.isfinite(fps) and fps > 0 else None
                ok, frame = cap.read()
                if not ok:
                    raise MocapError(f"{path}: the video's first frame cannot be decoded; the file is empty or "
                                     "corrupt, re-export it")
                first = _to_grey(frame)
                if self.n_frames <= 0:  # the container does not say: count by decoding
                    self.n_frames = 1 + sum(1 for _ in iter(cap.grab, False))
            finally:
                cap.release()
        self.size = None if first is None else (first.shape[1], first.shape[0])  # (w, h)

    def pad_front(self, frames: int) -> None:
        """Put ``frames`` missing (blind) frames before a PNG folder's first file."""
        self._files = [None] * frames + self._files
        self.n_frames += frames

    def _read_png(self, index: int) -> np.ndarray | None:
        image = cv2.imread(str(self._files[index]), cv2.IMREAD_UNCHANGED)
        if image is not None and image.dtype == np.uint16:
            image = self._to_8_bits(image)
        if image is None or image.dtype != np.uint8:
            return None
        return _to_grey(image)

    def _to_8_bits(self, image: np.ndarray) -> np.ndarray:
        """A 16-bit PNG (10-, 12- or 16-bit sensor data) scaled to 8 bits: the bit depth is taken from the
        recording's first 16-bit frame (its brightest pixel), and brighter pixels later saturate."""
        if self._shift is None:
            bits = max(8, int(image.max()).bit_length())
            self._shift = bits - 8
            log.info("%s: 16-bit PNGs holding %d-bit values, scaled to 8 bits for detection", self.path, bits)
        return np.minimum(image >> self._shift, 255).astype(np.uint8)

    def _bad_frame(self, index: int, what: str) -> None:
        self._warned += 1
        if self._warned <= _MAX_FRAME_WARNINGS:
            log.warning("%s: frame %d %s; the camera is treated as blind in that frame%s", self.path, index, what,
                        " (further such warnings for this recording are not shown)"
                        if self._warned == _MAX_FRAME_WARNINGS else "")

    def frames(self, start: int, stop: int, size: tuple[int, int]) -> Iterator[np.ndarray | None]:
        """(H, W) uint8 grey frames ``start..stop-1``; None for one that cannot be decoded."""
        self._warned = 0
        if self._files:
            for index in range(start, stop):
                if self._files[index] is None:  # (missing from the numbering: reported when opened)
                    yield None
                    continue
                image = self._read_png(index)
                if image is None:
                    self._bad_frame(index, f"({self._files[index].name}) cannot be read as an 8- or 16-bit PNG")
                elif (image.shape[1], image.shape[0]) != size:
                    raise MocapError(f"{self._files[index]}: image size {image.shape[1]}x{image.shape[0]} differs "
                                     f"from the calibration's {size[0]}x{size[1]}; all frames must have that size")
                yield image
            return
        cap = _open_video(self.path)
        try:
            for _ in range(start):  # decode-and-drop: exact on every codec, unlike seeking
                cap.grab()
            for index in range(start, stop):
                ok, frame = cap.read()
                if not ok:
                    self._bad_frame(index, "cannot be decoded")
                    yield None
                else:
                    yield _to_grey(frame)
        finally:
            cap.release()


@dataclass
class Take:
    """An opened take (use :func:`open_take`).

    Attributes:
        path: the take folder.
        rig: the calibration.
        fps: frame rate, Hz.
        n_frames: frames every camera has (the shortest recording).
        camera_names: camera names, in rig order.
        kind: "images" (videos / PNG folders) or "centroids" (centroid files).
        info: the ``take.toml`` table (empty without one).
    """

    path: Path
    rig: Rig
    fps: float
    n_frames: int
    camera_names: list[str]
    kind: str
    info: dict[str, Any] = field(default_factory=dict)
    _sources: list[Any] = field(default_factory=list, repr=False)

    def _range(self, start: int, stop: int | None) -> tuple[int, int]:
        stop = self.n_frames if stop is None else min(stop, self.n_frames)
        if start < 0:
            raise MocapError(f"{self.path}: start frame {start} is negative")
        return start, max(start, stop)

    def images(self, start: int = 0, stop: int | None = None, threads: int = DECODE_THREADS
               ) -> Iterator[tuple[int, list[np.ndarray | None]]]:
        """Yield ``(frame_index, images)``: one (H, W) uint8 grey image per camera in rig order, or None
        where that camera's frame could not be decoded (a warning names the file and frame).

        With ``threads`` > 1 the cameras' next frames are decoded in that many threads while the caller
        works on the current one (the decoders release the GIL); 0 or 1 decodes in the caller's thread.
        """
        if self.kind != "images":
            raise MocapError(f"{self.path}: this take holds centroid files, not images")
        start, stop = self._range(start, stop)
        streams = [rec.frames(start, stop, cam.size) for rec, cam in zip(self._sources, self.rig, strict=True)]
        if threads <= 1 or stop - start < 2:
            for index, images in zip(range(start, stop), zip(*streams, strict=True), strict=True):
                yield index, list(images)
            return
        with ThreadPoolExecutor(threads, thread_name_prefix="mocap-decode") as pool:
            pending = [pool.submit(next, s) for s in streams]
            for index in range(start, stop):
                images = [f.result() for f in pending]  # each camera's stream is advanced by one task at a time
                if index + 1 < stop:
                    pending = [pool.submit(next, s) for s in streams]
                yield index, images

    def centroids(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, list[Detections]]]:
        """Yield ``(frame_index, detections)``: one :class:`Detections` per camera in rig order."""
        if self.kind != "centroids":
            raise MocapError(f"{self.path}: this take holds images; detect blobs first (mocap.detect)")
        start, stop = self._range(start, stop)
        streams = [f.frames(start, stop) for f in self._sources]
        yield from zip(range(start, stop), (list(d) for d in zip(*streams, strict=True)), strict=True)


def _read_take_toml(path: Path) -> dict[str, Any]:
    if not path.exists():
        return {}
    try:
        info = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise MocapError(f"{path}: not valid TOML ({exc}); fix it or delete it") from None
    fps = info.get("fps")
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, int | float) or not 0 < fps < 1e6):
        raise MocapError(f"{path}: 'fps' must be a positive number of frames per second, got {fps!r}")
    return info


def _find_recordings(folder: Path) -> dict[str, list[Path]]:
    """Candidate recordings in a take folder, by the camera name their file name implies."""
    found: dict[str, list[Path]] = {}
    for entry in sorted(folder.iterdir()):
        name = entry.name
        lower = name.lower()
        if name.startswith("."):
            continue
        if entry.is_dir():
            if not any(p.suffix.lower() == ".png" for p in entry.iterdir()):
                continue
            stem = name
        elif lower.endswith(CENTROID_SUFFIXES):
            stem = name[: -len(".centroids.csv")]
        elif entry.suffix.lower() in VIDEO_SUFFIXES:
            stem = entry.stem
        else:
            continue
        found.setdefault(stem, []).append(entry)
    return found


def open_take(path: str | os.PathLike, fps: float | None = None) -> Take:
    """Open a take folder, check it, and return a :class:`Take` that streams it.

    Args:
        path: the take folder.
        fps: frame rate, Hz; overrides ``take.toml``, which overrides the videos' metadata.

    Raises:
        MocapError: no such folder, no calibration, a camera without a recording (or with two),
            an unreadable recording, image size different from the calibration, no frame rate,
            or no frames.
    """
    folder = Path(path)
    if not folder.exists():
        raise MocapError(f"{folder}: no such take folder")
    if not folder.is_dir():
        raise MocapError(f"{folder}: a take is a folder holding calibration.toml and one recording per camera, "
                         "not a file")
    rig = load_rig(folder / "calibration.toml")
    info = _read_take_toml(folder / "take.toml")
    found = _find_recordings(folder)
    names = rig.names
    for stem in sorted(set(found) - set(names)):
        log.warning("%s: %s has no camera named %r in calibration.toml; ignored", folder,
                    ", ".join(p.name for p in found[stem]), stem)

    def kind_of(p: Path) -> str:
        return "centroids" if p.name.lower().endswith(CENTROID_SUFFIXES) else "images"

    per_camera: list[Path] = []
    missing = [n for n in names if n not in found]
    if missing:
        raise MocapError(f"{folder}: no recording for camera(s) {missing} of calibration.toml; add "
                         f"<name>.mkv/.avi/.mp4, a <name>/ folder of PNG frames or <name>.centroids.csv for each, "
                         "or remove the camera from the calibration")
    for n in names:
        paths = found[n]
        if len(paths) > 1:
            raise MocapError(f"{folder}: camera {n!r} has several recordings ({', '.join(p.name for p in paths)}); "
                             "keep one")
        per_camera.append(paths[0])
    kinds = {kind_of(p) for p in per_camera}
    if len(kinds) > 1:
        raise MocapError(f"{folder}: some cameras have images and some centroid files; a take holds one kind")
    kind = kinds.pop()

    declared = info.get("frames")
    if declared is not None and (isinstance(declared, bool) or not isinstance(declared, int) or declared < 0):
        raise MocapError(f"{folder / 'take.toml'}: 'frames' must be a whole number >= 0, got {declared!r}")
    sources: list[Any]
    if kind == "images":
        sources = [_Recording(p) for p in per_camera]
        _align_numbering(sources)
        for rec, cam in zip(sources, rig, strict=True):
            if rec.size is not None and rec.size != cam.size:
                raise MocapError(f"{rec.path}: image size {rec.size[0]}x{rec.size[1]} differs from the size "
                                 f"{cam.size[0]}x{cam.size[1]} of camera {cam.name!r} in calibration.toml; use the "
                                 "calibration made for these cameras at this resolution")
    else:
        sources = [open_centroids(p) for p in per_camera]
        if declared is not None:
            for f in sources:  # files whose rows stop early end in blob-less frames
                f.n_frames = max(f.n_frames, declared)

    counts = [s.n_frames for s in sources]
    n_frames = min(counts)
    if len(set(counts)) > 1:
        log.warning("%s: cameras have different frame counts (%s); only the first %d frames (common to all) are "
                    "used", folder, ", ".join(f"{s.path.name}: {c}" for s, c in zip(sources, counts, strict=True)),
                    n_frames)
    if declared is not None and n_frames < declared:
        log.warning("%s: take.toml says %d frames, the recordings hold %d; only those are used (was a copy or an "
                    "export cut short? re-copy the recordings if frames are missing)", folder, declared, n_frames)
    if n_frames == 0:
        raise MocapError(f"{folder}: the take is empty (0 frames in {', '.join(s.path.name for s in sources)})")

    rate = fps if fps is not None else info.get("fps")
    if rate is None and kind == "images":
        video_rates = {s.fps for s in sources if s.fps is not None}
        if len(video_rates) > 1:
            log.warning("%s: the videos disagree on the frame rate (%s Hz); using the first camera's", folder,
                        ", ".join(f"{r:g}" for r in sorted(video_rates)))
        rate = next((s.fps for s in sources if s.fps is not None), None)
    if rate is None:
        raise MocapError(f"{folder}: unknown frame rate; add take.toml with a line 'fps = 120.0' or pass --fps")
    if not 0 < float(rate) < 1e6:
        raise MocapError(f"{folder}: frame rate {rate!r} must be a positive number of frames per second")
    return Take(folder, rig, float(rate), n_frames, names, kind, info, sources)

