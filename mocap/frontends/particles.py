"""Shared particle-filter core: vectorised over particles, seeded ``np.random.Generator`` throughout.

A particle set is an ``(N, D)`` float array of states and an ``(N,)`` array of normalised weights.
Models (dynamics, likelihoods) live with the trackers; this module holds what every filter shares.
"""

from __future__ import annotations

import numpy as np

__all__ = [
    "normalise",
    "effective_sample_size",
    "systematic_resample",
    "predict_linear",
    "weighted_mean",
]


def normalise(weights: np.ndarray) -> np.ndarray:
    """(N,) non-negative weights -> (N,) weights summing to one (uniform if they sum to zero or NaN)."""
    w = np.asarray(weights, dtype=np.float64)
    total = w.sum()
    if not np.isfinite(total) or total <= 0:
        return np.full(w.shape, 1.0 / w.size)
    return w / total


def effective_sample_size(weights: np.ndarray) -> float:
    """Effective sample size ``1 / sum(w_i^2)`` of (N,) normalised weights; N for uniform weights."""
    w = np.asarray(weights, dtype=np.float64)
    return float(1.0 / np.dot(w, w))


def systematic_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling (Kitagawa 1996): one uniform draw, N evenly spaced pointers.

    Args:
        weights: (N,) normalised weights.
        rng: the random generator.

    Returns:
        (N,) int indices of the chosen particles, sorted ascending.
    """
    w = np.asarray(weights, dtype=np.float64)
    n = w.size
    positions = (rng.random() + np.arange(n)) / n
    cumulative = np.cumsum(w)
    cumulative[-1] = 1.0  # guard against round-off leaving the last pointer unmatched
    return np.searchsorted(cumulative, positions, side="right").clip(0, n - 1)


def predict_linear(states: np.ndarray, A: np.ndarray, noise_std: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Propagate particles through ``x(k) = A x(k-1) + w`` with ``w ~ N(0, diag(noise_std^2))``.

    Args:
        states: (N, D) particle states.
        A: (D, D) transition matrix.
        noise_std: (D,) process-noise standard deviations (same units as the states).
        rng: the random generator.

    Returns:
        (N, D) propagated states (new array).
    """
    states = np.asarray(states, dtype=np.float64)
    return states @ np.asarray(A).T + rng.standard_normal(states.shape) * np.asarray(noise_std)


def weighted_mean(states: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(N, D) states and (N,) normalised weights -> (D,) weighted mean (the MMSE estimate)."""
    return np.asarray(weights) @ np.asarray(states)
