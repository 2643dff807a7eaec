"""`mocap evaluate`: scores against hand-made truth, the Cramér–Rao bound against Monte Carlo."""

from __future__ import annotations

import copy
import json
import logging
import math

import numpy as np
import pytest

from mocap.camera import Rig, rig_to_toml, save_rig
from mocap.cli import main
from mocap.crlb import crlb_covariance
from mocap.errors import MocapError
from mocap.evaluate import evaluate
from mocap.export.c3d import read_c3d, write_c3d
from mocap.geometry import triangulate_weighted
from mocap.trajectories import Trajectories
from mocap.truth import Truth, save_truth
from tests.conftest import ring_rig

FPS = 100.0


def make_truth(rig: Rig, frames: int = 60, markers: int = 8, seed: int = 0) -> Truth:
    """Markers circling (0, 0, 1) m >= 0.2 m apart; random visibility (some marker-frames seen by
    0 or 1 camera), random per-blob sigma, and one gap in the source motion (marker 3, frames 5-9)."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / FPS
    angle = 2 * np.pi * np.arange(markers) / markers
    phase = angle[None, :] + 2.0 * t[:, None]  # (F, M)
    radius = 0.5 + 0.05 * np.sin(3 * t)[:, None]
    positions = np.stack(
        [radius * np.cos(phase), radius * np.sin(phase), 1.0 + 0.3 * np.cos(angle)[None, :] + 0 * phase], axis=2
    )
    positions[5:10, 3] = np.nan
    C = len(rig)
    uv = rig.project(positions.reshape(-1, 3)).reshape(C, frames, markers, 2).transpose(1, 0, 2, 3)
    inside = np.stack([cam.in_image(uv[:, c].reshape(-1, 2)).reshape(frames, markers) for c, cam in enumerate(rig)], 1)
    # Few cameras per marker-frame so that 0-, 1- and 2-view cases all occur.
    visible = inside & (rng.random((frames, C, markers)) < 0.45)
    sigma = np.where(visible, rng.uniform(0.05, 0.3, (frames, C, markers)), np.nan)
    return Truth(
        labels=[f"T{j}" for j in range(markers)],
        fps=FPS,
        positions=positions,
        camera_names=rig.names,
        uv=uv,
        visible=visible,
        sigma_px=sigma,
        settings={"calibration_toml": rig_to_toml(rig)},
    )


@pytest.fixture(scope="module")
def truth() -> Truth:
    return make_truth(ring_rig())


def output_of(positions: np.ndarray, first_frame: int = 0) -> Trajectories:
    return Trajectories([f"O{j}" for j in range(positions.shape[1])], FPS, positions, first_frame=first_frame)


def required(truth: Truth) -> np.ndarray:
    return (truth.views >= 2) & np.isfinite(truth.positions).all(axis=2)


def test_truth_fixture_has_every_view_count(truth: Truth) -> None:
    exists = np.isfinite(truth.positions).all(axis=2)
    for views in (0, 1, 2):
        assert ((truth.views == views) & exists).any()


def test_perfect_output_through_c3d(truth: Truth, tmp_path) -> None:
    write_c3d(output_of(truth.positions), tmp_path / "out.c3d")
    report = evaluate(read_c3d(tmp_path / "out.c3d"), truth)
    req = required(truth)
    assert report.rmse_mm < 1e-3  # C3D stores float32 mm
    assert report.max_mm < 1e-3
    assert report.required == report.matched == int(req.sum())
    assert report.completeness == 1.0
    assert report.switches == 0 and report.switches_per_10k == 0.0
    assert report.idf1 == report.idp == report.idr == report.mota == 1.0
    assert report.ghosts == report.duplicates == 0 and report.ghost_rate == 0.0
    # Samples on markers seen by 0 or 1 camera are neither scored nor ghosts.
    exists = np.isfinite(truth.positions).all(axis=2)
    assert report.unscored == int((exists & ~req).sum())
    assert report.output_points == int(exists.sum())
    assert [m.completeness for m in report.per_marker] == [1.0] * len(truth.labels)


def test_swapped_labels_count_two_switches(truth: Truth) -> None:
    k = 25
    pos = truth.positions.copy()
    pos[k:, [0, 1]] = pos[k:, [1, 0]]
    report = evaluate(output_of(pos), truth)
    # py-motmetrics counts a SWITCH per truth object whose matched hypothesis changes: markers 0
    # and 1 each change output track once (they are >= 0.2 m apart, beyond the gate) -> 2.
    assert report.switches == 2
    assert report.reference_jumps == report.switches_at_reference_jumps == 0  # the truth moves smoothly
    assert [m.switches for m in report.per_marker] == [1, 1] + [0] * (len(truth.labels) - 2)
    req = required(truth)
    assert report.switches_per_10k == pytest.approx(2e4 / req.sum())
    assert report.completeness == 1.0 and report.rmse_mm == 0.0
    # IDF1: the global one-to-one track assignment keeps the longer half of markers 0 and 1;
    # every hypothesis sits on a required marker, so IDF1 = IDP = IDR = IDTP / required.
    idtp = req[:, 2:].sum() + max(req[:k, :2].sum(), req[k:, :2].sum())
    assert report.idf1 == pytest.approx(idtp / req.sum())
    assert report.idp == pytest.approx(idtp / req.sum()) and report.idr == pytest.approx(idtp / req.sum())
    assert report.mota == pytest.approx(1 - 2 / req.sum())
    # Per marker, the marker-frames under the track IDF1 pairs it with: they sum to IDTP.
    assert sum(m.identified for m in report.per_marker) == idtp
    assert [m.identity for m in report.per_marker[2:]] == [1.0] * (len(truth.labels) - 2)
    halves = (req[:k, :2] if req[:k, :2].sum() >= req[k:, :2].sum() else req[k:, :2]).sum(axis=0)
    assert [m.identified for m in report.per_marker[:2]] == halves.tolist()
    # The list of switches: where, whose, from which track (last matched when) to which.
    events = [(e.label, e.before, e.after, e.at_reference_jump) for e in report.switch_events]
    assert sorted(events) == [("T0", "O0", "O1", False), ("T1", "O1", "O0", False)]
    for e in report.switch_events:
        j = int(e.label[1])
        assert e.frame == np.flatnonzero(req[k:, j])[0] + k  # the first required frame after the swap
        assert e.before_frame == np.flatnonzero(req[:k, j])[-1]  # the last one before it
    shifted = evaluate(output_of(pos[5:], first_frame=5), truth)  # truth frame numbers, whatever the output's start
    assert [e.frame for e in shifted.switch_events] == [e.frame for e in report.switch_events]
    assert [line.split()[1] for line in report.table(switches=True).splitlines()[-2:]] == ["T0", "T1"]


def test_switches_at_a_label_swap_in_the_truth_are_put_down_to_it(truth: Truth) -> None:
    req = required(truth)
    both = req[:, 0] & req[:, 1]
    k = next(f for f in range(10, truth.n_frames - 10) if both[f - 1:f + 2].all())
    swapped = copy.deepcopy(truth)
    swapped.positions[k, [0, 1]] = swapped.positions[k, [1, 0]]  # the recording swapped two labels for one frame
    report = evaluate(output_of(truth.positions), swapped)  # the output follows the markers
    assert report.switches == 4  # markers 0 and 1 change track at frame k and back at k + 1
    assert report.switches_at_reference_jumps == 4
    assert report.reference_jumps == 6  # both markers' second differences at k - 1, k and k + 1
    assert "4 of the ID switches are within 2 frames" in report.table()
    assert [e.at_reference_jump for e in report.switch_events] == [True] * 4
    assert [e.frame for e in report.switch_events] == [k, k, k + 1, k + 1]
    assert sum(line.endswith("(the recording's labelling)") for line in report.table(switches=True).splitlines()) == 4
    own = truth.positions.copy()
    own[k + 5:, [2, 3]] = own[k + 5:, [3, 2]]  # a real swap of the output, away from the truth's jump
    report = evaluate(output_of(own), swapped)
    assert report.switches == 6 and report.switches_at_reference_jumps == 4
    ours = [(e.label, e.at_reference_jump) for e in report.switch_events if e.frame >= k + 5]
    assert sorted(ours)[:2] == [("T2", False), ("T3", False)]


def test_switches_where_the_truth_renames_a_marker_are_put_down_to_it(truth: Truth) -> None:
    """The whole sprint's frames 3202-3247: the recording names one marker ArmL Marker2, then ForearmL Marker4 (a
    label last seen on another marker), then ArmL Marker2 again, with no jump. An output that follows the marker
    counts a switch for the label that came back elsewhere; the rename is a labelling fault."""
    k = 30
    renamed = copy.deepcopy(truth)
    renamed.visible[:] = True  # (every sample scored)
    renamed.positions[k - 10:, 1] = np.nan  # marker 1 leaves (label B last seen on it at k - 11) ...
    renamed.positions[k + 1:, 1] = truth.positions[k + 1:, 0]  # ... and from k + 1 marker 0 is labelled B
    renamed.positions[k + 1:, 0] = np.nan
    output = truth.positions.copy()
    output[k - 10:, 1] = np.nan  # the output follows the markers
    report = evaluate(output_of(output), renamed)
    assert report.switches == 1  # label B: output 1 before, output 0 from k + 1
    assert report.switches_at_reference_jumps == 1 and report.reference_jumps == 2
    moved = copy.deepcopy(renamed)
    moved.positions[k + 1:, 1] += 0.01  # 10 mm from where marker 0 was heading: another marker, not a rename
    assert evaluate(output_of(output), moved).reference_jumps == 0


def test_a_label_given_to_another_marker_for_one_frame_is_put_down_to_the_recording(truth: Truth) -> None:
    """The whole sprint's frame 2340: the recording names three hidden ArmL markers SWL Marker2-4 for one frame (the
    steering wheel's labels, unseen for 78 frames), then ArmL again. An output that follows the markers matches SWL
    Marker2 to the arm marker's identity there, and counts the switch where the label is next seen, on the wheel.
    The one-frame label lies on the path the arm marker's label comes back on (its backward extrapolation), and the
    switch is put down to the recording because the label's previous match was there."""
    k, back = 30, 45
    renamed = copy.deepcopy(truth)
    renamed.visible[:] = True  # (every sample scored)
    renamed.positions[:, 1] = np.nan
    renamed.positions[k, 1] = truth.positions[k, 0]  # label B on marker 0 for frame k ...
    renamed.positions[back:, 1] = truth.positions[back:, 1]  # ... and on its own marker from frame 45
    renamed.positions[k - 5: k + 1, 0] = np.nan  # label A hidden before k, and renamed at k
    output = truth.positions.copy()
    output[k - 5: k, 0] = np.nan  # the output follows the markers
    output[:back, 1] = np.nan
    assert np.linalg.norm(truth.positions[k + 1, 0] - truth.positions[k, 0]) > 0.005  # (a lone sample: no lead)
    report = evaluate(output_of(output), renamed)
    assert report.switches == 1  # label B: output 0 at frame k, output 1 from frame 45
    assert report.reference_jumps == 2 and report.switches_at_reference_jumps == 1
    moved = copy.deepcopy(renamed)
    moved.positions[k, 1] += 0.01  # 10 mm off the marker's path: another marker, not a rename
    report = evaluate(output_of(output), moved)
    assert report.reference_jumps == 0 and report.switches_at_reference_jumps == 0


