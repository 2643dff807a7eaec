"""C3D reading and writing with ezc3d.

Written files: POINT:UNITS "mm", POINT:RATE = fps, float storage (POINT:SCALE < 0, also in
the header, as the C3D spec and the ``c3d`` package require); residuals in mm, rounded by C3D
to steps of |POINT:SCALE| (chosen from the data so the largest residual fits the format's 8
bits); invalid samples have residual -1; the camera mask holds the first 7 cameras (a C3D
limit). Labels must be printable ASCII.

Any length: the header counts frames in 16 bits, so every file also carries
TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (1-based first and last frame as two 16-bit words,
low word first; c3d.org, "Maintaining C3D frame count compatibility"), plus POINT:LONG_FRAMES
(float) above 65,535 frames; the header's first and last frame are capped at 65,535. Files have
no ROTATION group: with one, ezc3d 1.7 stops reading after 65,535 frames; without, it reads
POINT:FRAMES = 0xFFFF as "to the end of the data".

The residual/camera word follows the C3D spec (c3d.org, "Notes for programmers"): residual in
the low byte, camera bits in the high byte. ezc3d 1.7 swaps the two bytes, so both are written
and read here straight from the file's point records (Intel-format files; for DEC/MIPS files
ezc3d's values are used).
"""

from __future__ import annotations

import os
import struct
from dataclasses import dataclass
from pathlib import Path

import ezc3d
import numpy as np

from mocap.atomic import atomic_output
from mocap.errors import MocapError
from mocap.export.common import check_labels
from mocap.trajectories import Trajectories

__all__ = ["write_c3d", "read_c3d", "UNIT_TO_METRES"]

