"""Exchanges between a skin-mounted cluster's identities undone by the neighbours' distances (mocap.skin)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from mocap.skin import SkinConfig, _exchanged, undo_skin_exchanges
from mocap.trajectories import Trajectories

F = 600
FPS = 120.0
# The sprint's forearm: references A1 and A2 49 mm apart; X 75 mm from A1 and 46 mm from A2, Y 60 and 64 mm.
FOREARM = np.array([[0.0, 0.0, 0.0], [0.049, 0.0, 0.0], [0.060, 0.045, 0.0], [0.020, 0.040, 0.040]])
A1, A2, X, Y = range(4)


def _skin(local: np.ndarray, seed: int, wobble_m: float = 0.003) -> np.ndarray:
    """(F, n, 3) markers at ``local`` (n, 3) m on a turning, travelling forearm, each wobbling on the skin by up to
    ``wobble_m`` (slow sinusoids of random phase: their distances spread by millimetres, more than a plate's)."""
    rng = np.random.default_rng(seed)
    t = np.arange(F) / FPS
    turn = Rotation.from_rotvec(np.stack([0.9 * np.sin(2.1 * t), 0.6 * np.cos(1.3 * t), 0.8 * t], axis=1))
    centre = np.stack([0.5 * np.sin(0.7 * t), 0.4 * np.cos(0.9 * t), 1.0 + 0.1 * t], axis=1)
    phase = rng.uniform(0, 2 * np.pi, size=(len(local), 3))
    rate = rng.uniform(1.0, 3.0, size=(len(local), 3))
    wobble = wobble_m / np.sqrt(3) * np.sin(rate[None] * 2 * np.pi * t[:, None, None] + phase[None])
    world = np.stack([turn.apply(p) for p in local], axis=1) + centre[:, None, :] + wobble
    return world + rng.normal(scale=0.0003, size=world.shape)


def _in_turn() -> tuple[np.ndarray, np.ndarray]:
    """(F,) bool frames X and Y are seen in: blocks of 40 frames in turn, 5 frames apart (the hand on the rim)."""
    phase = np.arange(F) % 90
    return phase < 40, (phase >= 45) & (phase < 85)


def _traj(truth: np.ndarray, columns: list[np.ndarray]) -> Trajectories:
    """Identity columns: ``columns`` (F,) int truth marker per frame, -1 where the identity has no sample."""
    P = np.full((F, len(columns), 3), np.nan)
    for col, marker in enumerate(columns):
        held = marker >= 0
        P[held, col] = truth[np.flatnonzero(held), marker[held]]
    return Trajectories([f"id{k}" for k in range(len(columns))], FPS, P)


def _held(traj: Trajectories, truth: np.ndarray, col: int) -> np.ndarray:
    """(F,) int: the truth marker identity ``col`` holds in each frame, -1 where none."""
    d = np.linalg.norm(traj.positions[:, col, None, :] - truth, axis=2)
    return np.where(np.isfinite(d[:, 0]), np.nanargmin(np.nan_to_num(d, nan=np.inf), axis=1), -1)


def _forearm_columns(x_seen: np.ndarray, y_seen: np.ndarray, exchanged: np.ndarray) -> list[np.ndarray]:
    """A1's, A2's, X's and Y's identity columns, X's and Y's holding each other's markers in frames ``exchanged``."""
    x_col = np.where(x_seen, X, -1)
    y_col = np.where(y_seen, Y, -1)
    x_col[exchanged], y_col[exchanged] = y_col[exchanged], x_col[exchanged].copy()
    return [np.full(F, A1), np.full(F, A2), x_col, y_col]


def test_identities_that_took_each_others_markers_while_seen_in_turn_get_them_back():
    truth = _skin(FOREARM, seed=1)
    x_seen, y_seen = _in_turn()
    exchanged = (np.arange(F) >= 220) & (np.arange(F) < 400)  # two of Y's blocks and two of X's
    traj = _traj(truth, _forearm_columns(x_seen, y_seen, exchanged))
    assert undo_skin_exchanges(traj) == 1
    assert (_held(traj, truth, 2) == np.where(x_seen, X, -1)).all()
    assert (_held(traj, truth, 3) == np.where(y_seen, Y, -1)).all()
    assert (_held(traj, truth, 0) == A1).all() and (_held(traj, truth, 1) == A2).all()


def test_an_exchange_after_a_gap_both_markers_share_is_undone_where_both_are_seen():
    truth = _skin(FOREARM, seed=2)
    seen = np.ones(F, dtype=bool)
    seen[300:303] = False  # both hidden for 3 frames; back under each other's identities for 50 frames
    exchanged = (np.arange(F) >= 303) & (np.arange(F) < 353)
    exchanged_at_gap = np.copy(seen)
    exchanged_at_gap[353:356] = False  # ... and handed back after a second shared gap
    traj = _traj(truth, _forearm_columns(exchanged_at_gap, exchanged_at_gap, exchanged))
    assert undo_skin_exchanges(traj) == 1
    assert (_held(traj, truth, 2) == np.where(exchanged_at_gap, X, -1)).all()
    assert (_held(traj, truth, 3) == np.where(exchanged_at_gap, Y, -1)).all()


def test_identities_that_kept_their_markers_are_left_alone():
    truth = _skin(FOREARM, seed=3)
    x_seen, y_seen = _in_turn()
    traj = _traj(truth, _forearm_columns(x_seen, y_seen, np.zeros(F, dtype=bool)))
    before = traj.positions.copy()
    assert undo_skin_exchanges(traj) == 0
    np.testing.assert_array_equal(traj.positions, before)


def test_a_point_of_neither_marker_is_not_moved():
    """X's identity holds a third marker for a block where X is hidden (the hand: 62 mm from A1 and 75 from A2, so
    nearer Y's distances than X's, yet 11 mm off Y's from A2): it fits Y too badly to move there; without the fit
    test it would."""
    hand = np.array([[0.0063, 0.0, 0.0617]])
    truth = _skin(np.vstack([FOREARM, hand]), seed=4)
    x_seen, y_seen = _in_turn()
    columns = _forearm_columns(x_seen, y_seen, np.zeros(F, dtype=bool))
    columns[2][180:220] = 4
    traj = _traj(truth, columns)
    assert undo_skin_exchanges(traj) == 0
    assert (_held(traj, truth, 2)[180:220] == 4).all()
    assert undo_skin_exchanges(_traj(truth, columns), SkinConfig(fit_chi2=np.inf)) == 1


def test_one_reference_seen_is_not_enough():
    """Where A2 is unseen, a sample's distance to A1 alone places it on a sphere: such samples are not scored, and an
    exchange seen only so is left alone; with ``min_references=1`` it is undone."""
    truth = _skin(FOREARM, seed=6)
    x_seen, y_seen = _in_turn()
    exchanged = (np.arange(F) >= 220) & (np.arange(F) < 320)
    columns = _forearm_columns(x_seen, y_seen, exchanged)
    columns[1][220:320] = -1
    assert undo_skin_exchanges(_traj(truth, columns)) == 0
    assert undo_skin_exchanges(_traj(truth, columns), SkinConfig(min_references=1)) == 1


@pytest.mark.parametrize(("wobble_m", "undone"), [(0.002, 1), (0.012, 0)])
def test_markers_wobbling_past_the_spread_limit_are_no_references(wobble_m, undone):
    """Skin wobbling by 12 mm spreads the distances past ``spread_m`` (5 mm): the identities have no references and
    the exchange is left alone; at 2 mm it is undone."""
    truth = _skin(FOREARM, seed=7, wobble_m=wobble_m)
    x_seen, y_seen = _in_turn()
    exchanged = (np.arange(F) >= 220) & (np.arange(F) < 400)
    traj = _traj(truth, _forearm_columns(x_seen, y_seen, exchanged))
    assert undo_skin_exchanges(traj) == undone
    columns = _forearm_columns(x_seen, y_seen, exchanged & (undone == 0))  # what each identity holds now
    assert (_held(traj, truth, 2) == columns[2]).all() and (_held(traj, truth, 3) == columns[3]).all()


@pytest.mark.parametrize("seed", range(5))
def test_the_labelling_is_the_most_likely_one(seed):
    """The Viterbi labelling scores as well as the best of all labellings found by enumeration."""
    rng = np.random.default_rng(seed)
    score = rng.normal(scale=8.0, size=12)
    breaks = rng.random(12) < 0.5
    breaks[0] = True
    cost = 6.0

    def total(state: np.ndarray) -> float:
        changes = np.diff(np.concatenate([[False], state]).astype(int)) != 0
        return float(score[state].sum() - cost * changes.sum()) if not changes[~breaks].any() else -np.inf

    best = max(total(np.array(s, dtype=bool)) for s in itertools.product([False, True], repeat=12))
    assert total(_exchanged(score, breaks, cost)) == pytest.approx(best)


def test_empty_and_markerless_trajectories_are_left_alone():
    assert undo_skin_exchanges(Trajectories([f"id{k}" for k in range(5)], FPS, np.full((F, 5, 3), np.nan))) == 0
    assert undo_skin_exchanges(Trajectories([], FPS, np.zeros((F, 0, 3)))) == 0


def test_markers_of_two_segments_are_told_apart_by_their_own_references():
    """The forearm's X and a marker W of a rigid plate (the wheelchair, its other markers 0.3 m away) pass within
    40 mm of each other and come back from a shared gap under each other's identities for 60 frames: no reference
    is shared, each one's own tell them apart, and the exchange is undone."""
    forearm = _skin(FOREARM, seed=8)
    t = np.arange(F) / FPS
    plate = np.array([[0.0, 0.0, 0.0], [0.3, 0.0, 0.05], [0.1, 0.25, 0.0]])  # W, B1, B2
    turn = Rotation.from_rotvec(np.stack([0.3 * np.sin(1.1 * t), 0.2 * t, 0.5 * np.cos(0.7 * t)], axis=1))
    away = 0.04 + 0.3 * np.abs(t - t[F // 2])[:, None] * np.array([[1.0, 0.5, 0.2]])  # W 40 mm from X at mid-take
    w_at = forearm[:, X] + away
    wheel = np.stack([turn.apply(p) for p in plate], axis=1) - turn.apply(plate[0])[:, None] + w_at[:, None]
    truth = np.concatenate([forearm, wheel], axis=1)  # markers A1, A2, X, Y, W, B1, B2
    seen = np.ones(F, dtype=bool)
    seen[[267, 268, 269, 330, 331, 332]] = False  # X and W hidden together twice
    x_col, w_col = np.where(seen, X, -1), np.where(seen, 4, -1)
    exchanged = (np.arange(F) >= 270) & (np.arange(F) < 330)
    x_col[exchanged], w_col[exchanged] = 4, X
    columns = [np.full(F, A1), np.full(F, A2), x_col, np.full(F, Y), w_col, np.full(F, 5), np.full(F, 6)]
    traj = _traj(truth, columns)
    assert undo_skin_exchanges(traj) == 1
    assert (_held(traj, truth, 2) == np.where(seen, X, -1)).all()
    assert (_held(traj, truth, 4) == np.where(seen, 4, -1)).all()
    assert undo_skin_exchanges(_traj(truth, columns), SkinConfig(meet_m=0.03)) == 0  # never that near: no pair
