"""Command-line plumbing shared by ``mocap track-head`` and ``mocap track-hand``."""

from __future__ import annotations

import argparse
import importlib.util
import logging
from pathlib import Path

from mocap.atomic import check_output_path
from mocap.camera import Rig
from mocap.export.c3d import write_c3d
from mocap.trajectories import Trajectories

__all__ = ["add_common_arguments", "check_outputs", "write_outputs"]

log = logging.getLogger(__name__)


def add_common_arguments(parser: argparse.ArgumentParser, gate_px: float) -> None:
    """TAKE, --c3d, --mcap, --fps, --seed, --gate."""
    parser.add_argument("take", type=Path, metavar="TAKE",
                        help="take folder: calibration.toml + one colour video (or PNG folder) per camera")
    parser.add_argument("--c3d", type=Path, required=True, metavar="OUT.c3d", help="write the 3D tracks here")
    parser.add_argument("--mcap", type=Path, metavar="OUT.mcap", help="also write a Foxglove MCAP log")
    parser.add_argument("--fps", type=float, help="frame rate, Hz (default: take.toml, else the videos)")
    parser.add_argument("--seed", type=int, default=0, help="random seed of the particle filters (default 0)")
    parser.add_argument("--gate", type=float, default=gate_px, metavar="PX",
                        help=f"reprojection error above which a camera's point is rejected (default {gate_px} px)")


def check_outputs(args: argparse.Namespace) -> None:
    """Fail before any work if an output cannot be written."""
    check_output_path(args.c3d)
    if args.mcap is not None:
        check_output_path(args.mcap)


def write_outputs(traj: Trajectories, rig: Rig, args: argparse.Namespace) -> None:
    """C3D always; MCAP when asked for (needs :mod:`mocap.export.mcap`)."""
    write_c3d(traj, args.c3d)
    log.info("wrote %s (%d frames, %s)", args.c3d, traj.n_frames, ", ".join(traj.labels))
    if args.mcap is not None:
        if importlib.util.find_spec("mocap.export.mcap") is None:
            log.warning("this build has no MCAP writer; %s not written", args.mcap)
            return
        from mocap.export.mcap import write_mcap

        write_mcap(traj, args.mcap, rig)
        log.info("wrote %s", args.mcap)