UNIT_TO_METRES = {"mm": 1e-3, "cm": 1e-2, "dm": 1e-1, "m": 1.0, "in": 0.0254, "inch": 0.0254, "ft": 0.3048}
_RESIDUAL_STEPS_MM = (0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
_C3D_CAMERA_BITS = 7
_HEADER_FIRST_FRAME_OFFSET = 6  # header word 4: the 1-based first frame, 16 bits
_HEADER_SCALE_OFFSET = 12  # header words 7-8: the POINT scale factor, a float (Intel byte order)
_WORD_MAX = 0xFFFF  # header frame numbers and POINT:FRAMES are 16-bit words


def _residual_scale(residuals_mm: np.ndarray) -> float:
    """Smallest step (mm) from a 1-2-5 series that fits the largest residual into 255 steps."""
    finite = residuals_mm[np.isfinite(residuals_mm)]
    largest = float(finite.max()) if finite.size else 0.0
    for step in _RESIDUAL_STEPS_MM:
        if largest <= 255 * step:
            return step
    return _RESIDUAL_STEPS_MM[-1]


def write_c3d(traj: Trajectories, path: str | os.PathLike) -> None:
    """Write ``traj`` to a C3D file atomically (positions in mm)."""
    check_labels(traj.labels, path, "C3D")
    F, M = traj.n_frames, traj.n_markers
    if F == 0:
        raise MocapError(f"{path}: no frames to write; a C3D file needs at least one frame")
    valid = traj.valid
    points = np.zeros((4, M, F))
    points[:3] = np.transpose(np.where(valid[..., None], traj.positions * 1000.0, np.nan), (2, 1, 0))
    points[3] = valid.T
    step = _residual_scale(traj.residuals)
    # ezc3d truncates residual / step: hand it the middle of the nearest step so the file holds the rounded value
    steps = np.clip(np.round(np.nan_to_num(traj.residuals, nan=0.0) / step), 0, 255)
    residuals = np.where(valid, (steps + 0.5) * step, -1.0)
    bits = (traj.camera_masks[..., None] >> np.arange(_C3D_CAMERA_BITS, dtype=np.uint32)) & 1  # (F, M, 7)
    masks = np.transpose(bits.astype(bool) & valid[..., None], (2, 1, 0))
    c3d = ezc3d.c3d()
    del c3d["data"]["rotations"]  # no ROTATION group (see the module docstring)
    c3d["parameters"]["POINT"]["RATE"]["value"] = [float(traj.fps)]
    c3d["parameters"]["POINT"]["LABELS"]["value"] = list(traj.labels)
    c3d["parameters"]["POINT"]["UNITS"]["value"] = ["mm"]
    c3d["parameters"]["POINT"]["SCALE"]["value"] = [-step]
    if traj.camera_names:
        c3d.add_parameter("POINT", "CAMERAS", list(traj.camera_names)[:_C3D_CAMERA_BITS])
    c3d["header"]["points"]["first_frame"] = int(traj.first_frame)
    _add_frame_range(c3d, int(traj.first_frame), F)
    c3d["data"]["points"] = points
    c3d["data"]["meta_points"] = {"residuals": residuals.T[None], "camera_masks": masks}
    with atomic_output(path) as tmp:
        c3d.write(str(tmp))
        with open(tmp, "r+b") as f:  # ezc3d wraps a first frame above 65535 and leaves the scale at -1
            f.seek(_HEADER_FIRST_FRAME_OFFSET)
            f.write(struct.pack("<H", min(int(traj.first_frame) + 1, _WORD_MAX)))  # the TRIAL fields hold the rest
            f.seek(_HEADER_SCALE_OFFSET)
            f.write(struct.pack("<f", -step))
        words = _point_words(tmp, M, F, -step, mode="r+")
        if words is not None:  # None: no samples at all
            code = words.astype(np.int32)
            words[:] = np.where(code < 0, -1.0, ((code & 0x7F) << 8) | (code >> 8))  # ezc3d's order -> the spec's
            words.flush()


def _add_frame_range(c3d: ezc3d.c3d, first_frame: int, n_frames: int) -> None:
    """TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD (and POINT:LONG_FRAMES above 65,535 frames)."""
    for name, frame in (("ACTUAL_START_FIELD", first_frame + 1), ("ACTUAL_END_FIELD", first_frame + n_frames)):
        c3d.add_parameter("TRIAL", name, [0, 0])  # ezc3d's Python API stores int lists as floats ...
        param = c3d["parameters"]["TRIAL"][name]
        param["type"] = ezc3d.ezc3d.INT  # ... the spec wants two 16-bit words: low, high
        param["value"] = np.array([frame & _WORD_MAX, frame >> 16])
    if n_frames > _WORD_MAX:
        c3d.add_parameter("POINT", "LONG_FRAMES", [float(n_frames)])


def _trial_range(c3d: ezc3d.c3d) -> tuple[int, int] | None:
    """1-based first and last frame from TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD, or None if absent."""
    trial = c3d["parameters"].get("TRIAL", {})
    if "ACTUAL_START_FIELD" not in trial or "ACTUAL_END_FIELD" not in trial:
        return None
    frames = []
    for name in ("ACTUAL_START_FIELD", "ACTUAL_END_FIELD"):
        words = np.asarray(trial[name]["value"]).ravel().astype(np.int64) & _WORD_MAX  # ezc3d reads them signed
        if words.size != 2:
            return None
        frames.append(int(words[0] | words[1] << 16))
    return frames[0], frames[1]


@dataclass(frozen=True)
class _Layout:
    """Where a C3D file's point records are: byte offset, word type, words per frame, processor."""

    start: int
    dtype: np.dtype
    frame_words: int
    intel: bool
    declared_frames: int
    saturated: bool  # the header's last frame is 65535: its 16-bit frame range may have overflowed

    @classmethod
    def of(cls, path: Path, n_points: int, scale: float) -> _Layout:
        """Layout of ``path`` holding ``n_points`` points with POINT:SCALE ``scale`` (< 0: float words)."""
        with open(path, "rb") as f:
            header = f.read(512)
            f.seek((header[0] - 1) * 512 + 3)
            processor = f.read(1)
        order = ">" if processor == b"\x56" else "<"  # MIPS is big-endian; Intel and DEC little-endian
        dtype = np.dtype(f"{order}f4") if scale < 0 else np.dtype(f"{order}i2")
        words = struct.unpack(f"{order}9H", header[:18])
        return cls((words[8] - 1) * 512, dtype, 4 * n_points + words[2], processor == b"\x54",
                   words[4] - words[3] + 1, words[4] == _WORD_MAX)

    def frames_in(self, path: Path) -> int:
        """Complete frames the file holds."""
        return max(0, path.stat().st_size - self.start) // (self.frame_words * self.dtype.itemsize)


def _point_words(path: Path, n_points: int, n_frames: int, scale: float, mode: str = "r") -> np.memmap | None:
    """(F, M) view of the residual/camera word of every point record, or None if not an Intel-format file."""
    layout = _Layout.of(path, n_points, scale)
    if not layout.intel or n_points == 0 or n_frames == 0 or layout.frames_in(path) < n_frames:
        return None
    records = np.memmap(path, dtype=layout.dtype, mode=mode, offset=layout.start,
                        shape=(n_frames, layout.frame_words))
    return records[:, 3:4 * n_points:4]


def _residuals_and_masks(path: Path, c3d: ezc3d.c3d, n_points: int, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """(F, M) residuals (in POINT:UNITS, -1 where invalid) and (F, M) uint32 camera masks, per the C3D spec."""
    if not n_points:
        return np.zeros((n_frames, 0)), np.zeros((n_frames, 0), dtype=np.uint32)
    scale = float(c3d["parameters"]["POINT"]["SCALE"]["value"][0])
    words = _point_words(path, n_points, n_frames, scale)
    if words is not None:
        code = np.asarray(words).astype(np.int32)
        residuals = np.where(code < 0, -1.0, (code & 0xFF) * abs(scale))
        return residuals, np.where(code < 0, 0, (code >> 8) & 0x7F).astype(np.uint32)
    meta = c3d["data"].get("meta_points", {})
    residuals = np.asarray(meta.get("residuals", np.zeros((1, n_points, n_frames))), dtype=np.float64)[0].T
    masks = np.zeros(residuals.shape, dtype=np.uint32)
    if "camera_masks" in meta:
        cm = np.asarray(meta["camera_masks"], dtype=bool)  # (7, M, F)
        weights = (1 << np.arange(cm.shape[0], dtype=np.uint32))[:, None, None]
        masks = (cm * weights).sum(axis=0).T.astype(np.uint32)
    return residuals, masks


def read_c3d(path: str | os.PathLike) -> Trajectories:
    """Read a C3D file's points into :class:`Trajectories` (metres; NaN where invalid).

    Accepts any POINT:UNITS in :data:`UNIT_TO_METRES`. Samples with residual < 0 or all-zero
    coordinates (the usual gap conventions) become NaN. Axes are left as in the file.
    """
    path = Path(path)
    if not path.is_file():
        raise MocapError(f"{path}: C3D file not found")
    try:
        c3d = ezc3d.c3d(str(path))
    except Exception as exc:  # ezc3d raises bare RuntimeError/IOError on corrupt files
        raise MocapError(f"{path}: cannot read as C3D ({exc}); the file may be truncated or not a C3D") from None
    params = c3d["parameters"]["POINT"]
    units = str(params.get("UNITS", {}).get("value", ["mm"])[0] or "mm").strip().lower()
    if units not in UNIT_TO_METRES:
        raise MocapError(f"{path}: unknown POINT:UNITS {units!r}; expected one of {sorted(UNIT_TO_METRES)}")
    fps = float(params["RATE"]["value"][0])
    labels = [str(label).strip() for label in params["LABELS"]["value"]]
    pts = np.asarray(c3d["data"]["points"], dtype=np.float64)  # (4, M, F)
    labels = labels[: pts.shape[1]] + [f"M{i:03d}" for i in range(len(labels), pts.shape[1])]
    layout = _Layout.of(path, pts.shape[1], float(params["SCALE"]["value"][0]))
    first, declared, source = int(c3d["header"]["points"].get("first_frame", 0)), layout.declared_frames, "its header"
    trial = _trial_range(c3d) if layout.saturated else None
    if trial is not None:  # a range the header cannot hold; ezc3d reads these files to the end of the data
        first, declared, source = trial[0] - 1, trial[1] - trial[0] + 1, "TRIAL:ACTUAL_START_FIELD/ACTUAL_END_FIELD"
        pts = pts[:, :, :declared]
    if not pts.shape[1]:  # no points: only the header / TRIAL count the frames
        pts = np.zeros((4, 0, declared))
    held = min(pts.shape[2], layout.frames_in(path)) if pts.shape[1] else declared
    if held < declared:
        raise MocapError(f"{path}: the file is truncated: {source} declares {declared} frames but "
                         f"it holds {held}; re-export it")
    positions = np.transpose(pts[:3], (2, 1, 0)) * UNIT_TO_METRES[units]
    residuals, masks = _residuals_and_masks(path, c3d, pts.shape[1], pts.shape[2])
    residuals = np.where(residuals < 0, residuals, residuals * UNIT_TO_METRES[units] * 1000.0)  # -> mm
    invalid = (residuals < 0) | ~np.isfinite(positions).all(axis=2) | (positions == 0).all(axis=2)
    positions[invalid] = np.nan
    residuals = np.where(invalid, np.nan, residuals)
    masks[invalid] = 0
    cameras = params.get("CAMERAS", {}).get("value", [])
    metadata: dict = {"units": units}
    not_markers = _not_markers(params, labels)
    if not_markers:  # (model outputs stored as points: mocap synth does not film them)
        metadata["not_markers"] = not_markers
    return Trajectories(labels, fps, positions, residuals, masks, [str(c) for c in cameras], first, metadata)


# POINT parameters that name the points a modelling package stored that are not markers (Vicon Nexus writes joint
# angles, forces, moments and powers as points, and its model's copies of markers as modelled markers).
NOT_MARKER_GROUPS = ("ANGLES", "FORCES", "MOMENTS", "POWERS", "SCALARS", "REACTIONS", "MODELED_MARKERS")


def _not_markers(params: dict, labels: list[str]) -> list[str]:
    """Labels (of ``labels``) that the POINT parameters ``params`` name as model outputs, not markers: those listed
    by the parameters of :data:`NOT_MARKER_GROUPS` and of POINT:TYPE_GROUPS (name, type pairs)."""
    groups = set(NOT_MARKER_GROUPS)
    type_groups = [str(v).strip().upper() for v in params.get("TYPE_GROUPS", {}).get("value", [])]
    groups.update(type_groups[0::2])
    named = {str(v).strip() for group in groups for v in params.get(group, {}).get("value", [])}
    return [label for label in labels if label in named]
