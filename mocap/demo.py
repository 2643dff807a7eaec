"""``mocap demo``: the whole product in one command, on a take it renders itself.

Renders the built-in marching person through a six-camera ring (default realism: noise,
ghost reflections, occlusion, dropouts, merged blobs), reconstructs it from the images,
writes C3D / TRC / CSV / MCAP and a PNG plot, and scores the result against the ground truth.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from mocap.atomic import atomic_write_bytes
from mocap.errors import MocapError
from mocap.evaluate import evaluate
from mocap.pipeline import ReconstructOptions, reconstruct, write_outputs
from mocap.synth import SynthSettings, marching_motion, render_take, ring_rig

__all__ = ["configure_parser", "run", "run_demo"]


def run_demo(out: Path, frames: int = 360, seed: int = 1, progress: bool = True) -> dict[str, Path]:
    """Render, reconstruct, write and score the demo take; returns the files written by name."""
    out.mkdir(parents=True, exist_ok=True)
    files = {
        "take": out / "take", "truth": out / "take.truth.npz", "c3d": out / "markers.c3d",
        "trc": out / "markers.trc", "csv": out / "markers.csv", "mcap": out / "markers.mcap",
        "plot": out / "markers.png", "report": out / "evaluation.json",
    }
    t0 = time.perf_counter()
    rig = ring_rig(6, seed=seed)
    motion = marching_motion(frames, fps=120.0, seed=seed)
    truth = render_take(files["take"], rig, motion, SynthSettings(seed=seed), truth_path=files["truth"],
                        progress=progress, force=True)
    t1 = time.perf_counter()
    print(f"rendered {truth.n_frames} frames x {len(rig)} cameras of {len(truth.labels)} markers "
          f"in {t1 - t0:.1f} s -> {files['take']}")
    traj = reconstruct(files["take"], ReconstructOptions(progress=progress), mcap=files["mcap"])
    t2 = time.perf_counter()
    print(f"reconstructed {traj.n_markers} marker identities in {t2 - t1:.1f} s "
          f"({traj.n_frames / max(t2 - t1, 1e-9):.0f} frames/s including detection)")
    write_outputs(traj, c3d=str(files["c3d"]), trc=str(files["trc"]), csv=str(files["csv"]))
    from mocap.plot import plot_trajectories

    plot_trajectories(traj, files["plot"])
    report = evaluate(traj, truth)
    atomic_write_bytes(files["report"], json.dumps(report.to_dict(), indent=2).encode())
    print(report.table())
    print("files: " + ", ".join(str(p) for k, p in files.items() if k not in ("take", "truth")))
    return files


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", type=Path, default=Path("demo_out"), help="output folder (default demo_out)")
    parser.add_argument("--frames", type=int, default=360, help="frames to render at 120 Hz (default 360)")
    parser.add_argument("--seed", type=int, default=1, help="random seed of the scene (default 1)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    if args.frames < 10:
        raise MocapError("--frames must be at least 10")
    run_demo(args.out, args.frames, args.seed, progress=not args.no_progress)
    return 0
