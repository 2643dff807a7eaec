"""Speed of the tracking core from 2D centroids, against the plain reference baseline, in one run.

The take is simulated at centroid level (no images): ``mocap.synth`` plans the take (projection,
capsule occlusion, dropouts, ghosts, Cramér–Rao centroid noise) and ``mocap.synth.wand.centroid_frames``
turns it into per-camera detections, which are prepared before any timing. Both trackers then run on
the same frames on one core (BLAS threads pinned to 1); the figures are frames per second of
``Tracker.step`` (undistortion, prediction, association, fusion, identities, recording) plus
``finish``, and the accuracy / identity scores of both outputs from ``mocap.evaluate``.

Usage:
    python tools/bench_tracking.py [--frames 1200] [--markers 40] [--cameras 6] [--motion body|FILE.c3d]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from mocap.evaluate import evaluate  # noqa: E402
from mocap.reference import ReferenceTracker  # noqa: E402
from mocap.synth import SynthSettings, marching_motion, motion_from_c3d, plan_take, ring_rig  # noqa: E402
from mocap.synth.wand import centroid_frames  # noqa: E402
from mocap.tracker import Tracker  # noqa: E402


def _take(args: argparse.Namespace):
    if args.motion == "body":
        motion = marching_motion(args.frames, 120.0, args.markers, seed=args.seed)
    else:
        motion = motion_from_c3d(args.motion).window(0, args.frames).centred()
    rig = ring_rig(args.cameras, seed=args.seed)
    plan = plan_take(rig, motion, SynthSettings(seed=args.seed))
    return rig, plan.truth, centroid_frames(plan, seed=args.seed)


def _time(make, rig, fps, frames) -> tuple[float, object]:
    tracker = make(rig, fps)
    t0 = time.perf_counter()
    for k, dets in enumerate(frames):
        tracker.step(k, dets)
    traj = tracker.finish()
    return time.perf_counter() - t0, traj


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--markers", type=int, default=40, help="markers on the built-in body (1..49)")
    ap.add_argument("--cameras", type=int, default=6)
    ap.add_argument("--motion", default="body", help="'body' (marching person, 120 Hz) or a C3D file")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each tracker (best is reported)")
    args = ap.parse_args()

    rig, truth, frames = _take(args)
    print(f"machine: {describe()}")
    n_blobs = np.mean([sum(len(d) for d in dets) for dets in frames])
    print(f"take: {args.motion}, {len(frames)} frames at {truth.fps:g} Hz, {truth.positions.shape[1]} markers, "
          f"{len(rig)} cameras, {n_blobs:.0f} blobs per frame (all cameras); centroid-level simulation")
    rows = []
    for name, make in (("reference", ReferenceTracker), ("tracker", Tracker)):
        best, traj = min((_time(make, rig, truth.fps, frames) for _ in range(args.repeat)), key=lambda r: r[0])
        report = evaluate(traj, truth)
        rows.append((name, len(frames) / best, report))
    base = rows[0][1]
    print(f"{'':10s} {'frames/s':>9s} {'x ref':>6s} {'RMSE mm':>8s} {'/CRLB':>6s} {'complete%':>9s} {'ghost%':>7s} "
          f"{'switches':>8s} {'/10k':>6s} {'IDF1':>6s}")
    for name, fps, r in rows:
        print(f"{name:10s} {fps:9.0f} {fps / base:6.2f} {r.rmse_mm:8.3f} {r.rmse_over_crlb:6.2f} "
              f"{100 * r.completeness:9.2f} {100 * r.ghost_rate:7.3f} {r.switches:8d} {r.switches_per_10k:6.1f} "
              f"{r.idf1:6.4f}")


if __name__ == "__main__":
    main()
