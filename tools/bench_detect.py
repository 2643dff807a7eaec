"""Benchmark: blob detection speed and centroid accuracy against the OpenCV baseline.

Renders realistic 1024x768 frames with the project's sensor model (:class:`mocap.synth.render.Sensor`:
blurred anti-aliased discs, background 12, noise 2, saturation at 255): 14 mm markers 2-6 m from a
f = 1000 px camera (2.3-7 px across, brightness falling as 1/d^2), a few larger ghost reflections.
Then, on the same frames, in interleaved rounds:

- baseline: ``cv2.threshold`` + ``cv2.connectedComponentsWithStats`` (its centroids), at the same
  threshold that :func:`mocap.detect.detect` chooses;
- the same with Grana's labelling algorithm chosen explicitly (OpenCV's default choice is ~3x slower
  on one thread), for reference;
- ``detect(refine="centroid")`` and ``detect()`` (the default, ``refine="fit"``).

OpenCV runs on ONE thread (``--threads`` to change): detection is a per-camera job that a pipeline runs
in parallel over cameras, and the baseline's second thread would otherwise make the ratio depend on
whether the other core happens to be idle.

Prints ms/frame, frames/s, speed ratios (baseline time / method time, median over rounds) and the
centroid accuracy against the true centres (isolated markers, matched within 1.5 px): RMSE per axis,
and the RMS of each error divided by that marker's own Cramér–Rao bound (1.00 = at the bound; the
RMSE's own reference is the RMS bound, not the mean), plus the machine.
Run: ``python tools/bench_detect.py [--frames N] [--rounds N]``.
"""

from __future__ import annotations

import argparse
import time

import cv2
import numpy as np
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)
from scipy.spatial import cKDTree

from mocap.detect import K_SIGMA, MIN_CONTRAST, background_level, detect
from mocap.synth.render import Sensor

SIZE = (768, 1024)
FOCAL_PX = 1000.0
MARKER_M = 0.014


def render(n_frames: int, n_markers: int, seed: int) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Frames, true centres (isolated markers only) and their Cramér–Rao std, per frame."""
    rng = np.random.default_rng(seed)
    sensor = Sensor()
    frames, truths, bounds = [], [], []
    for _ in range(n_frames):
        image = sensor.background_frame(SIZE, rng)
        depth = rng.uniform(2.0, 6.0, n_markers)
        uv = np.c_[rng.uniform(8, SIZE[1] - 8, n_markers), rng.uniform(8, SIZE[0] - 8, n_markers)]
        radius = FOCAL_PX * MARKER_M / 2 / depth
        amp = 300.0 * (4.0 / depth) ** 2
        ghosts = np.c_[rng.uniform(20, SIZE[1] - 20, 3), rng.uniform(20, SIZE[0] - 20, 3)]
        sensor.draw(image, np.r_[uv, ghosts], np.r_[radius, rng.uniform(5, 9, 3)], np.r_[amp, np.full(3, 200.0)],
                    rng)
        everything = np.r_[uv, ghosts]
        dist, _ = cKDTree(everything).query(uv, 2)
        isolated = dist[:, 1] > 20
        frames.append(image)
        truths.append(uv[isolated])
        bounds.append(sensor.centroid_sigma(uv[isolated], radius[isolated], amp[isolated]))
    return frames, truths, bounds


def baseline(image: np.ndarray, threshold: int) -> np.ndarray:
    """(N, 2) centroids of ``cv2.threshold`` + ``cv2.connectedComponentsWithStats`` (area >= 2)."""
    _, binary = cv2.threshold(image, threshold, 255, cv2.THRESH_BINARY)
    _, _, stats, centroids = cv2.connectedComponentsWithStats(binary, connectivity=8)
    return centroids[1:][stats[1:, cv2.CC_STAT_AREA] >= 2]


def grana(image: np.ndarray, threshold: int) -> np.ndarray:
    """The baseline with Grana's labelling algorithm chosen explicitly."""
    _, binary = cv2.threshold(image, threshold, 255, cv2.THRESH_BINARY)
    _, _, stats, centroids = cv2.connectedComponentsWithStatsWithAlgorithm(binary, 8, cv2.CV_32S, cv2.CCL_GRANA)
    return centroids[1:][stats[1:, cv2.CC_STAT_AREA] >= 2]