def test_a_label_moved_onto_another_marker_across_a_short_gap_is_put_down_to_the_recording(truth: Truth) -> None:
    """The whole sprint's frame 2156: the lateral epicondyle's label, missing one frame, lies on the upper arm's
    Marker2 (its label missing for the two frames before), on where that marker's path leads and 47 mm from where
    its own does; then it is missing for a while. An output that follows the markers has Marker2's identity there,
    and the switch there and back is the recording's."""
    k, back = 30, 45
    P = truth.positions
    moved = copy.deepcopy(truth)
    moved.visible[:] = True  # (every sample scored)
    moved.positions[k - 2:back, 1] = np.nan  # label B missing from k - 2 ...
    moved.positions[k - 1:back, 0] = np.nan  # ... label A from k - 1, back on marker 1 for frame k only
    moved.positions[k, 0] = P[k, 1]
    lead_b = P[k - 3, 1] + 3 * (P[k - 3, 1] - P[k - 4, 1])  # where B's path leads at k
    lead_a = P[k - 2, 0] + 2 * (P[k - 2, 0] - P[k - 3, 0])  # ... and A's
    assert np.linalg.norm(lead_b - P[k, 1]) < 0.009 and np.linalg.norm(lead_a - P[k, 1]) > 0.03  # (the premise)
    report = evaluate(output_of(P), moved)  # the output follows the markers
    assert report.switches == 2  # label A: output 0, output 1 at frame k, output 0 from frame 45
    assert report.switches_at_reference_jumps == 2 and report.reference_jumps == 1
    off = copy.deepcopy(moved)
    off.positions[k, 0] += 0.01  # 10 mm off B's path: another marker, not a label moved
    report = evaluate(output_of(P), off)
    assert report.reference_jumps == 0 and report.switches_at_reference_jumps == 0


