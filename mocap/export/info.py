"""``mocap info FILE``: markers, frames, rate, duration, units and gaps of any trajectory file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from mocap.export.formats import format_of, read_trajectories
from mocap.trajectories import Trajectories

__all__ = ["gap_runs", "summary", "configure_parser", "run"]


def gap_runs(valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Gaps per marker: runs of consecutive missing samples.

    Args:
        valid: (F, M) bool, True where the sample exists.

    Returns:
        counts: (M,) number of gaps; longest: (M,) length of the longest gap, frames.
    """
    F, M = valid.shape
    missing = np.zeros((F + 2, M), dtype=np.int8)
    missing[1:-1] = ~valid
    edges = np.diff(missing, axis=0).T  # (M, F + 1): +1 where a gap starts, -1 after it ends
    start_m, start_f = np.nonzero(edges == 1)
    _, end_f = np.nonzero(edges == -1)
    longest = np.zeros(M, dtype=np.int64)
    np.maximum.at(longest, start_m, end_f - start_f)
    return np.bincount(start_m, minlength=M), longest


def summary(traj: Trajectories, name: str, kind: str) -> str:
    """The text ``mocap info`` prints for ``traj`` read from file ``name`` of format ``kind``."""
    counts, longest = gap_runs(traj.valid)
    present = 100.0 * traj.valid.mean(axis=0) if traj.n_frames else np.zeros(traj.n_markers)
    residual = np.full(traj.n_markers, np.nan)
    has = traj.valid.any(axis=0)
    residual[has] = np.nanmean(traj.residuals[:, has], axis=0)
    units = traj.metadata.get("units", "m")
    lines = [
        f"{name} ({kind})",
        f"markers    {traj.n_markers}",
        f"frames     {traj.n_frames} (first {traj.first_frame})",
        f"rate       {traj.fps:g} Hz",
        f"duration   {traj.n_frames / traj.fps:.3f} s",
        f"units      {units} (in the file)",
    ]
    if traj.camera_names:
        lines.append(f"cameras    {len(traj.camera_names)}: {', '.join(traj.camera_names)}")
    overall = 100.0 * traj.valid.mean() if traj.valid.size else 0.0
    lines.append(f"samples    {overall:.1f} % present, {int(counts.sum())} gaps")
    if traj.n_markers:
        width = max(6, *(len(label) for label in traj.labels))
        lines.append(f"{'marker':<{width}}  present %   gaps   longest gap        residual mm")
        for m, label in enumerate(traj.labels):
            res = "-" if np.isnan(residual[m]) else f"{residual[m]:.3f}"
            lines.append(f"{label:<{width}}  {present[m]:9.1f}  {counts[m]:5d}   {longest[m]:6d} fr "
                         f"{longest[m] / traj.fps:7.3f} s  {res:>11}")
    return "\n".join(lines)


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="trajectory file: .c3d, .trc, .csv (Motive) or .mcap (incl. a take's log)")


def run(args: argparse.Namespace) -> int:
    path = Path(args.file)
    print(summary(read_trajectories(path), str(path), format_of(path).name))
    return 0