def accuracy(found: list[np.ndarray], truths: list[np.ndarray], bounds: list[np.ndarray]
             ) -> tuple[float, float, float]:
    """Centroid RMSE per axis (px) over matched true centres, the RMS of the errors in units of each
    marker's Cramér–Rao bound, and the fraction of true centres found."""
    err, scaled, n_true, n_hit = [], [], 0, 0
    for xy, uv, bound in zip(found, truths, bounds, strict=True):
        n_true += len(uv)
        if len(xy) == 0:
            continue
        dist, idx = cKDTree(xy).query(uv)
        hit = dist < 1.5
        n_hit += int(hit.sum())
        err.append(xy[idx[hit]] - uv[hit])
        scaled.append(err[-1] / bound[hit, None])
    e, s = np.concatenate(err), np.concatenate(scaled)
    return float(np.sqrt((e**2).mean())), float(np.sqrt((s**2).mean())), n_hit / max(n_true, 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", type=int, default=20, help="distinct frames (default 20)")
    parser.add_argument("--markers", type=int, default=40, help="markers per frame (default 40)")
    parser.add_argument("--rounds", type=int, default=5, help="timing rounds over all frames (default 5)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="OpenCV threads (default 1, see above)")
    args = parser.parse_args()
    cv2.setNumThreads(args.threads)

    frames, truths, bounds = render(args.frames, args.markers, args.seed)
    thresholds = []
    for image in frames:
        level, sigma = background_level(image)
        thresholds.append(int(level + max(K_SIGMA * sigma, MIN_CONTRAST)))
    methods = {
        "baseline threshold+CCWithStats": lambda i: baseline(frames[i], thresholds[i]),
        "  same, Grana's algorithm": lambda i: grana(frames[i], thresholds[i]),
        "detect(refine='centroid')": lambda i: detect(frames[i], refine="centroid").xy,
        "detect() (refine='fit', default)": lambda i: detect(frames[i]).xy,
    }
    results = {name: [method(i) for i in range(len(frames))] for name, method in methods.items()}
    times: dict[str, list[float]] = {name: [] for name in methods}
    for _ in range(args.rounds):  # interleaved, so load changes hit every method alike
        for name, method in methods.items():
            t0 = time.perf_counter()
            for i in range(len(frames)):
                method(i)
            times[name].append((time.perf_counter() - t0) / len(frames))

    print(f"machine: {describe()}")
    crlb = np.concatenate(bounds)
    print(f"{len(frames)} frames {SIZE[1]}x{SIZE[0]}, {args.markers} markers + 3 ghosts each, {args.rounds} rounds; "
          f"Cramér–Rao bound of the isolated markers per axis: mean {crlb.mean():.4f} px, "
          f"RMS {np.sqrt((crlb**2).mean()):.4f} px")
    base = np.array(times["baseline threshold+CCWithStats"])
    print(f"{'method':34s} {'ms/frame':>9s} {'frames/s':>9s} {'speed-up':>9s} {'RMSE px':>9s} {'RMS/CRLB':>9s} "
          f"{'found':>7s}")
    for name in methods:
        t = np.array(times[name])
        err, scaled, found = accuracy(results[name], truths, bounds)
        print(f"{name:34s} {1e3 * np.median(t):9.3f} {1 / np.median(t):9.1f} {np.median(base / t):9.2f} "
              f"{err:9.4f} {scaled:9.2f} {100 * found:6.1f}%")


if __name__ == "__main__":
    main()