def _arm_truth(exchange: bool) -> Truth:
    """An upper arm (three markers) and a forearm (three markers 0.12, 0.15 and 0.18 m from the elbow) whose elbow
    opens from 100 to 160 degrees while the arm moves on; the forearm is hidden for frames 30-49, and with
    ``exchange`` the recording gives its first and last markers each other's labels after that gap."""
    F = 80
    s = np.linspace(0.0, 1.0, F)[:, None]
    elbow = np.array([0.0, 0.0, 1.0]) + s * np.array([0.4, 0.1, 0.0])  # (F, 3)
    u, w, n = np.eye(3)  # upper arm along x (elbow to shoulder), the elbow turns in the x-y plane about z
    theta = np.radians(100.0 + 60.0 * s)  # (F, 1)
    v = np.cos(theta) * u + np.sin(theta) * w  # (F, 3) forearm direction
    upper = [0.06 * u + 0.03 * n, 0.10 * u - 0.03 * n, 0.14 * u + 0.03 * n]
    fore = [0.12 * v, 0.15 * v + 0.04 * n, 0.18 * v]
    positions = np.stack([elbow + p for p in upper] + [elbow + p for p in fore], axis=1)  # (F, 6, 3)
    positions[30:50, 3:] = np.nan
    if exchange:
        positions[50:, [3, 5]] = positions[50:, [5, 3]]
    M = positions.shape[1]
    return Truth(labels=[f"A{j}" for j in range(3)] + [f"F{j}" for j in range(3)], fps=FPS, positions=positions,
                 camera_names=["c1", "c2"], uv=np.zeros((F, 2, M, 2)), visible=np.ones((F, 2, M), dtype=bool),
                 sigma_px=np.full((F, 2, M), 0.1), settings={})


