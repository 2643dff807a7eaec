"""``mocap export IN --c3d/--trc/--csv/--mcap OUT``: convert trajectories between file formats."""

from __future__ import annotations

import argparse
from pathlib import Path

from mocap.atomic import check_output_path
from mocap.camera import Rig, load_rig
from mocap.errors import MocapError
from mocap.export.formats import FORMATS, read_trajectories, write_trajectories
from mocap.trajectories import Trajectories

__all__ = ["convert", "configure_parser", "run"]

_CSV_UNITS = {"mm": "Millimeters", "cm": "Centimeters", "m": "Meters"}


def _input_rig(path: Path) -> Rig | None:
    """The cameras stored in an input MCAP take log, if any."""
    if path.suffix.lower() != ".mcap":
        return None
    from mocap.export.mcap import read_mcap_take

    try:
        return read_mcap_take(path).rig
    except MocapError:
        return None


def convert(source: str | Path, outputs: dict[str, str], units: str = "mm", y_up: bool = False,
            in_up_axis: str | None = None, rig: Rig | None = None) -> Trajectories:
    """Read ``source`` and write it to every ``{format suffix: path}`` in ``outputs``.

    Args:
        units: "mm", "cm" or "m" for TRC and CSV outputs.
        y_up: write TRC and CSV outputs in the y-up frame (OpenSim, Motive).
        in_up_axis: "y" or "z": the up axis of a TRC or CSV input (default: TRC z, CSV from the file, else y).
        rig: cameras to include in an MCAP output (default: those of an MCAP input).
    """
    source = Path(source)
    for out in outputs.values():
        check_output_path(out)
        if Path(out).resolve() == source.resolve():
            raise MocapError(f"{out}: the output would overwrite the input; choose another name")
    up = in_up_axis.lower() if in_up_axis else None
    traj = read_trajectories(source, y_up=up == "y" if up else None, up_axis=up.upper() if up else None)
    rig = rig if rig is not None else _input_rig(source)
    for suffix, out in outputs.items():
        options = {"y_up": y_up, "rig": rig,
                   "units": _CSV_UNITS[units] if suffix == ".csv" else units}
        write_trajectories(traj, out, **options)
    return traj


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="trajectory file: .c3d, .trc, .csv (Motive) or .mcap")
    for suffix in (".c3d", ".trc", ".csv", ".mcap"):
        parser.add_argument(f"--{suffix[1:]}", metavar=f"OUT{suffix}", help=f"write {FORMATS[suffix].name}")
    parser.add_argument("--units", choices=sorted(_CSV_UNITS), default="mm", help="TRC/CSV length unit (default mm)")
    parser.add_argument("--y-up", action="store_true", help="write TRC/CSV in the y-up frame (OpenSim, Motive)")
    parser.add_argument("--in-up-axis", choices=("y", "z"),
                        help="up axis of a TRC/CSV input (default: TRC z; CSV its 'Up Axis' entry, else y)")
    parser.add_argument("--calibration", metavar="calibration.toml", help="cameras to include in an MCAP output")


def run(args: argparse.Namespace) -> int:
    outputs = {s: getattr(args, s[1:]) for s in (".c3d", ".trc", ".csv", ".mcap") if getattr(args, s[1:])}
    if not outputs:
        raise MocapError("no output given; add at least one of --c3d, --trc, --csv, --mcap OUT")
    rig = load_rig(args.calibration) if args.calibration else None
    traj = convert(args.input, outputs, args.units, args.y_up, args.in_up_axis, rig)
    print(f"{traj.n_markers} markers, {traj.n_frames} frames at {traj.fps:g} Hz -> {', '.join(outputs.values())}")
    return 0
