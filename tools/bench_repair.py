"""Time and memory of the offline identity repair as a take grows (the part of `mocap reconstruct` after tracking).

A long take has many more identities than markers: every marker hidden from every camera for a while may come
back as a new one, and the repair's passes must follow the identities seen at once, not all those of the take,
or its time grows with the square of the take's length. Each duration runs in a fresh process:

* the marching body's 40 markers (six cameras, 120 Hz; the 10 s motion played forwards then backwards), each
  hidden from every camera in gaps of ``--gap-s`` mean length over ``--hidden`` of its frames (a two-state chain
  per marker, seeded), projected with 0.02 px noise and fed to the tracker (timed: the baseline), which forgets a
  lost identity after ``--keep-lost-s``: every longer gap ends in a new identity (the walking body is easy to
  re-identify; a real take's fast, crowded markers are not), so identities pile up for the repair to join;
* :func:`mocap.relabel.repair_identities` on its output (timed), then the process's peak resident memory.

Printed per duration: identities before and after the repair, tracking and repair time, the repair's time per
minute of take and as a fraction of the tracking's (the baseline, same process), and peak memory minus the output
arrays; then the repair's time per minute of the longest take over that of the shortest (1.0: linear).

Usage: python tools/bench_repair.py [--minutes 1 4] [--hidden 0.05] [--gap-s 0.3] [--keep-lost-s 0.1]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import numpy as np
from machine_info import describe, peak_rss_kib  # noqa: E402  (tools/ is on sys.path when run as a script)


def _child(minutes: float, hidden: float, gap_s: float, keep_lost_s: float) -> dict[str, float]:
    """Run in a fresh process: track ``minutes`` of the hidden-gap stream, repair it; figures as a dict."""
    from mocap.detections import Detections
    from mocap.relabel import RelabelConfig, repair_identities
    from mocap.synth import SynthSettings, marching_motion, ring_rig, simulate
    from mocap.tracker import Tracker, TrackerConfig

    fps, period = 120.0, 1200
    rig = ring_rig(6, seed=1)
    truth = simulate(rig, marching_motion(period, fps=fps, seed=1), SynthSettings(seed=1))
    uv, visible = truth.uv.astype(np.float64), truth.visible  # (period, C, M, 2), (period, C, M)
    rng = np.random.default_rng(0)
    n_markers = uv.shape[2]
    leave = 1.0 / max(1.0, gap_s * fps)  # per frame: a hidden marker comes back ...
    enter = leave * hidden / (1.0 - hidden)  # ... and a seen one is hidden (the chain spends ``hidden`` hidden)
    gone = np.zeros(n_markers, dtype=bool)
    config = TrackerConfig(keep_lost_s=keep_lost_s)
    tracker = Tracker(rig, fps, config)
    n_frames = int(round(minutes * 60 * fps))
    t0 = time.perf_counter()
    for k in range(n_frames):
        cycle = k % (2 * period)
        f = cycle if cycle < period else 2 * period - 1 - cycle
        flip = rng.random(n_markers) < np.where(gone, leave, enter)
        gone ^= flip
        dets = []
        for c in range(len(rig)):
            xy = uv[f, c][visible[f, c] & ~gone]
            dets.append(Detections(xy + rng.normal(0.0, 0.02, xy.shape)))
        tracker.step(k, dets)
    traj = tracker.finish()
    tracking_s = time.perf_counter() - t0
    identities = traj.n_markers
    t0 = time.perf_counter()
    repair_identities(traj, RelabelConfig(confirm_frames=config.confirm_frames),
                      unconfirmed=tracker.unconfirmed())
    repair_s = time.perf_counter() - t0
    output = traj.positions.nbytes + traj.residuals.nbytes + traj.camera_masks.nbytes
    return {"minutes": minutes, "frames": n_frames, "tracked_ids": identities, "repaired_ids": traj.n_markers,
            "tracking_s": tracking_s, "repair_s": repair_s, "peak_rss_mib": peak_rss_kib() / 1024,
            "output_mib": output / 2**20}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--minutes", type=float, nargs="+", default=[1.0, 4.0],
                    help="take lengths, minutes (the tracker's output holds frames x identities: 4 min of this "
                         "stream, 1,231 identities, is 1.3 GB before the repair joins them)")
    ap.add_argument("--hidden", type=float, default=0.05, help="fraction of each marker's frames hidden")
    ap.add_argument("--gap-s", type=float, default=0.3, help="mean length of a hidden gap, s")
    ap.add_argument("--keep-lost-s", type=float, default=0.1,
                    help="the tracker forgets a lost identity after this long, s (short: every longer gap ends in a "
                         "new identity, which the repair must join: the identities pile up as the take goes on)")
    ap.add_argument("--child", type=float, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child is not None:
        print(json.dumps(_child(args.child, args.hidden, args.gap_s, args.keep_lost_s)))
        return
    print(f"machine: {describe()}")
    print(f"repair of the marching body (40 markers, 6 cameras, 120 Hz), {args.hidden:.0%} of each marker's frames "
          f"hidden in gaps of {args.gap_s:g} s mean, lost identities forgotten after {args.keep_lost_s:g} s (fresh "
          "process each)")
    print(f"    {'minutes':>7} {'frames':>7} {'ids tracked':>11} {'ids repaired':>12} {'tracking s':>10} "
          f"{'repair s':>9} {'repair s/min':>12} {'repair/tracking':>15} {'peak - output MiB':>17}")
    rows = []
    for minutes in args.minutes:
        out = subprocess.run([sys.executable, __file__, "--child", str(minutes), "--hidden", str(args.hidden),
                              "--gap-s", str(args.gap_s), "--keep-lost-s", str(args.keep_lost_s)],
                             capture_output=True, text=True)
        if out.returncode != 0:
            sys.exit(f"the {minutes:g}-minute run failed:\n{out.stderr}")
        r = json.loads(out.stdout.strip().splitlines()[-1])
        rows.append(r)
        print(f"    {r['minutes']:7g} {r['frames']:7d} {r['tracked_ids']:11d} {r['repaired_ids']:12d} "
              f"{r['tracking_s']:10.1f} {r['repair_s']:9.1f} {r['repair_s'] / r['minutes']:12.2f} "
              f"{r['repair_s'] / r['tracking_s']:15.2f} {r['peak_rss_mib'] - r['output_mib']:17.1f}")
    if len(rows) > 1:
        first, last = rows[0], rows[-1]
        growth = (last["repair_s"] / last["minutes"]) / (first["repair_s"] / first["minutes"])
        print(f"    repair time per minute, {last['minutes']:g} min over {first['minutes']:g} min: {growth:.2f} "
              "(1.0: linear in the take's length)")


if __name__ == "__main__":
    main()
