"""The compiled kernels (:mod:`mocap.kernels`, numba) against the numpy functions they replace.

Every function that switches to a kernel is run on the same seeded inputs with ``kernels.HAVE_NUMBA`` off
(numpy, the reference) and on (compiled): the same numbers to rounding, the same integer and boolean
outputs, NaN in the same places; edge cases included (no tracks, one camera, points the geometry cannot
place). The whole tracker, run both ways, keeps the same state frame after frame.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np
import pytest
from conftest import ring_rig
from helpers_engine import body_take
from scipy import special

from mocap import detect as mocap_detect
from mocap import kernels, rigid
from mocap.attached import AttachedDistances
from mocap.camera import Camera, Lenses
from mocap.detect import (
    FAINT_PIXEL_VAR,
    FALLBACK_PIXEL_VAR,
    _fit_discs,
    _fit_results,
    _groups,
    _label_blobs,
    _neighbour_medians,
    _peaks,
    _tile_medians,
    background_level,
    detect,
)
from mocap.detections import MIN_CENTROID_STD_PX, Detections
from mocap.ekf import ca_process_noise, ca_transition, init_state, predict, update_position
from mocap.fusion import Triangulated, _gauss_newton, repick, robust_triangulate
from mocap.pairs import CameraPairs, camera_pairs
from mocap.stereo import assign, dist2, epipolar_consistency, gate, match_pairs, triangulate_matches
from mocap.synth import SynthSettings
from mocap.synth.render import Sensor, disc_profile
from mocap.tracker import Tracker, _Frame, _Measurements, _Tracks

pytestmark = pytest.mark.skipif(not kernels.HAVE_NUMBA, reason=f"compiled kernels off: {kernels.REASON}")


@pytest.fixture
def both(monkeypatch):
    """``run(fn, *args)``: ``fn`` on copies of ``args``, numpy path then compiled path -> (reference, compiled)."""

    def run(fn, *args):
        out = []
        for on in (False, True):
            monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
            out.append(fn(*copy.deepcopy(args)))
        return out

    return run


def _same(ref, got, rtol: float = 1e-11) -> None:
    """Equal arrays (exactly for integers and booleans; for floats within ``rtol`` times the array's largest
    magnitude, NaN in the same places), tuples and dataclasses field by field."""
    if dataclasses.is_dataclass(ref):
        for f in dataclasses.fields(ref):
            _same(getattr(ref, f.name), getattr(got, f.name), rtol)
    elif isinstance(ref, tuple | list):
        assert len(ref) == len(got)
        for r, g in zip(ref, got, strict=True):
            _same(r, g, rtol)
    else:
        ref, got = np.asarray(ref), np.asarray(got)
        assert ref.shape == got.shape and ref.dtype.kind == got.dtype.kind
        if ref.dtype.kind == "f":
            finite = np.abs(ref[np.isfinite(ref)])
            scale = finite.max() if finite.size else 0.0
            np.testing.assert_allclose(got, ref, rtol=0, atol=rtol * scale)  # (NaN must match NaN, inf inf)
        else:
            np.testing.assert_array_equal(got, ref)


def _projections(P: np.ndarray, X: np.ndarray) -> np.ndarray:
    """(C, K, 2) ideal pixels of points ``X`` (K, 3) through projection matrices ``P`` (C, 3, 4)."""
    h = np.einsum("cij,kj->cki", P, np.concatenate([X, np.ones((len(X), 1))], axis=1))
    return h[..., :2] / h[..., 2:]


def _scene(rng: np.random.Generator, P: np.ndarray, K: int = 40):
    """Detections of K points with every trouble the fusion handles: noise, unseen cameras (0 to C views),
    dragged cameras (a ghost, a merged blob), precise wrong cameras, inflated covariances."""
    C = len(P)
    X = rng.normal(scale=0.3, size=(K, 3)) + [0, 0, 1]
    uv = _projections(P, X) + rng.normal(scale=0.05, size=(C, K, 2))
    cov = np.broadcast_to(np.eye(2) * 0.05**2, (C, K, 2, 2)).copy()
    cov *= rng.uniform(0.5, 2.0, size=(C, K, 1, 1))
    views = rng.integers(0, C + 1, size=K)
    for k in range(K):
        uv[rng.permutation(C)[views[k]:], k] = np.nan
    dragged = rng.random((C, K)) < 0.12
    uv[dragged] += rng.choice([-1.0, 1.0], size=(dragged.sum(), 2)) * rng.uniform(0.5, 6.0, size=(dragged.sum(), 2))
    precise = dragged & (rng.random((C, K)) < 0.5)
    cov[precise] /= 100.0
    cov[rng.random((C, K)) < 0.1] *= 100.0
    start = X + rng.normal(scale=0.005, size=X.shape)
    return X, uv, cov, start


def test_robust_triangulation_is_the_numpy_one(rig, both):
    rng = np.random.default_rng(21)
    P = rig.projection_matrices()
    for _ in range(5):
        _, uv, cov, start = _scene(rng, P)
        ref, got = both(robust_triangulate, P, uv, cov, start, 5.0, 0.3)
        _same(ref, got)
        seen = np.isfinite(uv[..., 0]).T
        assert (seen & ~ref.used & np.isfinite(ref.X[:, :1])).any()  # some cameras were rejected ...
        assert np.isnan(ref.X).any() and np.isfinite(ref.X).any()  # ... some points failed, most did not
    # the same through views: the transposed layouts the tracker passes
    ref, got = both(robust_triangulate, P, uv.swapaxes(0, 1).copy().swapaxes(0, 1), cov, start[:, :3], 6.0, 0.05, 2)
    _same(ref, got)


def test_robust_triangulation_edge_cases(rig, both):
    rng = np.random.default_rng(22)
    P = rig.projection_matrices()
    P[0] = [[1000.0, 0.0, 512.0, 0.0], [0.0, 1000.0, 384.0, 0.0], [0.0, 0.0, 1.0, 0.0]]  # at the origin, looking up
    X, uv, cov, start = _scene(rng, P, K=6)
    _same(*both(robust_triangulate, P, uv[:, :0], cov[:, :0], start[:0], 5.0, 0.3))  # no tracks
    one_camera = both(robust_triangulate, P[:1], uv[:1], cov[:1], start, 5.0, 0.3)  # one camera: no point
    _same(*one_camera)
    assert np.isnan(one_camera[1].X).all() and not one_camera[1].used.any()
    uv[:, 0] = _projections(P, X[:1])[:, 0]
    start[0] = 0.0  # a start at camera 0's centre: 0 / 0 there
    singular = cov.copy()  # zero covariances: infinite weights
    singular[:, 1] = 0.0
    with np.errstate(invalid="ignore", divide="ignore"):  # (the numpy path computes 0 / 0 there)
        ref, got = both(robust_triangulate, P, uv, singular, start, 5.0, 0.3)
    _same(ref, got)
    assert np.isnan(ref.X[:2]).all() and np.isfinite(ref.X[2:]).any()


def test_gauss_newton_kernel_is_the_numpy_one(rig):
    rng = np.random.default_rng(23)
    P = rig.projection_matrices()
    C = len(P)
    for iterations in (1, 3):
        X, uv, cov, start = _scene(rng, P, K=30)
        mask = np.isfinite(uv[..., 0])
        mask[:, :3] = False  # no camera, one camera: the identity stands in for the normal matrix
        mask[0, 1] = True
        uvz = np.where(mask[..., None], uv, 0.0)
        Winv = np.linalg.inv(cov)
        ref = _gauss_newton(P, uvz, Winv * mask[..., None, None], start, iterations)
        K = len(X)
        Xk = start.copy()
        out = np.empty((K, 3, 3)), np.empty((C, K, 2)), np.empty((C, K, 2)), np.empty((C, K))
        kernels.gauss_newton(P, uvz, Winv, mask, np.arange(K), Xk, iterations, 1e-6, *out)
        _same(ref, (Xk, *out))


def test_repick_is_the_numpy_one(rig, both):
    rng = np.random.default_rng(24)
    P = rig.projection_matrices()
    C = len(P)
    for _ in range(5):
        X, uv, cov, start = _scene(rng, P, K=20)
        tri = robust_triangulate(P, uv, cov, start, 5.0, 0.3)
        near = tri.proj[:, rng.permutation(20)[:12]] + rng.normal(scale=0.6, size=(C, 12, 2))
        D = np.concatenate([near, tri.proj[:, :2] + [0.5, 0.0], tri.proj[:, :2] - [0.5, 0.0],  # ties
                            np.full((C, 3, 2), np.nan)], axis=1)
        free = rng.random(D.shape[:2]) < 0.8
        limit = rng.uniform(0.5, 2.0, size=D.shape[:2])
        for lim in (1.0, limit):
            ref, got = both(repick, tri, D, free, lim)
            _same(ref, got)
            assert (ref >= 0).any() and (ref < 0).any()
    empty = Triangulated(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros(0), np.zeros((0, C), dtype=bool),
                         np.zeros((C, 0, 2)), np.zeros((C, 0)))
    _same(*both(repick, empty, D, free, 1.0))
    _same(*both(repick, tri, D, np.zeros_like(free), 1.0))
    # Contested: track 1 is nearer to the blob both want; track 0 then takes nothing (not its second choice).
    proj = np.array([[[100.0, 100.0], [101.0, 100.0], [300.0, 300.0]]])  # (1, 3, 2)
    tri = Triangulated(np.zeros((3, 3)), np.zeros((3, 3, 3)), np.zeros(3), np.array([[False], [False], [True]]),
                       proj, np.ones((1, 3)))
    D = np.array([[[100.6, 100.0], [99.3, 100.0], [300.0, 300.5]]])
    ref, got = both(repick, tri, D, np.ones((1, 3), dtype=bool), 1.0)
    assert ref[:, 0].tolist() == [-1, 0, -1]
    _same(ref, got)


@pytest.mark.parametrize("dims", [2, 3])
def test_filter_prediction_and_update_are_the_numpy_ones(dims, both):
    rng = np.random.default_rng(25 + dims)
    n = 3 * dims
    for damping in (0.0, 0.5, 1.0):
        F, Q = ca_transition(1 / 100, dims, damping), ca_process_noise(1 / 100, dims, 40.0)
        K = 30
        A = rng.normal(size=(K, n, n))
        P = A @ A.transpose(0, 2, 1) + np.eye(n)
        x = rng.normal(size=(K, n))
        Qk = Q * rng.uniform(1.0, 10.0, size=(K, 1, 1))
        for q in (Q, Qk):
            _same(*both(predict, x, P, F, q), rtol=1e-12)
        z = rng.normal(size=(K, dims))
        B = rng.normal(size=(K, dims, dims))
        R = B @ B.transpose(0, 2, 1) * 1e-2 + np.eye(dims) * 1e-4
        _same(*both(update_position, x, P, z, R), rtol=1e-10)
        _same(*both(update_position, x, P, z, R[0]), rtol=1e-10)
    _same(*both(predict, x[:0], P[:0], F, Q))
    _same(*both(update_position, x[:0], P[:0], z[:0], R[:0]))


def test_gate_and_epipolar_pruning_are_the_numpy_ones(rig, both):
    rng = np.random.default_rng(27)
    pairs = camera_pairs(rig)
    P = rig.projection_matrices()
    C = len(P)
    X, uv, cov, _ = _scene(rng, P, K=25)
    choice = uv.swapaxes(0, 1).copy()  # (K, C, 2)
    sigma = rng.uniform(0.02, 0.5, size=choice.shape[:2])
    for s in (None, sigma):
        ref, got = both(epipolar_consistency, pairs, choice, 2.0, s, 4.0)
        _same(ref, got)
        assert (ref[1] & ~ref[0]).any() and ref[0].any()  # some choices fail their partners, most pass
    _same(*both(epipolar_consistency, pairs, choice[:0], 2.0, sigma[:0], 4.0))
    no_pairs = CameraPairs(np.zeros((0, 2), dtype=np.intp), np.zeros((0, 3, 3)), np.zeros(0), np.zeros(0),
                           np.zeros(0, dtype=bool))
    _same(*both(epipolar_consistency, no_pairs, choice, 2.0, sigma, 4.0))
    D = np.concatenate([uv[:, :20] + rng.normal(scale=2.0, size=(C, 20, 2)), np.full((C, 4, 2), np.nan)], axis=1)
    pred = choice.copy()
    radius = rng.uniform(1.0, 5.0, size=pred.shape[:2])
    q = both(gate, pred, radius, D)
    _same(*q)
    assert (q[0] < 1).any() and np.isinf(q[0]).any()
    _same(*both(gate, pred[:0], radius[:0], D))
    _same(*both(gate, pred, radius, D[:, :0]))


def test_new_marker_pair_matching_and_triangulation_are_the_numpy_ones(rig, both):
    """All-pairs epipolar matching of free detections (fresh or not, widened by centroid stds or not) and the
    two-view triangulation of the matches: the same matches in the same order, the same points, covariances and
    residuals; a match whose rays meet nowhere (a camera's own centre) gives NaN on both paths."""
    rng = np.random.default_rng(32)
    pairs = camera_pairs(rig)
    P = rig.projection_matrices()
    C = len(P)
    X, uv, cov, _ = _scene(rng, P, K=30)
    D = np.concatenate([uv, np.full((C, 3, 2), np.nan)], axis=1)  # (C, N, 2) with padding
    S = np.concatenate([cov, np.broadcast_to(np.eye(2), (C, 3, 2, 2))], axis=1)
    free = np.isfinite(D[..., 0]) & (rng.random(D.shape[:2]) < 0.8)
    fresh = free & (rng.random(D.shape[:2]) < 0.5)
    sigma = np.sqrt(0.5 * (S[..., 0, 0] + S[..., 1, 1]))
    for fr, s in ((None, None), (fresh, None), (fresh, sigma), (None, sigma)):
        ref, got = both(match_pairs, pairs, D, free, 2.0, fr, s, 4.0)
        _same(ref, got)
        assert len(ref[0]) > 20 and (ref[3] > 0.5).any()  # true matches and chance ones
        tri = both(triangulate_matches, P, pairs, D, S, *ref[:3])
        _same(*tri, rtol=1e-9)
        assert np.isfinite(tri[0][0]).all()
    _same(*both(match_pairs, pairs, D, np.zeros_like(free), 2.0, fresh, sigma, 4.0))  # nothing free
    _same(*both(match_pairs, pairs, D[:, :0], free[:, :0], 2.0, fresh[:, :0], sigma[:, :0], 4.0))  # no detections
    pair, n1, n2, _ = match_pairs(pairs, D, free, 2.0)
    centre = -np.linalg.solve(P[pairs.index[pair[0], 0], :, :3], P[pairs.index[pair[0], 0], :, 3])
    D[pairs.index[pair[0], 1], n2[0]] = _projections(P, centre[None])[pairs.index[pair[0], 1], 0]  # the epipole
    with np.errstate(invalid="ignore", divide="ignore"):
        tri = both(triangulate_matches, P, pairs, D, S, pair, n1, n2)
    _same(*tri, rtol=1e-9)
    assert np.isnan(tri[0][0][0]).all() and np.isfinite(tri[0][0][1:]).all()


def test_assignment_is_the_numpy_one(both):
    """Random gates from empty to crowded: the same detections chosen, the contested ones as the unambiguous."""
    rng = np.random.default_rng(31)
    contested = 0
    for reach in (0.3, 1.0, 1.6, 3.0):
        K, C, N = 12, 4, 9
        q = rng.uniform(0.0, reach, size=(K, C, N))
        q[rng.random(q.shape) < 0.1] = np.inf
        eligible = rng.random((C, N)) < 0.85
        ref, got = both(assign, q, eligible)
        _same(ref, got)
        _same(*both(assign, q))
        contested += int((((q < 1) & eligible).sum(axis=2) > 1).sum())
        assert (ref >= 0).any()
    assert contested > 0
    _same(*both(assign, np.zeros((0, 3, 4)), None))
    _same(*both(assign, np.zeros((3, 2, 0)), None))


def _random_tracker(rig, K: int, seed: int) -> Tracker:
    """A tracker whose K live tracks have random, plausible states (the same for the same seed)."""
    rng = np.random.default_rng(seed)
    C = len(rig)
    tracker = Tracker(rig, 100.0)
    P = rig.projection_matrices()
    X = rng.normal(scale=0.3, size=(K, 3)) + [0, 0, 1]
    x3, P3 = init_state(X, np.broadcast_to(np.eye(3) * 1e-6, (K, 3, 3)), rng.normal(scale=1.0, size=(K, 3)), 1.0,
                        30.0)
    uv = _projections(P, X).swapaxes(0, 1)  # (K, C, 2)
    vel2 = rng.normal(scale=300.0, size=(K, C, 2))
    x2, P2 = init_state(uv.reshape(-1, 2) + 0.3, np.broadcast_to(np.eye(2) * 0.01, (K * C, 2, 2)), vel2.reshape(-1, 2),
                        1e3, 1e5)
    last_v = rng.normal(size=(K, 3))
    last_v[rng.random(K) < 0.3] = np.nan
    tracker._t = _Tracks(np.arange(K), np.where(rng.random(K) < 0.8, np.arange(K), -1), np.full(K, -1),
                         rng.integers(1, 10, size=K), rng.choice([0, 1, 1, 1, 2, 5], size=K), x3, P3,
                         rng.uniform(1e-4, 1e-2, size=(K, 3)), X + rng.normal(scale=0.003, size=(K, 3)), last_v,
                         x2.reshape(K, C, 6), P2.reshape(K, C, 6, 6), rng.random((K, C)) < 0.7,
                         rng.integers(0, 20, size=(K, C)), rng.uniform(0.05, 3.0, size=(K, C, 3)),
                         uv - vel2 / 100.0, vel2 + rng.normal(scale=10.0, size=(K, C, 2)), np.zeros(K, dtype=bool),
                         X.copy(), rng.uniform(1e-5, 1e-3, size=K), np.full((K, C, 7), np.nan),
                         rng.integers(0, 5, size=(K, C)), rng.integers(0, 5, size=(K, C)),
                         rng.integers(0, 5, size=(K, C)))
    if K:  # one track behind camera 0
        tracker._t.x3[0, :3] = -np.linalg.solve(P[0, :, :3], P[0, :, 3]) - 0.5 * P[0, 2, :3]
    tracker._expect = tracker._expected_blobs()
    tracker._assigned_blobs = np.zeros((K, C), dtype=bool)
    return tracker


@pytest.mark.parametrize("K", [0, 1, 30])
def test_tracker_search_regions_crowding_and_update_are_the_numpy_ones(K, monkeypatch):
    rig = ring_rig()
    C = len(rig)
    rng = np.random.default_rng(28 + K)
    lock = rng.random((K, C)) < 0.6
    play = rng.random(K) < 0.9
    N = 2 * K + 3
    D = rng.uniform([0, 0], [1024, 768], size=(C, N, 2))
    D[:, N - 2:] = np.nan
    A = rng.normal(size=(C, N, 2, 2))
    S = A @ A.transpose(0, 1, 3, 2) * 0.01 + np.eye(2) * 1e-4
    fr = _Frame(D, S, np.isfinite(D[..., 0]), np.zeros((C, N), dtype=bool), rng.uniform(0.7, 1.0, size=(C, N)),
                rng.uniform(3, 35, size=(C, N)), rng.uniform(300, 5000, size=(C, N)), [N] * C)
    asg = np.where(rng.random((K, C)) < 0.7, rng.integers(0, N, size=(K, C)), -1)
    asg[:, -1] = -1  # one camera saw none of them
    meas = _Measurements.empty(K, C)
    meas.asg = asg
    meas.X = rng.normal(scale=0.3, size=(K, 3)) + [0, 0, 1]
    B = rng.normal(size=(K, 3, 3))
    meas.cov = B @ B.transpose(0, 2, 1) * 1e-8 + np.eye(3) * 1e-10
    idx = np.flatnonzero(rng.random(K) < 0.8)
    results = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        tracker = _random_tracker(rig, K, seed=K)
        pred, radius, depth = tracker._search_regions(lock)
        crowded = tracker._crowded(pred, play, depth, asg)
        tracker._update(fr, copy.deepcopy(meas), idx)
        results.append(((pred, radius, depth), crowded, tracker._t))
    _same(*results, rtol=1e-10)
    (pred, radius, depth), crowded, _ = results[0]
    if K > 1:  # crowded tracks, a track behind a camera, image filters' and projected predictions
        front = lock & (depth > 0)
        x2 = _random_tracker(rig, K, seed=K)._t.x2
        assert crowded.any() and np.isnan(pred[~(depth > 0)]).all() and (pred[front] == x2[front][:, :2]).all()


def _measurement_scene(K: int):
    """A tracker of K tracks and a frame for its measurement: detections at the tracks' projections (with noise),
    some swapped for another track's or a random point, crowded views, merged blobs, cameras without a view and
    free detections near the tracks' unused cameras. Returns (tracker, frame, asg (K, C), crowded (K, C))."""
    rig = ring_rig()
    C = len(rig)
    rng = np.random.default_rng(40 + K)
    tracker = _random_tracker(rig, K, seed=K)
    X = tracker._t.last_X.copy()
    if K > 3:  # two tracks 5 mm apart: one takes the other's blob where the other has none (not free for a re-pick)
        X[K - 3] = X[K - 2] + [0.005, 0.0, 0.0]
        tracker._t.x3[K - 3, :3] = X[K - 3]
    uv = _projections(rig.projection_matrices(), X)  # (C, K, 2)
    N = K + 4
    D = np.full((C, N, 2), np.nan)
    D[:, :K] = uv + rng.normal(scale=0.3, size=uv.shape)
    D[:, K:K + 2] = rng.uniform([0, 0], [1024, 768], size=(C, 2, 2))
    if K:
        D[:, K + 2] = uv[:, -1] + rng.normal(scale=0.5, size=(C, 2))  # a free blob by the last track's image
    A = rng.normal(size=(C, N, 2, 2))
    S = A @ A.transpose(0, 1, 3, 2) * 0.02 + np.eye(2) * 0.01
    merged = rng.random((C, N)) < 0.1
    fr = _Frame(D, S, np.isfinite(D[..., 0]), merged, np.ones((C, N)), np.full((C, N), 15.0), np.full((C, N), np.nan),
                [N] * C)
    asg = np.where(rng.random((K, C)) < 0.8, np.arange(K)[:, None], -1)
    asg[rng.random((K, C)) < 0.1] = K  # a random blob
    if K > 1:
        asg[0, :2] = 1  # another track's blobs
        asg[-1] = np.where(np.arange(C) < 3, K - 1, -1)  # the last track seen by three cameras only
    if K > 3:
        asg[K - 3, 0], asg[K - 2, 0] = K - 2, -1
    crowded = rng.random((K, C)) < 0.3
    return tracker, fr, asg, crowded


@pytest.mark.parametrize("K", [0, 1, 14])
def test_tracker_measurement_of_its_views_is_the_numpy_one(K, monkeypatch):
    """Epipolar pruning, robust triangulation and re-pick in one kernel (``kernels.measure_views``) on
    :func:`_measurement_scene`."""
    tracker, fr, asg, crowded = _measurement_scene(K)
    results = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        a = asg.copy()
        tri, extra, sigma = tracker._triangulate_views(fr, crowded, a)
        results.append((tri, extra, sigma, a))
    _same(*results, rtol=1e-10)
    tri, extra, _, a = results[0]
    if K > 1:  # points made, views dropped, a free blob re-picked
        assert np.isfinite(tri.X).all(axis=1).sum() >= K // 2 and (a < asg).any() and (extra >= 0).any()


@pytest.mark.parametrize("K", [0, 1, 14])
def test_tracker_measurement_verdicts_are_the_numpy_ones(K, monkeypatch):
    """The whole measurement of :func:`_measurement_scene` (``Tracker._measure``): the same points, and the same
    verdicts on them (``kernels.measured_points``: finite, output or withheld for leaning on merged or crowded
    views)."""
    tracker, fr, asg, crowded = _measurement_scene(K)
    rng = np.random.default_rng(K)
    tracker._t.x3[:, :3] += rng.normal(scale=0.002, size=(K, 3))  # predictions a few mm off the points ...
    tracker._t.e3[:, 0] = rng.uniform(0.0, 0.01, K)  # ... gates below the bounds, between and above
    crowded |= rng.random(crowded.shape) < 0.5  # views left clean: none, one or more
    results = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        meas = _Measurements.empty(K, len(fr.D))
        meas.asg[:] = asg
        tracker._measure(fr, crowded, meas)
        results.append(meas)
    _same(*results, rtol=1e-10)
    if K > 1:  # some points output, some withheld
        assert results[0].out.any() and (results[0].ok & ~results[0].out).any()


@pytest.mark.parametrize("explained_px", [0.4, 400.0])
def test_two_view_ghosts_explained_elsewhere_are_the_numpy_ones(explained_px, monkeypatch):
    """Which two-view points another point's third view refutes (``kernels.explained_elsewhere``), on the points of
    :func:`_measurement_scene` (some dropped to two views, one put on another point's ray in a camera that point is
    not seen in); with a 400 px reach most points explain each other's blobs, mutual pairs included."""
    tracker, fr, asg, crowded = _measurement_scene(14)
    tracker._cfg = dataclasses.replace(tracker._cfg, explained_px=explained_px)
    meas = _Measurements.empty(14, len(fr.D))
    meas.asg[:] = asg
    tracker._measure(fr, crowded, meas)
    rng = np.random.default_rng(5)
    two = np.flatnonzero(meas.ok)[:6]
    for k in two:  # two views left
        seen = np.flatnonzero(meas.asg[k] >= 0)
        meas.asg[k, seen[2:]] = -1
    meas.out[rng.random(14) < 0.2] = False
    p, q = two[0], np.flatnonzero(meas.ok & meas.out & ((meas.asg >= 0).sum(axis=1) >= 3))[0]
    c = int(np.flatnonzero(meas.asg[p] >= 0)[0])
    fr.merged[c, meas.asg[p, c]] = False
    meas.asg[q, c] = -1
    eye = -np.linalg.solve(tracker._P[c, :, :3], tracker._P[c, :, 3])
    meas.X[q] = eye + 1.3 * (meas.X[p] - eye)  # behind p on camera c's ray: its image there is p's
    fr.D[c, meas.asg[p, c]] = tracker._P[c, :2] @ np.r_[meas.X[p], 1.0] / (tracker._P[c, 2] @ np.r_[meas.X[p], 1.0])
    results = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        results.append(tracker._explained_elsewhere(fr, meas))
    np.testing.assert_array_equal(results[1], results[0])
    assert results[0][p]
    if explained_px > 100:
        assert results[0].sum() < (meas.ok & ((meas.asg >= 0).sum(axis=1) == 2)).sum()  # mutual pairs kept


def test_partly_hidden_views_and_the_running_blobs_are_the_numpy_ones(monkeypatch):
    """Which views show their marker partly hidden (``kernels.partly_hidden``, against ``kernels.expected_blobs``)
    and the running blob averages (``kernels.follow_blobs``), on random blobs against a random tracker's: some
    smaller, darker or flatter than expected, some merged, some tracks with no blob yet in a camera, some blobs or
    tracks with no light known; the light scaled to depth by a fitted power, and that fit's sums."""
    rig = ring_rig()
    C, K, N = len(rig), 30, 12
    rng = np.random.default_rng(41)
    tracker = _random_tracker(rig, K, seed=7)
    blob = rng.uniform([4.0, 0.8, 3.0, 500.0, 0.0, 500.0, 3.0], [30.0, 1.0, 6.0, 5000.0, 0.05, 5000.0, 6.0],
                       (K, C, 7))
    blob[rng.random((K, C)) < 0.2, 3:] = np.nan  # (no light known)
    blob[rng.random((K, C)) < 0.1, 4] = np.nan  # (no deviation yet)
    tracker._t.blob = np.where(rng.random((K, C, 1)) < 0.8, blob, np.nan)
    tracker._light_power = 2.6  # (as fitted to another renderer's blobs)
    tracker._light_fit = np.array([0.5, -1.3])
    D = rng.uniform([0, 0], [1024, 768], size=(C, N, 2))
    flux = np.where(rng.random((C, N)) < 0.8, rng.uniform(100.0, 8000.0, (C, N)), np.nan)
    fr = _Frame(D, np.broadcast_to(np.eye(2) * 0.01, (C, N, 2, 2)).copy(), np.ones((C, N), dtype=bool),
                rng.random((C, N)) < 0.1, rng.uniform(0.5, 1.0, (C, N)), rng.uniform(2.0, 35.0, (C, N)), flux,
                [N] * C)
    views = rng.permutation(K * C)[:120]  # distinct (track, camera) pairs: each running average steps once
    tracks, cams, blobs = views // C, views % C, rng.integers(0, N, 120)
    results = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        t = copy.deepcopy(tracker)
        t._expect = t._expected_blobs()
        hidden = t._partly_hidden(fr, tracks, cams, blobs)
        t._follow_blobs(fr, tracks, cams, blobs)
        results.append((t._expect, hidden, t._t.blob, t._t.cut_run, t._t.dark_run, t._light_fit))
    _same(*results, rtol=1e-12)
    assert results[0][5][0] > 0.5  # (successive clean views added to the light's fit)
    hidden = results[0][1]
    assert 0 < hidden.sum() < len(hidden) and not hidden[fr.merged[cams, blobs]].any()
    moved = np.isfinite(results[0][2][tracks, cams, 0]) & ~np.isfinite(tracker._t.blob[tracks, cams, 0])
    assert moved.any()  # (a track's first blob in a camera starts its average)
    assert 0 < results[0][4][tracks, cams].sum()  # (some judged darker)


def test_the_tracker_keeps_the_same_state_on_both_paths(monkeypatch):
    """A marching body with ghosts, a camera black for a while and one broken throughout, blobs carrying their
    light and some of it halved (a marker partly hidden): after every frame the same tracks (identities, counters,
    locks, filters, running errors) and the same output, and the same points withheld from the written output."""
    take = body_take(frames=90, fps=120.0, markers=20, seed=3, settings=SynthSettings(seed=3, ghosts=4))
    rng = np.random.default_rng(12)
    cut = [[rng.random(len(d)) < 0.05 for d in dets] for dets in take.frames]  # (half the light, 1 px off)
    frames = [[Detections(d.xy + np.where(h, 1.0, 0.0)[:, None], np.maximum(d.area, 20.0), d.roundness, d.cov,
                          d.merged, 2000.0 * rng.normal(1.0, 0.01, len(d)) * np.where(h, 0.5, 1.0))
               for d, h in zip(dets, hit, strict=True)] for dets, hit in zip(take.frames, cut, strict=True)]
    for k, dets in enumerate(frames):
        dets[5] = Detections.empty()
        if 30 <= k < 50:
            dets[2] = Detections.empty()
    trackers = []
    for on in (False, True):
        monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
        trackers.append(Tracker(take.rig, take.truth.fps))
    for k, dets in enumerate(frames):
        out = []
        for on, tracker in zip((False, True), trackers, strict=True):
            monkeypatch.setattr(kernels, "HAVE_NUMBA", on)
            out.append(tracker.step(k, dets))
        _same(out[0], out[1], rtol=1e-9)
        np.testing.assert_allclose(out[1].positions, out[0].positions, rtol=0, atol=1e-12)  # m
        _same(trackers[0]._t, trackers[1]._t, rtol=1e-9)
    assert len(trackers[0]._t) >= 20 and trackers[0].finish().n_markers == 20
    trackers[1].finish()
    withheld = [tracker.withheld() for tracker in trackers]
    _same(withheld[0], withheld[1], rtol=1e-9)
    assert len(withheld[0].rows) > 0  # (two-view points leaning on views judged darker)


def _blob_frame(rng: np.random.Generator) -> np.ndarray:
    """A 480x640 frame with what the detector fits: isolated markers 2-7 px across at various brightness (some
    saturated), touching pairs and triples (fitted as two or more discs), and large reflections."""
    sensor = Sensor()
    image = sensor.background_frame((480, 640), rng)
    uv = np.c_[rng.uniform(10, 630, 40), rng.uniform(10, 470, 40)]
    radius = rng.uniform(1.0, 3.5, 40)
    amplitude = rng.uniform(40.0, 900.0, 40)
    pairs = uv[:8, None] + rng.uniform(2.0, 4.0, (8, 1, 1)) * np.array([[[0.0, 0.0], [1.0, 0.3]]])
    sensor.draw(image, np.r_[uv, pairs.reshape(-1, 2), uv[8:10] + [3.0, -2.0]],
                np.r_[radius, np.full(16, 1.75), np.full(2, 1.5)], np.r_[amplitude, np.full(18, 200.0)], rng)
    sensor.draw(image, np.c_[rng.uniform(20, 620, 2), rng.uniform(20, 460, 2)], np.full(2, 8.0), np.full(2, 250.0), rng)
    return image


def test_detection_fit_kernel_is_the_numpy_one(both):
    """The compiled disc fit runs in float64, the numpy one's pixel arithmetic in float32: the same blobs, split
    alike, centres within 1e-6 px for half of them, 2e-4 px for 99 % and 2e-3 px for all (a saturated disc's and a
    split blob's fits are the most sensitive to the float32 sums; the centres' Cramer-Rao bound is ~5e-3 px),
    covariances within 2 %."""
    rng = np.random.default_rng(11)
    frames = [_blob_frame(rng) for _ in range(6)]
    ref, got = both(lambda images: [detect(im) for im in images], frames)
    assert sum(len(d) for d in ref) > 240
    dxy = []
    for r, g in zip(ref, got, strict=True):
        assert len(r) == len(g)
        np.testing.assert_array_equal(r.merged, g.merged)
        np.testing.assert_array_equal(r.area, g.area)
        dxy.append(np.abs(r.xy - g.xy).max(axis=1))
        np.testing.assert_allclose(g.cov, r.cov, rtol=0, atol=0.02 * np.abs(r.cov).max())
    dxy = np.concatenate(dxy)
    assert np.median(dxy) < 1e-6 and np.percentile(dxy, 99) < 2e-4 and dxy.max() < 2e-3
    assert (np.concatenate([d.roundness for d in ref]) == 1.0).sum() >= 2  # a split fit was exercised (parts: 1.0)


def test_detection_fit_checks_are_the_numpy_ones(both):
    """The checks of fitted discs (fallback to the start where a fit failed): the same centres, covariances and
    failures, for one disc and for three, on fits that are fine, not finite (a NaN radius alone fails nothing, as
    with np.maximum), not positive, vague, or that wandered off their start."""
    rng = np.random.default_rng(23)
    for k in (1, 3):
        n = 400
        start = np.c_[rng.normal(0, 1, n), rng.uniform(-3, 3, (n, 5 * k))]
        start[:, 4::5] = rng.uniform(0.5, 3.0, (n, k))  # radii
        params = start + rng.normal(0, 0.6, start.shape)  # some wander beyond 1.5 px
        a = rng.uniform(1e-4, 0.05, (n, 2 * k))
        pcov = np.einsum("ni,ij->nij", a, np.eye(2 * k)) + 0.3 * np.sqrt(a[:, :, None] * a[:, None, :]) * (
            1 - np.eye(2 * k))
        centroid_cov = np.einsum("n,ij->nij", rng.uniform(0.001, 0.01, n), np.eye(2))
        params[::17, 1] = np.nan  # not finite
        params[5::23, 4] = np.nan  # a NaN radius only
        pcov[3::19, 0, 0] = -1e-3  # not positive
        pcov[7::29, 1, 1] = 5.0  # vague
        pcov[11::31, 0, 1] = pcov[11::31, 1, 0] = 1.0  # not positive definite
        origin = rng.integers(0, 600, (n, 2)).astype(np.int64)
        pixel_var = rng.choice([FALLBACK_PIXEL_VAR, FAINT_PIXEL_VAR], n)
        ref, got = both(_fit_results, params, pcov, start, origin, centroid_cov, 2.3, k, pixel_var)
        _same(ref, got, rtol=0)
        assert 0.1 < ref[2].mean() < 0.9  # both kinds of disc exercised


def test_the_cut_disc_fit_kernel_is_the_numpy_one(both, monkeypatch):
    """Markers partly hidden by a straight edge (half a radius out or through the centre, 1.5-4 px radius, some
    saturated) among whole ones: both paths refit the same blobs as cut discs, to the same centres and covariances
    (the fits' sums run in another order: centres within 2e-3 px, most to 1e-6)."""
    monkeypatch.setattr(mocap_detect, "CUT_FIT", True)  # (off by default)
    rng = np.random.default_rng(29)
    sensor = Sensor()
    frames, truth, cut = [], [], []
    for _ in range(3):
        uv = np.c_[rng.uniform(15, 625, 60), rng.uniform(15, 465, 60)]
        uv = uv[(np.linalg.norm(uv[:, None] - uv[None], axis=2) + 1e3 * np.eye(len(uv))).min(axis=1) > 15]
        radius, amplitude = rng.uniform(1.5, 4.0, len(uv)), rng.uniform(60.0, 600.0, len(uv))
        edge = np.where(rng.random(len(uv)) < 0.5, rng.choice([0.0, 0.5], len(uv)), np.inf) * radius
        angle = rng.uniform(0, 2 * np.pi, len(uv))
        x, y, rho = sensor._patches(uv, radius)
        along = ((x - uv[:, 0, None, None]) * np.cos(angle)[:, None, None]
                 + (y - uv[:, 1, None, None]) * np.sin(angle)[:, None, None])
        signal = (amplitude[:, None, None] * disc_profile(rho, radius[:, None, None], sensor.sigma)
                  * special.ndtr((edge[:, None, None] - along) / sensor.sigma))
        image = sensor.background_frame((480, 640), rng).astype(np.float64)
        np.add.at(image, (y, x), signal)  # (the patches lie inside the frame)
        frames.append(np.clip(np.rint(image), 0, 255).astype(np.uint8))
        truth.append(uv)
        cut.append(np.isfinite(edge))
    ref, got = both(lambda images: [detect(im) for im in images], frames)
    errors = []
    for r, g, uv, hidden in zip(ref, got, truth, cut, strict=True):
        assert len(r) == len(g)
        np.testing.assert_array_equal(r.merged, g.merged)
        dxy = np.abs(r.xy - g.xy).max(axis=1)
        assert np.median(dxy) < 1e-6 and dxy.max() < 2e-3  # (a slow fit's last steps: 1e-4 px at most seen)
        np.testing.assert_allclose(g.cov, r.cov, rtol=0, atol=0.02 * np.abs(r.cov).max())
        distance = np.linalg.norm(uv[hidden, None] - r.xy[None], axis=2).min(axis=1)
        errors.append(distance)
    errors = np.concatenate(errors)
    assert len(errors) > 60 and np.median(errors) < 0.05  # (measured as cut discs: 0.2-0.42 radius off as whole ones)


def test_faint_markers_in_heavy_noise_are_found_alike(both):
    """Noise 6 and blur 1.5 px: an eighth of the markers are found only in the 3x3 mean image; both paths find the
    same blobs, in the same order, at the same centres (the fits' float32 / float64 arithmetic aside)."""
    rng = np.random.default_rng(19)
    sensor = Sensor(noise=6.0, blur_px=1.5)
    frames = []
    for _ in range(4):
        image = sensor.background_frame((480, 640), rng)
        uv = np.c_[rng.uniform(5, 635, 150), rng.uniform(5, 475, 150)]
        sensor.draw(image, uv, rng.uniform(0.8, 2.0, 150), rng.uniform(60.0, 400.0, 150), rng)
        frames.append(image)
    ref, got = both(lambda images: [detect(im) for im in images], frames)
    for r, g in zip(ref, got, strict=True):
        assert len(r) == len(g) > 100
        np.testing.assert_array_equal(g.area, r.area)
        np.testing.assert_array_equal(g.merged, r.merged)
        assert np.quantile(np.abs(g.xy - r.xy).max(axis=1), 0.99) < 2e-3


def test_background_tiles_levels_are_the_numpy_ones(both):
    """The levelling's tile medians and noise (every 8th and every 4th pixel): the same on both paths, on a lit ramp,
    a bright centre, a level frame, pure noise and frames whose sides are not multiples of a tile."""
    rng = np.random.default_rng(23)
    h, w = 480, 640
    yy, xx = np.mgrid[0:h, 0:w]
    ramp = 12 + 60.0 * xx / w
    centre = 12 + 60.0 * np.exp(-((xx - w / 2) ** 2 + (yy - h / 2) ** 2) / (2 * 150.0**2))
    frames = [np.clip(np.rint(base + rng.normal(0, 2, (h, w))), 0, 255).astype(np.uint8) for base in (ramp, centre)]
    frames += [np.full((h, w), 12, np.uint8), rng.integers(0, 256, (h, w), dtype=np.uint8),
               rng.integers(0, 256, (37, 301), dtype=np.uint8), rng.integers(0, 40, (130, 70), dtype=np.uint8)]
    for step in (8, 4):
        ref, got = both(lambda images, k: [_tile_medians(im, k) for im in images], frames, step)
        for (r_med, r_sigma), (g_med, g_sigma) in zip(ref, got, strict=True):
            np.testing.assert_array_equal(g_med, r_med)
            assert g_sigma == r_sigma


def test_detection_fit_kernel_on_a_degenerate_window(both):
    """A window of one pixel cannot fix a disc's six parameters: neither path fails, and what they return is
    finite (the fit's checks in ``_measure`` then fall back to the weighted centroid; an ill-posed fit's numbers
    need not agree)."""
    values, ox, oy = np.array([50.0], np.float32), np.array([0.0], np.float32), np.array([0.0], np.float32)
    params = np.array([[0.0, 0.1, -0.1, 60.0, 1.5, 0.5]])
    for out in both(lambda: _fit_discs(values, ox, oy, np.zeros(1, np.intp), np.zeros(1, np.intp), params, 2)):
        assert out[0].shape == (1, 6) and out[1].shape == (1, 2, 2)
        assert np.isfinite(out[0]).all() and np.isfinite(out[1]).all()


def test_detection_labelling_and_blob_sums_are_the_numpy_ones(both):
    """The compiled labelling (flood fill in the frame) finds the numpy mosaic's blobs in the same order, with the
    same pixels: with the weighted centroid (no fit), detections agree to rounding, full frame and in boxes, and
    blobs cut by the image border or by a box's edge included."""
    rng = np.random.default_rng(12)
    frames = [_blob_frame(rng) for _ in range(4)]
    border = frames[0].copy()
    border[:3, 100:110] = border[200:206, :4] = border[-2:, -5:] = 255  # blobs on the edges and in the corner
    frames.append(border)
    rois = np.array([[0, 0, 300, 200], [250, 150, 639, 479], [600, 0, 700, 50]])
    found = []
    for kwargs in ({"refine": "centroid"}, {"refine": "centroid", "rois": rois}):
        ref, got = both(lambda images, kw: [detect(im, **kw) for im in images], frames, kwargs)
        for r, g in zip(ref, got, strict=True):
            _same(r, g, rtol=1e-12)
        found.append(sum(len(d) for d in ref))
    assert found[0] > 200 and 60 < found[1] < found[0]


def test_detection_neighbour_medians_are_the_numpy_ones(both):
    """The medians of the blobs' nearest neighbours' areas and fluxes (where oversized and overbright blobs are told):
    the same k nearest, ties of distance to the lower index, on random centres and on an integer grid (many ties),
    with infinite values among them and fewer blobs than k + 1."""
    rng = np.random.default_rng(21)
    for trial in range(200):
        n = int(rng.integers(3, 60))
        xy = rng.integers(0, 12, (n, 2)).astype(float) if trial % 2 else rng.uniform(0, 1000, (n, 2))
        values = rng.uniform(1, 100, (n, 2))
        values[rng.random(values.shape) < 0.1] = np.inf
        _same(*both(_neighbour_medians, xy, values), rtol=0)


def test_detection_peaks_are_the_numpy_ones(both):
    """The compiled search for the significant maxima of blobs (where merged markers are split) finds the numpy
    one's, in the same order, on every blob of frames with touching pairs, triples and large reflections."""
    rng = np.random.default_rng(13)
    faint = Sensor().background_frame((480, 640), rng)  # faint touching pairs: dips near the noise's threshold
    centres = np.c_[rng.uniform(20, 620, 60), rng.uniform(20, 460, 60)]
    Sensor().draw(faint, np.r_[centres, centres + rng.uniform(2.0, 4.5, (60, 1)) * [1.0, 0.4]], np.full(120, 1.6),
                  rng.uniform(15.0, 60.0, 120), rng)
    found = 0
    for image in [_blob_frame(rng) for _ in range(4)] + [faint]:
        level, sigma = background_level(image)
        t = int(level + max(6 * sigma, 8))
        pixels, _, starts = _label_blobs(image, t, *_groups(image, t, None))
        every = np.arange(len(starts))
        ref, got = both(_peaks, image, pixels, starts, every, level, sigma)
        _same(ref, got, rtol=0)
        found += int((np.bincount(ref[0]) >= 2).sum())
        _same(*both(_peaks, image, pixels, starts, every[1::3], level, sigma), rtol=0)  # some of the blobs
    assert found >= 4  # blobs with two or more significant maxima (touching markers)


@pytest.mark.parametrize("shape", [(480, 640), (203, 317)])
def test_coarse_groups_and_background_are_the_numpy_ones(shape, both):
    """The compiled coarse pass (4x4 cell maxima, 8-connected groups of cells) labels the groups as OpenCV's Grana
    algorithm does, boxes and order included, on sparse and crowded random frames, with the image's last cells cut
    by its border and with boxes; the compiled histogram gives the same background level and noise."""
    rng = np.random.default_rng(14)
    for density in (0.002, 0.02, 0.2):
        image = rng.integers(0, 30, shape, dtype=np.uint8)
        image[rng.random(shape) < density] = 200
        image[-1, -1] = image[0, -1] = image[-1, 0] = 255
        rois = np.array([[0, 0, 100, 80], [150, 120, shape[1] - 1, shape[0] - 1]])
        for boxes in (None, rois):
            ref, got = both(_groups, image, 100, boxes)
            _same(ref, got, rtol=0)
        assert len(ref[1]) > (30 if density < 0.1 else 0)
        _same(*both(background_level, image), rtol=0)


def test_undistortion_is_opencvs(both):
    """The compiled undistortion (all cameras of a frame in one call) gives OpenCV's ``undistortPoints`` within
    1e-9 px: 4, 5 and 8 coefficients, strong lenses, points far outside the image (where OpenCV's iteration is
    damped or gives up), NaN rows and a camera without distortion."""
    rng = np.random.default_rng(15)
    cameras, points = [], []
    for n in (4, 5, 8, 5, 0):
        dist = np.zeros(max(n, 4))
        dist[:n] = rng.normal(0.0, [0.2, 0.1, 0.002, 0.002, 0.05, 0.1, 0.05, 0.02][:n])
        f = rng.uniform(600.0, 2000.0)
        matrix = np.array([[f, 0.0, rng.uniform(400, 600)], [0.0, f * rng.uniform(0.98, 1.02), 350.0], [0, 0, 1]])
        cameras.append(Camera(f"c{len(cameras)}", (1024, 768), matrix, dist, np.zeros(3), np.zeros(3)))
        uv = np.c_[rng.uniform(-300, 1300, 400), rng.uniform(-300, 1000, 400)]
        uv[::37] = np.nan
        points.append(uv)
    ref, got = both(lambda: Lenses(cameras).undistort(points))
    assert np.array_equal(np.isnan(ref), np.isnan(got)) and np.isnan(ref).any()
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)
    assert np.array_equal(got[-400:], points[-1], equal_nan=True)  # no distortion: the points themselves
    far = np.abs(ref - np.concatenate(points)).max(axis=1)
    assert np.nanmax(far) > 100.0  # strong lenses were exercised


