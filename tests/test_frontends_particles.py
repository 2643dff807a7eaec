"""Particle-filter core: systematic resampling, effective sample size, linear prediction."""

from __future__ import annotations

import numpy as np
import pytest

from mocap.frontends.particles import (
    effective_sample_size,
    normalise,
    predict_linear,
    systematic_resample,
    weighted_mean,
)


@pytest.mark.parametrize("seed", range(5))
def test_systematic_resample_copies_each_particle_floor_or_ceil_of_n_w(seed):
    rng = np.random.default_rng(seed)
    w = normalise(rng.gamma(0.3, size=200))
    idx = systematic_resample(w, rng)
    counts = np.bincount(idx, minlength=w.size)
    assert idx.shape == (200,)
    assert np.all(counts >= np.floor(200 * w) - 1e-9)
    assert np.all(counts <= np.ceil(200 * w) + 1e-9)


def test_systematic_resample_is_reproducible_with_a_seed():
    w = normalise(np.arange(1.0, 51.0))
    a = systematic_resample(w, np.random.default_rng(7))
    b = systematic_resample(w, np.random.default_rng(7))
    np.testing.assert_array_equal(a, b)


def test_effective_sample_size_bounds():
    assert effective_sample_size(np.full(40, 1 / 40)) == pytest.approx(40.0)
    one_hot = np.zeros(40)
    one_hot[3] = 1.0
    assert effective_sample_size(one_hot) == pytest.approx(1.0)


def test_normalise_falls_back_to_uniform_when_all_weights_vanish():
    np.testing.assert_allclose(normalise(np.zeros(4)), 0.25)
    np.testing.assert_allclose(normalise(np.array([np.nan, 1.0])), 0.5)


def test_predict_linear_moments_match_the_model():
    rng = np.random.default_rng(3)
    A = np.array([[1.0, 1.0], [0.0, 0.5]])
    x0 = np.tile([2.0, 4.0], (200_000, 1))
    out = predict_linear(x0, A, np.array([0.5, 2.0]), rng)
    np.testing.assert_allclose(out.mean(axis=0), A @ [2.0, 4.0], atol=0.02)
    np.testing.assert_allclose(out.std(axis=0), [0.5, 2.0], rtol=0.01)
    np.testing.assert_allclose(weighted_mean(out, normalise(np.ones(len(out)))), out.mean(axis=0))
