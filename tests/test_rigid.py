"""Distances between identities of finished trajectories (:mod:`mocap.rigid`)."""

from __future__ import annotations

import numpy as np

from mocap import rigid


def test_close_pairs_finds_every_close_pair_of_a_long_take_with_short_lived_identities():
    """Against all pairs compared in every frame: the same (frame, a, b), a < b, in frame order, over spans and
    blocks (identities seen in one span only, one identity through the take, pairs at the gate's edge)."""
    rng = np.random.default_rng(7)
    F, M = 1300, 60  # (spans of 256 frames; most identities live in one or two of them)
    P = np.full((F, M, 3), np.nan)
    for m in range(M):
        start = rng.integers(0, F - 50)
        length = F if m == 0 else rng.integers(20, 400)
        P[start:start + length, m] = rng.uniform(0.0, 0.4, 3) + 0.002 * rng.standard_normal((min(length, F - start),
                                                                                              3)).cumsum(axis=0)
    P[rng.random((F, M)) < 0.05] = np.nan  # (scattered missing samples)
    near = 0.08
    expected = []
    for f in range(F):
        d = np.linalg.norm(P[f, :, None] - P[f, None, :], axis=2)
        a, b = np.nonzero(np.triu(np.nan_to_num(d, nan=np.inf) < near, 1))
        expected += [(f, int(i), int(j)) for i, j in zip(a, b, strict=True)]
    blocks = list(rigid.close_pairs(P, near))
    found = np.concatenate(blocks)
    assert len(expected) > 300
    assert [tuple(map(int, row)) for row in found] == sorted(expected)
    assert (found[:, 1] < found[:, 2]).all()


def test_close_pairs_of_an_empty_take_yield_nothing():
    assert sum(len(block) for block in rigid.close_pairs(np.full((300, 5, 3), np.nan), 0.1)) == 0
    assert list(rigid.close_pairs(np.zeros((0, 5, 3)), 0.1)) == []


def test_jump_starts_in_blocks_of_columns_equal_one_block(monkeypatch):
    """A long take's columns are judged a block at a time: the same jumps and reversals as all at once."""
    rng = np.random.default_rng(11)
    F, M = 400, 37
    P = np.cumsum(rng.normal(0.0, 0.004, (F, M, 3)), axis=0)
    hops = rng.random((F, M)) < 0.02
    P[hops] += rng.normal(0.0, 0.05, (int(hops.sum()), 3))  # (one-frame hops: two large accelerations each)
    P[rng.random((F, M)) < 0.05] = np.nan
    whole = rigid.jump_starts(P, 0.03, 0.02)
    monkeypatch.setattr(rigid, "_JUMP_ENTRIES", 3 * F)  # blocks of 3 columns
    assert whole.sum() > 50
    np.testing.assert_array_equal(rigid.jump_starts(P, 0.03, 0.02), whole)
