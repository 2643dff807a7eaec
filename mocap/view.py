"""``mocap view FILE``: interactive 3D playback with open3d (the optional ``viz`` extra).

:func:`frame_geometry` builds each frame's geometry as numpy arrays (tested without a window);
:func:`run` only turns them into open3d objects. Keys: space pauses, left/right step a frame.
"""

from __future__ import annotations

import argparse
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from mocap.errors import MocapError
from mocap.export.common import identity_colors
from mocap.export.formats import read_trajectories
from mocap.trajectories import Trajectories

__all__ = ["FrameGeometry", "frame_geometry", "configure_parser", "run"]

INSTALL_HINT = "the 3D viewer needs open3d: pip install 'mocap[viz]' (on Debian also apt-get install libusb-1.0-0)"


@dataclass
class FrameGeometry:
    """What the viewer draws at one frame.

    Attributes:
        points: (K, 3) positions of the markers present, metres.
        colors: (K, 3) RGB in [0, 1], by marker identity (the same colours as the MCAP log and plots).
        markers: (K,) indices of those markers in the trajectories.
        trail_points: (P, 3) vertices of the recent-path polylines, metres.
        trail_lines: (L, 2) vertex index pairs, one per segment between consecutive present samples.
        trail_colors: (L, 3) RGB per segment.
    """

    points: np.ndarray
    colors: np.ndarray
    markers: np.ndarray
    trail_points: np.ndarray
    trail_lines: np.ndarray
    trail_colors: np.ndarray


def frame_geometry(traj: Trajectories, frame: int, trail: int = 30) -> FrameGeometry:
    """Markers at ``frame`` (an index into ``traj``) and each marker's path over the previous ``trail`` frames."""
    if not 0 <= frame < traj.n_frames:
        raise ValueError(f"frame {frame} outside 0..{traj.n_frames - 1}")
    palette = identity_colors(np.arange(traj.n_markers))[:, :3]
    valid = traj.valid
    markers = np.flatnonzero(valid[frame])
    lo = max(0, frame - trail)
    window = traj.positions[lo:frame + 1]  # (T, M, 3)
    both = valid[lo:frame] & valid[lo + 1:frame + 1]  # (T - 1, M): segment t -> t + 1 exists
    T, M = window.shape[:2]
    t_idx, m_idx = np.nonzero(both)
    start = t_idx * M + m_idx  # vertex index into window.reshape(-1, 3)
    lines = np.column_stack([start, start + M]) if len(start) else np.zeros((0, 2), dtype=np.int64)
    return FrameGeometry(traj.positions[frame, markers], palette[markers], markers, window.reshape(T * M, 3),
                         lines, palette[m_idx])


def _open3d() -> Any:
    try:
        import open3d
    except ImportError:
        raise MocapError(INSTALL_HINT) from None
    return open3d


def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", help="trajectory file: .c3d, .trc, .csv (Motive) or .mcap")
    parser.add_argument("--trail", type=int, default=30, help="frames of path drawn behind each marker (default 30)")
    parser.add_argument("--speed", type=float, default=1.0, help="playback speed, 1 = real time")


def run(args: argparse.Namespace) -> int:
    o3d = _open3d()
    traj = read_trajectories(Path(args.file))
    if traj.n_frames == 0:
        raise MocapError(f"{args.file}: no frames to show")
    cloud, trails = o3d.geometry.PointCloud(), o3d.geometry.LineSet()
    state = {"frame": 0, "paused": False, "clock": time.perf_counter()}

    def show(frame: int) -> None:
        g = frame_geometry(traj, frame, args.trail)
        cloud.points = o3d.utility.Vector3dVector(g.points)
        cloud.colors = o3d.utility.Vector3dVector(g.colors)
        trails.points = o3d.utility.Vector3dVector(np.nan_to_num(g.trail_points))
        trails.lines = o3d.utility.Vector2iVector(g.trail_lines)
        trails.colors = o3d.utility.Vector3dVector(g.trail_colors)

    def tick(vis: Any) -> bool:
        if state["paused"]:
            return False
        now = time.perf_counter()
        advance = int((now - state["clock"]) * traj.fps * args.speed)
        if advance == 0:
            return False
        state["clock"] += advance / (traj.fps * args.speed)
        state["frame"] = (state["frame"] + advance) % traj.n_frames
        show(state["frame"])
        vis.update_geometry(cloud)
        vis.update_geometry(trails)
        return True

    def step(delta: int) -> Any:
        def key(vis: Any) -> bool:
            state["paused"] = True
            state["frame"] = (state["frame"] + delta) % traj.n_frames
            show(state["frame"])
            vis.update_geometry(cloud)
            vis.update_geometry(trails)
            return True
        return key

    def pause(vis: Any) -> bool:
        state["paused"] = not state["paused"]
        state["clock"] = time.perf_counter()
        return False

    vis = o3d.visualization.VisualizerWithKeyCallback()
    vis.create_window(window_name=f"mocap view {args.file}")
    show(0)
    vis.add_geometry(cloud)
    vis.add_geometry(trails)
    vis.add_geometry(o3d.geometry.TriangleMesh.create_coordinate_frame(size=0.5))
    vis.get_render_option().point_size = 8.0
    vis.register_animation_callback(tick)
    vis.register_key_callback(ord(" "), pause)
    vis.register_key_callback(262, step(1))  # GLFW right arrow
    vis.register_key_callback(263, step(-1))  # GLFW left arrow
    vis.run()
    vis.destroy_window()
    return 0
