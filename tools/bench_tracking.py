"""Speed of the tracking core from 2D centroids, against the plain reference baseline, in one run.

The take is simulated at centroid level (no images): ``mocap.synth`` plans the take (projection,
capsule occlusion, dropouts, ghosts, Cramér–Rao centroid noise) and ``mocap.synth.wand.centroid_frames``
turns it into per-camera detections, which are prepared before any timing. Both trackers then run on
the same frames on one core (BLAS threads pinned to 1); the figures are frames per second of
``Tracker.step`` (undistortion, prediction, association, fusion, identities, recording) plus
``finish``, and the accuracy / identity scores of both outputs from ``mocap.evaluate``.

The tracker runs twice when numba is installed: on the numpy path (``mocap.kernels.HAVE_NUMBA`` off, as with
``MOCAP_NO_NUMBA=1``) and with the compiled kernels (after one untimed warm-up run that compiles them or loads
them from numba's cache, timed on its own), and the largest difference of their outputs is printed.

``--stages`` adds one more (untimed-for-the-table) tracker run with a timer around each stage method of
``Tracker`` and around the main functions it calls (EKF, gating, assignment, epipolar pruning, fusion), on
the default path (compiled kernels when numba is installed), and prints microseconds per frame and per call
(inclusive: a stage called from another counts in both; each timer adds ~1 us per call), to see where the
time goes.

Usage:
    python tools/bench_tracking.py [--frames 1200] [--markers 40] [--cameras 6] [--motion body|FILE.c3d]
                                   [--stages]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from mocap import kernels  # noqa: E402
from mocap.evaluate import evaluate  # noqa: E402
from mocap.reference import ReferenceTracker  # noqa: E402
from mocap.synth import SynthSettings, marching_motion, motion_from_file, plan_take, ring_rig  # noqa: E402
from mocap.synth.wand import centroid_frames  # noqa: E402
from mocap.tracker import Tracker  # noqa: E402


def _take(args: argparse.Namespace):
    if args.motion == "body":
        motion = marching_motion(args.frames, 120.0, args.markers, seed=args.seed)
    else:
        motion = motion_from_file(args.motion).window(0, args.frames).centred()
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


# Tracker methods timed by --stages (names missing from the current Tracker are skipped).
_STAGES = ("_prepare", "_predict", "_associate", "_search_regions", "_crowded", "_measure", "_neighbour_shift",
           "_update", "_refute_by_attached", "_explained_elsewhere", "_new_markers", "_known_clutter", "_lifecycle",
           "_record", "finish")
# Module functions timed by --stages, patched where they are looked up while the tracker runs.
_FUNCTIONS = {
    "mocap.tracker": ("predict", "update_position", "gate", "assign", "epipolar_consistency", "robust_triangulate",
                      "repick", "new_points", "reidentify"),
    "mocap.fusion": ("_gauss_newton", "_consensus", "match_pairs", "triangulate_matches"),
}


def _stage_times(rig, fps, frames) -> dict[str, tuple[float, int]]:
    """Per stage (seconds, calls) over one run: each stage method of a Tracker and each function of
    ``_FUNCTIONS`` wrapped in a timer (the functions are restored afterwards)."""
    tracker = Tracker(rig, fps)
    totals: dict[str, list] = {}

    def timed(name, method):
        def wrapper(*a, **kw):
            t0 = time.perf_counter()
            try:
                return method(*a, **kw)
            finally:
                entry = totals.setdefault(name, [0.0, 0])
                entry[0] += time.perf_counter() - t0
                entry[1] += 1
        return wrapper

    for name in _STAGES:
        if hasattr(tracker, name):
            setattr(tracker, name, timed(name, getattr(tracker, name)))
    patched = []
    for module_name, names in _FUNCTIONS.items():
        module = sys.modules[module_name]
        for name in names:
            if hasattr(module, name):
                patched.append((module, name, getattr(module, name)))
                setattr(module, name, timed(f"{module_name.split('.')[-1]}.{name}", getattr(module, name)))
    try:
        t0 = time.perf_counter()
        for k, dets in enumerate(frames):
            tracker.step(k, dets)
        tracker.finish()
        totals["(all)"] = [time.perf_counter() - t0, len(frames)]
    finally:
        for module, name, function in patched:
            setattr(module, name, function)
    return {name: (sec, calls) for name, (sec, calls) in totals.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=1200)
    ap.add_argument("--markers", type=int, default=40, help="markers on the built-in body (1..49)")
    ap.add_argument("--cameras", type=int, default=6)
    ap.add_argument("--motion", default="body", help="'body' (marching person, 120 Hz) or a C3D file")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--repeat", type=int, default=3, help="timed runs of each tracker (best is reported)")
    ap.add_argument("--stages", action="store_true", help="also print the tracker's time per stage")
    args = ap.parse_args()

    rig, truth, frames = _take(args)
    compiled = kernels.HAVE_NUMBA
    print(f"machine: {describe()}")
    print(f"tracker paths: numpy{' and compiled kernels' if compiled else ''} ({kernels.REASON})")
    n_blobs = np.mean([sum(len(d) for d in dets) for dets in frames])
    print(f"take: {args.motion}, {len(frames)} frames at {truth.fps:g} Hz, {truth.positions.shape[1]} markers, "
          f"{len(rig)} cameras, {n_blobs:.0f} blobs per frame (all cameras); centroid-level simulation")
    runs = [("reference", ReferenceTracker, False), ("tracker", Tracker, False)]
    if compiled:
        t0 = time.perf_counter()
        _time(Tracker, rig, truth.fps, frames[:30])  # untimed warm-up: compile, or load from numba's cache
        print(f"compiled kernels ready in {time.perf_counter() - t0:.2f} s (first use in this process)")
        runs.append(("tracker+nb", Tracker, True))
    rows, outputs = [], []
    for name, make, on in runs:
        kernels.HAVE_NUMBA = on
        best, traj = min((_time(make, rig, truth.fps, frames) for _ in range(args.repeat)), key=lambda r: r[0])
        report = evaluate(traj, truth)
        rows.append((name, len(frames) / best, report))
        outputs.append(traj)
    kernels.HAVE_NUMBA = compiled
    base = rows[0][1]
    print(f"{'':10s} {'frames/s':>9s} {'x ref':>6s} {'RMSE mm':>8s} {'/CRLB':>6s} {'complete%':>9s} {'ghost%':>7s} "
          f"{'switches':>8s} {'/10k':>6s} {'IDF1':>6s}")
    for name, fps, r in rows:
        print(f"{name:10s} {fps:9.0f} {fps / base:6.2f} {r.rmse_mm:8.3f} {r.rmse_over_crlb:6.2f} "
              f"{100 * r.completeness:9.2f} {100 * r.ghost_rate:7.3f} {r.switches:8d} {r.switches_per_10k:6.1f} "
              f"{r.idf1:6.4f}")
    if compiled:
        a, b = outputs[1], outputs[2]
        same = a.labels == b.labels and np.array_equal(np.isnan(a.positions), np.isnan(b.positions))
        diff = np.nanmax(np.abs(a.positions - b.positions), initial=0.0) if same else np.nan
        print(f"tracker+nb (compiled kernels) vs tracker (numpy): {rows[2][1] / rows[1][1]:.2f}x the frames/s; "
              f"same identities and samples: {same and np.array_equal(a.camera_masks, b.camera_masks)}, "
              f"largest position difference {diff:.1e} m")
    if args.stages:
        print(f"stages on the {'compiled' if compiled else 'numpy'} path")
        stages = _stage_times(rig, truth.fps, frames)
        print(f"tracker stages and functions (inclusive, one run with timers; {len(frames)} frames):")
        print(f"{'stage':30s} {'us/frame':>9s} {'calls/frame':>11s} {'us/call':>8s} {'share':>6s}")
        total = stages["(all)"][0]
        for name, (sec, calls) in sorted(stages.items(), key=lambda kv: -kv[1][0]):
            print(f"{name:30s} {1e6 * sec / len(frames):9.1f} {calls / len(frames):11.2f} {1e6 * sec / calls:8.1f} "
                  f"{100 * sec / total:5.1f}%")


if __name__ == "__main__":
    main()
