"""Distances between identities of finished trajectories, and the rigid structures they show.

Shared by the identity repair's shape passes (:mod:`mocap.reunite`, :mod:`mocap.plates`, :mod:`mocap.anchors`):
markers on one rigid body keep their distances, so the median distance of two identities over the frames both are
seen in, and its robust spread, tell which identities move together; a sample those passes move to another
identity must not make it jump (:func:`placement_jumps`), and the pieces they move are runs of an identity's
samples cut where it jumped (:func:`split_tracklets`).
"""

from __future__ import annotations

import itertools
import warnings
from collections.abc import Iterator

import numpy as np

from mocap import kernels

__all__ = ["PAIRS", "PERMUTATIONS", "close_pairs", "column_runs", "pair_statistics", "placement_jumps", "jump_starts",
           "rigid_triangles", "second_differences", "seen_blocks", "split_tracklets"]

STATISTICS_FRAMES = 4096  # frames per chunk of the co-seen counts, and most frames the distances are taken over
_SPAN_FRAMES = 256  # frames whose seen identities :func:`seen_blocks` gives together
_JUMP_ENTRIES = 1 << 21  # frames x columns per block of :func:`jump_starts` (48 MB per temporary)
_PAIRS_PER_BLOCK = 1 << 21  # identity pairs x frames per block of its all-pairs distances (48 MB of differences)


