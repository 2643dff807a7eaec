"""Benchmark the trajectory writers/readers and the live MCAP logger.

Synthetic data (no real recording): a take of --minutes minutes, --markers markers at --fps Hz
with 10 % gaps, and for the logger a six-camera ring rig seeing every marker plus 3 clutter
blobs per camera. Prints absolute numbers, the machine, and the logger's per-frame cost as a
ratio to a baseline measured in the same run: ``numpy.save`` of the same per-frame arrays.

    python tools/bench_export.py [--minutes 10] [--markers 40] [--fps 120] [--logger-frames 2000]
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from conftest import ring_rig  # noqa: E402 - the tests' rig and synthetic data
from helpers_export import synthetic_detections, synthetic_trajectories  # noqa: E402
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from mocap.camera import rig_to_toml  # noqa: E402
from mocap.export.formats import read_trajectories, write_trajectories  # noqa: E402
from mocap.export.mcap import McapLogger  # noqa: E402
from mocap.trajectories import Trajectories  # noqa: E402


def bench_formats(traj: Trajectories, folder: Path) -> None:
    print(f"\nfile formats: {traj.n_frames} frames x {traj.n_markers} markers "
          f"({traj.n_frames / traj.fps / 60:.1f} min at {traj.fps:g} Hz)")
    print(f"{'format':<6} {'frames':>7} {'write s':>8} {'write frames/s':>15} {'read s':>7} "
          f"{'read frames/s':>14} {'bytes/marker-frame':>19}")
    for suffix in (".c3d", ".trc", ".csv", ".mcap"):
        path = folder / f"take{suffix}"
        start = time.perf_counter()
        write_trajectories(traj, path)
        write_s = time.perf_counter() - start
        start = time.perf_counter()
        frames = read_trajectories(path).n_frames
        read_s = time.perf_counter() - start
        size = path.stat().st_size / (traj.n_frames * traj.n_markers)
        print(f"{suffix[1:]:<6} {frames:>7} {write_s:>8.2f} {traj.n_frames / write_s:>15.0f} {read_s:>7.2f} "
              f"{frames / read_s:>14.0f} {size:>19.1f}")
        path.unlink()


def bench_logger(n_frames: int, n_markers: int, fps: float, folder: Path) -> None:
    rig = ring_rig(6)
    traj = synthetic_trajectories(n_frames, n_markers, fps, gap_fraction=0.1, seed=1, n_cameras=len(rig))
    rng = np.random.default_rng(2)
    dets = [synthetic_detections(rig, np.nan_to_num(traj.positions[f], nan=1.0), rng) for f in range(n_frames)]
    frames = []
    for f in range(n_frames):
        ids = np.flatnonzero(traj.valid[f])
        frames.append((f, dets[f], ids, traj.positions[f, ids], traj.residuals[f, ids], traj.camera_masks[f, ids]))

    start = time.perf_counter()
    with McapLogger(folder / "log.mcap", rig, fps, rig_to_toml(rig), {"bench": "yes"}) as logger:
        for frame in frames:
            logger.log_frame(*frame)
    logger_s = time.perf_counter() - start
    size = (folder / "log.mcap").stat().st_size

    start = time.perf_counter()
    with open(folder / "baseline.npy", "wb") as out:
        for _, frame_dets, ids, pos, res, masks in frames:
            buf = io.BytesIO()
            for d in frame_dets:
                np.save(buf, np.column_stack([d.xy, d.area, d.roundness, d.cov.reshape(-1, 4), d.merged]))
            np.save(buf, ids)
            np.save(buf, np.column_stack([pos, res, masks]))
            out.write(buf.getvalue())
    baseline_s = time.perf_counter() - start
    blobs = sum(len(d) for frame_dets in dets for d in frame_dets) / n_frames
    print(f"\nMCAP logger: {n_frames} frames, {len(rig)} cameras, {blobs:.0f} blobs and "
          f"{traj.valid.sum() / n_frames:.0f} markers per frame")
    print(f"  log_frame   {1e3 * logger_s / n_frames:.3f} ms/frame ({n_frames / logger_s:.0f} frames/s), "
          f"{size / n_frames / 1024:.1f} KiB/frame on disk (zstd)")
    print(f"  baseline    {1e3 * baseline_s / n_frames:.3f} ms/frame (numpy.save of the same arrays, uncompressed)")
    print(f"  ratio       {logger_s / baseline_s:.2f} x the baseline")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=10.0)
    parser.add_argument("--markers", type=int, default=40)
    parser.add_argument("--fps", type=float, default=120.0)
    parser.add_argument("--logger-frames", type=int, default=2000)
    args = parser.parse_args()
    print(f"machine: {describe()}")
    n_frames = round(args.minutes * 60 * args.fps)
    with tempfile.TemporaryDirectory() as tmp:
        bench_logger(args.logger_frames, args.markers, args.fps, Path(tmp))
        bench_formats(synthetic_trajectories(n_frames, args.markers, args.fps, seed=0), Path(tmp))


if __name__ == "__main__":
    main()
