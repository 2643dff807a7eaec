"""Score reconstructed trajectories against the ground truth of a synthetic take.

Frame k of the output is truth frame ``k + traj.first_frame``. In every frame the output points
are assigned one-to-one to the truth markers that exist (finite position) by minimum total
Euclidean distance (``scipy.optimize.linear_sum_assignment``), pairs further apart than the gate
being forbidden. A truth marker-frame is *required* when at least two cameras saw it
(``truth.visible``); only required marker-frames enter accuracy and completeness. Every output
point is then exactly one of:

* matched to a required marker (scored);
* matched to a marker seen by fewer than two cameras (``unscored``: neither right nor wrong);
* unmatched but within the gate of a marker already taken by another point (``duplicate``);
* unmatched with no truth marker within the gate (``ghost``).

Identity metrics (ID switches, IDF1/IDP/IDR, MOTA) come from py-motmetrics fed with, per frame,
the required markers, the output points that are not ``unscored``, and their distances (NaN
beyond the gate). The Cramér–Rao reference RMSE is ``sqrt(mean trace(I^-1))`` over the matched
required marker-frames, I being the Fisher information of the cameras that saw the marker
(:mod:`mocap.crlb`).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import motmetrics as mm
import numpy as np
from scipy.ndimage import binary_dilation
from scipy.optimize import linear_sum_assignment

from mocap.atomic import atomic_write_bytes, check_output_path
from mocap.camera import Rig, load_rig, parse_rig
from mocap.crlb import crlb_covariance
from mocap.errors import MocapError
from mocap.export.c3d import read_c3d
from mocap.relabel import RelabelConfig
from mocap.rigid import column_runs
from mocap.trajectories import Trajectories
from mocap.truth import Truth, load_truth

__all__ = ["EvalReport", "MarkerScore", "SwitchEvent", "evaluate", "rig_from_truth", "configure_parser", "run"]

log = logging.getLogger(__name__)

_MOT_METRICS = ["num_switches", "idf1", "idp", "idr", "mota"]
_UNRELATED_FRACTION = 0.05  # fewer output points than this fraction matched: the truth is of another take
_JUMP_REACH = 2  # frames: a switch this near a jump of its truth marker is put down to the jump
_CLUSTER_M = 0.12  # m: two labels this near (median) may be exchanged by the recording ...
_CLUSTER_SPREAD_M = 0.01  # m: ... if their distance holds this well (robust spread)
_MOVED_GAP = 5  # frames: a label back after at most this many on another label's path, gone as long, moved there ...
_MOVED_OFF_M = 0.03  # m: ... where its own path (as far extrapolated) leads at least this far from it
_CONTEXT_M = 0.4  # m: neighbours within this tell the two apart ...
_EXCHANGE_M = 0.03  # m: ... by how far each stands from one and the other; an exchange changes that by this at least
_EXCHANGE_RATIO = 0.25  # and turns it round at every such neighbour (a + b below this fraction of a - b) ...
_EXCHANGE_NEIGHBOURS = 3  # ... of this many at least


@dataclass
class MarkerScore:
    """Scores of one truth marker (NaN where undefined)."""

    label: str
    required: int  # marker-frames seen by >= 2 cameras
    matched: int  # of those, matched by an output point
    completeness: float
    rmse_mm: float
    switches: int
    identified: int = 0  # of the required marker-frames, those its IDF1 identity (output track) matched
    identity: float = math.nan  # identified / required: where the IDF1 is lost


@dataclass
class SwitchEvent:
    """One ID switch: in truth ``frame`` the truth marker ``label``, last matched to the output track ``before`` in
    ``before_frame``, is matched to the track ``after``; ``at_reference_jump``: put down to the recording's
    labelling (see :attr:`EvalReport.switches_at_reference_jumps`)."""

    frame: int
    label: str
    before: str
    before_frame: int
    after: str
    at_reference_jump: bool


@dataclass
class EvalReport:
    """Scores of one output against its truth; distances in mm, NaN where undefined.

    ``rmse_axis_mm`` is (x, y, z). ``crlb_rmse_mm`` is NaN without a calibration (``has_calibration``) or
    without matches.
    """

    frames: int
    first_frame: int
    fps: float
    gate_mm: float
    truth_markers: int
    output_tracks: int
    required: int
    matched: int
    completeness: float
    output_points: int
    ghosts: int
    duplicates: int
    unscored: int
    ghost_rate: float
    rmse_mm: float
    median_mm: float
    p95_mm: float
    max_mm: float
    rmse_axis_mm: list[float]
    switches: int
    switches_per_10k: float
    reference_jumps: int  # truth marker-frames where the truth jumps, a marker is renamed or two labels exchanged
    switches_at_reference_jumps: int  # of ``switches``, those within 2 frames of a jump of their truth marker (at
    # the switch, or at that marker's previous match: the identity it had there was the recording's fault), or
    # whose span since that match overlaps a gap its label was exchanged across
    idf1: float
    idp: float
    idr: float
    mota: float
    crlb_rmse_mm: float
    rmse_over_crlb: float
    has_calibration: bool
    per_marker: list[MarkerScore] = field(default_factory=list)
    switch_events: list[SwitchEvent] = field(default_factory=list)  # in frame order

    def to_dict(self) -> dict[str, Any]:
        """Plain JSON-ready dict (NaN -> None)."""
        return _json_ready(asdict(self))

    def table(self, per_marker: bool = False, switches: bool = False) -> str:
        """A short human-readable summary (optionally one line per truth marker, and one per ID switch)."""
        f = _fmt
        axes = " / ".join(f(v, 3) for v in self.rmse_axis_mm)
        if not self.has_calibration:
            crlb = "n/a (no calibration: pass --calibration)"
        elif not math.isfinite(self.crlb_rmse_mm):
            crlb = "n/a (no marker-frame matched)"
        else:
            crlb = f"{f(self.crlb_rmse_mm, 3)} mm   RMSE/CRLB {f(self.rmse_over_crlb, 2)}"
        last = self.first_frame + self.frames - 1
        lines = [
            f"frames {self.first_frame}..{last} ({self.frames} at {self.fps:g} Hz), "
            f"{self.truth_markers} truth markers, {self.output_tracks} output tracks, gate {self.gate_mm:g} mm",
            f"accuracy     RMSE {f(self.rmse_mm, 3)} mm   median {f(self.median_mm, 3)}   "
            f"p95 {f(self.p95_mm, 3)}   max {f(self.max_mm, 3)}   x/y/z RMSE {axes}",
            f"CRLB         {crlb}",
            f"completeness {f(100 * self.completeness, 3)} %  ({self.matched} of {self.required} marker-frames "
            f"seen by >= 2 cameras)",
            f"ghost rate   {f(100 * self.ghost_rate, 3)} %  ({self.ghosts} ghosts, {self.duplicates} duplicates, "
            f"{self.unscored} on markers seen by < 2 cameras, of {self.output_points} output points)",
            f"identity     {self.switches} ID switches ({f(self.switches_per_10k, 2)} per 10,000 marker-frames)   "
            f"IDF1 {f(self.idf1, 4)}   IDP {f(self.idp, 4)}   IDR {f(self.idr, 4)}   MOTA {f(self.mota, 4)}",
        ]
        if self.reference_jumps:
            lines.append(
                f"truth jumps  {self.reference_jumps} truth marker-frames jump or change label (the recording's "
                f"labelling); "
                f"{self.switches_at_reference_jumps} of the ID switches are within 2 frames of one or across an "
                f"exchange")
        if per_marker:
            width = max([len(m.label) for m in self.per_marker] + [6])
            lines.append(f"{'marker':<{width}}  complete %   RMSE mm  switches  identity %")
            lines += [
                f"{m.label:<{width}}  {f(100 * m.completeness, 2):>10}  {f(m.rmse_mm, 3):>8}  {m.switches:>8}"
                f"  {f(100 * m.identity, 2):>10}"
                for m in self.per_marker
            ]
        if switches:
            width = max([len(e.label) for e in self.switch_events] + [6])
            lines.append(f"{'frame':>6}  {'marker':<{width}}  output track (last matched at frame) -> track")
            lines += [
                f"{e.frame:>6}  {e.label:<{width}}  {e.before} ({e.before_frame}) -> {e.after}"
                + ("   (the recording's labelling)" if e.at_reference_jump else "")
                for e in self.switch_events
            ]
        return "\n".join(lines)


def _fmt(value: float, digits: int) -> str:
    return f"{value:.{digits}f}" if math.isfinite(value) else "n/a"


def _json_ready(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_ready(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_json_ready(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def rig_from_truth(truth: Truth, where: str = "truth") -> Rig | None:
    """The rig stored in ``truth.settings["calibration_toml"]`` (None when absent)."""
    text = truth.settings.get("calibration_toml")
    if not text:
        return None
    return parse_rig(str(text), f"{where} settings['calibration_toml'] (or pass --calibration)")


def _truth_rig(rig: Rig, truth: Truth) -> Rig:
    """``rig``'s cameras in the truth's camera order."""
    try:
        return Rig([rig[rig.index(name)] for name in truth.camera_names], rig.metadata)
    except MocapError as exc:
        raise MocapError(f"the calibration does not match the truth's cameras: {exc}") from None


def _aligned_frames(traj: Trajectories, truth: Truth) -> slice:
    """The truth frames covered by ``traj``; MocapError when rate or range disagree."""
    if not math.isclose(traj.fps, truth.fps, rel_tol=1e-4):
        raise MocapError(
            f"frame rates differ: output {traj.fps:g} Hz, truth {truth.fps:g} Hz; score the output of this take"
        )
    start, stop = traj.first_frame, traj.first_frame + traj.n_frames
    if start < 0 or stop > truth.n_frames:
        raise MocapError(
            f"output frames {start}..{stop - 1} are not inside the truth's frames 0..{truth.n_frames - 1}; "
            "score the output of this take (frame counts must agree)"
        )
    return slice(start, stop)


@dataclass
class _Matches:
    """Matched output/truth pairs over all frames, and per-output-point tallies."""

    frame: np.ndarray  # (K,) output frame index
    marker: np.ndarray  # (K,) truth marker index
    error: np.ndarray  # (K, 3) output - truth, mm
    ghosts: int
    duplicates: int
    unscored: int


def _match(
    out_pos: np.ndarray, truth_pos: np.ndarray, required: np.ndarray, gate_mm: float, acc: mm.MOTAccumulator
) -> _Matches:
    """Assign output points to truth markers frame by frame; feed ``acc`` with the identity events.

    Args:
        out_pos: (F, N, 3) output positions, mm; NaN where missing.
        truth_pos: (F, M, 3) truth positions, mm; NaN where the marker does not exist.
        required: (F, M) bool: seen by >= 2 cameras.
    """
    out_ok = np.isfinite(out_pos).all(axis=2)
    truth_ok = np.isfinite(truth_pos).all(axis=2)
    frames, markers, errors = [], [], []
    ghosts = duplicates = unscored = 0
    for k in range(out_pos.shape[0]):
        hyp = np.flatnonzero(out_ok[k])
        obj = np.flatnonzero(truth_ok[k])
        dist = np.linalg.norm(out_pos[k][hyp][:, None] - truth_pos[k][obj][None], axis=2)  # (n_hyp, n_obj)
        near = dist <= gate_mm
        # Forbidden pairs cost more than any full set of allowed ones: maximum matches first.
        rows, cols = linear_sum_assignment(np.where(near, dist, gate_mm * (min(dist.shape) + 1)))
        keep = near[rows, cols]
        rows, cols = rows[keep], cols[keep]
        scored = required[k, obj[cols]]
        frames.append(np.full(scored.sum(), k))
        markers.append(obj[cols[scored]])
        errors.append(out_pos[k, hyp[rows[scored]]] - truth_pos[k, obj[cols[scored]]])
        unmatched = np.ones(len(hyp), dtype=bool)
        unmatched[rows] = False
        has_near = near.any(axis=1)
        ghosts += int((unmatched & ~has_near).sum())
        duplicates += int((unmatched & has_near).sum())
        unscored += int((~scored).sum())
        # Identity: required markers against every output point not sitting on an unscored marker.
        mot_hyp = np.ones(len(hyp), dtype=bool)
        mot_hyp[rows[~scored]] = False
        mot_obj = required[k, obj]
        mot_dist = np.where(near, dist, np.nan)[np.ix_(mot_hyp, mot_obj)].T
        acc.update(obj[mot_obj], hyp[mot_hyp], mot_dist)
    return _Matches(
        np.concatenate(frames).astype(np.intp),
        np.concatenate(markers).astype(np.intp),
        np.concatenate(errors).reshape(-1, 3),
        ghosts,
        duplicates,
        unscored,
    )


def _ratio(num: float, den: float) -> float:
    return float(num) / float(den) if den else math.nan


def evaluate(traj: Trajectories, truth: Truth, rig: Rig | None = None, gate_mm: float = 20.0) -> EvalReport:
    """Score ``traj`` against ``truth`` (see the module docstring for the definitions).

    Args:
        traj: reconstructed trajectories, metres; frame k is truth frame ``k + traj.first_frame``.
        truth: the take's ground truth.
        rig: calibration for the Cramér–Rao reference; default: the one stored in the truth.
        gate_mm: largest distance at which an output point can be the truth marker, mm.

    Raises:
        MocapError: rates or frame ranges disagree, a bad gate, or a calibration without the truth's cameras.
    """
    if not (math.isfinite(gate_mm) and gate_mm > 0):
        raise MocapError(f"--gate-mm must be a positive distance in mm, got {gate_mm}")
    frames = _aligned_frames(traj, truth)
    truth_pos = truth.positions[frames] * 1000.0
    visible = truth.visible[frames]
    required = (visible.sum(axis=1) >= 2) & np.isfinite(truth_pos).all(axis=2)  # (F, M)
    acc = mm.MOTAccumulator(auto_id=True)
    m = _match(traj.positions * 1000.0, truth_pos, required, gate_mm, acc)

    n_req, n_match = int(required.sum()), len(m.frame)
    sq = (m.error**2).sum(axis=1)
    dist = np.sqrt(sq)
    rmse = math.sqrt(sq.mean()) if n_match else math.nan
    out_points = int(traj.valid.sum())
    if n_match < _UNRELATED_FRACTION * min(out_points, n_req):
        log.warning("only %d of %d output points lie within %g mm of a truth marker: the output and the truth look "
                    "like different takes, or different frames of reference (units, axes, calibration); check that "
                    "this truth belongs to this output", n_match, out_points, gate_mm)
    mot = _mot_summary(acc)
    switch_frames, switch_oids, switch_from, switch_from_frame, switch_to = _switch_events(acc)
    truth_m = truth_pos / 1000.0
    exchanges = _exchanged_across_gaps(truth_m, float(truth.fps))
    jumps = _reference_jumps(truth_m, float(truth.fps), exchanges)
    near_jump = binary_dilation(jumps, structure=np.ones((2 * _JUMP_REACH + 1, 1), dtype=bool))  # (F, M)

    crlb = math.nan
    rig = rig if rig is not None else rig_from_truth(truth)
    if rig is not None:
        rig = _truth_rig(rig, truth)
    if rig is not None and n_match:
        vis = visible[m.frame, :, m.marker]  # (K, C)
        sigma = truth.sigma_px[frames][m.frame, :, m.marker]
        cov = crlb_covariance(rig, truth_pos[m.frame, m.marker] / 1000.0, vis, sigma)
        crlb = math.sqrt(float(np.nanmean(np.trace(cov, axis1=1, axis2=2)))) * 1000.0

    at_jumps = _at_reference_jumps(switch_frames, switch_oids, m, near_jump, exchanges)
    first = traj.first_frame  # truth frame of output frame 0
    switch_events = [
        SwitchEvent(frame=int(f) + first, label=truth.labels[o], before=traj.labels[b], before_frame=int(bf) + first,
                    after=traj.labels[a], at_reference_jump=bool(j))
        for f, o, b, bf, a, j in zip(switch_frames, switch_oids, switch_from, switch_from_frame, switch_to, at_jumps,
                                     strict=True)
    ]

    M = truth.positions.shape[1]
    req_per = required.sum(axis=0)
    match_per = np.bincount(m.marker, minlength=M)
    sq_per = np.bincount(m.marker, weights=sq, minlength=M)
    switches_per = np.bincount(switch_oids, minlength=M)
    identified_per = _identified(acc, M)
    per_marker = [
        MarkerScore(
            label=truth.labels[j],
            required=int(req_per[j]),
            matched=int(match_per[j]),
            completeness=_ratio(match_per[j], req_per[j]),
            rmse_mm=math.sqrt(_ratio(sq_per[j], match_per[j])),
            switches=int(switches_per[j]),
            identified=int(identified_per[j]),
            identity=_ratio(identified_per[j], req_per[j]),
        )
        for j in range(M)
    ]
    return EvalReport(
        frames=traj.n_frames,
        first_frame=traj.first_frame,
        fps=float(truth.fps),
        gate_mm=float(gate_mm),
        truth_markers=M,
        output_tracks=traj.n_markers,
        required=n_req,
        matched=n_match,
        completeness=_ratio(n_match, n_req),
        output_points=out_points,
        ghosts=m.ghosts,
        duplicates=m.duplicates,
        unscored=m.unscored,
        ghost_rate=_ratio(m.ghosts, out_points),
        rmse_mm=rmse,
        median_mm=float(np.median(dist)) if n_match else math.nan,
        p95_mm=float(np.percentile(dist, 95)) if n_match else math.nan,
        max_mm=float(dist.max()) if n_match else math.nan,
        rmse_axis_mm=np.sqrt((m.error**2).mean(axis=0)).tolist() if n_match else [math.nan] * 3,
        switches=int(mot["num_switches"]),
        switches_per_10k=_ratio(1e4 * mot["num_switches"], n_req),
        reference_jumps=int(jumps.sum()),
        switches_at_reference_jumps=int(at_jumps.sum()),
        idf1=mot["idf1"],
        idp=mot["idp"],
        idr=mot["idr"],
        mota=mot["mota"],
        crlb_rmse_mm=crlb,
        has_calibration=rig is not None,
        rmse_over_crlb=rmse / crlb,
        per_marker=per_marker,
        switch_events=switch_events,
    )


def _mot_summary(acc: mm.MOTAccumulator) -> dict[str, float]:
    """Switches, IDF1, IDP, IDR and MOTA from py-motmetrics (NaN where undefined)."""
    summary = mm.metrics.create().compute(acc, metrics=_MOT_METRICS, name="take")
    return {name: float(summary[name].iloc[0]) for name in _MOT_METRICS}


def _identified(acc: mm.MOTAccumulator, n_markers: int) -> np.ndarray:
    """(n_markers,) marker-frames each truth marker spends matched to the output track IDF1 pairs it with: the
    pairing of truth markers and tracks that matches the most marker-frames (within the gate), as IDF1's global
    assignment does; their sum is IDF1's IDTP."""
    events = acc.events
    raw = events.loc[(events["Type"] == "RAW") & events["D"].notna(), ["OId", "HId"]].to_numpy(dtype=np.intp)
    out = np.zeros(n_markers, dtype=np.intp)
    if len(raw) == 0:
        return out
    hyps, h = np.unique(raw[:, 1], return_inverse=True)
    together = np.zeros((n_markers, len(hyps)), dtype=np.intp)  # frames each marker and track were within the gate
    np.add.at(together, (raw[:, 0], h), 1)
    rows, cols = linear_sum_assignment(-together)
    out[rows] = together[rows, cols]
    return out


