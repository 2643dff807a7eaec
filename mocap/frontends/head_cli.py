"""``mocap track-head TAKE --c3d OUT.c3d``: track the head in every camera's colour video, lift it to 3D."""

from __future__ import annotations

import argparse
import logging

import numpy as np
from tqdm import tqdm

from mocap.errors import MocapError
from mocap.frontends.command import add_common_arguments, check_outputs, write_outputs
from mocap.frontends.head import CueMode, HeadConfig, track_head
from mocap.frontends.lift import lift_tracks
from mocap.frontends.video import open_colour_take

__all__ = ["configure_parser", "run", "parse_box"]

log = logging.getLogger(__name__)


def parse_box(text: str) -> tuple[str | None, tuple[float, float, float, float]]:
    """``"cam1=x,y,w,h"`` or ``"x,y,w,h"`` (every camera) -> (camera name or None, box)."""
    name, _, spec = text.rpartition("=")
    try:
        values = tuple(float(v) for v in spec.split(","))
    except ValueError:
        values = ()
    if len(values) != 4 or values[2] <= 2 or values[3] <= 2:
        raise MocapError(f"--box {text!r}: expected CAMERA=x,y,w,h (pixels, w and h > 2), e.g. cam1=40,20,24,30")
    return (name or None), (values[0], values[1], values[2], values[3])


def configure_parser(parser: argparse.ArgumentParser) -> None:
    add_common_arguments(parser, gate_px=5.0)
    parser.add_argument("--box", action="append", default=[], metavar="CAM=x,y,w,h",
                        help="head box in the first frame of camera CAM (repeat per camera; without CAM= it applies "
                             "to every camera); cameras without a box find the head by skin colour")
    parser.add_argument("--mode", choices=[m.value for m in CueMode], default=CueMode.FUSED.value,
                        help="cues: fused (default), colour only or shape only")
    parser.add_argument("--particles", type=int, default=200, help="particles per camera (default 200)")


def run(args: argparse.Namespace) -> int:
    check_outputs(args)
    if args.particles < 10:
        raise MocapError(f"--particles {args.particles}: use at least 10")
    take = open_colour_take(args.take, args.fps)
    boxes = dict(parse_box(b) for b in args.box)
    unknown = set(boxes) - {None, *take.rig.names}
    if unknown:
        raise MocapError(f"--box names camera(s) {sorted(unknown)} not in {take.folder / 'calibration.toml'} "
                         f"(cameras: {take.rig.names})")
    config = HeadConfig(particles=args.particles, mode=CueMode(args.mode))
    tracks = []
    for c, cam in enumerate(tqdm(take.rig.cameras, desc="track-head", unit="camera", disable=None)):
        box = boxes.get(cam.name, boxes.get(None))
        try:
            centre, _, _ = track_head(take.frames(c), box, config, args.seed + c)
        except MocapError as exc:
            raise MocapError(f"{take.sources[c]}: {exc}") from None
        log.info("%s: head tracked in %d of %d frames", cam.name, np.isfinite(centre).all(axis=1).sum(), len(centre))
        tracks.append(centre)
    n = min(len(t) for t in tracks)
    if n == 0:
        raise MocapError(f"{take.folder}: the recordings hold no frames")
    stacked = np.stack([t[:n] for t in tracks])[:, :, None, :]
    traj = lift_tracks(take.rig, stacked, ["head"], take.fps, max_error_px=args.gate,
                       metadata={"source": "mocap track-head", "mode": args.mode})
    log.info("head in 3D in %d of %d frames", traj.valid.sum(), n)
    write_outputs(traj, take.rig, args)
    return 0
