"""``mocap track-hand TAKE --c3d OUT.c3d``: track fingertips and palm in every camera, lift them to 3D."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

import numpy as np
from tqdm import tqdm

from mocap.errors import MocapError
from mocap.frontends.command import add_common_arguments, check_outputs, write_outputs
from mocap.frontends.hand import track_hand
from mocap.frontends.lift import lift_tracks
from mocap.frontends.postures import DEFAULT_MODEL_PATH, FINGERS, PostureModel
from mocap.frontends.video import open_colour_take

__all__ = ["configure_parser", "run", "LABELS"]

log = logging.getLogger(__name__)

LABELS = [*FINGERS, "palm"]


def configure_parser(parser: argparse.ArgumentParser) -> None:
    add_common_arguments(parser, gate_px=4.0)
    parser.add_argument("--model", type=Path, default=DEFAULT_MODEL_PATH, metavar="MODEL.json",
                        help="posture classifier (default: the model shipped with mocap)")


def run(args: argparse.Namespace) -> int:
    check_outputs(args)
    model = PostureModel.load(args.model)
    take = open_colour_take(args.take, args.fps)
    tracks = []
    for c, cam in enumerate(tqdm(take.rig.cameras, desc="track-hand", unit="camera", disable=None)):
        try:
            tips, palm, posture = track_hand(take.frames(c), model, seed=args.seed + c)
        except MocapError as exc:
            raise MocapError(f"{take.sources[c]}: {exc}") from None
        letters, counts = np.unique(posture[posture != ""], return_counts=True)
        log.info("%s: hand found in %d of %d frames; postures %s", cam.name, (posture != "").sum(), len(posture),
                 dict(zip(letters.tolist(), counts.tolist(), strict=True)))
        tracks.append(np.concatenate([tips, palm[:, None, :]], axis=1))
    n = min(len(t) for t in tracks)
    if n == 0:
        raise MocapError(f"{take.folder}: the recordings hold no frames")
    traj = lift_tracks(take.rig, np.stack([t[:n] for t in tracks]), LABELS, take.fps, max_error_px=args.gate,
                       metadata={"source": "mocap track-hand"})
    log.info("3D samples per label: %s", dict(zip(LABELS, traj.valid.sum(axis=0).tolist(), strict=True)))
    write_outputs(traj, take.rig, args)
    return 0
