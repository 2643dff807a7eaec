"""Benchmark: synthetic take rendering speed at 1024x768, against baselines measured in the same run.

Prints camera-frames per second for: generating the noise image alone (baseline), rendering
(noise + markers + ghosts), FFV1-encoding black frames (baseline), encoding finished frames,
the whole take to MKV and to PNG, and the truth computation; then the projected time of a
600-frame six-camera take. Usage: ``python tools/bench_render.py [--frames 120]``.
"""

from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from mocap.synth import SynthSettings, marching_motion, plan_take, render_frame, ring_rig
from mocap.synth.writer import write_take


def rate(n: int, fn: Callable[[], None]) -> tuple[float, float]:
    """(camera-frames per second, seconds) of ``fn`` doing ``n`` camera-frames."""
    start = time.perf_counter()
    fn()
    elapsed = time.perf_counter() - start
    return n / elapsed, elapsed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=120, help="frames per measurement (default 120)")
    args = parser.parse_args()
    F = args.frames
    rig = ring_rig(seed=0)
    C = len(rig)
    w, h = rig[0].size
    settings = SynthSettings(seed=0)
    motion = marching_motion(F, seed=0)
    n = F * C
    print(f"machine: {describe()}")
    print(f"scene: built-in body, {len(motion.labels)} markers, {C} cameras at {w}x{h}, {F} frames "
          f"({n} camera-frames), default settings (noise {settings.noise}, {settings.ghosts} ghosts/camera)")

    truth_rate, truth_s = rate(F, lambda: plan_take(rig, motion, settings))
    plan = plan_take(rig, motion, settings)
    rng = np.random.default_rng(0)
    noise_rate, _ = rate(n, lambda: [plan.sensor.background_frame((h, w), rng) for _ in range(n)])

    def render_all() -> None:
        streams = plan.noise_streams()
        for f in range(F):
            for c in range(C):
                render_frame(plan, f, c, streams[c])

    render_rate, _ = rate(n, render_all)
    tmp = Path(tempfile.mkdtemp(prefix="bench_render."))
    try:
        black = np.zeros((h, w), dtype=np.uint8)
        noisy = plan.sensor.background_frame((h, w), rng)

        def encode(image: np.ndarray) -> Callable[[], None]:
            def run() -> None:
                writer = cv2.VideoWriter(str(tmp / "enc.mkv"), cv2.VideoWriter_fourcc(*"FFV1"), 120.0, (w, h), False)
                for _ in range(n):
                    writer.write(image)
                writer.release()
            return run

        black_rate, _ = rate(n, encode(black))
        noisy_rate, _ = rate(n, encode(noisy))

        def take(fmt: str) -> Callable[[], None]:
            def run() -> None:
                folder = tmp / fmt
                folder.mkdir()
                write_take(folder, plan, fmt, progress=False)
            return run

        mkv_rate, mkv_s = rate(n, take("mkv"))
        png_rate, png_s = rate(n, take("png"))
        mkv_mb = sum(p.stat().st_size for p in (tmp / "mkv").glob("*.mkv")) / 1e6
    finally:
        shutil.rmtree(tmp, ignore_errors=True)

    print(f"{'measurement':52s} {'cam-frames/s':>12s}  vs baseline")
    print(f"{'baseline: noise image alone (1024x768)':52s} {noise_rate:12.1f}")
    print(f"{'render: noise + markers + ghosts':52s} {render_rate:12.1f}  {render_rate / noise_rate:.2f}x noise")
    print(f"{'baseline: FFV1-encode black frames':52s} {black_rate:12.1f}")
    print(f"{'FFV1-encode one noisy frame repeatedly':52s} {noisy_rate:12.1f}  {noisy_rate / black_rate:.2f}x black")
    print(f"{'whole take, FFV1 .mkv (render + encode)':52s} {mkv_rate:12.1f}  {mkv_rate / black_rate:.2f}x black "
          f"encode; {mkv_s:.1f} s, {mkv_mb / F:.2f} MB per frame of the rig")
    print(f"{'whole take, PNG frames':52s} {png_rate:12.1f}  {png_s:.1f} s")
    print(f"{'truth without pixels (plan_take), frames/s':52s} {truth_rate:12.1f}  {truth_s:.2f} s")
    projected = 600 / truth_rate + 600 * C / mkv_rate
    print(f"projected 600 frames x {C} cameras to MKV: {projected:.0f} s")


if __name__ == "__main__":
    main()
