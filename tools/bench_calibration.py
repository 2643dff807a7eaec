"""Benchmark: a full six-camera wand calibration (centroid level), on one core.

Prints the time of each stage and of the whole calibration, the ratio to a baseline measured in
the same run (triangulating every wand frame once with the true rig: the least work that touches
every observation), the accuracy reached, and the machine. Run: ``python tools/bench_calibration.py``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from calibration.align import DEFAULT_LFRAME  # noqa: E402
from calibration.compare import compare_rigs  # noqa: E402
from calibration.extrinsics import WandOptions, calibrate_wand  # noqa: E402
from calibration.wand import Wand, wand_observations  # noqa: E402
from mocap.camera import Rig  # noqa: E402
from mocap.geometry import triangulate_weighted  # noqa: E402
from mocap.synth.wand import DEFAULT_WAND_M, simulate_wand_take  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--frames", type=int, default=1200, help="frames of the wave (120 Hz)")
    parser.add_argument("--max-frames", type=int, default=600, help="frames in the bundle adjustment")
    parser.add_argument("--extra-noise", type=float, default=0.0, help="centroid noise beyond the CRLB, px")
    args = parser.parse_args()
    print(f"machine: {describe()} (BLAS threads limited to 1)")

    take = simulate_wand_take(n_frames=args.frames, extra_noise_px=args.extra_noise)
    wand = Wand(DEFAULT_WAND_M)
    unposed = Rig([c.with_pose(np.zeros(3), np.zeros(3)) for c in take.rig])

    t0 = time.perf_counter()
    obs = wand_observations(take.wand_frames, wand)
    t_find = time.perf_counter() - t0

    F, C, K = obs.shape[:3]
    ideal = np.stack([take.rig[c].undistort(obs[:, c].reshape(-1, 2)) for c in range(C)])
    t0 = time.perf_counter()
    triangulate_weighted(take.rig.projection_matrices(), ideal)
    t_base = time.perf_counter() - t0

    t0 = time.perf_counter()
    cal = calibrate_wand(unposed, take.wand_frames, wand, WandOptions(max_frames=args.max_frames),
                         take.lframe_frames, DEFAULT_LFRAME)
    t_all = time.perf_counter() - t0

    diff = compare_rigs(cal.rig, take.rig)
    rep = cal.report
    print(f"take: {C} cameras, {F} frames, wand {DEFAULT_WAND_M} m, centroid noise RMS "
          f"{rep['reprojection']['centroid_sigma_rms_px']:.4f} px (Cramer-Rao of the rendered blobs"
          f"{f' + {args.extra_noise} px' if args.extra_noise else ''})")
    print(f"baseline (triangulate all {F} frames once): {t_base * 1000:.1f} ms")
    print(f"wand finding: {t_find:.2f} s")
    print(f"full calibration ({rep['frames']['fitted']} frames fitted, {rep['bundle']['nfev']} solver evaluations): "
          f"{t_all:.2f} s = {t_all / t_base:.0f} x baseline")
    print(f"accuracy: camera positions max {diff['max_position_mm']:.3f} mm, orientations max "
          f"{diff['max_angle_deg']:.4f} deg (L-frame world frame); held-out wand length RMS "
          f"{rep['holdout_wand']['end_to_end']['rms_mm']:.3f} mm; "
          f"reprojection RMS {rep['reprojection']['rms_px']:.4f} px")


if __name__ == "__main__":
    main()