def pair_statistics(P: np.ndarray, min_frames: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(M, M) median distance m, robust spread m (NaN where seen together in fewer than ``min_frames``
    frames) and co-seen frame count of every pair of identities in ``P`` (F, M, 3).

    The counts are exact; the medians of long takes are taken over every k-th frame (at most
    ``STATISTICS_FRAMES``), which bounds time and memory. With numba, one compiled loop over the pairs
    (:func:`mocap.kernels.pair_distance_statistics`, the same numbers).
    """
    F, M = P.shape[:2]
    count = np.zeros((M, M), dtype=np.int64)
    for start in range(0, F, STATISTICS_FRAMES):  # (frame chunks: the (F, M) product stays small)
        seen = np.isfinite(P[start:start + STATISTICS_FRAMES, :, 0]).astype(np.float32)
        count += np.rint(seen.T @ seen).astype(np.int64)
    sample = P[:: max(1, -(-F // STATISTICS_FRAMES))]
    if kernels.HAVE_NUMBA:
        return (*kernels.pair_distance_statistics(kernels.contiguous(sample), count, min_frames), count)
    median = np.full((M, M), np.nan)
    spread = np.full((M, M), np.nan)
    for a in range(M):
        others = np.flatnonzero(count[a] >= min_frames)
        others = others[others > a]
        if others.size == 0:
            continue
        with np.errstate(invalid="ignore"), warnings.catch_warnings():  # (a pair never seen in the sample: NaN)
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.linalg.norm(sample[:, others] - sample[:, a, None], axis=2)  # (F', n), NaN where either is unseen
            med = np.nanmedian(d, axis=0)
            mad = 1.4826 * np.nanmedian(np.abs(d - med), axis=0)
        median[a, others] = median[others, a] = med
        spread[a, others] = spread[others, a] = mad
    return median, spread, count


def seen_blocks(seen: np.ndarray, entries: int) -> Iterator[tuple[int, int, np.ndarray]]:
    """(start, stop, columns) blocks of frames of ``seen`` (F, M) bool, in frame order, with the columns seen in
    the span of ``_SPAN_FRAMES`` frames the block lies in, (stop - start) x columns^2 at most ``entries`` (one
    frame at least): all-pairs work on a long take follows the identities seen at once, not all of its columns."""
    F = len(seen)
    for span in range(0, F, _SPAN_FRAMES):
        end = min(span + _SPAN_FRAMES, F)
        alive = np.flatnonzero(seen[span:end].any(axis=0))
        block = max(1, entries // max(alive.size ** 2, 1))  # frames
        for start in range(span, end, block):
            yield start, min(start + block, end), alive


def close_pairs(P: np.ndarray, near_m: float) -> Iterator[np.ndarray]:
    """Blocks of (n, 3) frame, a, b (a < b), in frame order: every frame in which identities a and b of ``P``
    (F, M, 3) are both seen and closer than ``near_m`` (m); the identities compared in blocks
    (:func:`seen_blocks`, ``_PAIRS_PER_BLOCK`` pairs x frames at most)."""
    for start, stop, alive in seen_blocks(np.isfinite(P[..., 0]), _PAIRS_PER_BLOCK):
        Q = P[start:stop, alive]
        with np.errstate(invalid="ignore"):  # (NaN where either is missing: never near)
            d = np.linalg.norm(Q[:, :, None] - Q[:, None, :], axis=3)  # (f, A, A)
        f, a, b = np.nonzero(np.triu(d < near_m, 1))
        yield np.stack([f + start, alive[a], alive[b]], axis=1)


def rigid_triangles(rigid: np.ndarray, among: np.ndarray) -> np.ndarray:
    """(T, 3) triples (ascending) of identities in ``among`` whose three pairs are all rigid."""
    sub = rigid[np.ix_(among, among)]
    i, j = np.nonzero(np.triu(sub, 1))
    if i.size == 0:
        return np.zeros((0, 3), dtype=np.intp)
    third = sub[i] & sub[j]  # (pairs, n): rigid with both
    third &= np.arange(len(among))[None, :] > j[:, None]
    p, k = np.nonzero(third)
    return among[np.stack([i[p], j[p], k], axis=1)]


PERMUTATIONS = np.array(list(itertools.permutations(range(3))))  # (6, 3)
PAIRS = np.array([[0, 1], [0, 2], [1, 2]])  # a triangle's three distances


def placement_jumps(P: np.ndarray, rows: np.ndarray, member: np.ndarray, X: np.ndarray, limit: float) -> np.ndarray:
    """(n,) bool: points ``X`` (n, 3) placed in ``P`` (F, M, 3) at (``rows``, ``member``) make an acceleration above
    ``limit``, m/frame^2: with the identity's samples on both sides (one frame away, else two: a marker seen every
    other frame), else the two on one side, else the one next to it or, failing that, the one two frames away (as if
    at rest); False where it has no sample within two frames."""
    F = len(P)

    def at(offset: int) -> np.ndarray:
        f = rows + offset
        inside = (f >= 0) & (f < F)
        out = np.full((len(rows), 3), np.nan)
        out[inside] = P[f[inside], member[inside]]
        return out

    before, after, before2, after2 = at(-1), at(1), at(-2), at(2)
    acc = np.full(len(rows), np.nan)
    for change in (after - 2 * X + before, X - 2 * before + before2, X - 2 * after + after2,
                   (after2 - 2 * X + before2) / 4, X - before, X - after, (X - before2) / 4, (X - after2) / 4):
        acc = np.where(np.isnan(acc), np.linalg.norm(change, axis=1), acc)
    return acc > limit


def jump_starts(P: np.ndarray, split_acc: float, reversal_acc: float = np.inf) -> np.ndarray:
    """(F, M) bool: samples of ``P`` (F, M, 3) whose identity has a sample in the frame before too but jumped to
    them: the acceleration (second difference, m/frame^2) exceeds ``split_acc`` on both samples of the step, or
    ``reversal_acc`` on both with opposite directions. In blocks of columns (``_JUMP_ENTRIES`` frames x columns):
    a long take's thousands of identity columns need no (F, M, 3) temporaries."""
    out = np.zeros(P.shape[:2], dtype=bool)
    block = max(1, _JUMP_ENTRIES // max(1, len(P)))  # columns
    for start in range(0, P.shape[1], block):
        out[:, start:start + block] = _jump_starts(P[:, start:start + block], split_acc, reversal_acc)
    return out


def second_differences(P: np.ndarray) -> np.ndarray:
    """(F, M, 3) the acceleration (second difference) of every sample of ``P`` (F, M, 3), m/frame^2; NaN at the
    ends and next to missing samples."""
    second = np.full(P.shape, np.nan)
    second[1:-1] = P[2:] - 2 * P[1:-1] + P[:-2]
    return second


def _jump_starts(P: np.ndarray, split_acc: float, reversal_acc: float) -> np.ndarray:
    """:func:`jump_starts` of one block of columns."""
    valid = np.isfinite(P[:, :, 0])
    vec = second_differences(P)
    acc = np.zeros(valid.shape)  # (0 where it cannot be computed: no jump)
    acc[1:-1] = np.nan_to_num(np.linalg.norm(vec[1:-1], axis=2))
    with np.errstate(invalid="ignore"):  # (NaN where a sample is missing: no reversal)
        turned = ((acc[:-1] > reversal_acc) & (acc[1:] > reversal_acc)
                  & ((vec[:-1] * vec[1:]).sum(axis=2) < -0.5 * acc[:-1] * acc[1:]))
    out = np.zeros(valid.shape, dtype=bool)
    out[1:] = valid[1:] & valid[:-1] & (((acc[:-1] > split_acc) & (acc[1:] > split_acc)) | turned)
    return out


def column_runs(seen: np.ndarray, jumped: np.ndarray, max_step: int = 1) -> Iterator[tuple[int, np.ndarray]]:
    """(column, frames) of every run of samples of ``seen`` (F, M) bool, column by column in time order: cut where
    two samples are more than ``max_step`` frames apart, and before every sample of ``jumped`` (F, M) bool."""
    for col in range(seen.shape[1]):
        frames = np.flatnonzero(seen[:, col])
        if frames.size == 0:
            continue
        cut = np.flatnonzero((np.diff(frames) > max_step) | jumped[frames[1:], col]) + 1
        for run in np.split(frames, cut):
            yield col, run


def split_tracklets(P: np.ndarray, split_acc: float, reversal_acc: float = np.inf) -> list[np.ndarray]:
    """Cut every identity column into runs of consecutive samples, also where it jumped (:func:`jump_starts`);
    returns (frames, column) index pairs per run."""
    runs = column_runs(np.isfinite(P[:, :, 0]), jump_starts(P, split_acc, reversal_acc))
    return [np.stack([run, np.full(run.size, col)], axis=1) for col, run in runs]
