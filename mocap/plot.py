"""``mocap plot FILE [-o OUT.png]``: 3D trajectories plus per-marker gap and residual charts (matplotlib, Agg).

matplotlib is imported inside :func:`plot_trajectories` only, so the rest of mocap never loads it.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path
from typing import Any

import numpy as np

from mocap.atomic import atomic_output, check_output_path
from mocap.export.common import identity_colors
from mocap.export.formats import read_trajectories
from mocap.export.info import gap_runs
from mocap.trajectories import Trajectories

__all__ = ["plot_trajectories", "configure_parser", "run"]

MAX_POINTS_PER_LINE = 4000
MAX_MARKER_TICKS = 60


def plot_trajectories(traj: Trajectories, path: str | os.PathLike, title: str = "") -> Any:
    """Write a PNG: 3D paths (left), gap timeline per marker (top right), residuals per marker (bottom right).

    Returns the matplotlib ``Figure`` (for inspection); the PNG is written atomically.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = check_output_path(path)
    F, M = traj.n_frames, traj.n_markers
    colors = identity_colors(np.arange(M))[:, :3]
    fig = Figure(figsize=(15, 8), dpi=100, layout="constrained")
    FigureCanvasAgg(fig)
    grid = fig.add_gridspec(2, 2, width_ratios=(1.2, 1))
    fig.suptitle(title or f"{M} markers, {F} frames at {traj.fps:g} Hz, {100 * traj.valid.mean():.1f} % present"
                 if F * M else title or "no samples")

    ax = fig.add_subplot(grid[:, 0], projection="3d")
    step = max(1, F // MAX_POINTS_PER_LINE)
    sampled = traj.positions[::step]
    for m in range(M):
        ax.plot(*sampled[:, m].T, color=colors[m], linewidth=0.8)
    finite = traj.positions[traj.valid]
    if len(finite):
        lo, hi = finite.min(axis=0), finite.max(axis=0)
        ax.set_box_aspect(np.maximum(hi - lo, 1e-3))
    ax.set(xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title="trajectories (world frame)")

    gaps = fig.add_subplot(grid[0, 1])
    gaps.imshow(traj.valid.T, aspect="auto", interpolation="nearest", cmap="Greys_r", vmin=0, vmax=1,
                extent=(traj.first_frame / traj.fps, (traj.first_frame + F) / traj.fps, M - 0.5, -0.5))
    counts, longest = gap_runs(traj.valid)
    gaps.set(xlabel="time (s)", title="samples present (white) and gaps (black)")
    _marker_ticks(gaps, traj.labels, [f"{c} gaps, longest {n}" for c, n in zip(counts, longest, strict=True)])

    res = fig.add_subplot(grid[1, 1])
    box = [traj.residuals[traj.valid[:, m], m] for m in range(M)]
    if M:
        res.boxplot([b if len(b) else [np.nan] for b in box], orientation="horizontal", showfliers=False,
                    positions=np.arange(M))
    res.invert_yaxis()
    recorded = bool(np.nan_to_num(traj.residuals).any())
    res.set(xlabel="triangulation residual (mm)", title="residual per marker (box: quartiles, whiskers 1.5 IQR)"
            if recorded else "residual per marker: none recorded in this file")
    _marker_ticks(res, traj.labels)
    with atomic_output(path) as tmp:
        fig.savefig(tmp, format="png")
    return fig


def _marker_ticks(ax: Any, labels: list[str], notes: list[str] | None = None) -> None:
    if len(labels) > MAX_MARKER_TICKS:
        ax.set_ylabel("marker index")
        return
    ax.set_yticks(np.arange(len(labels)))
    ax.set_yticklabels(labels if notes is None else [f"{lb} ({n})" for lb, n in zip(labels, notes, strict=True)],
                       fontsize=7)


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="trajectory file: .c3d, .trc, .csv (Motive) or .mcap")
    parser.add_argument("-o", "--output", metavar="OUT.png", help="image to write (default: FILE with .png)")


def run(args: argparse.Namespace) -> int:
    source = Path(args.file)
    out = Path(args.output) if args.output else source.with_suffix(".png")
    traj = read_trajectories(source)
    plot_trajectories(traj, out, title=f"{source.name}: {traj.n_markers} markers, {traj.n_frames} frames at "
                                       f"{traj.fps:g} Hz")
    print(out)
    return 0