def test_detection_on_small_random_frames_is_the_numpy_ones(both):
    """Small frames of any size (1-89 px a side) with square blobs of any brightness anywhere, touching each other
    and the border, with and without boxes and seeds: both paths find the same blobs in the same order (OpenCV's
    own label order depends on its algorithm and threads; both paths renumber in raster order)."""
    rng = np.random.default_rng(16)
    found = 0
    for trial in range(300):
        h, w = rng.integers(1, 90, 2)
        image = rng.integers(0, 20, (h, w)).astype(np.uint8)
        for _ in range(rng.integers(0, 6)):
            y, x, r = rng.integers(0, h), rng.integers(0, w), rng.integers(0, 6)
            image[max(0, y - r): y + r + 1, max(0, x - r): x + r + 1] = rng.integers(60, 256)
        seeds = rng.uniform(0, max(h, w), (rng.integers(0, 5), 2))
        rois = np.array([[0.0, 0.0, w / 2 + 0.37, h / 2 + 0.61]]) if trial % 3 == 0 else None  # (no exact ties)
        ref, got = both(lambda im, s, r: detect(im, seeds=s, rois=r), image, seeds, rois)
        assert len(ref) == len(got)  # (the fits of square blobs are ill-posed: float32 and float64 part ways)
        np.testing.assert_array_equal(got.area, ref.area)
        np.testing.assert_array_equal(got.merged, ref.merged)
        _same(*both(lambda im, r: detect(im, rois=r, refine="centroid"), image, rois), rtol=1e-9)
        found += len(ref)
    assert found > 300


