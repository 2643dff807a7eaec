"""CSV in OptiTrack Motive's export layout, writing and reading.

Layout (Motive format version 1.23)::

    Format Version,1.23,Take Name,NAME,...,Export Frame Rate,120.0,...,Length Units,Millimeters,...,Up Axis,Z
    (blank line)
    ,Type,Marker,Marker,Marker,...
    ,Name,L1,L1,L1,L2,...
    ,ID,1,1,1,2,...
    ,,Position,Position,Position,...
    Frame,Time (Seconds),X,Y,Z,X,Y,Z,...
    0,0.000000,x,y,z,...

Frame numbers are 0-based take frames; gaps are empty cells; coordinates use the shortest exact
float repr. ``Up Axis`` is this project's addition to the metadata row: Motive itself works in a
y-up frame, so the reader assumes y-up (and rotates to z-up) when a file does not say.
The reader takes every ``Marker``-typed Position triple (Motive's rigid-body and bone columns are
skipped), an optional ``Parent`` row and an optional ``TimeCode`` column.
"""

from __future__ import annotations

import logging
import os
from pathlib import Path

import numpy as np

from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError
from mocap.export.common import check_labels, y_up_to_z_up, z_up_to_y_up
from mocap.export.text import format_rows, parse_rows
from mocap.trajectories import Trajectories

__all__ = ["write_csv", "read_csv", "MOTIVE_UNITS"]

log = logging.getLogger(__name__)

MOTIVE_UNITS = {"millimeters": 1e-3, "centimeters": 1e-2, "meters": 1.0}


def write_csv(traj: Trajectories, path: str | os.PathLike, units: str = "Millimeters", y_up: bool = False) -> None:
    """Write ``traj`` as a Motive-style CSV file, atomically.

    Args:
        units: "Millimeters" (default), "Centimeters" or "Meters".
        y_up: rotate the z-up world into Motive's y-up frame ((x, y, z) -> (x, z, -y)).
    """
    path = Path(path)
    if units.lower() not in MOTIVE_UNITS:
        raise MocapError(f"{path}: unknown CSV length unit {units!r}; use Millimeters, Centimeters or Meters")
    check_labels(traj.labels, path, "CSV", forbidden=',"')
    F, M = traj.n_frames, traj.n_markers
    positions = z_up_to_y_up(traj.positions) if y_up else traj.positions
    values = (positions / MOTIVE_UNITS[units.lower()]).reshape(F, 3 * M)
    fps = repr(float(traj.fps))
    meta = {
        "Format Version": "1.23", "Take Name": path.stem, "Take Notes": "", "Capture Frame Rate": fps,
        "Export Frame Rate": fps, "Capture Start Time": "", "Capture Start Frame": str(traj.first_frame),
        "Total Frames in Take": str(F), "Total Exported Frames": str(F), "Rotation Type": "Quaternion",
        "Length Units": units.capitalize(), "Coordinate Space": "Global", "Up Axis": "Y" if y_up else "Z",
    }
    header = [
        ",".join(f"{k},{v}" for k, v in meta.items()),
        "",
        ",".join(["", "Type"] + ["Marker"] * 3 * M),
        ",".join(["", "Name"] + [label for label in traj.labels for _ in range(3)]),
        ",".join(["", "ID"] + [str(i + 1) for i in range(M) for _ in range(3)]),
        ",".join(["", ""] + ["Position"] * 3 * M),
        ",".join(["Frame", "Time (Seconds)"] + ["X", "Y", "Z"] * M),
    ]
    frames = np.arange(F) + traj.first_frame
    body = format_rows(frames, frames / traj.fps, values, ",")
    atomic_write_bytes(path, ("\n".join(header) + "\n" + body).encode("ascii"))