def test_labels_a_recording_exchanged_across_a_gap_are_put_down_to_it() -> None:
    """The whole sprint's forearm (frames 1037-1282, 2314-2382, 2458-2529): after a gap the recording gives the
    cluster's first and last markers each other's labels (its triangle with the middle marker is nearly isosceles).
    The upper arm's markers, all farther from the forearm's far end whatever the elbow's angle, show it; the output
    that follows the markers counts two switches there, put down to the recording. The elbow opening by 60 degrees
    over the gap alone is no exchange."""
    physical = _arm_truth(exchange=False)
    report = evaluate(output_of(physical.positions), _arm_truth(exchange=True))
    assert report.switches == 2 and report.switches_at_reference_jumps == 2
    assert report.reference_jumps == 4  # both labels' samples at frames 29 and 50
    missed = physical.positions.copy()
    missed[20:30] = missed[50:60] = np.nan  # the output has the forearm only well away from the gap
    report = evaluate(output_of(missed), _arm_truth(exchange=True))
    assert report.switches == 2 and report.switches_at_reference_jumps == 2
    report = evaluate(output_of(physical.positions), physical)
    assert report.switches == 0 and report.reference_jumps == 0


def test_restarted_track_is_one_switch_and_a_gap_none(truth: Truth) -> None:
    F = truth.n_frames
    restarted = np.concatenate([truth.positions, np.full((F, 1, 3), np.nan)], axis=1)
    restarted[30:, -1] = restarted[30:, 0]  # marker 0 continues under a new identity from frame 30
    restarted[30:, 0] = np.nan
    report = evaluate(output_of(restarted), truth)
    assert report.switches == 1 and report.per_marker[0].switches == 1
    assert report.completeness == 1.0
    req0 = required(truth)[:, 0]
    assert report.per_marker[0].identity == pytest.approx(max(req0[:30].sum(), req0[30:].sum()) / req0.sum())
    gap = truth.positions.copy()
    gap[20:25, 0] = np.nan  # same identity after the gap
    report = evaluate(output_of(gap), truth)
    assert report.switches == 0
    assert report.per_marker[0].matched == required(truth)[:, 0].sum() - required(truth)[20:25, 0].sum()


