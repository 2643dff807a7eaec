"""Writing a rendered take (DESIGN.md sec. 1) and its truth file, atomically.

A take folder holds ``calibration.toml``, ``take.toml`` (``fps`` and other facts) and one recording
per camera named after it: ``<name>.mkv`` (lossless FFV1, grey) or ``<name>/000000.png ...``.
The folder is built under a temporary name beside the destination and renamed at the end, so
it is either complete or absent. The truth goes OUTSIDE the take (default ``<take>.truth.npz``).
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np
import tomli_w
from tqdm import tqdm

from mocap.atomic import atomic_write_bytes, check_output_path
from mocap.camera import Rig, save_rig
from mocap.errors import MocapError
from mocap.synth.motion import Motion
from mocap.synth.settings import SynthSettings
from mocap.synth.simulate import TakePlan, plan_take, render_frame
from mocap.truth import Truth, save_truth

__all__ = ["render_take", "write_take", "default_truth_path", "staged_directory"]

_SPACE_CHECK_FRAMES = 50  # frames between checks of the free disk space while rendering
_MIN_FREE_BYTES = 64 * 2**20  # rendering stops below this much free space


def default_truth_path(out_dir: str | os.PathLike) -> Path:
    """``<take>.truth.npz`` beside the take folder."""
    out_dir = Path(out_dir)
    return out_dir.with_name(out_dir.name + ".truth.npz")


@contextlib.contextmanager
def staged_directory(out_dir: str | os.PathLike, force: bool = False) -> Iterator[Path]:
    """Yield a temporary folder beside ``out_dir``; rename it onto ``out_dir`` on success.

    An existing empty ``out_dir`` is replaced; a non-empty one only with ``force`` (and only once
    the new take is complete). On failure the temporary folder is removed.

    Raises:
        MocapError: ``out_dir`` is a file, is a non-empty folder without ``force``, or its parent is missing.
    """
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise MocapError(f"{out_dir}: is a file; give a folder name for the take")
    if out_dir.is_dir() and any(out_dir.iterdir()) and not force:
        raise MocapError(f"{out_dir}: folder exists and is not empty; choose a new folder or pass --force "
                         "to replace it")
    if not out_dir.parent.is_dir():
        raise MocapError(f"{out_dir}: parent folder {out_dir.parent} does not exist; create it first")
    tmp = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}.", suffix=".tmp"))
    try:
        yield tmp
        old = None
        if out_dir.is_dir() and any(out_dir.iterdir()):
            old = Path(tempfile.mkdtemp(dir=out_dir.parent, prefix=f".{out_dir.name}.", suffix=".old"))
            os.replace(out_dir, old)
        os.replace(tmp, out_dir)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def write_take(folder: Path, plan: TakePlan, fmt: str = "mkv", progress: bool = True) -> None:
    """Render every frame of ``plan`` into ``folder`` (which must exist): calibration, take.toml, images."""
    rig = plan.rig
    truth = plan.truth
    save_rig(rig, folder / "calibration.toml")
    facts = {"fps": float(truth.fps), "frames": int(truth.n_frames), "synthetic": True,
             "cameras": rig.names, "motion": str(truth.settings.get("motion", {}).get("source", ""))}
    atomic_write_bytes(folder / "take.toml", tomli_w.dumps(facts).encode())
    writers: list[cv2.VideoWriter] = []
    if fmt == "mkv":
        for cam in rig:
            path = folder / f"{cam.name}.mkv"
            writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"FFV1"), float(truth.fps), cam.size, False)
            if not writer.isOpened():
                raise MocapError(f"{path}: this OpenCV build cannot write FFV1 video; use --format png")
            writers.append(writer)
    else:
        for cam in rig:
            (folder / cam.name).mkdir()
    streams = plan.noise_streams()
    try:
        with tqdm(total=truth.n_frames, desc="rendering", unit="frame", disable=None if progress else True) as bar:
            for f in range(truth.n_frames):
                if f % _SPACE_CHECK_FRAMES == 0:
                    _check_free_space(folder, f, truth.n_frames)
                for c, cam in enumerate(rig):
                    image = render_frame(plan, f, c, streams[c])
                    if writers:
                        writers[c].write(image)
                    elif not cv2.imwrite(str(folder / cam.name / f"{f:06d}.png"), image):
                        raise MocapError(f"{folder / cam.name}: cannot write PNG frames there (disk full?)")
                bar.update(1)
    finally:
        for writer in writers:
            writer.release()
    if writers:  # (the video writer does not report a failed write)
        for cam in rig:
            _check_video_frames(folder / f"{cam.name}.mkv", truth.n_frames)


def _check_free_space(folder: Path, frame: int, n_frames: int) -> None:
    """Stop rendering, with a clear error, when the disk holding ``folder`` is all but full."""
    free = shutil.disk_usage(folder).free
    if free < _MIN_FREE_BYTES:
        raise MocapError(f"{folder}: the disk is full ({free / 2**20:.0f} MiB left after {frame} of {n_frames} "
                         "frames); free some space or render the take elsewhere")


def _check_video_frames(path: Path, n_frames: int) -> None:
    """Raise if the video at ``path`` does not hold ``n_frames`` frames (a write failed: disk full, I/O error)."""
    cap = cv2.VideoCapture(str(path))
    try:
        count = cap.get(cv2.CAP_PROP_FRAME_COUNT) if cap.isOpened() else 0.0
    finally:
        cap.release()
    if count != n_frames:
        held = f"{count:.0f} of {n_frames}" if 0 <= count < n_frames else f"not the {n_frames}"
        raise MocapError(f"{path}: the video was written incompletely ({held} frames; disk full?); free some "
                         "space and render the take again")


def render_take(out_dir: str | os.PathLike, rig: Rig, motion: Motion | tuple[list[str], float, np.ndarray],
                settings: SynthSettings | None = None,
                truth_path: str | os.PathLike | None = None, progress: bool = True, force: bool = False) -> Truth:
    """Render a synthetic take of ``motion`` seen by ``rig`` and save its ground truth.

    Args:
        out_dir: the take folder to create.
        rig: the cameras (written as the take's calibration.toml).
        motion: what to film (z up, metres), or ``(labels, fps, positions)``.
        settings: rendering settings (default :class:`SynthSettings`).
        truth_path: where the truth goes; default ``<out_dir>.truth.npz``. Must be outside the take.
        progress: show a progress bar on a terminal.
        force: replace an existing non-empty ``out_dir``.

    Returns:
        The truth that was saved.
    """
    settings = settings or SynthSettings()
    out_dir = Path(out_dir)
    truth_path = Path(truth_path) if truth_path is not None else default_truth_path(out_dir)
    if out_dir.resolve() in truth_path.resolve().parents:
        raise MocapError(f"{truth_path}: the truth file must not be inside the take folder {out_dir} "
                         "(the engine could read it); put it beside the take")
    check_output_path(truth_path)
    with staged_directory(out_dir, force) as folder:
        plan = plan_take(rig, motion, settings)
        write_take(folder, plan, settings.format, progress)
    save_truth(plan.truth, truth_path)
    return plan.truth
