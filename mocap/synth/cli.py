"""``mocap synth``: render a synthetic take (and its ground truth) from a C3D file or the built-in body."""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import inspect
import logging
import re
import time
from pathlib import Path

import numpy as np

from mocap.camera import Rig
from mocap.errors import MocapError
from mocap.synth.body import DEFAULT_MARKERS, marching_motion
from mocap.synth.motion import UP_AXES, Motion, motion_from_file
from mocap.synth.rig import DEFAULT_CAMERAS, DEFAULT_RADIUS_M, WALKWAY_MIN_LENGTH_M, rig_for_motion, ring_rig
from mocap.synth.settings import FORMATS, SynthSettings
from mocap.synth.writer import default_truth_path, render_take

__all__ = ["configure_parser", "run"]

log = logging.getLogger(__name__)

DEFAULT_BODY_FRAMES = 600
_SCENES = {"wand": ("mocap.synth.wand", "render_wand_take"), "board": ("mocap.synth.board", "render_board_take")}


def _size(text: str) -> tuple[int, int]:
    match = re.fullmatch(r"\s*(\d+)\s*[xX]\s*(\d+)\s*", text)
    if not match or int(match[1]) < 16 or int(match[2]) < 16:
        raise argparse.ArgumentTypeError(f"{text!r}: give the image size as WIDTHxHEIGHT, e.g. 1024x768")
    return int(match[1]), int(match[2])


def configure_parser(parser: argparse.ArgumentParser) -> None:
    d = SynthSettings()
    parser.add_argument("out_dir", type=Path, metavar="OUT_DIR", help="take folder to create")
    src = parser.add_argument_group("motion and cameras")
    src.add_argument("--scene", choices=("body", "wand", "board"), default="body",
                     help="what to film: markers on a body (default), a calibration wand wave, or a board")
    src.add_argument("--motion", type=Path, metavar="FILE",
                     help="marker motion to film: a C3D, TRC or Motive CSV file (any units, any up axis); default: "
                          "the built-in marching body")
    src.add_argument("--up", choices=sorted(UP_AXES), help="the motion file's up axis (default: detected)")
    src.add_argument("--frames", type=int, help=f"frames to render (default: the whole file, or "
                                                f"{DEFAULT_BODY_FRAMES} for the built-in body)")
    src.add_argument("--start", type=int, default=0,
                     help="first frame of the motion to render, counted at the take's frame rate (after --fps; "
                          "default 0)")
    src.add_argument("--fps", type=float, help="frame rate of the take, Hz (default: the file's rate, or 120 for "
                                               "the built-in body); a C3D file is resampled linearly")
    src.add_argument("--markers", type=int, default=DEFAULT_MARKERS,
                     help=f"markers on the built-in body (default {DEFAULT_MARKERS}, at most 49)")
    src.add_argument("--layout", choices=("auto", "ring", "walkway"), default="auto",
                     help="camera layout: a ring around the motion, or two staggered rows along a long straight "
                          f"path (default auto: a walkway for a C3D motion over {WALKWAY_MIN_LENGTH_M:g} m long "
                          "and 3x longer than wide)")
    src.add_argument("--cameras", type=int,
                     help=f"number of cameras (default {DEFAULT_CAMERAS} on a ring; along a walkway, as many as "
                          "give 99%% of the motion 4 views)")
    src.add_argument("--size", type=_size, default=(1024, 768), metavar="WxH", help="image size (default 1024x768)")
    src.add_argument("--focal", type=float, default=1000.0, help="focal length, px (default 1000)")
    src.add_argument("--distortion", type=float, default=0.05,
                     help="bound of the random radial distortion k1 (default 0.05; 0: none)")
    src.add_argument("--radius", type=float,
                     help=f"camera ring radius, m (default {DEFAULT_RADIUS_M}, widened to cover a C3D motion); "
                          f"along a walkway, the cameras' distance from its centre line (default: half its width "
                          f"+ {DEFAULT_RADIUS_M:g})")
    img = parser.add_argument_group("image realism (every artefact has a knob; --clean turns them all off)")
    img.add_argument("--marker-mm", type=float, help=f"marker diameter, mm (default {d.marker_mm:g})")
    img.add_argument("--background", type=float, help=f"background grey level (default {d.background:g})")
    img.add_argument("--noise", type=float, help=f"sensor noise std, grey levels (default {d.noise:g})")
    img.add_argument("--brightness", type=float,
                     help=f"marker peak above background at 4 m, grey levels (default {d.brightness:g}; 1/d^2)")
    img.add_argument("--blur", type=float, dest="blur_px", help=f"optical blur std, px (default {d.blur_px:g})")
    img.add_argument("--exposure", type=float, dest="exposure_ms",
                     help=f"shutter time, ms: moving markers smear over it (default {d.exposure_ms:g}: none)")
    img.add_argument("--ghosts", type=int, help=f"fixed reflections per camera (default {d.ghosts})")
    img.add_argument("--ghost-blink", type=float,
                     help=f"fraction of the ghosts that flicker (default {d.ghost_blink:g})")
    img.add_argument("--dropout-rate", type=float,
                     help=f"fraction of marker samples dropped at random (default {d.dropout_rate:g})")
    img.add_argument("--dropout-frames", type=float,
                     help=f"mean length of a dropout, frames (default {d.dropout_frames:g})")
    img.add_argument("--hidden-rate", type=float,
                     help=f"fraction of marker samples hidden from every camera at once (default {d.hidden_rate:g})")
    img.add_argument("--hidden-frames", type=float,
                     help=f"mean length of such a gap in every view, frames (default {d.hidden_frames:g})")
    img.add_argument("--no-occlusion", dest="occlusion", action="store_const", const=False,
                     help="do not hide markers behind the body")
    img.add_argument("--clean", action="store_true",
                     help="no noise, no ghosts, no dropouts or gaps (8-bit rounding stays)")
    out = parser.add_argument_group("output")
    out.add_argument("--format", choices=FORMATS, help="mkv: lossless FFV1 video per camera (default); "
                                                       "png: a folder of numbered frames per camera")
    out.add_argument("--seed", type=int, help=f"seed of every random choice (default {d.seed})")
    out.add_argument("--truth", type=Path, help="ground-truth file (default: OUT_DIR.truth.npz beside the take)")
    out.add_argument("--force", action="store_true", help="replace OUT_DIR if it exists")
    out.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")


