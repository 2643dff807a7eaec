"""Shared fixtures: a small realistic rig, and the path to the real recorded data."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from mocap.camera import Camera, Rig

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


def ring_rig(n: int = 6, radius: float = 4.0, height: float = 2.2, size=(1024, 768), f: float = 1000.0,
             distortions=(-0.05, 0.01, 0.0005, -0.0003, 0.0)) -> Rig:
    """``n`` cameras on a ring of ``radius`` m at ``height`` m, all looking at (0, 0, 1) m."""
    cams = []
    target = np.array([0.0, 0.0, 1.0])
    for i in range(n):
        a = 2 * np.pi * i / n
        c = np.array([radius * np.cos(a), radius * np.sin(a), height])
        z = target - c
        z /= np.linalg.norm(z)
        x = np.cross(z, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(z, x)
        R = np.stack([x, y, z])
        K = np.array([[f, 0, size[0] / 2 - 0.5 + 3.1], [0, f * 1.001, size[1] / 2 - 0.5 - 2.7], [0, 0, 1]])
        cams.append(Camera(f"cam{i + 1}", size, K, np.array(distortions), cv2.Rodrigues(R)[0].ravel(), -R @ c))
    return Rig(cams, {"made_by": "tests"})


@pytest.fixture
def rig() -> Rig:
    return ring_rig()


def require_shared_data(sub: str) -> Path:
    """The folder ``shared/data/<sub>``, or skip the test with the reason."""
    path = SHARED_DATA / sub
    if not path.exists():
        pytest.skip(f"real data folder {path} is absent (it sits beside the project in CI, not in a fresh clone)")
    return path
