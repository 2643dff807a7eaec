"""tools/render_other_model.py's partly hidden markers (``cut``): the drawn disc loses the part beyond its edge, and
only camera-frames next to one where that camera alone lost the marker are cut."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tool():
    spec = importlib.util.spec_from_file_location("render_other_model", ROOT / "tools" / "render_other_model.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _centroid(tool, edge: float, normal=(1.0, 0.0)) -> tuple[np.ndarray, float]:
    """Intensity-weighted centroid (px) and summed signal of one noise-free disc of radius 5 px at (32, 32), cut by
    an edge ``edge`` px from its centre along ``normal``."""
    sensor = tool.OtherSensor(noise=0.0)
    tool.OtherSensor.model = "cut"
    image = sensor.background_frame((64, 64), np.random.default_rng(0))
    tool._CUT[0] = (np.array([normal]), np.array([edge]), 0)
    try:
        sensor.draw(image, np.array([[32.0, 32.0]]), np.array([5.0]), np.array([200.0]), np.random.default_rng(0))
    finally:
        tool._CUT[0] = None
    signal = np.maximum(image.astype(float) - sensor.background, 0.0)
    ys, xs = np.mgrid[:64, :64]
    return np.array([(signal * xs).sum(), (signal * ys).sum()]) / signal.sum(), float(signal.sum())


def test_a_disc_cut_through_its_centre_moves_its_centroid_by_four_thirds_of_a_radius_over_pi(tool):
    whole, flux = _centroid(tool, np.inf)
    np.testing.assert_allclose(whole, [32.0, 32.0], atol=1e-6)
    half, half_flux = _centroid(tool, 0.0)  # the part beyond x = 32 is hidden
    assert half[0] == pytest.approx(32.0 - 4 * 5.0 / (3 * np.pi), abs=0.15) and half[1] == pytest.approx(32.0)
    assert half_flux == pytest.approx(flux / 2, rel=0.03)
    outer, _ = _centroid(tool, 2.5, normal=(0.0, -1.0))  # half a radius out, upwards: a small shift downwards
    assert 32.0 < outer[1] < 32.0 + 0.2 * 5.0 and outer[0] == pytest.approx(32.0)


def test_only_frames_next_to_a_camera_specific_hide_are_cut(tool):
    F, C, M = 8, 2, 3
    drawn = np.ones((F, C, M), dtype=bool)
    drawn[4, 0, 0] = False  # marker 0 hidden from camera 0 alone at frame 4
    drawn[4, :, 1] = False  # marker 1 hidden from every camera at frame 4 (the recording's gap)
    plan = SimpleNamespace(drawn=drawn, radius_px=np.full((F, C, M), 2.0))
    tool._DRAWN_SOMEWHERE[0] = None
    edges = {f: tool._cut_edges(plan, f, 0, seed=1)[1] for f in range(F)}
    assert edges[3][0] == 0.0 and edges[5][0] == 0.0  # next to the hide: cut through the centre
    assert edges[2][0] == 1.0 and edges[6][0] == 1.0  # two frames away: half a radius (2 px) out
    assert np.isinf(edges[1][0]) and np.isinf(edges[7][0])
    assert len(edges[4]) == 1  # (only the markers drawn: marker 2)
    assert all(np.isinf(e[1]) and np.isinf(e[2]) for f, e in edges.items() if f != 4)  # a gap in every view: no cut
    normal, _ = tool._cut_edges(plan, 3, 0, seed=1)
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1.0)
    np.testing.assert_array_equal(normal, tool._cut_edges(plan, 3, 0, seed=1)[0])  # seeded