def test_clutter_test_is_the_numpy_one():
    """The tracker's test of fresh detections against the free detections of recent frames: the kernel flags
    exactly the detections the numpy expression flags (NaN slots never near anything)."""
    rng = np.random.default_rng(17)
    D = rng.uniform(0, 40, (4, 30, 2))
    D[rng.random((4, 30)) < 0.2] = np.nan
    old = rng.uniform(0, 40, (4, 25, 2))
    old[rng.random((4, 25)) < 0.3] = np.nan
    cc, nn = np.nonzero(rng.random((4, 30)) < 0.5)
    with np.errstate(invalid="ignore"):
        ref = (dist2(D[cc, nn][:, None, :], old[cc]) < 3.0**2).any(axis=1)
    got = kernels.near_any(D, cc, nn, old, 3.0**2)
    np.testing.assert_array_equal(got, ref)
    assert 5 < ref.sum() < len(ref) - 5


def test_tracker_frame_of_detections_is_the_numpy_one(both):
    """The tracker's frame of detections (ideal px, floored covariances, merged and roundness flags, vague blobs)
    is the same on both paths, with what the scenes of the other tests lack: covariances below the floor, NaN and
    inf ones, vague blobs, flat blobs big enough to judge near the image's edge and centre, cameras without blobs."""
    rig = ring_rig()
    rng = np.random.default_rng(18)
    dets = []
    for c in range(len(rig)):
        n = 0 if c == 2 else int(rng.integers(5, 40))
        cov = np.eye(2) * rng.choice([1e-7, 1e-3, 0.05, 4.0], size=(n, 1, 1))
        cov[:, 0, 1] = cov[:, 1, 0] = rng.uniform(-0.5, 0.5, n) * cov[:, 0, 0]
        cov[rng.random(n) < 0.1, 1, 0] = np.nan
        cov[rng.random(n) < 0.05, 0, 0] = np.inf
        dets.append(Detections(np.c_[rng.uniform(0, 1280, n), rng.uniform(0, 1024, n)], rng.integers(1, 30, n),
                               rng.uniform(0.3, 1.0, n), cov, rng.random(n) < 0.1))
    ref, got = both(lambda d: Tracker(rig, 120.0)._prepare(d), dets)
    _same(ref, got, rtol=1e-12)
    assert ref.merged.sum() > 20 and (~ref.merged & ref.valid).sum() > 20
    assert np.isclose(ref.S[ref.valid & ~ref.merged][:, 0, 0], MIN_CENTROID_STD_PX**2).any()  # floored