def test_dropping_samples_lowers_completeness_exactly(truth: Truth) -> None:
    rng = np.random.default_rng(1)
    req = required(truth)
    exists = np.isfinite(truth.positions).all(axis=2)
    req_idx = np.argwhere(req)[rng.choice(req.sum(), 37, replace=False)]
    other_idx = np.argwhere(exists & ~req)[:5]  # dropping unscored samples changes nothing scored
    pos = truth.positions.copy()
    pos[req_idx[:, 0], req_idx[:, 1]] = np.nan
    pos[other_idx[:, 0], other_idx[:, 1]] = np.nan
    report = evaluate(output_of(pos), truth)
    assert report.matched == req.sum() - 37
    assert report.completeness == (req.sum() - 37) / req.sum()
    assert report.unscored == (exists & ~req).sum() - 5
    per = report.per_marker
    dropped = np.bincount(req_idx[:, 1], minlength=len(per))
    assert [m.matched for m in per] == (req.sum(axis=0) - dropped).tolist()
    assert report.ghost_rate == 0.0 and report.switches == 0


def test_ghosts_and_duplicates(truth: Truth) -> None:
    F, M = truth.positions.shape[:2]
    rng = np.random.default_rng(2)
    extra = np.full((F, 3, 3), np.nan)
    ghost_frames = rng.choice(F, 20, replace=False)
    extra[ghost_frames, 0] = [0.0, 0.0, 3.0]  # far above every marker
    extra[::2, 1] = truth.positions[::2, 2] + [0.0, 0.012, 0.0]  # 12 mm from marker 2: a duplicate
    extra[10:14, 2] = truth.positions[10:14, 5] + [0.0, 0.0, 0.021]  # 21 mm: beyond the 20 mm gate
    out = output_of(np.concatenate([truth.positions, extra], axis=1))
    report = evaluate(out, truth)
    exists_2 = np.isfinite(truth.positions[::2, 2]).all(axis=1)
    assert report.ghosts == 20 + 4
    assert report.duplicates == int(exists_2.sum())
    assert report.output_points == int(out.valid.sum())
    assert report.ghost_rate == 24 / out.valid.sum()
    assert report.completeness == 1.0 and report.rmse_mm < 1e-9
    # With a 25 mm gate the 21 mm points become duplicates.
    wide = evaluate(out, truth, gate_mm=25.0)
    assert wide.ghosts == 20 and wide.duplicates == report.duplicates + 4


def test_noisy_output_rmse_is_sigma_sqrt3() -> None:
    rig = ring_rig()
    truth = make_truth(rig, frames=300, seed=3)
    sigma_mm = 2.0
    rng = np.random.default_rng(4)
    pos = truth.positions + rng.normal(0.0, sigma_mm / 1000.0, truth.positions.shape)
    report = evaluate(output_of(pos), truth)
    assert report.matched > 1000
    assert report.rmse_mm == pytest.approx(sigma_mm * math.sqrt(3), rel=0.05)
    assert report.rmse_axis_mm == pytest.approx([sigma_mm] * 3, rel=0.07)
    assert report.median_mm == pytest.approx(1.5382 * sigma_mm, rel=0.07)  # median of a Maxwell distribution
    assert report.p95_mm == pytest.approx(2.7955 * sigma_mm, rel=0.07)  # sqrt(chi2_3 95 % quantile)
    assert report.completeness == 1.0 and report.switches == 0


def _noisy_triangulations(rig: Rig, X: np.ndarray, vis: np.ndarray, sigma: np.ndarray, trials: int, seed: int):
    """``trials`` weighted triangulations of each point from centroids with Gaussian noise.

    X (N, 3), vis/sigma (N, C) -> (trials, N, 3) estimates."""
    rng = np.random.default_rng(seed)
    N, C = vis.shape
    uv = rig.project(X)  # (C, N, 2) distorted px
    noisy = uv[:, None] + rng.normal(size=(C, trials, N, 2)) * sigma.T[:, None, :, None]
    noisy[~np.broadcast_to(vis.T[:, None], (C, trials, N))] = np.nan
    ideal = np.stack([cam.undistort(noisy[c].reshape(-1, 2)) for c, cam in enumerate(rig)])
    cov2 = np.broadcast_to((sigma.T**2)[:, None, :, None, None] * np.eye(2), (C, trials, N, 2, 2)).reshape(-1, 2, 2)
    est, _, _ = triangulate_weighted(rig.projection_matrices(), ideal, cov2.reshape(C, trials * N, 2, 2))
    return est.reshape(trials, N, 3)


