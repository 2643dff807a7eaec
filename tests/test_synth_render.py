"""The blob rasteriser: exact disc area, unbiased centroids, the Cramer-Rao bound, noise, merging."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.optimize import least_squares

from mocap.synth.render import FULL_SCALE, Sensor, disc_profile, disc_profile_slope


def test_profile_slope_matches_finite_differences():
    rho = np.linspace(0.0, 8.0, 81)
    for radius in (0.4, 1.75, 5.0):
        h = 1e-6
        numeric = (disc_profile(rho + h, radius, 0.6) - disc_profile(rho - h, radius, 0.6)) / (2 * h)
        np.testing.assert_allclose(disc_profile_slope(rho, radius, 0.6), numeric, atol=1e-7)


@pytest.mark.parametrize("radius", [0.5, 1.75, 4.0])
def test_profile_holds_the_exact_disc_area(radius):
    # Blurring keeps the light: the profile integrates to pi r^2 whatever the blur.
    step = 0.05
    grid = np.arange(-radius - 6, radius + 6, step) + step / 2
    x, y = np.meshgrid(grid, grid)
    area = disc_profile(np.hypot(x, y), radius, 0.58).sum() * step**2
    assert area == pytest.approx(np.pi * radius**2, rel=1e-3)


def test_noise_free_blob_centroid_is_unbiased_at_any_subpixel_position():
    sensor = Sensor(background=12.0, noise=0.0, blur_px=0.5)
    rng = np.random.default_rng(3)
    uv = rng.uniform(20, 21, (400, 2))
    radius = rng.uniform(0.5, 4.0, 400)
    x, y, level = sensor.profile(uv, radius, np.full(400, 200.0))  # unsaturated float profile
    signal = level - sensor.background
    cx = (signal * x).sum(axis=(1, 2)) / signal.sum(axis=(1, 2))
    cy = (signal * y).sum(axis=(1, 2)) / signal.sum(axis=(1, 2))
    err = np.hypot(cx - uv[:, 0], cy - uv[:, 1])
    assert err.max() < 0.005  # the brief asks < 0.01 px


def test_background_noise_has_the_stated_level_and_spread():
    sensor = Sensor(background=12.0, noise=2.0)
    frame = sensor.background_frame((300, 400), np.random.default_rng(0))
    assert frame.dtype == np.uint8 and frame.shape == (300, 400)
    assert frame.mean() == pytest.approx(12.0, abs=0.02)
    assert frame.std() == pytest.approx(np.sqrt(4 + 1 / 12), rel=0.02)
    again = sensor.background_frame((300, 400), np.random.default_rng(0))
    np.testing.assert_array_equal(frame, again)
    clean = Sensor(background=12.0, noise=0.0).background_frame((10, 10), np.random.default_rng(0))
    assert (clean == 12).all()


def test_draw_saturates_and_touches_only_pixels_near_blobs():
    sensor = Sensor(noise=0.0)
    image = sensor.background_frame((60, 80), np.random.default_rng(0))
    sensor.draw(image, np.array([[30.3, 20.6]]), np.array([2.0]), np.array([600.0]), np.random.default_rng(0))
    assert image.max() == FULL_SCALE
    ys, xs = np.nonzero(image != 12)
    assert np.hypot(xs - 30.3, ys - 20.6).max() < 2.0 + 4 * sensor.sigma + 1


def test_overlapping_markers_merge_into_one_blob():
    sensor = Sensor(noise=0.0)
    image = sensor.background_frame((60, 80), np.random.default_rng(0))
    uv = np.array([[30.0, 30.0], [33.0, 30.4], [60.0, 30.0]])
    sensor.draw(image, uv, np.full(3, 1.75), np.full(3, 300.0), np.random.default_rng(0))
    n, labels = cv2.connectedComponents((image > 40).astype(np.uint8))
    assert n - 1 == 2  # the close pair is one blob, the far marker another
    assert labels[30, 30] == labels[30, 33] != labels[30, 60]


@pytest.mark.parametrize("amplitude", [120.0, 400.0])  # unsaturated and saturated cores
def test_centroid_sigma_is_the_spread_of_a_maximum_likelihood_fit(amplitude):
    """Monte Carlo: fit the known profile to noisy rendered blobs; the spread approaches the bound."""
    sensor = Sensor(background=12.0, noise=2.0, blur_px=0.5)
    rng = np.random.default_rng(7)
    true_uv = np.array([[20.37, 19.81]])
    radius, amp = np.array([1.75]), np.array([amplitude])
    bound = sensor.centroid_sigma(true_uv, radius, amp)[0]
    errors = []
    for _ in range(300):
        image = sensor.background_frame((40, 40), rng)
        sensor.draw(image, true_uv, radius, amp, rng)
        window = image[13:28, 13:28].astype(np.float64)

        def residual(p: np.ndarray, window: np.ndarray = window) -> np.ndarray:
            x, y, level = sensor.profile(p[None], radius, amp)
            model = np.zeros((40, 40)) + sensor.background
            model[y[0], x[0]] = level[0]
            return (model[13:28, 13:28] - window).ravel()

        errors.append(least_squares(residual, true_uv[0] + rng.normal(0, 0.05, 2), x_scale=0.1).x - true_uv[0])
    spread = np.sqrt(np.mean(np.square(errors)))  # per-axis RMS error
    assert 0.9 * bound < spread < 1.25 * bound
