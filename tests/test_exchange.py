"""Identities exchanged where two markers passed close are given back by their attached markers' distances."""

from __future__ import annotations

import numpy as np

from mocap.exchange import ExchangeConfig, undo_exchanges
from mocap.relabel import repair_identities
from tests.test_relabel import _traj


def _wrist_and_finger(frames: int = 120) -> np.ndarray:
    """(F, 3, 3) at 50 Hz: a wrist on a 0.5 m circle at 10 m/s, its wrist bar's other marker 100 mm above it, and a
    finger 100 mm out from the wrist that swings in to 30 mm of it at frame 60 and out again."""
    t = np.arange(frames) / 50.0
    angle = 2 * np.pi * 3.2 * t
    out = np.stack([np.cos(angle), np.sin(angle), np.zeros_like(t)], axis=1)
    wrist = 0.5 * out + [0.0, 0.0, 1.0]
    reach = 0.1 - 0.07 * np.exp(-(((np.arange(frames) - 60) / 3.0) ** 2))
    finger = wrist + reach[:, None] * out
    bar = wrist + [0.0, 0.0, 0.1]
    return np.stack([wrist, finger, bar], axis=1)


def _exchanged_at(P: np.ndarray, frame: int) -> np.ndarray:
    """``P`` with the wrist's and the finger's tails exchanged from ``frame`` on, as the tracker left them."""
    seen = P.copy()
    seen[frame:, [0, 1]] = P[frame:, [1, 0]]
    return seen


def test_an_exchange_where_wrist_and_finger_pass_is_undone_by_the_wrist_bar():
    """The tracker exchanged wrist and finger at their closest frame; no acceleration spike shows it (the swap pass
    leaves it), but the wrist's identity's distance to the bar steps from 100 to 120-140 mm and the finger's now holds
    100 mm: the tails are exchanged back, from the exchange's own frame."""
    P = _wrist_and_finger()
    seen = _exchanged_at(P, 60)
    traj = _traj(seen)
    assert undo_exchanges(traj) == 1
    np.testing.assert_array_equal(traj.positions, P)
    repaired = _traj(seen)
    stats = repair_identities(repaired)
    assert stats.exchanges == 1 and stats.swaps == 0
    np.testing.assert_array_equal(repaired.positions, P)


def test_markers_that_pass_close_without_an_exchange_are_left_alone():
    P = _wrist_and_finger()
    traj = _traj(P)
    assert undo_exchanges(traj) == 0
    np.testing.assert_array_equal(traj.positions, P)
    seen = _exchanged_at(P, 60)
    strict = _traj(seen)  # the same exchange, with a step too small to trust
    assert undo_exchanges(strict, ExchangeConfig(step_m=0.2)) == 0
    np.testing.assert_array_equal(strict.positions, seen)


def test_an_identity_that_starts_at_the_passage_exchanged_nothing():
    """A hand 44 mm from a wrist marker (steady) turns out to 72 mm as a forearm marker, hidden until then, comes
    into view 46 mm from the wrist and within 40 mm of the hand. The hand's distance stepped and the newcomer's fits
    the hand's old one, but the newcomer's identity held no marker before: nothing was exchanged."""
    frames = 40
    wrist = np.tile([0.0, 0.0, 1.0], (frames, 1))
    reach = np.interp(np.arange(frames), [0, 17, 22, frames - 1], [0.044, 0.044, 0.072, 0.072])
    hand = wrist + reach[:, None] * [1.0, 0.0, 0.0]
    newcomer = wrist + [0.03, 0.035, 0.0]
    P = np.stack([hand, newcomer, wrist], axis=1)
    P[:19, 1] = np.nan
    traj = _traj(P)
    assert undo_exchanges(traj) == 0
    np.testing.assert_array_equal(traj.positions, P)