def test_crlb_matches_monte_carlo_triangulation() -> None:
    rig = ring_rig()
    X = np.array([[0.0, 0.0, 1.0], [0.4, -0.3, 1.5], [-0.5, 0.2, 0.3], [0.2, 0.6, 1.8]])
    vis = np.array([[1, 1, 0, 0, 0, 0], [1, 0, 1, 0, 1, 0], [1, 1, 1, 1, 1, 1], [0, 0, 1, 0, 0, 1]], dtype=bool)
    sigma = np.where(vis, np.random.default_rng(5).uniform(0.05, 0.5, vis.shape), np.nan)
    est = _noisy_triangulations(rig, X, vis, sigma, trials=4000, seed=6)
    err = est - X
    mse = (err**2).sum(axis=2).mean(axis=0)  # (N,) m^2
    bound = np.trace(crlb_covariance(rig, X, vis, sigma), axis1=1, axis2=2)
    np.testing.assert_allclose(mse, bound, rtol=0.10)
    # The full covariance agrees too (largest eigen-direction, where the bound is loosest to sample).
    emp = np.einsum("tni,tnj->nij", err, err) / len(err)
    np.testing.assert_allclose(np.linalg.eigvalsh(emp)[:, -1], np.linalg.eigvalsh(crlb_covariance(
        rig, X, vis, sigma))[:, -1], rtol=0.10)


def test_crlb_is_nan_without_two_views() -> None:
    rig = ring_rig()
    X = np.array([[0.0, 0.0, 1.0], [0.1, 0.0, 1.0]])
    vis = np.array([[1, 0, 0, 0, 0, 0], [0, 0, 0, 0, 0, 0]], dtype=bool)
    cov = crlb_covariance(rig, X, vis, np.full(vis.shape, 0.1))
    assert np.isnan(cov).all()


def test_triangulated_output_reaches_the_crlb_reference() -> None:
    """End to end: triangulating the truth's own noisy centroids scores RMSE/CRLB ~ 1."""
    rig = ring_rig()
    truth = make_truth(rig, frames=300, seed=7)
    F, C, M = truth.visible.shape
    X = truth.positions.reshape(-1, 3)
    vis = truth.visible.transpose(0, 2, 1).reshape(-1, C)
    sigma = truth.sigma_px.transpose(0, 2, 1).reshape(-1, C)
    ok = np.isfinite(X).all(axis=1) & (vis.sum(axis=1) >= 2)
    est = np.full_like(X, np.nan)
    est[ok] = _noisy_triangulations(rig, X[ok], vis[ok], sigma[ok], trials=1, seed=8)[0]
    report = evaluate(output_of(est.reshape(F, M, 3)), truth)
    assert report.completeness == 1.0
    assert report.rmse_over_crlb == pytest.approx(1.0, abs=0.1)
    assert report.crlb_rmse_mm == pytest.approx(
        math.sqrt(np.nanmean(np.trace(crlb_covariance(rig, X[ok], vis[ok], sigma[ok]), axis1=1, axis2=2))) * 1e3
    )


def test_output_of_a_frame_range(truth: Truth) -> None:
    report = evaluate(output_of(truth.positions[10:40], first_frame=10), truth)
    assert report.frames == 30 and report.first_frame == 10
    assert report.required == required(truth)[10:40].sum() == report.matched


def test_bad_inputs(truth: Truth) -> None:
    with pytest.raises(MocapError, match="not inside the truth"):
        evaluate(output_of(np.zeros((truth.n_frames + 1, 2, 3))), truth)
    with pytest.raises(MocapError, match="not inside the truth"):
        evaluate(output_of(truth.positions[:20], first_frame=50), truth)
    with pytest.raises(MocapError, match="frame rates differ"):
        evaluate(Trajectories(["a"], 2 * FPS, truth.positions[:, :1]), truth)
    with pytest.raises(MocapError, match="gate"):
        evaluate(output_of(truth.positions), truth, gate_mm=0.0)
    other = ring_rig(4)
    with pytest.raises(MocapError, match="does not match the truth's cameras"):
        evaluate(output_of(truth.positions), truth, rig=Rig([c for c in other][:3]))


def test_broken_calibration_in_truth_is_named(truth: Truth) -> None:
    broken = Truth(**{**truth.__dict__, "settings": {"calibration_toml": "[cam_1]\nname = 'cam1'\n"}})
    with pytest.raises(MocapError, match=r"truth settings\['calibration_toml'\].*missing field"):
        evaluate(output_of(truth.positions), broken)


