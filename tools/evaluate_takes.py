"""End-to-end accuracy and identity figures on rendered takes (issue 3's acceptance table).

For each named scenario of ``datasets/scenarios.toml`` (default: the built-in marching body and
one scenario per real C3D file in ../shared/data/c3d/), ``mocap synth`` renders a take with default
realism (a ring of six cameras; a walkway of cameras along the whole sprint's 12 m path),
``mocap reconstruct`` runs the engine on the images, and ``mocap evaluate`` scores the result against
the ground truth. The 3D motion of the C3D takes is real (recorded by
OptiTrack systems); the 2D images are simulated by this project's renderer.

Usage:
    python tools/evaluate_takes.py [--work /tmp/mocap-eval] [--frames N] [SCENARIO ...]

Prints one line per take as it finishes, then a table, and writes ``summary.json`` into the work folder.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
import tomllib
from pathlib import Path

from mocap.atomic import atomic_write_bytes

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data"
SCENARIOS = ROOT / "datasets" / "scenarios.toml"
DEFAULT = ["march", "tennis_serve", "tennis_2players", "walking", "basket_sprint_start"]
COLUMNS = [("take", "{}", 20), ("rmse_mm", "{:.3f}", 8), ("rmse_over_crlb", "{:.2f}", 9),
           ("completeness", "{:.2%}", 9), ("ghost_rate", "{:.3%}", 8), ("switches", "{}", 6),
           ("switches_per_10k", "{:.2f}", 8), ("idf1", "{:.4f}", 7), ("required", "{}", 8)]


def _run(cmd: list[str]) -> float:
    """Run a command, fail loudly, return its wall time in seconds."""
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        sys.exit(f"command failed ({proc.returncode}): {' '.join(cmd)}\n{proc.stdout}\n{proc.stderr}")
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenarios", nargs="*", default=DEFAULT, help=f"scenario names (default {' '.join(DEFAULT)})")
    ap.add_argument("--frames", type=int, help="override the number of frames rendered per take")
    ap.add_argument("--work", type=Path, default=Path("/tmp/mocap-eval"), help="scratch folder")
    ap.add_argument("--reuse", action="store_true", help="keep takes already rendered in the work folder")
    ap.add_argument("--synth-args", default="", help="extra arguments for mocap synth (quoted)")
    ap.add_argument("--reconstruct-args", default="", help="extra arguments for mocap reconstruct (quoted)")
    args = ap.parse_args()
    args.work.mkdir(parents=True, exist_ok=True)
    with open(SCENARIOS, "rb") as fh:
        scenarios = tomllib.load(fh)
    unknown = [n for n in args.scenarios if n not in scenarios]
    if unknown:
        sys.exit(f"unknown scenario(s) {unknown}; see {SCENARIOS}")
    print(f"machine: {platform.platform()}, {platform.processor() or platform.machine()}, python "
          f"{platform.python_version()}")
    rows = []
    for name in args.scenarios:
        spec = [a.replace("{data}", str(DATA)) for a in scenarios[name]["args"]]
        if any("{data}" in a for a in scenarios[name]["args"]) and not DATA.exists():
            print(f"skip {name}: {DATA} is absent")
            continue
        take, truth = args.work / name, args.work / f"{name}.truth.npz"
        out, report = args.work / f"{name}.c3d", args.work / f"{name}.json"
        synth = ["mocap", "synth", str(take), *spec, "--truth", str(truth), "--force", "--no-progress"]
        if args.frames:
            synth += ["--frames", str(args.frames)]
        reuse = args.reuse and truth.exists() and (take / "calibration.toml").exists()
        t_synth = 0.0 if reuse else _run(synth + args.synth_args.split())
        t_rec = _run(["mocap", "reconstruct", str(take), "--c3d", str(out), "--no-progress"]
                     + args.reconstruct_args.split())
        _run(["mocap", "evaluate", str(out), "--truth", str(truth), "--json", str(report)])
        result = json.loads(report.read_text())
        result.update({"take": name, "synth_s": round(t_synth, 1), "reconstruct_s": round(t_rec, 1)})
        rows.append(result)
        print(json.dumps({k: v for k, v in result.items() if not isinstance(v, (dict, list))}), flush=True)
    atomic_write_bytes(args.work / "summary.json", json.dumps(rows, indent=2).encode())
    print("  ".join(f"{name:>{width}}" for name, _, width in COLUMNS))
    for row in rows:
        cells = [fmt.format(row[key]) if row.get(key) is not None else "n/a" for key, fmt, _ in COLUMNS]
        print("  ".join(f"{c:>{w}}" for c, (_, _, w) in zip(cells, COLUMNS, strict=True)))


if __name__ == "__main__":
    main()
