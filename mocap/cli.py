"""The ``mocap`` command.

Each subcommand lives in the module that owns its job and exposes two functions:
``configure_parser(parser)`` adds its arguments and ``run(args) -> int`` does the work.
User errors (:class:`mocap.errors.MocapError`) are printed as one plain line, exit code 2.
"""

from __future__ import annotations

import argparse
import errno
import importlib
import logging
import sys

from mocap.errors import MocapError

# name -> (module, one-line help)
SUBCOMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("mocap.demo", "render the built-in take, reconstruct it, score it, write C3D and a plot"),
    "reconstruct": ("mocap.pipeline", "reconstruct labelled 3D trajectories from a take (or an MCAP log)"),
    "synth": ("mocap.synth.cli", "render a synthetic take with ground truth"),
    "evaluate": ("mocap.evaluate", "score reconstructed trajectories against ground truth"),
    "export": ("mocap.export.convert", "convert trajectories between C3D, TRC, CSV and MCAP"),
    "info": ("mocap.export.info", "summarise a trajectory file (markers, frames, rate, gaps)"),
    "plot": ("mocap.plot", "write a PNG of 3D trajectories and per-marker gaps/residuals"),
    "view": ("mocap.view", "interactive 3D viewer (needs the 'viz' extra)"),
    "calibrate": ("calibration.cli", "calibrate cameras: intrinsics, fundamental matrices, wand extrinsics"),
    "track-head": ("mocap.frontends.head_cli", "track a head in every camera and lift it to 3D"),
    "track-hand": ("mocap.frontends.hand_cli", "track hand fingertips in every camera and lift them to 3D"),
}


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The ``mocap`` parser; only ``command``'s module is imported (so ``mocap --help`` starts fast)."""
    parser = argparse.ArgumentParser(prog="mocap", description="Marker-based optical motion capture.")
    parser.add_argument("-v", "--verbose", action="store_true", help="log details of every stage")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (module_name, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == command:
            module = importlib.import_module(module_name)
            module.configure_parser(p)
            p.set_defaults(_run=module.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((a for a in argv if a in SUBCOMMANDS), None)
    parser = build_parser(command)
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(levelname)s: %(message)s",
        stream=sys.stderr,
    )
    if not getattr(args, "_run", None):
        parser.print_help()
        return 1
    try:
        return int(args._run(args) or 0)
    except MocapError as exc:
        print(f"mocap {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # (a full disk, a folder gone: what the command read or wrote, not a bug's traceback)
        where = f"{exc.filename}: " if exc.filename else ""
        hint = {errno.ENOSPC: "; free some space, or write the outputs to another disk",
                errno.EACCES: "; check the permissions"}.get(exc.errno, "")
        print(f"mocap {args.command}: error: {where}{exc.strerror or exc}{hint}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"mocap {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
