"""TRC (OpenSim marker trajectories) writing and reading.

Layout (OpenSim, tab-separated)::

    PathFileType  4  (X/Y/Z)  NAME.trc
    DataRate  CameraRate  NumFrames  NumMarkers  Units  OrigDataRate  OrigDataStartFrame  OrigNumFrames
    120.0     120.0       F          M           mm     120.0         1                   F
    Frame#  Time  L1        L2 ...
                  X1 Y1 Z1  X2 Y2 Z2 ...
    (blank line)
    1       0.000000  x y z  x y z ...

Frame# is 1-based (frame k of the take is row k+1); gaps are empty cells. Coordinates use the
shortest exact float repr, so a write -> read round trip gives the same float64 positions up
to the unit conversion (x * 1000 / 1000). ``y_up`` writes OpenSim's y-up frame.
The reader also takes the comma-separated variant and files whose NumFrames disagrees with
the rows present (it trusts the rows, and says so in the log).
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError
from mocap.export.c3d import UNIT_TO_METRES
from mocap.export.common import check_labels, y_up_to_z_up, z_up_to_y_up
from mocap.export.text import format_rows, parse_rows
from mocap.trajectories import Trajectories

__all__ = ["write_trc", "read_trc"]

log = logging.getLogger(__name__)

_HEADER_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
                "OrigDataStartFrame", "OrigNumFrames")


def write_trc(traj: Trajectories, path: str | os.PathLike, units: str = "mm", y_up: bool = False) -> None:
    """Write ``traj`` as a tab-separated TRC file, atomically.

    Args:
        units: length unit of the file, a key of :data:`mocap.export.c3d.UNIT_TO_METRES` (default mm).
        y_up: rotate the z-up world into OpenSim's y-up frame ((x, y, z) -> (x, z, -y)).
    """
    path = Path(path)
    if units not in UNIT_TO_METRES:
        raise MocapError(f"{path}: unknown TRC unit {units!r}; use one of {sorted(UNIT_TO_METRES)}")
    check_labels(traj.labels, path, "TRC", forbidden="\t,")
    F, M = traj.n_frames, traj.n_markers
    positions = z_up_to_y_up(traj.positions) if y_up else traj.positions
    values = (positions / UNIT_TO_METRES[units]).reshape(F, 3 * M)
    fps = repr(float(traj.fps))
    header = [
        "\t".join(["PathFileType", "4", "(X/Y/Z)", path.name]),
        "\t".join(_HEADER_KEYS),
        "\t".join([fps, fps, str(F), str(M), units, fps, str(traj.first_frame + 1), str(F)]),
        "\t".join(["Frame#", "Time"] + [f"{label}\t\t" for label in traj.labels]),
        "\t".join(["", ""] + [f"X{i}\tY{i}\tZ{i}" for i in range(1, M + 1)]),
        "",
    ]
    frames = np.arange(F) + traj.first_frame
    body = format_rows(frames + 1, frames / traj.fps, values, "\t")
    atomic_write_bytes(path, ("\n".join(header) + "\n" + body).encode("ascii"))


def read_trc(path: str | os.PathLike, y_up: bool = False) -> Trajectories:
    """Read a TRC file (tab- or comma-separated) into :class:`Trajectories` (metres).

    Args:
        y_up: the file is in OpenSim's y-up frame: rotate it back to z-up.

    Raises:
        MocapError: missing file, unreadable header, unknown units, ragged or non-numeric rows.
    """
    path = Path(path)
    try:
        text = path.read_bytes().decode("utf-8-sig")
    except FileNotFoundError:
        raise MocapError(f"{path}: TRC file not found") from None
    except UnicodeDecodeError:
        raise MocapError(f"{path}: not a text file; a TRC file is tab- or comma-separated text") from None
    lines = text.splitlines()
    if len(lines) < 5 or not lines[0].startswith("PathFileType"):
        raise MocapError(f"{path}: not a TRC file (the first line should start with 'PathFileType' and the "
                         f"header has 5 lines)")
    delimiter = "\t" if "\t" in lines[0] else ","
    header = _header(lines[1], lines[2], delimiter)
    try:
        fps = float(header.get("DataRate") or header["CameraRate"])
    except (KeyError, ValueError):
        raise MocapError(f"{path}: line 3 has no valid DataRate; the TRC header is damaged") from None
    units = (header.get("Units") or "mm").lower()
    if units not in UNIT_TO_METRES:
        raise MocapError(f"{path}: unknown Units {units!r} in the header; expected one of {sorted(UNIT_TO_METRES)}")
    names = [n.strip() for n in lines[3].split(delimiter)[2:]]
    labels = [n for n in names[::3] if n]
    try:
        declared = int(header.get("NumMarkers", ""))
    except ValueError:
        declared = len(labels)
    if declared != len(labels):
        raise MocapError(f"{path}: header says NumMarkers {declared} but line 4 names {len(labels)} markers")
    start = 5
    while start < len(lines) and not lines[start].strip(delimiter + " "):
        start += 1
    data_lines = [line for line in lines[start:] if line.strip(delimiter + " ")]
    rows = parse_rows(data_lines, delimiter, 2 + 3 * len(labels), str(path), start + 1)
    frames = _frame_numbers(rows[:, 0], path)
    first = int(frames[0]) if len(frames) else 1
    F = int(frames[-1] - first + 1) if len(frames) else 0
    positions = np.full((F, len(labels), 3), np.nan)
    positions[frames - first] = rows[:, 2:].reshape(len(rows), len(labels), 3) * UNIT_TO_METRES[units]
    if y_up:
        positions = y_up_to_z_up(positions)
    if header.get("NumFrames", str(len(rows))) != str(len(rows)):
        log.info("%s: header says NumFrames %s, the file holds %d rows; using the rows", path,
                 header.get("NumFrames"), len(rows))
    return Trajectories(labels, fps, positions, first_frame=first - 1, metadata={"units": units})


def _header(keys_line: str, values_line: str, delimiter: str) -> dict[str, str]:
    """The header's names (line 2) mapped to their values (line 3). Field by field where both lines have as many
    fields (trailing empty ones aside); otherwise their non-empty fields, where those pair up (OpenSim's files
    put two tabs between values and one between names)."""
    def fields(line: str) -> list[str]:
        out = [field.strip() for field in line.split(delimiter)]
        while out and not out[-1]:
            out.pop()
        return out

    keys, values = fields(keys_line), fields(values_line)
    if len(keys) != len(values):
        filled_keys, filled_values = [k for k in keys if k], [v for v in values if v]
        if len(filled_keys) == len(filled_values):
            keys, values = filled_keys, filled_values
    return dict(zip(keys, values, strict=False))


def _frame_numbers(column: np.ndarray, path: Path) -> np.ndarray:
    """(R,) Frame# column -> int64 array, checked to be whole, unique and increasing."""
    if not np.isfinite(column).all() or (column != np.round(column)).any() or (np.diff(column) <= 0).any():
        raise MocapError(f"{path}: the Frame# column must hold increasing whole numbers; the file is damaged")
    return column.astype(np.int64)
