"""Which identity holds which marker after each pass of the identity repair: find the pass that made a mistake.

Runs the offline identity repair (:func:`mocap.relabel.repair_identities`) on a capture of its input (made by
``tools/replay_repair.py capture``) and prints, after each pass, the output column (identity) that holds each chosen
truth marker at each chosen frame: the nearest output point within 20 mm of the truth, ``?`` where none is, ``-``
where the truth has no sample. Columns keep their numbers through the passes (the repair drops empty ones only at
its end), so a change between two rows is that pass's doing.

Usage:
    python tools/trace_repair.py CAPTURE.pkl TRUTH.npz --markers ForearmL --frames 2100,2440,2650 [--offset N]

``--markers`` picks the truth labels containing that text; ``--frames`` are the capture's frames (a capture made with
``--start N`` counts from N: give ``--offset N`` to read the truth there). Only captures you made (unpickling runs
code).
"""

from __future__ import annotations

import argparse
import inspect
import pickle
import sys
from pathlib import Path

import numpy as np

import mocap.relabel as relabel
from mocap.truth import load_truth

GATE_M = 0.02  # an output point within this of a truth marker is that marker's


def _holders(positions: np.ndarray, truth: np.ndarray, markers: list[int], frames: list[int]) -> str:
    """One row: per frame, the column holding each marker (``positions`` (F, M, 3), ``truth`` (F', K, 3) m, frames
    already offset into the truth)."""
    cells = []
    for f, tf in frames:
        row = []
        for m in markers:
            if not np.isfinite(truth[tf, m]).all():
                row.append("  -")
                continue
            d = np.linalg.norm(positions[f] - truth[tf, m], axis=1)
            if not np.isfinite(d).any():
                row.append("  ?")
                continue
            col = int(np.nanargmin(d))
            row.append(f"{col:3d}" if d[col] < GATE_M else "  ?")
        cells.append(" ".join(row))
    return " | ".join(cells)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("capture", type=Path)
    ap.add_argument("truth", type=Path)
    ap.add_argument("--markers", required=True, help="text the chosen truth labels contain")
    ap.add_argument("--frames", required=True, help="comma-separated frames of the capture")
    ap.add_argument("--offset", type=int, default=0, help="truth frame of the capture's frame 0")
    args = ap.parse_args(argv)
    with open(args.capture, "rb") as fh:
        traj, config, unconfirmed, _ = pickle.load(fh)  # (the points withheld after the repair: not traced)
    truth = load_truth(args.truth)
    markers = [k for k, label in enumerate(truth.labels) if args.markers in label]
    if not markers:
        print(f"error: no truth label contains {args.markers!r}", file=sys.stderr)
        return 2
    frames = [(f, f + args.offset) for f in map(int, args.frames.split(","))]
    short = " ".join(truth.labels[m].split(":")[-1].replace("Marker", "M")[-3:].rjust(3) for m in markers)
    print(f"{'markers: ' + ', '.join(truth.labels[m] for m in markers)}")
    print(f"{'after':30s} | " + " | ".join(f"{f}: {short}" for f, _ in frames))
    print(f"{'(input)':30s} | " + _holders(traj.positions, truth.positions, markers, frames), flush=True)

    def traced(name, function):
        def run(t, *a, **kw):
            result = function(t, *a, **kw)
            print(f"{name + ' -> ' + str(result):30s} | " + _holders(t.positions, truth.positions, markers, frames),
                  flush=True)
            return result
        return run

    # every pass repair_identities calls (the module-level functions it names), traced where it looks them up
    passes = [n for n in relabel.repair_identities.__code__.co_names
              if inspect.isfunction(getattr(relabel, n, None))]
    saved = {n: getattr(relabel, n) for n in passes}
    try:
        for n in passes:
            setattr(relabel, n, traced(n, saved[n]))
        relabel.repair_identities(traj, relabel.RelabelConfig(confirm_frames=config.confirm_frames),
                                  unconfirmed=unconfirmed)
    finally:
        for n, function in saved.items():
            setattr(relabel, n, function)
    return 0


if __name__ == "__main__":
    sys.exit(main())
