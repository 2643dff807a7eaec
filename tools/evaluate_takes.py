"""End-to-end accuracy and identity figures on rendered takes (issue 3's acceptance table).

For each motion (the built-in marching body and every real C3D in ../shared/data/c3d/):
``mocap synth`` renders a six-camera take with default realism, ``mocap reconstruct`` runs
the engine on the images, ``mocap evaluate`` scores the result against the ground truth.
The 3D motion of the C3D takes is real (recorded by OptiTrack systems); the 2D images are
simulated by this project's renderer.

Usage:
    python tools/evaluate_takes.py [--frames 600] [--work /tmp/mocap-eval] [--only NAME ...]

Prints one table row per take and writes ``summary.json`` into the work folder.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
C3D_DIR = ROOT.parent / "shared" / "data" / "c3d"


def _run(cmd: list[str]) -> float:
    """Run a command, fail loudly, return its wall time in seconds."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"command failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stdout}\n{proc.stderr}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=600, help="frames rendered per take (default 600)")
    ap.add_argument("--work", type=Path, default=Path("/tmp/mocap-eval"), help="scratch folder")
    ap.add_argument("--only", nargs="*", help="take names to run (body, or a C3D file stem)")
    ap.add_argument("--synth-args", default="", help="extra arguments for mocap synth (quoted)")
    ap.add_argument("--reconstruct-args", default="", help="extra arguments for mocap reconstruct (quoted)")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)

    motions: list[tuple[str, Path | None]] = [("body", None)]
    if C3D_DIR.exists():
        motions += [(p.stem, p) for p in sorted(C3D_DIR.glob("*.c3d"))]
    else:
        print(f"note: {C3D_DIR} is absent; only the built-in body is evaluated")
    if args.only:
        motions = [m for m in motions if m[0] in args.only]

    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, python "
          f"{platform.python_version()}")
    rows = []
    for name, motion in motions:
        take = args.work / name
        truth = args.work / f"{name}.truth.npz"
        out = args.work / f"{name}.c3d"
        report = args.work / f"{name}.json"
        synth = ["mocap", "synth", str(take), "--frames", str(args.frames), "--truth", str(truth), "--seed", "1",
                 "--force"]
        if motion is not None:
            synth += ["--motion", str(motion)]
        t_synth = _run(synth + args.synth_args.split())
        t_rec = _run(["mocap", "reconstruct", str(take), "--c3d", str(out), "--no-progress"]
                     + args.reconstruct_args.split())
        _run(["mocap", "evaluate", str(out), "--truth", str(truth), "--json", str(report)])
        result = json.loads(report.read_text())
        result.update({"take": name, "synth_s": t_synth, "reconstruct_s": t_rec})
        rows.append(result)
        print(json.dumps({k: v for k, v in result.items() if not isinstance(v, (dict, list))}), flush=True)
    (args.work / "summary.json").write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()
