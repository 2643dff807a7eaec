"""Capture the identity repair's input from a take, and replay the repair on captured inputs.

The offline identity repair (:func:`mocap.relabel.repair_identities`) runs on the tracker's finished
trajectories, so its input can be saved once and the repair replayed on it in seconds instead of rendering and
reconstructing again: a replay followed by the evaluation gives exactly what ``mocap reconstruct`` + ``mocap
evaluate`` give with the same repair. The engine log's before/after tables of repair rules are measured this
way (docs/engine-log.md).

Usage:
    python tools/replay_repair.py capture TAKE OUT.pkl [--start N] [--stop N]
    python tools/replay_repair.py replay CAPTURE.pkl [CAPTURE.pkl ...] [--truth TRUTH.npz]

``capture`` reconstructs the take (the repair runs too) and pickles the repair's input: the tracker's
trajectories, the repair's settings and the tracker's unconfirmed points, and the points the written trajectories
leave out after the repair (:meth:`mocap.tracker.Tracker.withheld`). ``replay`` runs the repair on each capture,
leaves those out, and prints one line of figures per capture against its truth (``NAME.truth.npz`` beside ``NAME.pkl``,
as ``mocap synth`` names it beside the take, unless ``--truth`` is given for a single capture). A capture is a
pickle of this version's objects: replay it with the code that wrote it or a later one that keeps their fields,
and only captures you made (unpickling runs code).
"""

from __future__ import annotations

import argparse
import copy
import pickle
import sys
import time
from pathlib import Path

import mocap.pipeline as pipeline
from mocap.errors import MocapError
from mocap.evaluate import evaluate
from mocap.relabel import RelabelConfig, repair_identities
from mocap.tracker import Tracker
from mocap.truth import load_truth


def capture(take: str, out: Path, start: int = 0, stop: int | None = None) -> None:
    """Reconstruct ``take`` (frames ``start`` .. ``stop``) and write the repair's input to ``out`` (atomically)."""
    real, real_withheld = pipeline.repair_identities, Tracker.withheld
    kept: list = []

    def keep_input(traj, config=None, unconfirmed=None):  # the pipeline's call, recorded before it runs
        kept[:] = [copy.deepcopy(traj), config, copy.deepcopy(unconfirmed)]
        return real(traj, config, unconfirmed=unconfirmed)

    def keep_withheld(tracker):  # (asked for after the repair)
        withheld = real_withheld(tracker)
        kept.append(withheld)
        return withheld

    pipeline.repair_identities, Tracker.withheld = keep_input, keep_withheld
    try:
        pipeline.reconstruct(take, pipeline.ReconstructOptions(progress=False, start=start, stop=stop))
    finally:
        pipeline.repair_identities, Tracker.withheld = real, real_withheld
    if len(kept) != 4:
        raise MocapError(f"{take}: the repair did not run (no frames?); nothing captured")
    tmp = out.with_name(out.name + ".partial")
    with open(tmp, "wb") as fh:
        pickle.dump(tuple(kept), fh)
    tmp.replace(out)


def replay(path: Path, truth_path: Path) -> str:
    """Run the repair on the capture at ``path`` and score it against ``truth_path``: one line of figures."""
    try:
        with open(path, "rb") as fh:
            traj, config, unconfirmed, withheld = pickle.load(fh)
    except (pickle.UnpicklingError, EOFError, AttributeError, ValueError) as err:
        raise MocapError(f"{path}: not a capture of this version ({err}); capture the take again") from err
    settings = RelabelConfig(confirm_frames=config.confirm_frames)
    began = time.perf_counter()
    repair_identities(traj, settings, unconfirmed=unconfirmed)
    took = time.perf_counter() - began
    withheld.apply(traj)
    report = evaluate(traj, load_truth(truth_path), None)
    return (f"{path.stem:14s} completeness {report.completeness:.4%}  ghosts {report.ghost_rate:.3%}  "
            f"switches {report.switches} ({report.switches_at_reference_jumps} at label jumps) "
            f"{report.switches_per_10k:.2f}/10k  IDF1 {report.idf1:.4f}  RMSE {report.rmse_mm:.3f} mm  "
            f"[repair {took:.1f} s]")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    verbs = parser.add_subparsers(dest="verb", required=True)
    cap = verbs.add_parser("capture", help="reconstruct a take and save the repair's input")
    cap.add_argument("take")
    cap.add_argument("out", type=Path)
    cap.add_argument("--start", type=int, default=0)
    cap.add_argument("--stop", type=int)
    rep = verbs.add_parser("replay", help="run the repair on captures and print their figures")
    rep.add_argument("captures", nargs="+", type=Path)
    rep.add_argument("--truth", type=Path, help="the truth of a single capture (default: NAME.truth.npz beside it)")
    args = parser.parse_args(argv)
    try:
        if args.verb == "capture":
            capture(args.take, args.out, args.start, args.stop)
            print(f"captured the repair's input of {args.take} in {args.out}")
            return 0
        if args.truth is not None and len(args.captures) > 1:
            raise MocapError("--truth names the truth of one capture; give one capture with it")
        for path in args.captures:
            if not path.is_file():
                raise MocapError(f"{path}: no such capture (make one with: replay_repair.py capture TAKE {path})")
            truth = args.truth or path.with_name(path.stem + ".truth.npz")
            print(replay(path, truth), flush=True)
    except MocapError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
