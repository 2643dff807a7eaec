"""Rigid bodies and skin markers for the identity repair's shape tests (reunion, plates)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from mocap.trajectories import Trajectories

FRAMES = 600  # 6 s at 100 Hz
# local marker coordinates, m: an asymmetric 4-marker plate and a larger triangle
PLATE = np.array([[0.0, 0.0, 0.0], [0.082, 0.0, 0.0], [0.03, 0.054, 0.0], [0.07, 0.045, 0.02]])
TRIANGLE = np.array([[0.0, 0.0, 0.0], [0.21, 0.0, 0.0], [0.05, 0.3, 0.0]])
SQUARE = np.array([[0.0, 0.0, 0.0], [0.08, 0.0, 0.0], [0.08, 0.08, 0.0], [0.0, 0.08, 0.0]])


def moving(local: np.ndarray, rng: np.random.Generator, offset: float) -> np.ndarray:
    """(F, n, 3) a rigid body's markers: tumbling and travelling 4 m over the take, 0.3 mm noise."""
    t = np.arange(FRAMES) / 100.0
    turn = Rotation.from_rotvec(np.c_[0.8 * np.sin(0.7 * t + offset), 0.5 * np.cos(0.4 * t), 0.6 * t])
    path = np.c_[0.7 * t, offset + 0.2 * np.sin(t), 1.0 + 0.1 * np.cos(2 * t)]
    world = np.einsum("fij,nj->fni", turn.as_matrix(), local) + path[:, None]
    return world + rng.normal(0, 0.0003, world.shape)


def skin(n: int, rng: np.random.Generator) -> np.ndarray:
    """(F, n, 3) markers that move independently (no rigid pairs), never hidden."""
    t = np.arange(FRAMES)[:, None, None] / 100.0
    walk = np.c_[0.7 * t[:, 0, 0], np.zeros(FRAMES), np.ones(FRAMES)]  # (F, 3) beside the plates
    base = walk[:, None] + np.c_[np.zeros(n), 1.0 + 0.15 * np.arange(n), np.zeros(n)]
    return base + 0.05 * np.sin(2 * np.pi * rng.uniform(0.2, 1.0, (1, n, 3)) * t + rng.uniform(0, 6, (1, n, 3)))


def columns_follow(traj: Trajectories, truth: np.ndarray) -> list[int]:
    """For every non-empty column, the truth marker it follows; asserts it follows only that one."""
    out = []
    for col in np.flatnonzero(np.isfinite(traj.positions[..., 0]).any(axis=0)):
        rows = np.isfinite(traj.positions[:, col, 0])
        d = np.linalg.norm(truth[rows] - traj.positions[rows, col][:, None], axis=2)
        owner = d.argmin(axis=1)
        assert (owner == owner[0]).all() and d.min(axis=1).max() < 1e-12
        out.append(int(owner[0]))
    return out
