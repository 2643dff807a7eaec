"""``mocap calibrate``: intrinsics, stereo pairs, fundamental matrices, wand extrinsics, checks.

Subcommands (``mocap calibrate SUB --help`` for each):

* ``intrinsics``  one camera's K and distortion from board images or a video;
* ``stereo``      a two-camera rig from stereo board image pairs;
* ``fundamental`` add every pair's fundamental matrix to a calibration file;
* ``wand``        the rig's extrinsics from a wand wave (and the world frame from an L-frame);
* ``compare``     a recovered calibration against a reference one;
* ``score``       reconstruct a synthetic take with a recovered calibration and with its own, and score both.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from calibration.boards import parse_board
from calibration.fundamental import TABLE, fundamental_table
from calibration.report import json_ready, write_json

__all__ = ["configure_parser", "run"]


def configure_parser(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="calibrate_command", metavar="STEP", required=True)

    p = sub.add_parser("intrinsics", help="one camera's intrinsics from board images or a video")
    p.add_argument("source", nargs="+", help="a folder of images, a video, or image files")
    p.add_argument("--board", required=True, help="checker:COLSxROWS:SQUARE_M or charuco:COLSxROWS:SQUARE_M:MARKER_M")
    p.add_argument("--name", required=True, help="the camera's name (the stem of its recordings)")
    p.add_argument("--out", required=True, metavar="calibration.toml",
                   help="file to write; an existing one keeps its other cameras and this camera's pose")
    p.add_argument("--every", type=int, default=1, help="use every n-th video frame (default 1)")
    p.add_argument("--max-views", type=int, default=40, help="most board views used (chosen for coverage)")
    p.add_argument("--report", metavar="REPORT.json", help="also write per-image errors as JSON")
    p.set_defaults(_step=_run_intrinsics)

    p = sub.add_parser("stereo", help="a two-camera rig from stereo board image pairs")
    p.add_argument("--list", metavar="stereo_calib.xml", help="OpenCV image list: left, right, left, right ...")
    p.add_argument("--left", nargs="*", default=[], help="left images (instead of --list)")
    p.add_argument("--right", nargs="*", default=[], help="right images, same order")
    p.add_argument("--board", required=True, help="checker:COLSxROWS:SQUARE_M or charuco:...")
    p.add_argument("--names", default="left,right", help="camera names (default left,right)")
    p.add_argument("--fix-intrinsics", action="store_true", help="keep each camera's own intrinsics")
    p.add_argument("--out", required=True, metavar="calibration.toml")
    p.add_argument("--report", metavar="REPORT.json")
    p.set_defaults(_step=_run_stereo)

    p = sub.add_parser("fundamental", help="add every camera pair's fundamental matrix to a calibration")
    p.add_argument("calibration", help="calibration.toml with poses")
    p.add_argument("--out", help="file to write (default: update the input)")
    p.set_defaults(_step=_run_fundamental)

    p = sub.add_parser("wand", help="extrinsics from a wand wave; world frame from an L-frame")
    p.add_argument("take", help="the wand-wave take folder")
    p.add_argument("--wand", help="marker positions along the wand, m, e.g. 0,0.15,0.5 (default: take.toml wand_m)")
    p.add_argument("--intrinsics", metavar="calibration.toml",
                   help="intrinsics per camera (default: the take's calibration.toml; poses are ignored)")
    p.add_argument("--lframe-take", metavar="TAKE", help="a still take of the L-frame on the floor")
    p.add_argument("--lframe", help="L-frame marker coordinates, m: 'x,y,z; x,y,z; ...' (default: take.toml "
                   "lframe_m, else corner 0,0,0; 0.2,0,0; 0.5,0,0; 0,0.35,0)")
    p.add_argument("--floor-take", metavar="TAKE", help="a still take of >= 3 markers on the floor (no L-frame)")
    p.add_argument("--every", type=int, default=1, help="use every n-th frame of the wave")
    p.add_argument("--max-frames", type=int, default=600, help="most frames in the bundle adjustment")
    p.add_argument("--refine-focal", action="store_true", help="also refine each camera's focal length")
    p.add_argument("--refine-k1", action="store_true", help="also refine each camera's k1")
    p.add_argument("--out", required=True, metavar="calibration.toml")
    p.add_argument("--report", metavar="REPORT.json", help="every figure as JSON")
    p.add_argument("--coverage", metavar="COVERAGE.png", help="plot of where each camera saw the wand")
    p.set_defaults(_step=_run_wand)

    p = sub.add_parser("compare", help="compare a calibration with a reference (e.g. the synthetic truth)")
    p.add_argument("calibration")
    p.add_argument("reference")
    p.add_argument("--json", metavar="OUT.json")
    p.set_defaults(_step=_run_compare)

    p = sub.add_parser("score", help="reconstruct a synthetic take with a calibration and with its own; score both")
    p.add_argument("take")
    p.add_argument("--calibration", required=True, metavar="calibration.toml", help="the calibration to test")
    p.add_argument("--truth", help="truth file (default <take>.truth.npz)")
    p.add_argument("--json", metavar="OUT.json")
    p.set_defaults(_step=_run_score)


def run(args: argparse.Namespace) -> int:
    return int(args._step(args) or 0)


# ------------------------------------------------------------------------------------------------ steps
def _run_intrinsics(args: argparse.Namespace) -> int:
    from calibration.intrinsics import calibrate_intrinsics, find_views, read_images
    from mocap.atomic import check_output_path
    from mocap.camera import Rig, load_rig, save_rig

    out = check_output_path(args.out)
    board = parse_board(args.board)
    source = args.source[0] if len(args.source) == 1 else args.source
    where = str(args.source[0]) if len(args.source) == 1 else f"{len(args.source)} images"
    views, missed, size = find_views(read_images(source, args.every), board, where)
    result = calibrate_intrinsics(views, board, size, max_views=args.max_views, where=where)
    result.no_board = missed
    camera = result.camera(args.name)
    if out.exists():
        rig = load_rig(out)
        cams = [camera.with_pose(c.rotation, c.translation) if c.name == args.name else c for c in rig]
        if args.name not in rig.names:
            cams.append(camera)
        rig = Rig(cams, rig.metadata, rig.extra_tables)
    else:
        rig = Rig([camera], {"made_by": "mocap calibrate intrinsics", "extrinsics": "unknown"})
    save_rig(rig, out)
    print(f"{args.name}: RMS {result.rms_px:.3f} px over {len(result.view_errors)} views "
          f"({len(result.rejected)} rejected, {len(missed)} without the board); fx {camera.matrix[0, 0]:.2f} "
          f"+- {result.std_focal_px:.2f} px -> {out}")
    if args.report:
        write_json({"camera": args.name, "rms_px": result.rms_px, "matrix": camera.matrix, "distortions":
                    camera.distortions, "view_errors_px": result.view_errors, "rejected_px": result.rejected,
                    "no_board": missed, "std_focal_px": result.std_focal_px}, args.report)
    return 0


def _run_stereo(args: argparse.Namespace) -> int:
    from calibration.intrinsics import read_images
    from calibration.stereo import calibrate_stereo, read_image_list
    from mocap.atomic import check_output_path
    from mocap.camera import save_rig
    from mocap.errors import MocapError

    out = check_output_path(args.out)
    board = parse_board(args.board)
    if args.list:
        pairs = read_image_list(args.list)
        left, right = [p[0] for p in pairs], [p[1] for p in pairs]
    else:
        left, right = [Path(p) for p in args.left], [Path(p) for p in args.right]
    if not left or len(left) != len(right):
        raise MocapError("stereo: give --list FILE, or --left and --right with the same number of images")
    names = tuple(n.strip() for n in args.names.split(","))
    if len(names) != 2:
        raise MocapError(f"--names {args.names!r}: give two camera names, e.g. left,right")
    views, sizes = [], []
    for files in (left, right):
        imgs = list(read_images(files))
        sizes.append(imgs[0][1].shape[::-1])
        views.append([board.detect(im, name) for name, im in imgs])
    if sizes[0] != sizes[1]:
        raise MocapError(f"stereo: left images are {sizes[0][0]}x{sizes[0][1]}, right ones "
                         f"{sizes[1][0]}x{sizes[1][1]}; both cameras must have the same resolution")
    result = calibrate_stereo(views[0], views[1], board, sizes[0], names, args.fix_intrinsics)
    x1, x2 = result.corners
    rig = result.rig
    rig.extra_tables[TABLE] = fundamental_table(rig, correspondences={(0, 1): (x1, x2)})
    save_rig(rig, out)
    print(f"stereo {names[0]}-{names[1]}: {len(result.pairs)} pairs, RMS {result.rms_px:.3f} px; epipolar distance "
          f"(mean) {result.rig_stats.mean_px:.3f} px with the rig's F, {result.fit.stats.mean_px:.3f} px with F fitted "
          f"to the corners; baseline {1000 * np.linalg.norm(rig[1].center):.1f} mm -> {out}")
    if args.report:
        write_json({"rms_px": result.rms_px, "pairs": result.pairs, "rig_F": rig.extra_tables[TABLE],
                    "rig_epipolar": result.rig_stats.as_dict(), "fitted_F": result.fit.F,
                    "fitted_epipolar": result.fit.stats.as_dict(),
                    "intrinsics_rms_px": [r.rms_px for r in result.intrinsics]}, args.report)
    return 0


def _run_fundamental(args: argparse.Namespace) -> int:
    from mocap.camera import load_rig, save_rig

    rig = load_rig(args.calibration)
    rig.extra_tables[TABLE] = fundamental_table(rig)
    out = args.out or args.calibration
    save_rig(rig, out)
    print(f"{len(rig.extra_tables[TABLE])} fundamental matrices -> {out}")
    return 0


def _run_wand(args: argparse.Namespace) -> int:
    from calibration.align import DEFAULT_LFRAME, parse_points
    from calibration.bundle import BundleOptions
    from calibration.extrinsics import WandOptions, calibrate_wand
    from calibration.report import coverage_png, wand_text
    from calibration.takes import read_blobs, take_facts
    from calibration.wand import Wand, parse_wand
    from mocap.atomic import check_output_path
    from mocap.camera import Rig, load_rig, save_rig
    from mocap.errors import MocapError

    out = check_output_path(args.out)
    for extra in (args.report, args.coverage):
        if extra:
            check_output_path(extra)
    facts = take_facts(args.take)
    if args.wand:
        wand = parse_wand(args.wand)
    elif "wand_m" in facts:
        wand = Wand(tuple(float(v) for v in facts["wand_m"]))
    else:
        raise MocapError(f"{args.take}: say what the wand is: --wand 0,0.15,0.5 (marker positions along it, m) "
                         "or wand_m = [...] in take.toml")
    rig, frames = read_blobs(args.take, args.every)
    if args.intrinsics:
        known = load_rig(args.intrinsics)
        rig = Rig([known[known.index(c.name)] for c in rig], rig.metadata)
    lframe_frames = floor_frames = lframe = None
    if args.lframe_take:
        _, lframe_frames = read_blobs(args.lframe_take)
        lf_facts = take_facts(args.lframe_take)
        lframe = (parse_points(args.lframe) if args.lframe else np.asarray(lf_facts["lframe_m"], dtype=float)
                  if "lframe_m" in lf_facts else DEFAULT_LFRAME)
    elif args.floor_take:
        _, floor_frames = read_blobs(args.floor_take)
    options = WandOptions(max_frames=args.max_frames,
                          bundle=BundleOptions(refine_focal=args.refine_focal, refine_k1=args.refine_k1))
    cal = calibrate_wand(rig, frames, wand, options, lframe_frames, lframe, floor_frames, where=str(args.take))
    save_rig(cal.rig, out)
    print(wand_text(cal.report))
    print(f"calibration -> {out}")
    if args.report:
        write_json(cal.report, args.report)
    if args.coverage:
        coverage_png(cal.rig, cal.obs, cal.residuals, args.coverage)
    return 0


def _run_compare(args: argparse.Namespace) -> int:
    from calibration.compare import compare_rigs
    from mocap.camera import load_rig

    result = compare_rigs(load_rig(args.calibration), load_rig(args.reference))
    print(f"{'camera':<10} {'pos mm':>8} {'angle deg':>10} {'aligned mm':>11} {'aligned deg':>12} {'focal %':>8}")
    for c in result["cameras"]:
        print(f"{c['name']:<10} {c['position_mm']:>8.3f} {c['angle_deg']:>10.4f} {c['aligned_position_mm']:>11.3f} "
              f"{c['aligned_angle_deg']:>12.4f} {c['focal_pct']:>8.3f}")
    if args.json:
        write_json(result, args.json)
    return 0


def _run_score(args: argparse.Namespace) -> int:
    from calibration.compare import reconstruction_scores
    from mocap.camera import load_rig

    take = Path(args.take)
    truth = Path(args.truth) if args.truth else take.with_name(take.name + ".truth.npz")
    scores = reconstruction_scores(take, truth, {"take": load_rig(take / "calibration.toml"),
                                                 "tested": load_rig(args.calibration)})
    base, test = scores["take"]["rmse_mm"], scores["tested"]["rmse_mm"]
    for label, s in scores.items():
        print(f"{label:<7} RMSE {s['rmse_mm']:.3f} mm, completeness {100 * s['completeness']:.2f} %, "
              f"ID switches {s['switches']}")
    if base and test is not None:
        print(f"RMSE ratio tested/take = {test / base:.3f}")
    if args.json:
        write_json(json_ready(scores), args.json)
    return 0