def _switch_events(acc: mm.MOTAccumulator) -> tuple[np.ndarray, ...]:
    """Every ID switch py-motmetrics counted, in frame order: (S,) frame, truth marker index, output track it was
    last matched to, the frame of that match, and the output track it is matched to now."""
    events = acc.mot_events
    matched = events.loc[events["Type"].isin(["MATCH", "SWITCH"])]
    frame = matched.index.get_level_values("FrameId").to_numpy(dtype=np.intp)
    oid = matched["OId"].to_numpy(dtype=np.intp)
    hid = matched["HId"].to_numpy(dtype=np.intp)
    switch = (matched["Type"] == "SWITCH").to_numpy()
    order = np.lexsort((frame, oid))  # by marker, then frame: each switch's previous match is the row before it
    at = np.flatnonzero(switch[order])
    rows, prev = order[at], order[np.maximum(at - 1, 0)]
    by_frame = np.argsort(frame[rows], kind="stable")
    rows, prev = rows[by_frame], prev[by_frame]
    return frame[rows], oid[rows], hid[prev], frame[prev], hid[rows]


def _reference_jumps(truth_pos: np.ndarray, fps: float, exchanges: list[tuple[int, int, int, int]]) -> np.ndarray:
    """(F, M) bool: truth samples (``truth_pos`` (F, M, 3), m) where the recording's labelling is at fault, so that an
    output that follows the markers counts ID switches there:

    * a jump: the acceleration (second difference) exceeds what a marker can do at ``fps`` (the identity repair's
      jump threshold, :meth:`RelabelConfig.jump_acc`): the recording gave the label to another marker;
    * a renamed marker: one label ends where another starts in the next frame, within ``duplicate_m`` (3 mm: no two
      marker centres are that close) of where the first one's path leads, or the first one's last sample within
      that of where the second one's path comes from (constant-velocity extrapolations, forwards and backwards;
      a single sample stands for itself): the recording gave the marker another name. Both labels' samples
      either side of the change are flagged;
    * two labels exchanged across a gap (``exchanges``, from :func:`_exchanged_across_gaps`): both labels' samples
      either side of it;
    * a label moved onto another marker across a short gap (:func:`_moved_across_gaps`): its sample back.
    """
    cfg = RelabelConfig()
    jumps = np.zeros(truth_pos.shape[:2], dtype=bool)
    acc = np.linalg.norm(truth_pos[2:] - 2 * truth_pos[1:-1] + truth_pos[:-2], axis=2)
    jumps[1:-1] = np.nan_to_num(acc) > cfg.jump_acc(fps)
    seen = np.isfinite(truth_pos[..., 0])
    ends = np.argwhere(seen[:-1] & ~seen[1:])  # (frame f, label): last sample at f (sorted by frame)
    starts = np.argwhere(~seen[:-1] & seen[1:])  # (frame f, label): first sample at f + 1 (sorted by frame)
    lo = np.searchsorted(starts[:, 0], ends[:, 0], side="left")
    count = np.searchsorted(starts[:, 0], ends[:, 0], side="right") - lo
    e = np.repeat(np.arange(len(ends)), count)  # every (end, start) pair of one frame
    b = lo[e] + np.arange(len(e)) - np.repeat(np.cumsum(count) - count, count)
    last = truth_pos[ends[e, 0], ends[e, 1]]
    before = truth_pos[np.maximum(ends[e, 0] - 1, 0), ends[e, 1]]  # (at frame 0 the sample itself)
    lead = np.where(np.isfinite(before), 2 * last - before, last)
    first = truth_pos[starts[b, 0] + 1, starts[b, 1]]
    after = truth_pos[np.minimum(starts[b, 0] + 2, len(truth_pos) - 1), starts[b, 1]]  # (at the end: the sample)
    source = np.where(np.isfinite(after), 2 * first - after, first)
    near = ((np.linalg.norm(lead - first, axis=1) < cfg.duplicate_m)
            | (np.linalg.norm(source - last, axis=1) < cfg.duplicate_m))
    jumps[ends[e[near], 0], ends[e[near], 1]] = True
    jumps[starts[b[near], 0] + 1, starts[b[near], 1]] = True
    for before, after, a, b in exchanges:
        jumps[before, [a, b]] = True
        jumps[after, [a, b]] = True
    frames, labels = _moved_across_gaps(truth_pos, cfg.duplicate_m)
    jumps[frames, labels] = True
    return jumps


