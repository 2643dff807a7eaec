"""The tracker's memory of attached distances (mocap.attached): what it learns, what it refutes, what it forgets."""

from __future__ import annotations

import numpy as np

from mocap.attached import AttachedDistances

# A rigid plate of four markers (identities 0-3) and a loose one (4) swinging about it, m.
PLATE = np.array([[0.0, 0.0, 0.0], [-0.03, 0.07, 0.0], [-0.05, -0.03, 0.02], [0.04, 0.0, 0.0]])


def _frames(n: int, seed: int = 0) -> list[np.ndarray]:
    """(5, 3) positions per frame: the plate translated and turned, the loose marker wandering 5-15 cm away."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        a = 0.02 * k
        R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
        plate = PLATE @ R.T + [0.01 * k, 0.0, 1.0] + rng.normal(0.0, 2e-4, PLATE.shape)
        loose = plate[0] + (0.1 + 0.05 * np.sin(0.3 * k)) * np.array([np.cos(0.1 * k), np.sin(0.1 * k), 0.3])
        out.append(np.vstack([plate, loose]))
    return out


def _learned(frames: list[np.ndarray], **kw) -> AttachedDistances:
    memory = AttachedDistances(**{"slots": 4, "reach_m": 0.3, "tolerance_m": 0.01, "steady_frames": 12,
                                  "forget_frames": 240, **kw})
    for X in frames:
        memory.learn(np.arange(len(X)), X)
    return memory


def test_a_neighbour_in_a_hidden_markers_place_is_refuted_and_the_marker_itself_fits():
    frames = _frames(60)
    memory = _learned(frames)
    X = frames[-1]
    here = np.array([1, 2, 4])  # identity 0 (A) and 3 (D) hidden in this frame; the loose marker seen
    # Identity 0 offered D's point: 23 and 35 mm off its distances to B and C (the loose marker is not steady).
    misfit, fits = memory.judge(np.array([0, 3]), np.stack([X[3], X[3]]), here, X[here])
    assert misfit.tolist() == [True, False] and fits.tolist() == [False, True]
    # Its own point fits; the loose marker, never steady, neither fits nor is refuted.
    misfit, fits = memory.judge(np.array([0, 4]), np.stack([X[0], X[0]]), here, X[here])
    assert misfit.tolist() == [False, False] and fits.tolist() == [True, False]
    # A point that keeps identity 3's distance to B only (D turned 90 degrees about B): one neighbour is no fit,
    # and one that holds is no refutation.
    a = np.pi / 2
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    turned = X[1] + (X[3] - X[1]) @ R.T
    here = np.array([0, 1, 2])
    misfit, fits = memory.judge(np.array([3]), turned[None], here, X[here])
    assert not misfit[0] and not fits[0]
    steady = memory.held[0] >= 12
    np.testing.assert_allclose(np.sort(memory.distance[0][steady]),
                               np.sort(np.linalg.norm(PLATE[1:] - PLATE[0], axis=1)), atol=1e-3)


def test_one_wrong_point_does_not_erase_the_memory_but_a_real_change_does():
    frames = _frames(60)
    memory = _learned(frames)
    before = memory.held[0].copy()
    wrong = frames[-1].copy()
    wrong[0] = wrong[3]  # identity 0 measured at D's place for one frame
    memory.learn(np.arange(5), wrong)
    kept = memory.neighbour[0] >= 0
    assert kept[before >= 12].all() and (memory.held[0][before >= 12] >= 12).all()
    # A marker that really moved 3 cm on its plate: after a few frames its old distances stop counting.
    moved = [X + np.where(np.arange(5)[:, None] == 1, [0.0, 0.03, 0.0], 0.0) for X in _frames(70)[60:]]
    for X in moved:
        memory.learn(np.arange(5), X)
    X = moved[-1]
    here = np.array([0, 2, 3])
    misfit, fits = memory.judge(np.array([1]), X[[1]], here, X[here])
    assert not misfit[0]


def test_slots_go_to_the_nearest_identities_within_reach_and_are_forgotten_when_unseen():
    frames = _frames(20)
    memory = _learned(frames, reach_m=0.06, forget_frames=10)
    # Within 6 cm of identity 0 only D (40 mm) is.
    assert set(memory.neighbour[0][memory.neighbour[0] >= 0].tolist()) == {3}
    for X in frames[:12]:  # identity 3 no longer measured with 0
        memory.learn(np.array([0, 1, 2, 4]), X[[0, 1, 2, 4]])
    assert 3 not in memory.neighbour[0]


def test_an_identity_turns_with_its_neighbours():
    """The plate turned 0.5 rad and moved 8 cm between two frames: the turn its three neighbours made carries
    identity 0 from its last place to its new one (to 1e-9 m); with too few neighbours, or one fitting badly, there
    is no turn."""
    memory = _learned(_frames(60))
    turn = 0.5
    R = np.array([[np.cos(turn), 0.0, np.sin(turn)], [0.0, 1.0, 0.0], [-np.sin(turn), 0.0, np.cos(turn)]])
    before = PLATE + [0.0, 0.0, 1.0]
    now = PLATE @ R.T + [0.08, -0.02, 1.03]
    ids = np.array([1, 2, 3])
    ok, turned, a, b = memory.turns(np.array([0]), ids, before[ids], ids, now[ids], 3)
    assert ok[0]
    np.testing.assert_allclose(turned[0] @ (before[0] - a[0]) + b[0], now[0], atol=1e-9)
    # the median translation of the neighbours, which the tracker uses without a turn, is centimetres off
    assert np.linalg.norm(before[0] + np.median(now[ids] - before[ids], axis=0) - now[0]) > 0.01
    assert not memory.turns(np.array([0]), ids, before[ids], ids, now[ids], 4)[0][0]
    bent = now.copy()
    bent[3] += [0.0, 0.03, 0.0]  # one neighbour 3 cm off the plate: 14 mm RMS, over the 10 mm tolerance
    assert not memory.turns(np.array([0]), ids, before[ids], ids, bent[ids], 3)[0][0]


def test_neighbours_in_a_line_give_no_turn():
    """Three neighbours on one line leave the turn about it free: no turn, however well they fit."""
    line = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.05, 0.0], [0.0, 0.15, 0.0], [0.06, 0.02, 0.0]])
    frames = [line + [0.01 * k, 0.0, 1.0] for k in range(30)]
    memory = AttachedDistances(slots=4, reach_m=0.3, tolerance_m=0.01, steady_frames=12, forget_frames=240)
    for X in frames:
        memory.learn(np.arange(5), X)
    ids = np.array([0, 1, 2, 3])
    ok, turned, a, b = memory.turns(np.array([4]), ids, frames[-2][ids], ids, frames[-1][ids], 3)
    assert not ok[0]
    np.testing.assert_array_equal(turned[0], np.eye(3))


def test_a_lost_identity_is_carried_by_the_neighbours_it_had_when_last_seen():
    """Identity 0 (A) is last measured in frame 59; over the next 20 frames its plate goes on turning and moving.
    The neighbours it had then, measured now, carry it to where it is (its last place is centimetres off); with
    fewer of them measured than asked for, or for an identity never seen, it stays where it was last seen."""
    frames = _frames(80)
    memory = _learned(frames[:60])
    for X in frames[60:]:
        memory.learn(np.arange(1, 5), X[1:])
    now = frames[-1]
    last = frames[59][[0, 0]]
    ok, where = memory.carried(np.array([0, 7]), last, np.arange(1, 5), now[1:], 3)
    assert ok.tolist() == [True, False]
    assert np.linalg.norm(where[0] - now[0]) < 0.002 < 0.02 < np.linalg.norm(last[0] - now[0])
    np.testing.assert_array_equal(where[1], last[1])
    ok, where = memory.carried(np.array([0]), last[:1], np.array([1, 2]), now[1:3], 3)
    assert not ok[0] and np.array_equal(where[0], last[0])


def test_an_identity_back_in_view_is_carried_from_its_newest_loss():
    """Lost, found again, lost again: the neighbours' places are those of the last frame before the newest loss."""
    frames = _frames(90)
    memory = _learned(frames[:40])
    for X in frames[40:50]:
        memory.learn(np.arange(1, 5), X[1:])
    for X in frames[50:70]:
        memory.learn(np.arange(5), X)
    for X in frames[70:90]:
        memory.learn(np.arange(1, 5), X[1:])
    ok, where = memory.carried(np.array([0]), frames[69][:1], np.arange(1, 5), frames[-1][1:], 3)
    assert ok[0] and np.linalg.norm(where[0] - frames[-1][0]) < 0.002