def test_attached_distance_learning_is_the_numpy_one(both):
    """A plate of four, a loose marker and an intermittent one, with wrong points and gaps: the same slots,
    distances, counts and failures after every frame."""
    rng = np.random.default_rng(5)
    plate = rng.uniform(-0.05, 0.05, (4, 3))

    def learn_all():
        memory = AttachedDistances(slots=3, reach_m=0.3, tolerance_m=0.01, steady_frames=5, forget_frames=20)
        states = []
        for k in range(120):
            X = np.vstack([plate + [0.01 * k, 0.0, 1.0], [0.1 * np.sin(0.2 * k), 0.1, 1.0], [0.0, -0.05, 1.0]])
            seen = np.flatnonzero(np.r_[True, k % 7 != 3, True, True, True, (k // 10) % 2 == 0])
            if k % 13 == 5:
                X[0] = X[3]  # a wrong point
            memory.learn(seen, X[seen])
            states.append([a.copy() for a in (memory.neighbour, memory.distance, memory.held, memory.last,
                                              memory.tries)])
        return states

    reference, compiled = both(learn_all)
    assert len(reference) == len(compiled) == 120
    for ref, com in zip(reference, compiled, strict=True):
        for a, b in zip(ref, com, strict=True):
            np.testing.assert_allclose(b, a, rtol=0, atol=1e-15)
    assert (reference[-1][2] >= 5).sum() >= 6 and reference[-1][4].sum() > 0  # steady slots, and failures


def test_pair_distance_statistics_are_the_numpy_ones(both, monkeypatch):
    """Identities with gaps, some never seen together and some seen together in too few frames, on a long take
    whose medians are taken over a subsample: the same medians, spreads and counts, NaN in the same places."""
    monkeypatch.setattr(rigid, "STATISTICS_FRAMES", 150)  # (subsampled: every 3rd of 400 frames)
    rng = np.random.default_rng(11)
    F, M = 400, 9
    P = rng.normal(scale=0.2, size=(F, M, 3)) + rng.normal(size=(1, M, 3))
    P[rng.random((F, M)) < 0.3] = np.nan
    P[:200, 7] = np.nan
    P[200:, 8] = np.nan  # 7 and 8 never together
    P[3:, 6] = np.nan  # 6: with the others in at most 3 frames
    reference, compiled = both(rigid.pair_statistics, P, 4)
    _same(reference, compiled, rtol=1e-15)
    median, spread, count = reference
    assert count[7, 8] == 0 and np.isnan(median[7, 8]) and (count[6] <= 3).all() and np.isnan(spread[6]).all()
    assert np.isfinite(median[:6, :6][~np.eye(6, dtype=bool)]).all()