def read_csv(path: str | os.PathLike, up_axis: str | None = None) -> Trajectories:
    """Read a Motive-style CSV file into :class:`Trajectories` (metres, z-up).

    Args:
        up_axis: "Y" or "Z": the file's up axis; None takes the file's ``Up Axis`` entry, else Y
            (Motive's own frame).

    Raises:
        MocapError: missing file, not a Motive CSV, unknown units, ragged or non-numeric rows.
    """
    path = Path(path)
    try:
        lines = path.read_bytes().decode("utf-8-sig").splitlines()
    except FileNotFoundError:
        raise MocapError(f"{path}: CSV file not found") from None
    except UnicodeDecodeError:
        raise MocapError(f"{path}: not a text file; expected a Motive CSV export") from None
    if not lines or not lines[0].startswith("Format Version"):
        raise MocapError(f"{path}: not a Motive CSV export (the first line should start with 'Format Version')")
    cells = [c.strip() for c in lines[0].split(",")]
    meta = dict(zip(cells[0::2], cells[1::2], strict=False))
    rows = {}
    header_end = None
    for i, line in enumerate(lines[1:12], start=1):
        fields = [f.strip().strip('"') for f in line.split(",")]
        if fields[0] == "Frame":
            header_end = i
            rows["Axis"] = fields
            break
        key = fields[1] if len(fields) > 1 and fields[1] else ("Kind" if len(fields) > 2 else "")
        if key:
            rows[key] = fields
    if header_end is None or "Name" not in rows:
        raise MocapError(f"{path}: no 'Frame,Time (Seconds),...' header row or no Name row; not a Motive CSV")
    try:
        fps = float(meta.get("Export Frame Rate") or meta["Capture Frame Rate"])
    except (KeyError, ValueError):
        raise MocapError(f"{path}: the first line has no valid 'Export Frame Rate'; the header is damaged") from None
    units = meta.get("Length Units", "Millimeters").lower()
    if units not in MOTIVE_UNITS:
        raise MocapError(f"{path}: unknown Length Units {units!r}; expected Millimeters, Centimeters or Meters")
    up = (up_axis or meta.get("Up Axis") or "Y").upper()
    if up not in ("Y", "Z"):
        raise MocapError(f"{path}: up axis {up!r} is not supported; use Y or Z")
    columns, labels = _marker_columns(rows)
    n_fields = len(rows["Axis"])
    data = parse_rows([line for line in lines[header_end + 1:] if line.strip(", ")], ",", n_fields, str(path),
                      header_end + 2)
    frames = data[:, 0]
    if not np.isfinite(frames).all() or (frames != np.round(frames)).any() or (np.diff(frames) <= 0).any():
        raise MocapError(f"{path}: the Frame column must hold increasing whole numbers; the file is damaged")
    first = int(frames[0]) if len(frames) else 0
    F = int(frames[-1]) - first + 1 if len(frames) else 0
    positions = np.full((F, len(labels), 3), np.nan)
    positions[frames.astype(np.int64) - first] = data[:, columns].reshape(len(data), len(labels), 3)
    positions *= MOTIVE_UNITS[units]
    if up == "Y":
        positions = y_up_to_z_up(positions)
    return Trajectories(labels, fps, positions, first_frame=first,
                        metadata={"units": units, "up_axis": up})


def _marker_columns(rows: dict[str, list[str]]) -> tuple[np.ndarray, list[str]]:
    """Column indices (3 per marker, X Y Z) and names of the Marker-typed Position triples (may be none)."""
    axis, names = rows["Axis"], rows["Name"]
    types = rows.get("Type", ["", ""] + ["Marker"] * (len(axis) - 2))
    kinds = rows.get("Kind", ["", ""] + ["Position"] * (len(axis) - 2))
    columns, labels = [], []
    for j in range(len(axis) - 2):
        if (j + 2 < len(types) and types[j] == "Marker" and kinds[j] == "Position" and axis[j] == "X"
                and axis[j + 1: j + 3] == ["Y", "Z"]):
            columns.extend([j, j + 1, j + 2])
            labels.append(names[j])
    return np.asarray(columns, dtype=np.int64), labels