def settings_from_args(args: argparse.Namespace) -> SynthSettings:
    """Defaults, then ``--clean``, then every flag given explicitly."""
    base = SynthSettings().clean() if args.clean else SynthSettings()
    given = {f.name: getattr(args, f.name) for f in dataclasses.fields(SynthSettings)
             if getattr(args, f.name, None) is not None}
    return base.replace(**given)


def _motion(args: argparse.Namespace, settings: SynthSettings) -> Motion:
    if args.motion is None:
        frames = args.frames if args.frames is not None else DEFAULT_BODY_FRAMES
        motion = marching_motion(args.start + frames, args.fps or 120.0, args.markers, settings.seed,
                                 settings.marker_mm)
        return motion.window(args.start, frames)
    motion = motion_from_file(args.motion, args.up)
    if args.fps is not None:
        motion = motion.resampled(args.fps)
    motion = motion.window(args.start, args.frames).centred()
    if not np.isfinite(motion.positions).all(axis=2).any():
        raise MocapError(f"{args.motion}: frames {args.start}..{args.start + motion.n_frames - 1} hold no marker "
                         "samples; choose other frames with --start/--frames")
    return motion


def _rig(args: argparse.Namespace, motion: Motion | None, seed: int) -> Rig:
    """The cameras: the default ring, or (around a C3D motion) :func:`rig_for_motion`'s fitted rig."""
    kwargs = {"size": args.size, "focal_px": args.focal, "distortion": args.distortion, "seed": seed}
    if motion is None or args.motion is None:
        return ring_rig(args.cameras or DEFAULT_CAMERAS, radius=args.radius or DEFAULT_RADIUS_M, **kwargs)
    return rig_for_motion(motion.positions, args.layout, args.cameras, args.radius, **kwargs)


def _rig_summary(rig: Rig) -> str:
    """One line on how the synthetic cameras stand."""
    meta = rig.metadata
    if meta.get("layout") == "walkway":
        return (f"walkway rig: {len(rig)} cameras in two rows {meta['standoff_m']:.2f} m from a "
                f"{meta['walkway_length_m']:.1f} m centre line")
    return f"ring of {len(rig)} cameras, radius {meta['ring_radius_m']:.2f} m"


def _render_scene(args: argparse.Namespace, rig: Rig, settings: SynthSettings, truth_path: Path) -> None:
    """A calibration scene (wand or board), rendered by the calibration utility's renderer.

    The renderer gets ``out_dir`` and whichever of rig, settings, n_frames, fps, truth_path, progress
    and force its signature names (the scene's layout is the renderer's; see docs/calibration.md).
    """
    module_name, function_name = _SCENES[args.scene]
    try:
        render = getattr(importlib.import_module(module_name), function_name)
    except (ImportError, AttributeError):
        raise MocapError(f"--scene {args.scene} needs {module_name}.{function_name}, which this build does not "
                         "have; render a body take instead") from None
    offered = {"rig": rig, "settings": settings, "n_frames": args.frames, "fps": args.fps, "truth_path": truth_path,
               "progress": args.progress, "force": args.force}
    accepted = inspect.signature(render).parameters
    render(args.out_dir, **{k: v for k, v in offered.items() if k in accepted and v is not None})


def run(args: argparse.Namespace) -> int:
    started = time.perf_counter()
    settings = settings_from_args(args)
    truth_path = args.truth or default_truth_path(args.out_dir)
    if args.scene != "body":
        if args.motion is not None:
            raise MocapError(f"--motion and --scene {args.scene} exclude each other; a calibration scene has "
                             "its own motion")
        _render_scene(args, _rig(args, None, settings.seed), settings, truth_path)
        print(f"{args.scene} scene written to {args.out_dir}")
        return 0
    motion = _motion(args, settings)
    rig = _rig(args, motion, settings.seed)
    truth = render_take(args.out_dir, rig, motion, settings, truth_path, progress=args.progress, force=args.force)
    views = truth.views[np.isfinite(truth.positions).all(axis=2)]
    print(f"take written to {args.out_dir} ({truth.n_frames} frames at {truth.fps:g} Hz, {len(rig)} cameras, "
          f"{len(truth.labels)} markers, {settings.format}); truth in {truth_path}")
    print(f"  source: {motion.info.get('source')}; {_rig_summary(rig)}")
    print(f"  marker samples seen by >= 2 cameras: {np.mean(views >= 2):.1%}, mean cameras per marker "
          f"{views.mean():.2f}; occluded {truth.settings['occluded_fraction']:.1%}, dropped "
          f"{truth.settings['dropped_fraction']:.1%} (hidden from every camera "
          f"{truth.settings['hidden_fraction']:.1%}); {time.perf_counter() - started:.1f} s")
    return 0
