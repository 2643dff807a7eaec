"""Render named synthetic takes from ``datasets/scenarios.toml``.

Usage: ``python datasets/render.py NAME... --out DIR [--data DIR] [--seed N]``, ``--all`` for every
scenario, ``--list`` to show them. Each take goes to ``DIR/NAME`` and its truth to
``DIR/NAME.truth.npz``; extra arguments after ``--`` go to ``mocap synth`` unchanged.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from pathlib import Path

from mocap.cli import main as mocap_main

HERE = Path(__file__).resolve().parent
SCENARIOS = HERE / "scenarios.toml"
DEFAULT_DATA = HERE.parent.parent / "shared" / "data"


def load_scenarios() -> dict[str, dict]:
    with open(SCENARIOS, "rb") as fh:
        return tomllib.load(fh)


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("names", nargs="*", help="scenarios to render")
    parser.add_argument("--out", type=Path, help="folder for the takes")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help=f"real-data folder (default {DEFAULT_DATA})")
    parser.add_argument("--all", action="store_true", help="render every scenario")
    parser.add_argument("--list", action="store_true", help="list the scenarios and exit")
    args = parser.parse_args(argv)
    scenarios = load_scenarios()
    if args.list:
        for name, spec in scenarios.items():
            print(f"{name:22s} {spec['description']}")
        return 0
    names = list(scenarios) if args.all else args.names
    unknown = [n for n in names if n not in scenarios]
    if unknown or not names or args.out is None:
        parser.error(f"unknown scenario(s) {unknown}" if unknown else "give scenario names (or --all) and --out")
    args.out.mkdir(parents=True, exist_ok=True)
    for name in names:
        spec_args = [a.replace("{data}", str(args.data)) for a in scenarios[name]["args"]]
        print(f"== {name}: {scenarios[name]['description']}")
        status = mocap_main(["synth", str(args.out / name), *spec_args, *extra])
        if status:
            return status
    return 0


if __name__ == "__main__":
    sys.exit(main())