def test_empty_output_scores_zero(truth: Truth) -> None:
    report = evaluate(output_of(np.full((truth.n_frames, 2, 3), np.nan)), truth)
    assert report.matched == 0 and report.completeness == 0.0 and report.output_points == 0
    assert math.isnan(report.rmse_mm) and math.isnan(report.ghost_rate) and report.mota == 0.0
    assert "no marker-frame matched" in report.table()
    assert json.loads(json.dumps(report.to_dict(), allow_nan=False))["rmse_mm"] is None


def test_an_output_of_another_take_or_in_other_units_is_warned_about(truth: Truth, caplog) -> None:
    """Scores of 0 % with no hint would read as an engine failure; the log names the likely cause."""
    with caplog.at_level(logging.WARNING, logger="mocap.evaluate"):
        evaluate(output_of(truth.positions.copy()), truth)
        assert not caplog.records
        evaluate(output_of(truth.positions * 1000.0), truth)  # (a take written in mm read as m)
        evaluate(output_of(truth.positions + [0.0, 0.0, 0.5]), truth)  # (another take's markers)
    assert len(caplog.records) == 2
    assert all("different takes" in r.getMessage() and "0 of" in r.getMessage() for r in caplog.records)


def test_calibration_camera_order_does_not_matter(truth: Truth) -> None:
    rig = ring_rig()
    default = evaluate(output_of(truth.positions), truth)
    reordered = evaluate(output_of(truth.positions), truth, rig=Rig(rig.cameras[::-1]))
    assert reordered.crlb_rmse_mm == pytest.approx(default.crlb_rmse_mm, rel=1e-12)


def test_no_calibration_leaves_crlb_undefined(truth: Truth) -> None:
    bare = Truth(**{**truth.__dict__, "settings": {}})
    report = evaluate(output_of(truth.positions), bare)
    assert math.isnan(report.crlb_rmse_mm)
    assert report.to_dict()["crlb_rmse_mm"] is None
    assert "no calibration" in report.table()


def test_cli_writes_table_and_json(truth: Truth, tmp_path, capsys) -> None:
    save_truth(truth, tmp_path / "take.truth.npz")
    save_rig(ring_rig(), tmp_path / "calibration.toml")
    write_c3d(output_of(truth.positions), tmp_path / "out.c3d")
    code = main(["evaluate", str(tmp_path / "out.c3d"), "--truth", str(tmp_path / "take.truth.npz"),
                 "--json", str(tmp_path / "score.json"), "--calibration", str(tmp_path / "calibration.toml"),
                 "--per-marker", "--switches"])
    assert code == 0
    printed = capsys.readouterr().out
    assert "RMSE" in printed and "IDF1 1.0000" in printed and "T7" in printed
    data = json.loads((tmp_path / "score.json").read_text())
    assert data["completeness"] == 1.0 and data["switches"] == 0
    assert data["required"] == int(required(truth).sum())
    assert [m["label"] for m in data["per_marker"]] == truth.labels
    assert [m["identity"] for m in data["per_marker"]] == [1.0] * len(truth.labels)
    assert "identity %" in printed and "output track (last matched at frame) -> track" in printed
    assert data["switch_events"] == []
    assert data["crlb_rmse_mm"] > 0


def test_cli_missing_truth_is_a_clear_error(tmp_path, capsys) -> None:
    write_c3d(output_of(np.zeros((3, 1, 3)) + 1.0), tmp_path / "out.c3d")
    code = main(["evaluate", str(tmp_path / "out.c3d"), "--truth", str(tmp_path / "absent.npz")])
    assert code == 2
    assert "absent.npz: truth file not found" in capsys.readouterr().err


def test_cli_frame_mismatch_names_both_files(truth: Truth, tmp_path, capsys) -> None:
    save_truth(truth, tmp_path / "take.truth.npz")
    write_c3d(output_of(np.ones((truth.n_frames + 5, 2, 3))), tmp_path / "out.c3d")
    code = main(["evaluate", str(tmp_path / "out.c3d"), "--truth", str(tmp_path / "take.truth.npz")])
    assert code == 2
    err = capsys.readouterr().err
    assert "out.c3d against" in err and "take.truth.npz" in err and "frame counts must agree" in err
