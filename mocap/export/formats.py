"""File suffix -> trajectory reader and writer, for ``mocap export``, ``info``, ``plot`` and ``view``."""

from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mocap.errors import MocapError
from mocap.trajectories import Trajectories

__all__ = ["FORMATS", "TrajectoryFormat", "format_of", "read_trajectories", "write_trajectories"]


@dataclass(frozen=True)
class TrajectoryFormat:
    """One file format: its name, the module holding it, its reader and writer function names, and
    which keyword options each accepts (so callers can pass a superset)."""

    name: str
    module: str
    reader: str
    writer: str
    read_options: tuple[str, ...] = ()
    write_options: tuple[str, ...] = ()

    def _function(self, attr: str) -> Any:
        return getattr(importlib.import_module(self.module), attr)

    def read(self, path: Path, **options: Any) -> Trajectories:
        kwargs = {k: v for k, v in options.items() if k in self.read_options and v is not None}
        return self._function(self.reader)(path, **kwargs)

    def write(self, traj: Trajectories, path: Path, **options: Any) -> None:
        kwargs = {k: v for k, v in options.items() if k in self.write_options and v is not None}
        self._function(self.writer)(traj, path, **kwargs)


FORMATS: dict[str, TrajectoryFormat] = {
    ".c3d": TrajectoryFormat("C3D", "mocap.export.c3d", "read_c3d", "write_c3d"),
    ".trc": TrajectoryFormat("TRC", "mocap.export.trc", "read_trc", "write_trc", ("y_up",), ("units", "y_up")),
    ".csv": TrajectoryFormat("CSV (Motive)", "mocap.export.csv", "read_csv", "write_csv", ("up_axis",),
                             ("units", "y_up")),
    ".mcap": TrajectoryFormat("MCAP (Foxglove)", "mocap.export.mcap", "read_mcap_trajectories", "write_mcap", (),
                              ("rig",)),
}


def format_of(path: str | os.PathLike) -> TrajectoryFormat:
    """The format of ``path`` from its suffix (case-insensitive)."""
    suffix = Path(path).suffix.lower()
    if suffix not in FORMATS:
        raise MocapError(f"{path}: unknown trajectory file type {suffix or '(no suffix)'!r}; "
                         f"use one of {', '.join(FORMATS)}")
    return FORMATS[suffix]


def read_trajectories(path: str | os.PathLike, **options: Any) -> Trajectories:
    """Read any supported trajectory file (options a format does not take are ignored)."""
    path = Path(path)
    if path.is_dir():
        raise MocapError(f"{path}: is a folder, not a trajectory file ({', '.join(FORMATS)}); a take folder is "
                         "reconstructed with 'mocap reconstruct'")
    fmt = format_of(path)
    if not path.is_file():
        raise MocapError(f"{path}: {fmt.name} file not found")
    return fmt.read(path, **options)


def write_trajectories(traj: Trajectories, path: str | os.PathLike, **options: Any) -> None:
    """Write ``traj`` in the format named by the suffix of ``path``, atomically."""
    format_of(path).write(traj, Path(path), **options)
