"""Calibration reports: a short text summary, a JSON file, and a coverage plot.

The coverage plot (matplotlib, Agg backend, imported only here) shows, per camera, every wand
marker the calibration used over the image rectangle, coloured by its reprojection error, with
the 8 x 6 cells the wand never reached shaded: the places where the lens model is extrapolated.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from calibration.quality import COVERAGE_GRID
from mocap.atomic import atomic_output, atomic_write_bytes
from mocap.camera import Rig

__all__ = ["json_ready", "write_json", "wand_text", "coverage_png"]


def json_ready(value: Any) -> Any:
    """Nested dicts/lists with numpy values -> plain JSON types (NaN -> None)."""
    if isinstance(value, dict):
        return {str(k): json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_json(report: dict[str, Any], path: str | os.PathLike) -> None:
    """Write ``report`` as indented JSON, atomically."""
    atomic_write_bytes(path, (json.dumps(json_ready(report), indent=2) + "\n").encode("utf-8"))


def _f(value: float | None, digits: int = 3) -> str:
    return "n/a" if value is None or not math.isfinite(value) else f"{value:.{digits}f}"


def _frame_text(al: dict[str, Any]) -> str:
    if al["method"] == "lframe":
        return f"L-frame (fit RMS {_f(al['rms_mm'])} mm, wand scale check {_f(al['scale'], 5)})"
    if al["method"] == "floor":
        return "floor markers"
    return f"camera {al['reference_camera']} (no L-frame)"


def wand_text(report: dict[str, Any]) -> str:
    """A human-readable summary of a wand calibration report."""
    fr = report["frames"]
    rep = report["reprojection"]
    e2e = report["holdout_wand"]["end_to_end"]
    lines = [
        f"wand {report['wand_m']} m; frames: {fr['total']} recorded, {fr['fitted']} fitted, "
        f"{fr['held_out']} held out, {fr['outliers_dropped']} outlier observations dropped",
        f"reprojection RMS {_f(rep['rms_px'], 4)} px per axis "
        f"(blob centroid noise RMS {_f(rep['centroid_sigma_rms_px'], 4)} px)",
        f"held-out wand length: RMS error {_f(e2e['rms_mm'])} mm, mean {_f(e2e['mean_mm'])} mm, "
        f"95 % within {_f(e2e['p95_abs_mm'])} mm ({e2e['n']} frames)",
        "world frame: " + _frame_text(report["alignment"]),
        f"{'camera':<10} {'frames':>7} {'obs':>7} {'RMS px':>8} {'max px':>8} {'coverage':>9}",
    ]
    for cam in report["per_camera"]:
        lines.append(f"{cam['name']:<10} {cam['frames_seen']:>7} {cam['observations']:>7} {_f(cam['rms_px'], 4):>8} "
                     f"{_f(cam['max_px'], 3):>8} {100 * cam['coverage']:>8.0f}%")
    lines += [f"warning: {w}" for w in report["warnings"]]
    return "\n".join(lines)


def coverage_png(rig: Rig, obs: np.ndarray, residuals: np.ndarray | None, path: str | os.PathLike) -> None:
    """Write the coverage plot.

    Args:
        rig: the cameras (names, image sizes).
        obs: (F, C, K, 2) wand markers seen, distorted pixels; NaN where unseen.
        residuals: (F, C, K, 2) reprojection errors (colour), or None.
        path: PNG file to write (atomically).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    C = len(rig)
    cols = min(C, 3)
    rows = math.ceil(C / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.4 * rows), squeeze=False)
    gx, gy = COVERAGE_GRID
    for c, cam in enumerate(rig):
        ax = axes[c // cols][c % cols]
        w, h = cam.size
        xy = obs[:, c].reshape(-1, 2)
        ok = np.isfinite(xy).all(axis=1)
        cx = np.clip((xy[ok, 0] / w * gx).astype(int), 0, gx - 1)
        cy = np.clip((xy[ok, 1] / h * gy).astype(int), 0, gy - 1)
        hit = np.zeros((gy, gx), dtype=bool)
        hit[cy, cx] = True
        ax.imshow(~hit, extent=(0, w, h, 0), cmap="Greys", vmin=0, vmax=4, alpha=0.9, interpolation="nearest")
        colour = None
        if residuals is not None:
            colour = np.linalg.norm(residuals[:, c].reshape(-1, 2), axis=1)[ok]
        sc = ax.scatter(xy[ok, 0], xy[ok, 1], s=1, c=colour, cmap="viridis")
        if colour is not None and np.isfinite(colour).any():
            fig.colorbar(sc, ax=ax, label="reprojection error, px")
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"{cam.name}: {ok.sum()} points, {100 * hit.mean():.0f} % of cells")
    for k in range(C, rows * cols):
        axes[k // cols][k % cols].axis("off")
    fig.suptitle("Wand coverage per camera (grey cells: never reached)")
    fig.tight_layout()
    with atomic_output(path) as tmp:
        fig.savefig(tmp, dpi=80, format="png")
    plt.close(fig)