def _moved_across_gaps(truth_pos: np.ndarray, duplicate_m: float) -> tuple[np.ndarray, np.ndarray]:
    """(n,) frames and (n,) labels of samples where the recording moved a label onto another marker across a gap
    (the whole sprint's frame 2156: the lateral epicondyle's label, missing one frame, lies on the upper arm's Marker2,
    missing since 2154, 4.5 mm from where that marker's path leads and 47 mm from where its own does): a label's
    first sample after a gap of at most ``_MOVED_GAP`` frames that lies within ``duplicate_m`` per frame extrapolated
    of where another label's path leads (constant velocity from its last two samples, missing since at most as
    long and at that frame), and at least ``_MOVED_OFF_M`` from where its own leads. ``truth_pos`` (F, M, 3) m."""
    seen = np.isfinite(truth_pos[..., 0])
    F, M = seen.shape
    last = np.maximum.accumulate(np.where(seen, np.arange(F)[:, None], -1), axis=0)  # (F, M) last sample at or before
    frames, labels = np.nonzero(~seen[:-1] & seen[1:])
    frames = frames + 1  # (each label's samples back after a gap)

    def lead(f: np.ndarray, m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where labels ``m`` (n,) lead at frames ``f`` (n,) from their last two samples before them, and how many
        frames on from the last (NaN and 0 where they have no two)."""
        e = last[f - 1, m]
        e2 = np.where(e >= 1, last[np.maximum(e - 1, 0), m], -1)
        ok = (e >= 0) & (e2 >= 0)
        e, e2 = np.where(ok, e, 0), np.where(ok, e2, 0)
        step = np.where(ok, f - e, 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            velocity = (truth_pos[e, m] - truth_pos[e2, m]) / np.where(ok, e - e2, 1)[:, None]
        return np.where(ok[:, None], truth_pos[e, m] + velocity * step[:, None], np.nan), step

    own, own_step = lead(frames, labels)
    short = (own_step >= 2) & (own_step <= _MOVED_GAP + 1)
    frames, labels, own = frames[short], labels[short], own[short]
    here = truth_pos[frames, labels]
    off_own = np.linalg.norm(here - own, axis=1) >= _MOVED_OFF_M
    frames, labels, here = frames[off_own], labels[off_own], here[off_own]
    moved = np.zeros(len(frames), dtype=bool)
    for other in range(M):  # (a few dozen labels; the candidates are few)
        rows = np.flatnonzero((labels != other) & ~seen[frames, other])
        if not rows.size:
            continue
        where, step = lead(frames[rows], np.full(rows.size, other))
        near = np.linalg.norm(here[rows] - where, axis=1) < duplicate_m * step
        moved[rows[near & (step >= 1) & (step <= _MOVED_GAP + 1)]] = True
    return frames[moved], labels[moved]


def _exchanged_across_gaps(truth_pos: np.ndarray, fps: float) -> list[tuple[int, int, int, int]]:
    """(last frame before, first frame after, label a, label b): two labels of one cluster (``truth_pos`` (F, M, 3),
    m) that the recording exchanged while both were hidden (an auto-labeller's guess at a symmetric cluster after a
    gap). A pair is a cluster where its median distance is under ``_CLUSTER_M`` and its robust spread under
    ``_CLUSTER_SPREAD_M``; it is compared by the markers around it (:func:`_contrast`, over 0.1 s at each end of a
    run of frames where both are seen). Where ``_EXCHANGE_NEIGHBOURS`` neighbours or more tell a from b on both
    sides of a gap and every one of them turned round (|before + after| under ``_EXCHANGE_RATIO`` of |before -
    after|, which averages over ``_EXCHANGE_M``), the labels were exchanged: a joint's turn changes how far a
    neighbour stands from a and from b by a few centimetres, it does not reverse that at every neighbour at once."""
    M = truth_pos.shape[1]
    seen = np.isfinite(truth_pos[..., 0])
    window = max(1, int(round(0.1 * fps)))
    found = []
    for a, b in zip(*np.triu_indices(M, 1), strict=True):
        both = seen[:, a] & seen[:, b]
        if both.sum() < 2:
            continue
        d = np.linalg.norm(truth_pos[both, a] - truth_pos[both, b], axis=1)
        middle = np.median(d)
        if middle > _CLUSTER_M or 1.4826 * np.median(np.abs(d - middle)) > _CLUSTER_SPREAD_M:
            continue
        anchor: tuple[int, dict[int, float]] | None = None  # the last run's end whose neighbours told a from b
        for _, run in column_runs(both[:, None], np.zeros((len(both), 1), dtype=bool)):
            first, last = int(run[0]), int(run[-1])
            if anchor is not None:
                head = _contrast(truth_pos, seen, np.arange(first, min(last, first + window - 1) + 1), a, b)
                common = [r for r in head if r in anchor[1]]
                if len(common) >= _EXCHANGE_NEIGHBOURS:
                    then = np.array([anchor[1][r] for r in common])
                    now = np.array([head[r] for r in common])
                    kept, turned = np.abs(then - now), np.abs(then + now)
                    if kept.mean() > _EXCHANGE_M and (turned < _EXCHANGE_RATIO * kept).all():
                        found.append((turned.sum() / kept.sum(), anchor[0], first, int(a), int(b)))
            tail = _contrast(truth_pos, seen, np.arange(max(first, last - window + 1), last + 1), a, b)
            if len(tail) >= _EXCHANGE_NEIGHBOURS:
                anchor = (last, tail)
    # A label moved to its partner's marker also turns round against a third marker midway between them: of the
    # exchanges found for one label over overlapping spans, only the clearest is kept.
    return [(before, after, a, b) for score, before, after, a, b in found
            if not any(other < score and {a, b} & {c, d} and before2 < after and before < after2
                       for other, before2, after2, c, d in found)]


def _contrast(truth_pos: np.ndarray, seen: np.ndarray, frames: np.ndarray, a: int, b: int) -> dict[int, float]:
    """For each other label seen in ``frames`` within ``_CONTEXT_M`` of label a: the median of its distance to a minus
    its distance to b over those frames, m, where that tells a from b (``_EXCHANGE_M`` / 2 or more)."""
    out = {}
    for r in np.flatnonzero(seen[frames].any(axis=0)):
        if r in (a, b):
            continue
        f = frames[seen[frames, r]]
        to_a = np.linalg.norm(truth_pos[f, a] - truth_pos[f, r], axis=1)
        value = float(np.median(to_a - np.linalg.norm(truth_pos[f, b] - truth_pos[f, r], axis=1)))
        if np.median(to_a) < _CONTEXT_M and abs(value) >= _EXCHANGE_M / 2:
            out[int(r)] = value
    return out


def _at_reference_jumps(frames: np.ndarray, oids: np.ndarray, m: _Matches, near_jump: np.ndarray,
                        exchanges: list[tuple[int, int, int, int]]) -> np.ndarray:
    """(S,) bool: the ID switches (``frames``, ``oids``: (S,) frame and truth marker) within ``_JUMP_REACH`` of a
    reference jump (``near_jump`` (F, M)) of their truth marker, at the switch or at that marker's previous matched
    frame: a label the recording gave another marker for one frame is matched to that marker's identity there, and
    the switch comes where the label is next seen on its own marker. A switch of one of two labels the recording
    exchanged across a gap (``exchanges``: last frame before, first after, the two labels) counts where the span
    from its previous match to it overlaps that gap: the output may have missed the samples either side of it."""
    F = near_jump.shape[0]
    key = np.sort(m.marker.astype(np.int64) * F + m.frame)  # matches by marker, then frame
    i = np.searchsorted(key, oids.astype(np.int64) * F + frames) - 1  # the match before the switch
    prev = key[np.maximum(i, 0)]
    prev_frame = np.where((i >= 0) & (prev // F == oids), prev % F, frames)
    at = near_jump[frames, oids] | near_jump[prev_frame, oids]
    for before, after, a, b in exchanges:
        at |= np.isin(oids, (a, b)) & (prev_frame <= after) & (frames >= before)
    return at


# ---------------------------------------------------------------------------- CLI
def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("output", metavar="OUT.c3d", help="reconstructed trajectories (C3D)")
    parser.add_argument("--truth", required=True, metavar="TRUTH.npz", help="ground truth written by mocap synth")
    parser.add_argument("--json", metavar="OUT.json", help="also write every figure (and per marker) as JSON")
    parser.add_argument("--gate-mm", type=float, default=20.0, help="matching gate, mm (default 20)")
    parser.add_argument(
        "--calibration", metavar="calibration.toml", help="rig for the Cramér–Rao reference (default: the truth's)"
    )
    parser.add_argument("--per-marker", action="store_true", help="print one line per truth marker")
    parser.add_argument("--switches", action="store_true",
                        help="print one line per ID switch: frame, truth marker, output tracks before and after")


def run(args: argparse.Namespace) -> int:
    if args.json:
        check_output_path(args.json)
    truth = load_truth(args.truth)
    traj = read_c3d(args.output)
    rig = load_rig(args.calibration) if args.calibration else None
    try:
        report = evaluate(traj, truth, rig, args.gate_mm)
    except MocapError as exc:
        raise MocapError(f"{args.output} against {args.truth}: {exc}") from None
    print(report.table(per_marker=args.per_marker, switches=args.switches))
    if args.json:
        atomic_write_bytes(args.json, (json.dumps(report.to_dict(), indent=2) + "\n").encode("utf-8"))
    return 0
