"""End-to-end speed and memory of `mocap reconstruct` (issue 3 (c), (d); issue 4's MCAP overhead).

(c) speed: a take is rendered first (not timed); then, in the same run, in interleaved rounds:
    * baseline: merely decoding every camera's lossless video (the take reader, nothing else: the same
      reader, with the same decoding threads, that ``reconstruct`` uses);
    * end to end: ``mocap.reconstruct`` on the same videos (decode + detect + track);
    * end to end with live MCAP logging.
    Printed as frames/s and ms/frame (best round), the speed ratio to the baseline (median over rounds of
    the ratio within a round, so that both runs of a ratio saw about the same load; target: end to end
    >= 0.8 of decode speed; MCAP logging slows reconstruct by < 10 %), and the process CPU time per frame
    (all threads, best round) with its ratio: on a machine shared with other jobs the wall-clock figures
    follow the other jobs' load, the CPU figures much less.
(d) memory: peak resident memory of the tracker fed a 1-minute and a 10-minute 120 Hz stream of 2D
    centroids (six cameras, the marching body's 40 markers, projected with noise; the motion is
    played forwards then backwards so any duration is continuous). Each run is a fresh process.
    The output arrays must grow with the take; everything else must not.

Usage: python tools/bench_pipeline.py [--frames 240] [--rounds 3] [--minutes 1 10] [--skip-speed] [--skip-memory]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from machine_info import describe, peak_rss_kib  # noqa: E402  (tools/ is on sys.path when run as a script)


def bench_speed(frames: int, rounds: int) -> None:
    from mocap.pipeline import ReconstructOptions, reconstruct
    from mocap.synth import SynthSettings, marching_motion, render_take, ring_rig
    from mocap.take import DECODE_THREADS, open_take

    with tempfile.TemporaryDirectory() as tmp:
        take = Path(tmp) / "take"
        render_take(take, ring_rig(6, seed=1), marching_motion(frames, fps=120.0, seed=1), SynthSettings(seed=1),
                    truth_path=Path(tmp) / "truth.npz", progress=False)
        opened = open_take(take)
        w, h = opened.rig[0].size
        print(f"(c) {frames} frames x {len(opened.rig)} cameras, {w}x{h} FFV1, 40 markers, default realism; "
              f"take reader decoding in {DECODE_THREADS} threads; {rounds} interleaved rounds")

        def decode_only() -> None:
            for _ in open_take(take).images():
                pass

        runs = {"decode only (baseline)": decode_only,
                "reconstruct": lambda: reconstruct(take, ReconstructOptions(progress=False)),
                "reconstruct + MCAP log": lambda: reconstruct(take, ReconstructOptions(progress=False),
                                                              mcap=Path(tmp) / "run.mcap")}
        wall = {name: np.zeros(rounds) for name in runs}
        cpu = {name: np.zeros(rounds) for name in runs}
        for r in range(rounds):
            for name, run in runs.items():
                t0, c0 = time.perf_counter(), time.process_time()
                run()
                wall[name][r], cpu[name][r] = time.perf_counter() - t0, time.process_time() - c0
        base, base_cpu = wall["decode only (baseline)"], cpu["decode only (baseline)"].min()
        print(f"    {'':26} {'frames/s':>9} {'ms/frame':>9} {'speed vs decode':>16} {'CPU ms/frame':>13} "
              f"{'CPU ratio':>10}")
        for name in runs:
            dt = wall[name].min()
            print(f"    {name:26} {frames / dt:9.1f} {1000 * dt / frames:9.2f} {np.median(base / wall[name]):16.2f} "
                  f"{1000 * cpu[name].min() / frames:13.2f} {base_cpu / cpu[name].min():10.2f}")
        print("    speed vs decode per round: " + ", ".join(f"{v:.2f}" for v in base / wall["reconstruct"]))
        overhead = np.median(wall["reconstruct + MCAP log"] / wall["reconstruct"]) - 1
        print(f"    MCAP logging overhead on reconstruct: {100 * overhead:+.1f} %")


def _memory_child(minutes: float) -> dict[str, float]:
    """Run in a fresh process: feed the tracker ``minutes`` of centroids, return peak RSS and sizes."""
    from mocap.detections import Detections
    from mocap.synth import SynthSettings, marching_motion, ring_rig, simulate
    from mocap.tracker import Tracker

    fps, period = 120.0, 1200  # a 10 s motion, played forwards and backwards
    rig = ring_rig(6, seed=1)
    truth = simulate(rig, marching_motion(period, fps=fps, seed=1), SynthSettings(seed=1))
    uv = truth.uv.astype(np.float64)  # (period, C, M, 2)
    visible = truth.visible
    rng = np.random.default_rng(0)
    tracker = Tracker(rig, fps)
    n_frames = int(round(minutes * 60 * fps))
    base_rss = peak_rss_kib()
    t0 = time.perf_counter()
    for k in range(n_frames):
        cycle = k % (2 * period)
        f = cycle if cycle < period else 2 * period - 1 - cycle
        dets = []
        for c in range(len(rig)):
            xy = uv[f, c][visible[f, c]]
            dets.append(Detections(xy + rng.normal(0.0, 0.02, xy.shape)))
        tracker.step(k, dets)
    traj = tracker.finish()
    elapsed = time.perf_counter() - t0
    peak = peak_rss_kib()
    output = traj.positions.nbytes + traj.residuals.nbytes + traj.camera_masks.nbytes
    return {"minutes": minutes, "frames": n_frames, "peak_rss_mib": peak / 1024, "start_rss_mib": base_rss / 1024,
            "output_mib": output / 2**20, "markers": traj.n_markers, "frames_per_s": n_frames / elapsed}


def bench_memory(durations: list[float]) -> None:
    print("(d) peak memory of the tracker on a 120 Hz, 6-camera, 40-marker centroid stream (fresh process each)")
    print(f"    {'minutes':>7} {'frames':>7} {'ids':>5} {'peak RSS MiB':>13} {'before MiB':>11} {'output MiB':>11} "
          f"{'peak - output':>14} {'frames/s':>9}")
    for minutes in durations:
        out = subprocess.run([sys.executable, __file__, "--memory-child", str(minutes)], capture_output=True,
                             text=True, check=True)
        r = json.loads(out.stdout.strip().splitlines()[-1])
        print(f"    {r['minutes']:7g} {r['frames']:7d} {r['markers']:5d} {r['peak_rss_mib']:13.1f} "
              f"{r['start_rss_mib']:11.1f} {r['output_mib']:11.1f} {r['peak_rss_mib'] - r['output_mib']:14.1f} "
              f"{r['frames_per_s']:9.0f}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=240, help="frames of the rendered take for (c)")
    ap.add_argument("--rounds", type=int, default=3, help="interleaved timing rounds for (c)")
    ap.add_argument("--minutes", type=float, nargs="+", default=[1.0, 10.0], help="stream lengths for (d)")
    ap.add_argument("--skip-speed", action="store_true")
    ap.add_argument("--skip-memory", action="store_true")
    ap.add_argument("--memory-child", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.memory_child is not None:
        print(json.dumps(_memory_child(args.memory_child)))
        return
    print(f"machine: {describe()}")
    if not args.skip_speed:
        bench_speed(args.frames, args.rounds)
    if not args.skip_memory:
        bench_memory(args.minutes)


if __name__ == "__main__":
    main()
