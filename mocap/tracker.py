"""The tracking engine (paper 004): 2D centroids of every camera in, labelled 3D markers out.

Per frame, for all tracks at once (numpy arrays, no per-marker Python objects):

1. **Predict** every track's 3D constant-acceleration EKF (world, metres) and its 2D EKFs (one per
   camera, ideal pixels). A camera's 2D prediction comes from its own image filter while that
   filter is locked (the marker was found there in the previous frame), else from projecting the
   3D prediction.
2. **Per-camera search** (:mod:`mocap.stereo`): each track's search region in each image has the
   radius given by its running prediction errors (:class:`mocap.ekf.RunningError`), widened while
   the marker is unseen; detections are assigned one-to-one per camera (optimal assignment where
   gates overlap). Confirmed tracks choose first, tentative ones take what is left.
3. **Epipolar pruning** over the stereo pairs (:mod:`mocap.pairs`): a choice no partner camera's
   epipolar line supports is dropped.
4. **Fusion** (:mod:`mocap.fusion`): covariance-weighted multi-view triangulation with per-camera
   outlier rejection, then the dropped/unseen cameras are offered the free detection nearest to the
   point's reprojection, and the point is recomputed. A view whose blob is smaller (scaled to depth) or
   flatter than the marker's own blob in that camera lately is the marker partly hidden, its centroid
   off: it is left out where two clean views remain (``partial_area``), and is no clean view where it stays. A
   two-view point leaning on a blob that holds less light than the marker's lately (``dark_flux``), off its
   prediction, is left out of the written trajectories after the identity repair (:meth:`Tracker.withheld`), not
   out of the tracking; a point with a view much darker than that (``dim_light``) and two clean views besides is
   written as triangulated without it (:meth:`Tracker.rewritten`).
5. **Update** the filters and the running errors with the measurements.
6. **New markers** from the detections no track used: all-pairs epipolar matching, triangulation,
   multi-view support. A point near a track that missed this frame re-acquires it; a point inside
   the (widening) search radius of a lost identity (around its prediction or last position, or where the
   steady neighbours it had when last seen carried it) starts a tentative track that inherits that
   identity when confirmed; any other starts a tentative track that gets a new identity after
   ``confirm_frames`` consecutive frames. Lost identities are kept ``keep_lost_s`` seconds. A take
   shorter than that gives identities, when it ends, to the tentative tracks measured in all its frames.

Between 4 and 5, where the measured neighbours of a track (markers within ``neighbour_m``) were
mispredicted alike by more than ``gate_floor_m``, their median error shifts the track's prediction
and steps 2-4 run again from the corrected predictions (fast swings at low frame rates).
Then a confirmed track's point that its identity's steady distances to the identities around it refute
(:mod:`mocap.attached`), where a lost identity's distances fit it, is left to that identity, and tracks that took
each other's markers (their points far off the extrapolation of their own last two points, each other's close by)
exchange them back (``settle_hops``), and a point from two cameras whose blob in one of them another point, not seen
there, projects onto is taken for a ghost: its track misses the frame (``yield_explained_blobs``).

The output position of a marker in a frame is its multi-view triangulation (not the filter state);
its residual is the RMS reprojection error back-projected to the marker's depth (px * depth / f).
"""

from __future__ import annotations

import math
import mmap
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, fields, replace
from itertools import accumulate

import numpy as np
from scipy.optimize import linear_sum_assignment

from mocap import kernels
from mocap.attached import AttachedDistances, verdicts
from mocap.camera import Lenses, Rig
from mocap.detect import MIN_SHAPE_AREA
from mocap.detections import MIN_CENTROID_STD_PX, Detections, floored_covariance
from mocap.ekf import RunningError, ca_process_noise, ca_transition, init_state, predict, update_position
from mocap.errors import MocapError
from mocap.fusion import (
    GAUSS_NEWTON_STEPS,
    NewPoints,
    Triangulated,
    distance_to_lost,
    new_points,
    reidentify,
    repick,
    robust_triangulate,
)
from mocap.geometry import project_ideal, reprojection_jacobians
from mocap.pairs import camera_pairs
from mocap.quickstats import nanmedian_columns, quick_median
from mocap.stereo import assign, dist2, epipolar_consistency, gate
from mocap.trajectories import RewrittenPoints, Trajectories, UnconfirmedPoints, WithheldPoints

__all__ = ["TrackerConfig", "FrameResult", "Tracker"]

# Per-frame code tests its small arrays with np.count_nonzero and indexes them with .nonzero()[0]: ndarray.any() and
# np.flatnonzero cost 3-7x as much there (~5 % and ~4 % of a frame on the tracking benchmark).


@dataclass
class TrackerConfig:
    """Every setting of the tracker (distances in metres or ideal pixels, times in frames or seconds).

    Attributes:
        confirm_frames: consecutive frames a new marker must be seen before it gets an identity.
        coast_frames: frames after its last measurement a track still searches its own gates.
        keep_lost_s: seconds a lost identity waits for re-identification before it is retired.
        jerk_std_3d: process noise of the 3D filters, std of the jerk, m/s^3.
        jerk_std_2d: process noise of the 2D image filters, std of the jerk, px/s^3.
        accel_damping: factor rho by which the filters' acceleration decays every frame (and only rho a
            drives the step, see :func:`mocap.ekf.ca_transition`): 1 is constant acceleration, 0 (the
            default) constant velocity. Constant acceleration extrapolated from precise measurements
            turns one swap of two neighbouring markers into a self-sustaining a, a, b, b swap cycle
            (the extrapolation 3 x1 - 3 x2 + x3 of that sequence always lands on the next one); at 50 Hz
            it also overshoots in fast, jerky motion.
        error_alpha: smoothing factor of the running prediction errors (paper 004).
        gate_scale: search radius = gate_scale x the running prediction error (+ floor).
        gate_floor_m: smallest 3D search radius, m.
        gate_floor_px: smallest 2D search radius, pixels.
        gate_max_px: largest 2D search radius, pixels.
        new_track_speed: speed assumed for the first prediction of a new track, m/s (its first gate).
        reid_max_m: largest re-identification radius of a lost identity, m.
        epipolar_px: largest symmetric epipolar distance of two views of one marker, pixels (or
            ``n_sigma`` x the two centroid stds combined, if larger).
        n_sigma: pixel tolerances (epipolar_px, repick_px, support_px) widen to this many centroid stds.
        outlier_sigma: a camera is rejected from a point beyond this many centroid stds ...
        outlier_min_px: ... and beyond this many pixels, or ``outlier_rms_factor`` x the take's typical
            reprojection RMS if larger (calibration error shows there).
        outlier_start_px: the rejection threshold before the take's typical RMS is measured, pixels (the
            running RMS starts from it / ``outlier_rms_factor``).
        outlier_rms_factor: see ``outlier_min_px``; the typical RMS is a running average (``error_alpha``) of
            each frame's median RMS over its points with three or more clean cameras.
        repick_px: a free detection this close to a point's reprojection joins the point, pixels.
        support_px: a free detection this close to a new point's reprojection supports it, pixels.
        new_min_views: cameras that must support a new marker (fewer when fewer cameras frame it).
        weak_motion_m: a track started from a weak new point (fewer supporting cameras than ``new_min_views``
            where more frame it) is confirmed only once it has moved this far, m, or while the confirmed tracks
            around it (``neighbour_m``, at least ``neighbour_min``) move less than that over ``confirm_frames``
            too (a still subject); confirmed that way and left behind when they move, it is withdrawn.
        weak_motion_sigma: ... or this many stds of the point's displacement if that is larger: two reflections
            whose rays cross 20 m away at 4 degrees make a point whose depth wanders by millimetres.
        min_separation_m: a new point closer than this to a measured track is that track's, not new.
        one_marker_m: two tracks' points closer than this (or ``n_sigma`` x their combined std, at most half
            ``marker_mm``) are one marker: only one of them keeps it (see ``Tracker._one_marker_one_track``).
        clutter_px: a free detection this close to one of the recent frames' free detections that no new point
            used is not new (see ``_known_clutter``).
        clutter_frames: free detections are remembered for at most this many frames; then the memory is
            cleared and everything is examined afresh (so a slow marker never stays hidden as clutter).
        marker_mm: marker diameter, mm: two markers predicted closer than their image diameter plus
            ``merge_px`` may share one merged blob in that image.
        merge_px: margin of that test, pixels.
        hidden_frames: ... counting only markers that camera saw within this many frames (one hidden from it for
            longer, behind the body, merges with nothing there).
        round_merged: a blob (of at least ``mocap.detect.MIN_SHAPE_AREA`` pixels) whose roundness is below this
            times cos(field angle), the roundness of a sphere's image there, is treated as merged.
        round_crowded: a blob flatter than this times cos(field angle) that another track is predicted close enough to
            share, holding none of its own, counts as merged for ``withhold_merged_depth``: two markers under a pixel
            apart flatten their blob less than ``round_merged`` catches (0.73-0.92 as two leg markers merged in the
            whole walking, 5 % hidden, seed 71; 99 % of the lone blobs there are 0.94 or rounder), and its centroid is
            up to half a pixel off. A marker seen alone beside a hidden neighbour stays round.
        smear_fraction: a flat blob a track takes alone is a streak of motion blur, not a merge, when a smear over
            this fraction of the track's image motion per frame (a shutter open that long) explains its shape.
        merged_variance_scale: centroid variance multiplier of blobs flagged as merged (by the detector,
            by ``round_merged``, or by two tracks predicted that close). A point is output only when two cameras
            without such blobs support it, or one does and it lies within ``suspect_m`` (clipped to ``gate_scale`` x
            the running position error) of its prediction; otherwise it only updates its filter.
        vague_px: a blob whose centroid std (RMS of the two axes) exceeds this, px, and 10x the frame's median
            std, is treated as merged too: a blob cut by the image border (std 2 px there) is no clean view.
        suspect_m: (low, high) bounds of that distance, m (high grows to ``n_sigma`` x the point's noise as its clean
            views give it).
        neighbour_m: tracks predicted this close are neighbours: markers of one body segment that fast motion
            mispredicts alike. When the median prediction error of a track's measured neighbours (itself
            included) exceeds ``gate_floor_m``, its prediction is shifted by it and the frame is associated again.
        neighbour_min: measured neighbours (itself included) needed for that correction.
        carry_m: where that correction exceeds this, m (a swing the constant-velocity prediction cannot follow),
            a confirmed track measured in the previous frame is predicted where the rotation and translation of
            its steady attached neighbours (see ``attached_check``; ``carry_neighbours`` or more, measured in both
            frames, not in a line, fitted within ``attached_tolerance_m`` RMS) carry it; 0: off ...
        carry_neighbours: see ``carry_m``.
        carry_lost: a lost identity is re-identified from where its steady attached neighbours, as they were in its
            last frame and as ``carry_neighbours`` or more of them are measured now, carry it (a rigid turn fitted
            within ``attached_tolerance_m`` RMS), instead of from its coasting prediction and last position (a marker
            back after a gap in a fast swing: its neighbour, seen where it vanished, is nearer to those).
        carry_in_play: a confirmed track two or more frames into its gap that still searches (``coast_frames``) is
            re-acquired, where its steady neighbours carry it (as ``carry_lost``), within its one-frame search radius
            of the carried place instead of its widened radius around its coasting prediction: a marker glimpsed in
            single frames of a fast swing (a serving hand's finger, 300 mm a frame at 50 Hz) is found again where
            the extrapolation of its last glimpse misses it, and the tentative tracks its glimpses start cannot
            follow it.
        carry_reach_m: a track without such neighbours (its distances broke: tracks stepping between a swinging
            segment's markers) is carried by the turn of the nearest carried track this close, m.
        settle_hops: where confirmed tracks measured in the previous frame too took points that their own last
            two points extrapolate to more than the hop acceleration away, and exchanging those points among them
            brings every track that changes within half of that of its extrapolation (and within half the distance
            to any other point), the points are exchanged before the update (see ``_settle_hops``) ...
        hop_acc_m, hop_acc_mps2: ... the hop acceleration: the larger of ``hop_acc_m`` m/frame^2 and
            ``hop_acc_mps2`` m/s^2 (the identity repair's jump, ``mocap.relabel.RelabelConfig.jump_acc``).
        deblend: a merged blob of two markers, one of them measured by two clean cameras or more, gives the
            other (when it has two clean cameras too) its mirror image about the first, checked against them (see
            ``_deblend``) ...
        deblend_px: ... with this std added, px (unequal blobs, a third marker's halo).
        withhold_merged_depth: a point seen cleanly by one camera only, its other views merged blobs that another
            live track's image lies in too (or ``round_crowded``'s), is not output (it still updates its filter): its
            depth along that camera's ray rests on the merged centroid, up to a marker radius off (see
            ``_depth_on_merged_blobs``).
        yield_explained_blobs: a point seen by two cameras, one of whose blobs (not merged) another measured point
            not seen in that camera projects onto (within ``explained_px`` or ``n_sigma`` blob stds), is a ghost: its
            track misses the frame (see ``_explained_elsewhere``) ...
        explained_px: ... px: the ghosts of the whole sprint (seed 1) lay 0.01-0.25 px from the other point's image,
            while a real two-view marker whose image overlaps a neighbour's (one blob, not flagged merged) has it
            0.6-1.5 px away.
        yield_outside_gate: a track's point outside its 3D search radius that an identity lost for at most
            ``yield_s`` holds inside its own, more tightly, is left to that identity (see ``_yield_outside_gate``) ...
        yield_s: ... seconds (at least one frame; the search radius of an identity lost for longer is wide enough
            to hold most points around it: at 120 Hz a plate marker's identity lost for 13 frames took a skin
            marker's point).
        attached_check: a confirmed identity's point whose distances to the identity's steady neighbours (see
            :mod:`mocap.attached`: up to ``attached_slots`` identities within ``attached_reach_m``, their distances
            held within ``attached_tolerance_m`` for ``attached_steady_s``) are all off, at least two of them, is
            left to a lost identity whose steady distances fit it (and whose search radius holds it): the track
            misses the frame, and the new-marker search gives the point to no identity it refutes while another
            fits. A hidden marker's widening gates otherwise take the neighbour that comes into view where it
            vanished (the sprint's forearm: markers 45-75 mm apart hidden in turn).
        attached_slots, attached_reach_m, attached_tolerance_m, attached_steady_s: see ``attached_check``.
        noisy_point_m: a track whose last point's std exceeds this (m) gets proportionally more 3D process
            noise (up to 10x ``jerk_std_3d``): noisy points (small, far markers) must not make the filter lag.
        rival_ratio: where the robust triangulation of a confirmed track's assigned blobs kept one group of views
            and dropped two or more that make a point of their own (another marker's blobs, in a wide gate), the
            track takes that dropped point instead if it lies within its search radius and under ``rival_ratio`` x
            the kept point's distance from the prediction, and the kept point is a hop (over ``hop_acc_m`` off
            it; see ``_nearer_rival``); 0: off. The triangulation's
            consensus takes the group with most views, which a fast swing's widened gates fill with a neighbour's.
        silent_yield: a new point that a lost identity's search radius holds and whose distance to one of that
            identity's steady neighbours measured this frame holds (none off) may not go to a lost identity with no
            steady neighbour measured (see ``_attached_allow``): the nearer last place of an identity nothing speaks
            for does not outweigh a neighbour's distance (a heel marker back after a step took the identity of a toe
            marker lost 117 frames before; its own was 364 mm off, its distance to the toe held to 1 mm).
        refuted_wide_m: a lost identity whose search radius has grown to this (m) or wider may not take a new point
            that its steady neighbours measured this frame all refute (two or more; see ``attached_check``), even
            where no other identity claims it: the point starts an identity of its own. After a long gap the
            radius (up to ``reid_max_m``) holds any marker nearby, and the distance alone says little (a 50 Hz
            serve's left-finger identity, lost 13 frames, took the tibia's return, which its hand's markers refute);
            0: off. (With no floor on the radius the 120 Hz sprint's forearm, whose glimpsed markers refute each
            other's identities in turn, lost 0.03 IDF1.)
        refuted_gap_frames: a confirmed track this many frames (or more) into its gap, still searching
            (``coast_frames``), may not take a point that its steady neighbours measured this frame all refute (two
            or more; see ``attached_check``), even where no lost identity claims it: the track misses the frame and
            the point starts an identity of its own. A coasting track's gate has widened over the gap and holds a
            neighbour coming back first (the two players' left hand at 50 Hz: the wrist's track, three frames into
            its gap, took the finger's return 88 mm from the wrist, and the repair then gave the finger's and the
            wrist's later samples the wrong identities). A longer-lost identity is judged by ``refuted_wide_m``:
            after long, a static marker's steady neighbours may have left while its search radius stays small;
            0: off. The gated path judges a track to its last searching frame (``coast_frames`` + 1 into its gap),
            re-acquisition from free points to ``coast_frames``: each bound measured better than the other there
            (``docs/engine-log.md``, seventy-eighth session).
        partial_area: a blob smaller than its marker's blob in that camera lately (a running average, scaled to
            the point's depth) by more than this / sqrt(that area) (the pixel count's spread), or ...
        partial_round: ... flatter by more than this / sqrt(area) and no larger, is the marker partly hidden (behind
            a limb, at an occluder's edge): its centroid is off towards the part seen, up to 0.4 of a radius, often
            along another camera's epipolar line where the fusion cannot see it. Such a view is left out of a point
            that keeps two clean views without it, and is not re-picked; 0: off.
        partial_min_area: blobs expected smaller than this (px) are not judged.
        partial_suspect: a partly hidden view that stays in a point is no clean view: a point leaning on it is
            output only where it agrees with the prediction, as one leaning on a merged blob (a two-view point with a
            cut view is 1-5 mm off, along the clean camera's ray, and nothing else tells).
        blob_alpha: smoothing factor of the running blob area and roundness per track and camera.
        partial_frames: a blob judged partly hidden more than this many frames in a row is taken for the marker's
            blob now (an exposure change, a marker of another size taken over, a lasting cover), and the running
            average starts again from it: without it such a track would have no clean view again.
        appearing_light: a blob of a marker measured in the previous frame, in a camera that had no blob of it then
            (coming out from behind something), with less than this of the marker's light in that camera lately (at
            the predicted depth; not judged where no light is known there yet) is taken for the marker partly
            hidden: left out where two clean views remain, and not offered back by the re-pick; 0: off. A cut to
            half a radius keeps 0.72-0.78 of the light, which the running deviation of a far camera's small blobs
            lets pass as whole; the frame back is when a cut is most likely.
        appearing_borrowed: ... and where that camera has no light of the marker yet, a blob of ``partial_min_area``
            px or more with less than this of the light its marker's other views give this frame (each moved to its
            depth and taken over its camera's gain, learnt over the take) is taken for partly hidden too; 0: off.
            Light compared across cameras at other depths errs by the depth power's fit and the cameras' gains:
            at 0.8 whole blobs entering a far camera of the whole sprint's walkway were left out; a blob cut through
            its centre keeps half the light.
        dark_borrowed: the darker-view judgement (``dark_flux``) of a view whose camera knows no light of the marker
            yet: under this of the light of the point's other views (as ``appearing_borrowed`` judges) it is darker;
            0: off. It withholds only points off their prediction, so it can judge more closely.
        dark_flux: a blob whose light (:attr:`mocap.detections.Detections.flux`) is less than its marker's blob's in
            that camera lately (a running average, scaled to depth as 1 / depth^4: a retroreflector lit from the
            camera) by more than this fraction, or by ``dark_spread`` times that light's running mean absolute
            relative deviation (faint blobs, a flickering marker) up to ``dark_max``, is the marker partly hidden: a
            point that leans on it (fewer than two clean views without it) and disagrees with the prediction is left
            out of the written trajectories, after the identity repair (:meth:`Tracker.withheld`). Tracking itself
            (assignment, filters, identities) does not use this judgement: small faint blobs' light jumps when a
            pixel crosses the threshold, and leaving such views out of the tracking cost the 12-camera sprint's
            forearm cluster its identities (engine-log.md, 75th session). 1: off.
        dark_spread, dark_max: see ``dark_flux``.
        dim_light: a view whose blob holds less than this of its marker's light in that camera lately (as
            ``dark_flux`` measures it) is the marker cut: where two clean views remain besides, the point is
            triangulated again without it (merged or not) and written so after the identity repair
            (:meth:`Tracker.rewritten`); where fewer remain, the point is not written (:meth:`Tracker.withheld`).
            The tracking does not change. Whole views of the default and one-height-light renders hold under 0.8 of
            their light 0.13-0.15 % of the time, the cut views the other rules leave in the points 96 % of it
            (engine-log.md, 80th session); 0: off.
    """

    confirm_frames: int = 4
    coast_frames: int = 3
    keep_lost_s: float = 20.0
    jerk_std_3d: float = 20.0
    jerk_std_2d: float = 50000.0
    accel_damping: float = 0.0
    error_alpha: float = 0.3
    gate_scale: float = 3.0
    gate_floor_m: float = 0.01
    gate_floor_px: float = 3.0
    gate_max_px: float = 200.0
    new_track_speed: float = 3.0
    reid_max_m: float = 0.5
    epipolar_px: float = 2.0
    n_sigma: float = 4.0
    outlier_sigma: float = 6.0
    outlier_min_px: float = 0.05
    outlier_start_px: float = 0.6
    outlier_rms_factor: float = 4.0
    repick_px: float = 1.5
    support_px: float = 2.0
    new_min_views: int = 3
    weak_motion_m: float = 0.003
    weak_motion_sigma: float = 4.0
    min_separation_m: float = 0.012
    one_marker_m: float = 0.003
    clutter_px: float = 0.5
    clutter_frames: int = 30
    marker_mm: float = 14.0
    merge_px: float = 1.5
    hidden_frames: int = 10
    round_merged: float = 0.8
    round_crowded: float = 0.93
    merged_variance_scale: float = 100.0
    vague_px: float = 0.5
    smear_fraction: float = 0.5
    suspect_m: tuple[float, float] = (0.001, 0.002)
    neighbour_m: float = 0.2
    noisy_point_m: float = 0.0003
    neighbour_min: int = 2
    carry_m: float = 0.03
    carry_neighbours: int = 3
    carry_lost: bool = True
    carry_in_play: bool = True
    carry_reach_m: float = 0.15
    settle_hops: bool = True
    hop_acc_m: float = 0.06
    hop_acc_mps2: float = 250.0
    deblend: bool = True
    deblend_px: float = 0.1
    withhold_merged_depth: bool = True
    yield_explained_blobs: bool = True
    explained_px: float = 0.4
    yield_outside_gate: bool = True
    yield_s: float = 0.085
    attached_check: bool = True
    attached_slots: int = 6
    attached_reach_m: float = 0.5
    attached_tolerance_m: float = 0.01
    attached_steady_s: float = 0.1
    rival_ratio: float = 0.25
    partial_area: float = 0.9
    partial_round: float = 0.45
    partial_min_area: float = 4.0
    partial_suspect: bool = True
    partial_frames: int = 8
    appearing_light: float = 0.92
    appearing_borrowed: float = 0.65
    dark_borrowed: float = 0.8
    dark_flux: float = 0.08
    dim_light: float = 0.8
    dark_spread: float = 4.0
    dark_max: float = 0.3
    blob_alpha: float = 0.3
    silent_yield: bool = True
    refuted_wide_m: float = 0.25
    refuted_gap_frames: int = 3

    def __post_init__(self) -> None:
        for name in ("confirm_frames", "new_min_views"):
            if getattr(self, name) < 1:
                raise MocapError(f"tracker setting {name} = {getattr(self, name)} must be >= 1")
        for name in ("epipolar_px", "gate_scale", "gate_floor_m", "gate_floor_px", "gate_max_px", "repick_px",
                     "support_px", "outlier_min_px", "outlier_start_px", "reid_max_m"):
            if not getattr(self, name) > 0:
                raise MocapError(f"tracker setting {name} = {getattr(self, name)} must be > 0")
        if not 0 <= self.accel_damping <= 1:
            raise MocapError(f"tracker setting accel_damping = {self.accel_damping} must be in [0, 1]")
        if not 0 < self.error_alpha <= 1:
            raise MocapError(f"tracker setting error_alpha = {self.error_alpha} must be in (0, 1]")
        if self.refuted_wide_m < 0:
            raise MocapError(f"tracker setting refuted_wide_m = {self.refuted_wide_m} must be >= 0")
        if self.refuted_gap_frames < 0:
            raise MocapError(f"tracker setting refuted_gap_frames = {self.refuted_gap_frames} must be >= 0")
        for name in ("appearing_light", "appearing_borrowed", "dark_borrowed"):
            if getattr(self, name) < 0:
                raise MocapError(f"tracker setting {name} = {getattr(self, name)} must be >= 0")
        if not 0 <= self.rival_ratio < 1:
            raise MocapError(f"tracker setting rival_ratio = {self.rival_ratio} must be in [0, 1)")


@dataclass
class FrameResult:
    """The confirmed markers measured in one frame.

    Attributes:
        frame_index: the frame.
        ids: (K,) identity index (label ``M{id+1:03d}``, as in the output of :meth:`Tracker.finish`).
        positions: (K, 3) m.
        residuals_mm: (K,) RMS reprojection error at the marker's depth, mm.
        camera_masks: (K,) uint32, bit c set when camera c was used.
        assignments: per camera, (N_c,) identity index of each detection, -1 = unused.
    """

    frame_index: int
    ids: np.ndarray
    positions: np.ndarray
    residuals_mm: np.ndarray
    camera_masks: np.ndarray
    assignments: list[np.ndarray] = field(default_factory=list)


# Prior std of a (re)started image filter's velocity (px/s) and acceleration (px/s^2); the gates come from
# the running errors, so these only set the first gains.
_IMAGE_VELOCITY_STD = 1e3
_IMAGE_ACCEL_STD = 1e5
_VAGUE_TYPICAL = 10.0  # a vague blob's std is also over this many times the frame's median (see vague_px)
_BLOB_FIELDS = 7  # a track's blob record per camera (_Tracks.blob)
_CAMERA_GAIN_ALPHA = 0.05  # smoothing of the cameras' light gains per frame (Tracker._learn_camera_gains)
_FLUX_DEPTH_POWER = 4  # a retroreflector lit from the camera: its light there falls as 1 / depth^4 (before any fit)
_FLUX_DEPTH_PRIOR = 0.04  # weight of that power against the fit's sum of squared log depth ratios
_FLUX_DEPTH_RANGE = (1.0, 6.0)  # the fitted power is kept within
_FLUX_STEP_CLIP = 0.3  # a log light ratio between two views counts at most this far off the power so far
_FORGET_ATTACHED_S = 2.0  # an attached neighbour not measured with its identity for this long is forgotten


def _released_on_free(shape: tuple[int, ...], dtype: type) -> np.ndarray:
    """An uninitialised array in its own anonymous memory map: freeing it returns its memory to the system at once
    (the C heap keeps freed blocks of a few MB for reuse, where the output arrays built from them cannot use them)."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    return np.frombuffer(mmap.mmap(-1, max(size, 1)), dtype=dtype, count=int(np.prod(shape))).reshape(shape)


class _Records:
    """Per-frame measurements in fixed-size chunks: appending never copies what is stored, so memory
    grows only by what the take adds (no per-frame objects, no capacity doubling); each chunk is released to the
    system when :meth:`drain` has moved it into the output."""

    CHUNK = 1 << 16
    _COLUMNS = (("frame", (), np.int32), ("uid", (), np.int32), ("pos", (3,), np.float64),
                ("res", (), np.float32), ("mask", (), np.uint32))

    def __init__(self) -> None:
        self._chunks: list[dict[str, np.ndarray]] = []
        self._fill = self.CHUNK  # samples used in the last chunk

    def append(self, **values: np.ndarray) -> None:
        k = len(values["uid"])
        if self._chunks and self._fill + k <= self.CHUNK:  # the usual case: one slice per column
            chunk, fill = self._chunks[-1], self._fill
            for name, value in values.items():
                chunk[name][fill : fill + k] = value
            self._fill += k
            return
        done = 0
        while done < k:
            if self._fill == self.CHUNK:
                self._chunks.append({name: _released_on_free((self.CHUNK,) + shape, dtype)
                                     for name, shape, dtype in self._COLUMNS})
                self._fill = 0
            take = min(k - done, self.CHUNK - self._fill)
            chunk = self._chunks[-1]
            for name, value in values.items():  # a scalar fills the rows, an array gives one per row
                chunk[name][self._fill : self._fill + take] = value[done : done + take] if np.ndim(value) else value
            self._fill += take
            done += take

    def peek(self, *names: str) -> Iterator[tuple[np.ndarray, ...]]:
        """Yield the stored samples' columns ``names``, chunk by chunk, keeping them."""
        for i, chunk in enumerate(self._chunks):
            used = self._fill if i == len(self._chunks) - 1 else self.CHUNK
            yield tuple(chunk[name][:used] for name in names)

    def drain(self) -> Iterator[dict[str, np.ndarray]]:
        """Yield the stored samples chunk by chunk, releasing each chunk once yielded."""
        while self._chunks:
            chunk = self._chunks.pop(0)
            used = self._fill if not self._chunks else self.CHUNK
            yield {name: column[:used] for name, column in chunk.items()}
        self._fill = self.CHUNK


class _Rows:
    """Parallel arrays, one row per track: select rows, or append another record's rows."""

    def keep(self, mask: np.ndarray) -> None:
        for f in fields(self):
            setattr(self, f.name, getattr(self, f.name)[mask])

    def extend(self, other: _Rows) -> None:
        for f in fields(self):
            setattr(self, f.name, np.concatenate([getattr(self, f.name), getattr(other, f.name)]))


@dataclass
class _Tracks(_Rows):
    """The live tracks as parallel arrays (first axis: track)."""

    uid: np.ndarray  # (K,) unique per track start; keys the records
    ident: np.ndarray  # (K,) identity, -1 while tentative
    cand: np.ndarray  # (K,) lost identity a tentative track may inherit, -1: none
    hits: np.ndarray  # (K,) consecutive measured frames
    since: np.ndarray  # (K,) frames since the last measurement (0: this frame)
    x3: np.ndarray  # (K, 9) world CA state, m
    P3: np.ndarray  # (K, 9, 9)
    e3: np.ndarray  # (K, 3) running errors: position m, velocity m/s, acceleration m/s^2
    last_X: np.ndarray  # (K, 3) last measured position, m
    last_v: np.ndarray  # (K, 3) last measured velocity (finite differences), NaN: unknown
    x2: np.ndarray  # (K, C, 6) image CA states, ideal px
    P2: np.ndarray  # (K, C, 6, 6)
    lock2: np.ndarray  # (K, C) image filter found the marker in the previous frame
    unseen2: np.ndarray  # (K, C) frames since the marker was last measured in that camera
    e2: np.ndarray  # (K, C, 3) running image errors: px, px/s, px/s^2
    last_uv: np.ndarray  # (K, C, 2) last measured image position, px
    last_uvv: np.ndarray  # (K, C, 2) last measured image velocity, px/s
    weak: np.ndarray  # (K,) started from a two-view point that not all framing cameras supported
    origin: np.ndarray  # (K, 3) where the track started, m
    noise: np.ndarray  # (K,) std of the last measured point, m
    blob: np.ndarray  # (K, C, 7) the marker's blob in each camera lately (NaN: none): area px, roundness, depth m,
    #   flux (grey levels) and its mean absolute relative deviation; the last clean view's flux and depth m
    cut_run: np.ndarray  # (K, C) consecutive views of it in that camera judged partly hidden
    dark_run: np.ndarray  # (K, C) ... judged darker
    blob_unseen: np.ndarray  # (K, C) frames since a blob was assigned to it in that camera (used or left out)

    @classmethod
    def empty(cls, C: int) -> _Tracks:
        i = np.zeros(0, dtype=np.intp)
        return cls(i, i, i, i, i, np.zeros((0, 9)), np.zeros((0, 9, 9)), np.zeros((0, 3)), np.zeros((0, 3)),
                   np.zeros((0, 3)), np.zeros((0, C, 6)), np.zeros((0, C, 6, 6)), np.zeros((0, C), dtype=bool),
                   np.zeros((0, C), dtype=np.intp), np.zeros((0, C, 3)), np.zeros((0, C, 2)), np.zeros((0, C, 2)),
                   np.zeros(0, dtype=bool), np.zeros((0, 3)), np.zeros(0), np.zeros((0, C, _BLOB_FIELDS)),
                   np.zeros((0, C), dtype=np.intp), np.zeros((0, C), dtype=np.intp), np.zeros((0, C), dtype=np.intp))

    def __len__(self) -> int:
        return len(self.uid)


@dataclass
class _Measurements(_Rows):
    """This frame's measurements of the K live tracks (row k: track k)."""

    ok: np.ndarray  # (K,) measured: the filters take it
    out: np.ndarray  # (K,) reliable (two clean cameras): it is output
    X: np.ndarray  # (K, 3) m
    cov: np.ndarray  # (K, 3, 3) m^2
    rms_px: np.ndarray  # (K,) reprojection RMS, px
    asg: np.ndarray  # (K, C) detection used per camera, -1: none
    withheld: np.ndarray  # (K,) output points the written trajectories leave out (Tracker._judge_dark_views)
    written: np.ndarray  # (K, 3) m, the position written instead of X (Tracker._without_dim_views); NaN: X
    written_residual: np.ndarray  # (K,) its residual, mm
    written_mask: np.ndarray  # (K,) uint32 its cameras (bit c: camera c)

    @classmethod
    def empty(cls, K: int, C: int) -> _Measurements:
        return cls(np.zeros(K, dtype=bool), np.zeros(K, dtype=bool), np.full((K, 3), np.nan),
                   np.full((K, 3, 3), np.nan), np.full(K, np.nan), np.full((K, C), -1, dtype=np.intp),
                   np.zeros(K, dtype=bool), *_Measurements.unwritten(K))

    @staticmethod
    def unwritten(K: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``written``, ``written_residual`` and ``written_mask`` of K points written as measured."""
        return np.full((K, 3), np.nan), np.full(K, np.nan), np.zeros(K, dtype=np.uint32)

    def rows(self, rows: np.ndarray) -> _Measurements:
        """A copy of the rows ``rows``."""
        return _Measurements(*(getattr(self, f.name)[rows] for f in fields(self)))

    def miss(self, rows: np.ndarray, C: int) -> None:
        """The tracks ``rows`` (of C cameras) are not measured this frame."""
        if rows.size:  # (most frames: none)
            self.put(rows, _Measurements.empty(len(rows), C))

    def put(self, rows: np.ndarray, other: _Measurements) -> None:
        """Copy ``other``'s rows (len(rows) of them) into ``rows``."""
        for f in fields(self):
            getattr(self, f.name)[rows] = getattr(other, f.name)


@dataclass
class _Frame:
    """One frame's detections, padded: ``D`` (C, N, 2) ideal px, ``S`` (C, N, 2, 2) px^2, ``valid``,
    ``merged`` (C, N) bool, ``roundness`` (C, N) (1 for blobs too small to tell), ``area`` (C, N) px, ``flux``
    (C, N) grey levels (NaN: not measured), ``counts`` per camera."""

    D: np.ndarray
    S: np.ndarray
    valid: np.ndarray
    merged: np.ndarray
    roundness: np.ndarray
    area: np.ndarray
    flux: np.ndarray
    counts: list[int]


class Tracker:
    """Multi-view marker tracker with stable identities (see the module docstring).

    Args:
        rig: the calibrated cameras; ``step`` takes their detections in this order.
        fps: frame rate, Hz.
        config: settings (defaults: :class:`TrackerConfig`).
    """

    def __init__(self, rig: Rig, fps: float, config: TrackerConfig | None = None) -> None:
        if not (np.isfinite(fps) and fps > 0):
            raise MocapError(f"frame rate must be a positive number of frames per second, got {fps}")
        self._rig = rig
        self._fps = float(fps)
        self._cfg = cfg = config or TrackerConfig()
        self._dt = dt = 1.0 / self._fps
        self._C = C = len(rig)
        self._P = rig.projection_matrices()
        self._pairs = camera_pairs(rig)
        self._pairs_index = kernels.contiguous(self._pairs.index, np.intp)  # (the kernels' layout)
        self._pairs_F = kernels.contiguous(self._pairs.F)
        self._focal = np.array([0.5 * (c.matrix[0, 0] + c.matrix[1, 1]) for c in rig.cameras])
        self._focal_xy = np.array([[c.matrix[0, 0], c.matrix[1, 1]] for c in rig.cameras])
        self._centre = np.array([[c.matrix[0, 2], c.matrix[1, 2]] for c in rig.cameras])
        self._lenses = Lenses(rig.cameras)
        self._sizes = np.array([c.size for c in rig.cameras], dtype=float)
        self._F3, self._Q3 = ca_transition(dt, 3, cfg.accel_damping), ca_process_noise(dt, 3, cfg.jerk_std_3d)
        self._F2, self._Q2 = ca_transition(dt, 2, cfg.accel_damping), ca_process_noise(dt, 2, cfg.jerk_std_2d)
        self._running = RunningError(cfg.error_alpha, cfg.gate_scale)
        self._keep_lost = max(1, int(round(cfg.keep_lost_s * self._fps)))
        self._yield_frames = max(1, int(round(cfg.yield_s * self._fps)))
        self._hop_m = max(cfg.hop_acc_m, cfg.hop_acc_mps2 * dt * dt)  # m/frame^2: a track's point over this off
        # the extrapolation of its last two points hopped (see _settle_hops)
        self._attached = AttachedDistances(cfg.attached_slots, cfg.attached_reach_m, cfg.attached_tolerance_m,
                                           max(1, int(round(cfg.attached_steady_s * self._fps))),
                                           max(1, int(round(_FORGET_ATTACHED_S * self._fps))))
        self._t = _Tracks.empty(C)
        self._blobs_followed = cfg.partial_area > 0 or cfg.dark_flux < 1  # (the running blob records)
        self._expect = np.zeros((0, C, 4))  # (K, C, 4) the tracks' blobs expected this frame (_expected_blobs)
        self._next_uid = 0
        self._uid_ident = np.full(256, -1, dtype=np.intp)
        self._n_ident = 0
        self._records = _Records()
        self._withheld: list[tuple[np.ndarray, np.ndarray]] = []  # (frame (n,), position (n, 3)) (_judge_dark_views)
        self._rewritten: list[tuple[np.ndarray, ...]] = []  # (frame, tracked, written, residual, mask)
        self._light = False  # some blob has carried its light (Detections.flux)
        self._light_fit = np.zeros(2)  # sums of x^2 and x y, x and y the log depth and light ratios of clean views
        self._light_power = float(_FLUX_DEPTH_POWER)  # the light falls as 1 / depth^power (_fit_light_power)
        self._camera_gain = np.zeros(len(rig))  # (C,) log of each camera's light over the others' (_learn_camera_gains)
        self._result: Trajectories | None = None
        self._unconfirmed: UnconfirmedPoints | None = None
        self._clutter: deque[np.ndarray] = deque(maxlen=max(cfg.clutter_frames, 1))  # recent free detections
        self._first: int | None = None
        self._next_views: list[tuple[np.ndarray, np.ndarray, np.ndarray]] | None = None  # _next_images, this step's
        self._last = -1
        self._assigned_blobs = np.zeros((0, self._C), dtype=bool)  # (K, C) blobs assigned this step (_measure)
        self._outlier_px = cfg.outlier_start_px  # camera rejection floor, px (follows the residual level)
        self._rms_px = cfg.outlier_start_px / max(cfg.outlier_rms_factor, 1.0)  # typical reprojection RMS, px
        kernels.announce()

    # ------------------------------------------------------------------ public API
    def step(self, frame_index: int, detections: list[Detections]) -> FrameResult:
        """Track one frame: ``detections`` holds one :class:`Detections` per camera, rig order."""
        if len(detections) != self._C:
            raise MocapError(f"frame {frame_index}: {len(detections)} detection sets for {self._C} cameras")
        if self._first is None:
            self._first = frame_index
        self._last = max(self._last, frame_index)
        self._next_views = None
        t, C = self._t, self._C
        fr = self._prepare(detections)
        self._light = self._light or bool(np.isfinite(fr.flux[:, :1]).any())  # (a frame's first blobs tell)
        t.since += 1
        t.unseen2 += 1
        t.blob_unseen += 1
        if self._blobs_followed:
            self._fit_light_power()
            self._expect = self._expected_blobs()
        self._predict()
        K = len(t)
        meas = _Measurements.empty(K, C)
        self._assigned_blobs = np.zeros((K, C), dtype=bool)
        play = self._in_play()
        if K and fr.D.shape[1]:
            self._associate(fr, play, t.lock2, meas)
            shift = self._neighbour_shift(meas, play)
            if self._cfg.attached_check and self._cfg.carry_m > 0:
                shift = self._carried_shift(meas, play, shift)
            moved = np.linalg.norm(shift, axis=1) > self._cfg.gate_floor_m
            if np.count_nonzero(moved):  # the neighbours say the prediction was off: associate again from them
                t.x3[moved, :3] += shift[moved]
                meas = _Measurements.empty(K, C)
                self._associate(fr, play, t.lock2 & ~moved[:, None], meas)
                t.x3[moved, :3] -= shift[moved]
            if self._cfg.yield_outside_gate:  # (judged from the predictions the points were searched from)
                self._yield_outside_gate(meas, np.where(moved[:, None], shift, 0.0))
            if self._cfg.attached_check:
                self._refute_by_attached(meas)
            if self._cfg.settle_hops:
                self._settle_hops(meas)
            if self._cfg.yield_explained_blobs:
                meas.miss(self._explained_elsewhere(fr, meas).nonzero()[0], C)
            self._without_dim_views(fr, meas)  # (before the update: the tracks' last depths)
            self._update(fr, meas, meas.ok.nonzero()[0])
            if self._light and (self._cfg.appearing_borrowed > 0 or self._cfg.dark_borrowed > 0):
                self._learn_camera_gains(fr, meas)
            t.blob_unseen[self._assigned_blobs] = 0  # (after every measuring pass: each judges the frame's blobs alike)
            self._follow_residual_level(fr, meas)
        self._new_markers(fr, fr.valid & ~_taken(meas.asg, fr.valid.shape), meas)
        self._lifecycle(meas)
        if self._cfg.attached_check:
            measured = ((self._t.ident >= 0) & (self._t.since == 0)).nonzero()[0]
            self._attached.learn(self._t.ident[measured], self._t.last_X[measured])
        return self._record(frame_index, fr, meas)

    def predicted_rois(self) -> list[np.ndarray]:
        """Per camera (K, 4) int ``x0, y0, x1, y1`` search windows (distorted pixels) for the next frame."""
        cfg = self._cfg
        out = []
        for c, (uv, depth, r3) in enumerate(self._next_images()):
            r = np.clip(r3 * self._focal[c] / depth, cfg.gate_floor_px, cfg.gate_max_px) + 2.0
            box = np.concatenate([uv - r[:, None], uv + r[:, None]], axis=1)
            w, h = self._rig.cameras[c].size
            out.append(np.clip(np.round(box), 0, [w - 1, h - 1, w - 1, h - 1]).astype(np.int64))
        return out

    def predicted_centres(self) -> list[np.ndarray]:
        """Per camera (K, 2) predicted marker positions (distorted pixels) in the next frame: the seeds with which
        :func:`mocap.detect.detect` splits a merged blob that shows no saddle."""
        return [uv for uv, _, _ in self._next_images()]

    def _next_images(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Per camera, the live tracks' predictions for the next frame in front of it: distorted pixels (K, 2),
        depths (K,) m and 3D search radii (K,) m (computed once per step: the windows and the seeds share it)."""
        if self._next_views is not None:
            return self._next_views
        t, cfg = self._t, self._cfg
        live = (t.since <= cfg.coast_frames) & ((t.ident >= 0) | (t.since == 0))
        x3, _ = predict(t.x3[live], t.P3[live], self._F3, self._Q3)
        r3 = np.minimum(self._running.radius(*t.e3[live].T, t.since[live] + 1, self._dt, cfg.gate_floor_m),
                        cfg.reid_max_m)
        self._next_views = []
        for cam in self._rig.cameras:
            uv = cam.project(x3[:, :3])
            depth = cam.world_to_camera(x3[:, :3])[:, 2]
            ok = np.isfinite(uv).all(axis=1) & (depth > 0)
            self._next_views.append((uv[ok], depth[ok], r3[ok]))
        return self._next_views

    def withheld(self) -> WithheldPoints:
        """The tracked points the written trajectories leave out: two-view points leaning on a view of their
        marker partly hidden (darker than its blob lately; :meth:`_judge_dark_views`) that disagree with the
        prediction, points with fewer than two clean views besides a view under ``dim_light`` of the marker's light
        (whatever the prediction), and points from the free blobs re-acquiring a track, or starting one that may
        inherit a lost identity, that lean on darker views (:meth:`_leans_on_dark_views`). For
        :meth:`WithheldPoints.apply` after the identity repair, which works on the tracked points, so that this
        judgement never moves an identity."""
        first = self._first if self._first is not None else 0
        if not self._withheld:
            return WithheldPoints(np.zeros(0, np.int64), np.zeros((0, 3)))
        frame, pos = (np.concatenate(column) for column in zip(*self._withheld, strict=True))
        return WithheldPoints(frame.astype(np.int64) - first, pos)

    def rewritten(self) -> RewrittenPoints:
        """The tracked points the written trajectories give another position: points with a dim view (under
        ``dim_light`` of their marker's light in that camera lately) and two clean views besides, triangulated again
        without it (:meth:`_without_dim_views`). For :meth:`RewrittenPoints.apply` after the identity repair, as
        :meth:`withheld`'s, so that this judgement never moves an identity."""
        first = self._first if self._first is not None else 0
        if not self._rewritten:
            return RewrittenPoints.none()
        frame, tracked, written, residual, mask = (np.concatenate(column) for column in zip(*self._rewritten,
                                                                                             strict=True))
        return RewrittenPoints(frame.astype(np.int64) - first, tracked, written, residual, mask)

    def _without_dim_views(self, fr: _Frame, meas: _Measurements) -> None:
        """``meas.written*``: the measured points of ``meas`` with a view whose light, moved to the point's depth, is
        under ``dim_light`` of its marker's there lately (:meth:`_light_of_views`; a blob flagged merged too: its
        variance is only scaled) and two clean views besides (not flagged merged, not dim), triangulated again
        without their dim views, with their residuals and cameras; a point whose clean views do not all stay in it
        keeps its views."""
        cfg = self._cfg
        if not (self._light and cfg.dim_light > 0):
            return
        rows = meas.ok.nonzero()[0]
        asg = meas.asg[rows]
        k, c = np.nonzero(asg >= 0)
        if k.size == 0:
            return
        ratio, merged, _ = self._light_of_views(fr, rows[k], c, asg[k, c], meas.X[rows[k]])
        dim = np.zeros(asg.shape, dtype=bool)
        with np.errstate(invalid="ignore"):  # (unknown light, NaN: not dim)
            dim[k, c] = ratio < cfg.dim_light
        clean = (asg >= 0) & ~_gather(fr.merged, asg) & ~dim
        sel = (dim.any(axis=1) & (clean.sum(axis=1) >= 2)).nonzero()[0]
        if sel.size == 0:
            return
        sub = np.where(dim[sel], -1, asg[sel])
        t2 = robust_triangulate(self._P, _gather(fr.D, sub).swapaxes(0, 1), _gather(fr.S, sub).swapaxes(0, 1),
                                meas.X[rows[sel]], cfg.outlier_sigma, self._outlier_px)
        ok = np.isfinite(t2.X).all(axis=1) & ~(clean[sel] & ~t2.used).any(axis=1)
        put = rows[sel[ok]]
        meas.written[put] = t2.X[ok]
        meas.written_residual[put], meas.written_mask[put] = self._residual_and_mask(t2.X[ok], t2.used[ok],
                                                                                      t2.rms_px[ok])

    def _residual_and_mask(self, X: np.ndarray, used: np.ndarray, rms_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(n,) residuals, mm (the reprojection RMS ``rms_px`` (n,) at the mean scale of the ``used`` (n, C) cameras
        at points ``X`` (n, 3) m), and (n,) uint32 camera masks (bit c: camera c used)."""
        depth = X @ self._P[:, 2, :3].T + self._P[:, 2, 3]
        scale = np.where(used, depth / self._focal[None, :], 0.0).sum(axis=1) / np.maximum(used.sum(axis=1), 1)
        return rms_px * scale * 1000.0, used @ (np.uint32(1) << np.arange(self._C, dtype=np.uint32))

    def unconfirmed(self) -> UnconfirmedPoints:
        """The points measured by tentative tracks that never got an identity, after :meth:`finish`."""
        if self._result is None:
            raise MocapError("Tracker.unconfirmed() is available after finish()")
        return self._unconfirmed

    def finish(self) -> Trajectories:
        """All frames stepped so far as :class:`Trajectories` (one column per confirmed identity).

        Ends the run: the stored measurements are moved into the output chunk by chunk, the output's rows
        written (and so given memory) as the chunks holding their frames are released, so the two are never
        held twice in full; calling it again returns the same result.
        """
        if self._result is not None:
            return self._result
        first = self._first if self._first is not None else 0
        F = max(self._last - first + 1, 0)
        self._confirm_whole_take(F)
        seen = np.zeros(self._n_ident, dtype=bool)  # identities withdrawn as reflections have no sample: no column
        for uid, p in self._records.peek("uid", "pos"):
            ident = self._uid_ident[uid]
            seen[ident[(ident >= 0) & np.isfinite(p[:, 0])]] = True
        seen = seen.nonzero()[0]
        col_of = np.full(self._n_ident, -1, dtype=np.intp)  # identity -> output column
        col_of[seen] = np.arange(len(seen))
        S = len(seen)
        pos, res = np.empty((F, S, 3)), np.empty((F, S))  # rows set to NaN as they are reached (see above)
        mask = np.zeros((F, S), dtype=np.uint32)
        ready = 0  # rows 0 .. ready - 1 are initialised
        loose: list[dict[str, np.ndarray]] = []
        for rec in self._records.drain():
            ident = self._uid_ident[rec["uid"]]
            ok = ident >= 0
            rows, cols = rec["frame"][ok] - first, col_of[ident[ok]]
            last = int(rows.max()) if rows.size else -1
            if last >= ready:
                pos[ready: last + 1] = np.nan
                res[ready: last + 1] = np.nan
                ready = last + 1
            pos[rows, cols] = rec["pos"][ok]
            res[rows, cols] = rec["res"][ok]
            mask[rows, cols] = rec["mask"][ok]
            loose.append({name: column[~ok] for name, column in rec.items()})
        pos[ready:] = np.nan
        res[ready:] = np.nan

        def joined(name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
            return np.concatenate([rec[name] for rec in loose]).astype(dtype) if loose else np.zeros(shape, dtype)

        self._unconfirmed = UnconfirmedPoints(joined("frame", (0,), np.int64) - first,
                                              joined("pos", (0, 3), np.float64), joined("res", (0,), np.float64),
                                              joined("mask", (0,), np.uint32))
        labels = [f"M{i + 1:03d}" for i in seen]  # the identities' live names (FrameResult, MCAP log)
        self._result = Trajectories(labels, self._fps, pos, res, mask, self._rig.names,
                                    first, {"tracker": "mocap.tracker", "identities": S})
        return self._result

    def _confirm_whole_take(self, frames: int) -> None:
        """A take of fewer than ``confirm_frames`` frames: tentative tracks measured in every one of them get
        identities, as no track could have been confirmed (weak ones, which must have moved, still do not)."""
        t = self._t
        if frames >= self._cfg.confirm_frames or not len(t):
            return
        whole = ((t.ident < 0) & (t.since == 0) & (t.hits >= frames) & ~t.weak).nonzero()[0]
        t.ident[whole] = self._n_ident + np.arange(len(whole))
        self._n_ident += len(whole)
        self._uid_ident[t.uid[whole]] = t.ident[whole]

    # ------------------------------------------------------------------ stages
    def _prepare(self, detections: list[Detections]) -> _Frame:
        counts = [len(d) for d in detections]
        N, C = max(counts, default=0), self._C
        fill = np.arange(N) < np.array(counts)[:, None]  # the (C, N) slots in use, camera-major like the concatenations
        area = np.zeros((C, N))
        flux = np.full((C, N), np.nan)
        roundness = np.ones(0)
        if N:
            # A blob measured as a marker partly hidden (Detections.cut) is a clean view at its fitted centre: its
            # size, shape and light, of the part in view, are no measure of the marker's (NaN: not judged, and
            # left out of the running averages that judge the others).
            cut = np.concatenate([det.cut for det in detections])
            area[fill] = np.where(cut, np.nan, np.concatenate([det.area for det in detections]))
            flux[fill] = np.where(cut, np.nan, np.concatenate([det.flux for det in detections]))
            roundness = np.where(cut, 1.0, np.concatenate([det.roundness for det in detections]))
        lenses = self._lenses.compiled
        if N and lenses is not None:  # (all of the steps below in one call)
            cfg = self._cfg
            return _Frame(*kernels.prepare_frame(
                np.concatenate([det.xy for det in detections]), np.array(counts), *lenses,
                np.concatenate([det.cov for det in detections]), np.concatenate([det.merged for det in detections]),
                area[fill], roundness,
                MIN_SHAPE_AREA, MIN_CENTROID_STD_PX, Detections.DEFAULT_SIGMA_PX, self._centre, self._focal_xy,
                cfg.round_merged, cfg.vague_px**2, _VAGUE_TYPICAL**2, cfg.merged_variance_scale),
                area, flux, counts)
        D = np.full((C, N, 2), np.nan)
        S = np.empty((C, N, 2, 2))
        S[:] = np.eye(2)
        merged = np.zeros((C, N), dtype=bool)
        round_ = np.ones((C, N))
        if N:
            D[fill] = self._lenses.undistort([det.xy for det in detections])
        if N and kernels.HAVE_NUMBA:  # (the same steps in one call)
            var = kernels.frame_detections(
                D, S, merged, round_, np.concatenate([det.cov for det in detections]),
                np.concatenate([det.merged for det in detections]), area[fill], roundness, np.array(counts),
                MIN_SHAPE_AREA,
                MIN_CENTROID_STD_PX, Detections.DEFAULT_SIGMA_PX, self._centre, self._focal_xy, self._cfg.round_merged)
        else:
            if N:
                S[fill] = floored_covariance(np.concatenate([det.cov for det in detections]))
                merged[fill] = np.concatenate([det.merged for det in detections])
                round_[fill] = np.where(area[fill] >= MIN_SHAPE_AREA, roundness, 1.0)
            # A sphere's image is an ellipse of axis ratio cos(field angle); a blob much flatter than that is two
            # markers merged without a saddle, or one partly hidden: its centroid is off by up to a radius.
            merged |= round_ < self._cfg.round_merged / _secant_field_angle(D, self._centre[:, None, :],
                                                                            self._focal_xy[:, None, :])
            var = 0.5 * (S[..., 0, 0] + S[..., 1, 1])  # (C, N) px^2; vague: cut by the image border, or faint
        valid = np.isfinite(D[..., 0]) & np.isfinite(D[..., 1])  # (reductions over an axis of 2 are slow)
        if np.count_nonzero(valid):
            typical = quick_median(var[valid])  # (centroid files may state one large std for every blob)
            merged |= var > max(self._cfg.vague_px**2, _VAGUE_TYPICAL**2 * typical)
        S[merged] *= self._cfg.merged_variance_scale
        return _Frame(D, S, valid, merged, round_, area, flux, counts)

    def _in_play(self) -> np.ndarray:
        """(K,) tracks that search their own gates: confirmed ones for ``coast_frames`` after their last
        measurement, tentative ones only in consecutive frames."""
        t = self._t
        return (t.since - 1 <= self._cfg.coast_frames) & ((t.ident >= 0) | (t.since == 1))

    def _predict(self) -> None:
        t, K, C = self._t, len(self._t), self._C
        if K == 0:
            return
        scale = np.clip(t.noise / self._cfg.noisy_point_m, 1.0, 10.0)
        Q3 = self._Q3 * (scale * scale)[:, None, None] if np.count_nonzero(scale > 1.0) else self._Q3  # (usually none)
        t.x3, t.P3 = predict(t.x3, t.P3, self._F3, Q3)
        x2, P2 = predict(t.x2.reshape(K * C, 6), t.P2.reshape(K * C, 6, 6), self._F2, self._Q2)
        t.x2, t.P2 = x2.reshape(K, C, 6), P2.reshape(K, C, 6, 6)

    def _associate(self, fr: _Frame, play: np.ndarray, lock: np.ndarray, meas: _Measurements) -> None:
        """Gate, assign and measure the tracks in ``play`` (fills ``meas``); ``lock`` (K, C): image filters
        that give the search centres (elsewhere the projected 3D prediction)."""
        t = self._t
        pred, radius, depth = self._search_regions(lock)
        q = gate(pred, radius, fr.D)
        conf = (play & (t.ident >= 0)).nonzero()[0]
        tent = (play & (t.ident < 0)).nonzero()[0]
        meas.asg[conf] = assign(q[conf], fr.valid)
        if tent.size:
            meas.asg[tent] = assign(q[tent], fr.valid & ~_taken(meas.asg, fr.valid.shape))
        crowded = self._crowded(pred, play, depth, meas.asg)
        self._clear_streaks(fr, meas.asg, crowded, depth, lock)
        assigned = meas.asg[conf]
        self._measure(fr, crowded, meas)
        if self._cfg.rival_ratio > 0:
            self._nearer_rival(fr, crowded, meas, conf, assigned)
        # A confirmed track's claim that its pruning or fusion dropped may have been a tentative track's blob:
        # tentative tracks left with fewer than two cameras try again with the detections now free.
        short = tent[(meas.asg[tent] >= 0).sum(axis=1) < 2]
        if short.size:
            again = assign(q[short], fr.valid & ~_taken(meas.asg, fr.valid.shape))
            enough = (again >= 0).sum(axis=1) >= 2
            if enough.any():
                self._measure_again(fr, crowded, meas, short[enough], again[enough])
        self._one_marker_one_track(fr, crowded, meas)

    def _nearer_rival(self, fr: _Frame, crowded: np.ndarray, meas: _Measurements, conf: np.ndarray,
                      assigned: np.ndarray) -> None:
        """Confirmed tracks ``conf`` (n,) whose measurement dropped two or more of their ``assigned`` (n, C) blobs
        that no other track took since are measured from those blobs alone; where that point (the rival) lies within
        the track's search radius of its prediction and under ``rival_ratio`` x the kept point's distance from it,
        and the kept point hops (lies over the hop acceleration off the prediction, see ``settle_hops``), the track
        takes the rival and the blobs it kept go free (see ``TrackerConfig.rival_ratio``)."""
        dropped = (assigned >= 0) & (meas.asg[conf] != assigned) & (meas.ok & (self._t.since == 1))[conf, None]
        if not np.count_nonzero(dropped.sum(axis=1) >= 2):  # (most frames)
            return
        dropped &= ~_taken(meas.asg, fr.valid.shape)[np.arange(self._C)[None, :], np.maximum(assigned, 0)]
        two = (dropped.sum(axis=1) >= 2).nonzero()[0]
        if two.size == 0:
            return
        rows = conf[two]
        rival = self._measured_from(fr, crowded, meas, rows, np.where(dropped[two], assigned[two], -1))
        pred = self._t.x3[rows, :3]
        near = np.linalg.norm(rival.X - pred, axis=1)
        kept = np.linalg.norm(meas.X[rows] - pred, axis=1)
        take = (rival.ok & ((rival.asg >= 0).sum(axis=1) >= self._cfg.new_min_views)
                & (kept > self._hop_m) & (near < self._cfg.rival_ratio * kept) & (near < self._radius3(rows)))
        if np.count_nonzero(take):
            rival.keep(take)
            meas.put(rows[take], rival)

    def _yield_outside_gate(self, meas: _Measurements, shift: np.ndarray) -> None:
        """Tracks whose point lies outside their own 3D search radius (:meth:`_radius3`) around the prediction (plus
        ``shift`` (K, 3) m, the neighbours' correction it was searched from), where an identity lost for at most
        ``yield_s`` holds it inside its own radius, and more tightly (distance / radius, from its
        prediction or where it was last seen, as :func:`mocap.fusion.reidentify` measures), miss the frame: the
        point is left to the new-marker search, which gives it to that identity. A camera whose image filter is
        locked searches around that filter's prediction alone, and where a marker vanishes as a neighbour a few
        centimetres away reappears, every camera's gate can hold the neighbour's blob (the sprint's forearm: steps
        of 45-65 mm onto the marker whose identity had just been lost). A fast swing outside the gate that no
        recently lost identity explains is measured as before."""
        t = self._t
        others = ((t.ident >= 0) & (t.since >= 1) & (t.since <= self._yield_frames) & ~meas.ok).nonzero()[0]
        rows = meas.ok.nonzero()[0]
        if others.size == 0 or rows.size == 0:  # (most frames)
            return
        miss = np.linalg.norm(meas.X[rows] - (t.x3[rows, :3] + shift[rows]), axis=1)
        beyond = miss > self._cfg.gate_floor_m  # (no radius is below its floor)
        rows, miss = rows[beyond], miss[beyond]
        far = miss > self._radius3(rows)
        if not np.count_nonzero(far):
            return
        d = distance_to_lost(meas.X[rows[far]], t.x3[others, :3], t.last_X[others])
        held = (d / self._radius3(others)[None]).min(axis=1) < 1.0
        yields = rows[far][held]
        if yields.size:
            meas.miss(yields, self._C)

    def _refute_by_attached(self, meas: _Measurements) -> None:
        """Confirmed tracks whose point their identity's steady attached distances refute, where a lost identity's
        fit it and its search radius holds it (``attached_check``) or the track is ``refuted_gap_frames`` into its
        gap, miss the frame: the point is left to the new-marker search, which gives it to that identity (or to a
        new one)."""
        t = self._t
        rows = (meas.ok & (t.ident >= 0)).nonzero()[0]
        coasting = self._coasting(rows, self._cfg.coast_frames + 1)  # (every track searching its gate: _in_play)
        # (a refutation needs two measured neighbours, and a lost identity to take the point or a gap behind it)
        if rows.size < 3 or not (np.count_nonzero((t.ident >= 0) & (t.since >= 1) & ~meas.ok)
                                 or np.count_nonzero(coasting)):
            return
        misfit, _ = self._attached.judge(t.ident[rows], meas.X[rows], t.ident[rows], meas.X[rows])
        bad, kept = rows[misfit], rows[~misfit]
        if bad.size == 0:
            return
        yields = bad[self._claimed_by_lost(meas.X[bad], t.ident[kept], meas.X[kept], ~meas.ok) | coasting[misfit]]
        if yields.size:
            meas.miss(yields, self._C)

    def _settle_hops(self, meas: _Measurements) -> None:
        """Confirmed tracks measured in the previous frame and this one whose points hop (lie over the hop
        acceleration from the constant-velocity extrapolation of their last two points) exchange points with
        each other where the exchange (optimal, ``linear_sum_assignment``) is clear: every track that changes then
        lies within half the hop acceleration of its extrapolation, within half the distance from its new point to
        any other, and at a quarter of the squared misses or less. After a burst of hops (a take's garbled labels,
        a fast swing) the filters' velocities and running errors hold the hops: their predictions fall between
        neighbouring markers, and the widened gates hold both, so the tracks went on hopping between a forearm's
        markers for 25 frames of slow motion (two-player seed 58, frames 332-356). The raw steps of the markers
        themselves, a few millimetres, tell which point is whose."""
        t, hop = self._t, self._hop_m
        rows = (meas.ok & (t.ident >= 0) & (t.since == 1) & np.isfinite(t.last_v[:, 0])).nonzero()[0]
        if rows.size < 2:
            return
        X = meas.X[rows]
        ext = t.last_X[rows] + t.last_v[rows] * self._dt
        own = X - ext
        if not np.count_nonzero((own * own).sum(axis=1) > hop * hop):  # (most frames)
            return
        gap = X[None, :, :] - ext[:, None, :]
        miss = np.sqrt((gap * gap).sum(axis=2))  # (track, point) m
        hopped = np.diag(miss) > hop
        near = (hopped | (miss[hopped].min(axis=0) < hop) | (miss[:, hopped].min(axis=1) < hop)).nonzero()[0]
        sub = miss[np.ix_(near, near)]
        track, point = linear_sum_assignment(sub * sub)
        moved = track != point
        if not np.count_nonzero(moved):
            return
        track, point = track[moved], point[moved]
        new, old = sub[track, point], sub[track, track]
        apart = np.sqrt(((X[near, None, :] - X[None, near, :]) ** 2).sum(axis=2))
        np.fill_diagonal(apart, np.inf)
        if (old.max() > hop and new.max() < 0.5 * hop and (new < 0.5 * apart[point].min(axis=1)).all()
                and (new * new).sum() < 0.25 * (old * old).sum()):
            meas.put(rows[near[track]], meas.rows(rows[near[point]]))  # (a copy: rows() gathers)

    def _claimed_by_lost(self, points: np.ndarray, here_ident: np.ndarray, here_X: np.ndarray,
                         unmeasured: np.ndarray) -> np.ndarray:
        """(L,) bool: the ``points`` (L, 3) m that a lost identity (its track ``unmeasured`` (K,) bool this frame)
        holds inside its search radius and whose attached distances to ``here_ident`` (h,), measured at ``here_X``
        (h, 3) m, fit."""
        t = self._t
        lost = ((t.ident >= 0) & (t.since >= 1) & unmeasured).nonzero()[0]
        if lost.size == 0 or len(points) == 0:
            return np.zeros(len(points), dtype=bool)
        inside = distance_to_lost(points, t.x3[lost, :3], t.last_X[lost]) < self._radius3(lost)[None]
        _, fits = self._attached.judge_pairs(t.ident[lost], points, here_ident, here_X)
        return (fits & inside).any(axis=1)

    def _coasting(self, tracks: np.ndarray, last: int) -> np.ndarray:
        """(T,) bool: which of the ``tracks`` (T,) are ``refuted_gap_frames`` to ``last`` frames into their gap
        (``since``), the steady neighbours' refutation then holding whether or not a lost identity claims the point;
        none where ``refuted_gap_frames`` is 0. The gated path judges to ``coast_frames`` + 1, re-acquisition from
        free points to ``coast_frames`` (see ``refuted_gap_frames``)."""
        gap, since = self._cfg.refuted_gap_frames, self._t.since[tracks]
        return (since >= gap) & (since <= last) if gap else np.zeros(tracks.size, dtype=bool)

    def _attached_allow(self, points: np.ndarray, tracks: np.ndarray,
                        lost_at: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> np.ndarray | None:
        """(L, T) bool: which of the ``tracks`` (T,) may take which of the ``points`` (L, 3) m: a pair the track's
        identity's attached distances refute only where a lost identity fits the point (see
        :meth:`_claimed_by_lost`; None: all, ``attached_check`` off), or where the track is ``refuted_gap_frames``
        into its gap and still searching (``coast_frames``). ``lost_at``: for lost identities being
        re-identified, where their search radius is measured from (predictions and last places (T, 3) m) and the
        radius (T,) m: a refuted pair is refused whoever claims the point where that radius is ``refuted_wide_m`` or
        wider, and an identity with no steady neighbour measured may not take a point whose distance to a measured
        steady neighbour of another one whose radius holds it holds, none off (``silent_yield``)."""
        t, cfg = self._t, self._cfg
        if not cfg.attached_check or points.size == 0 or tracks.size == 0:
            return None
        here = ((t.ident >= 0) & (t.since == 0)).nonzero()[0]
        n_ok, n_off = self._attached.tally_pairs(t.ident[tracks], points, t.ident[here], t.last_X[here])
        misfit, _ = verdicts(n_ok, n_off)
        refuse = misfit.copy()
        if refuse.any():
            refuse &= self._claimed_by_lost(points, t.ident[here], t.last_X[here], t.since >= 1)[:, None] \
                | self._coasting(tracks, cfg.coast_frames)
        if lost_at is not None:
            predicted, last, radius = lost_at
            if cfg.refuted_wide_m > 0:
                refuse |= misfit & (radius >= cfg.refuted_wide_m)[None, :]
            if cfg.silent_yield:
                vouched = (n_ok >= 1) & (n_off == 0) & (distance_to_lost(points, predicted, last) < radius[None])
                silent = (n_ok + n_off == 0).all(axis=0)  # (T,) no steady neighbour measured
                refuse |= vouched.any(axis=1)[:, None] & silent[None, :]
        return ~refuse if refuse.any() else None

    def _measure_again(self, fr: _Frame, crowded: np.ndarray, meas: _Measurements, rows: np.ndarray,
                       asg: np.ndarray) -> None:
        """Measure the tracks ``rows`` (sorted, unique) afresh from the detections ``asg`` (len(rows), C), into
        ``meas``."""
        meas.put(rows, self._measured_from(fr, crowded, meas, rows, asg))

    def _measured_from(self, fr: _Frame, crowded: np.ndarray, meas: _Measurements, rows: np.ndarray,
                       asg: np.ndarray) -> _Measurements:
        """The measurements (len(rows) of them) of the tracks ``rows`` (sorted, unique) from the detections ``asg``
        (len(rows), C); the re-pick offers none that ``meas`` gives another track."""
        others = meas.asg.copy()
        others[rows] = -1
        again = _Measurements.empty(len(self._t), self._C)
        again.asg[rows] = asg
        self._measure(replace(fr, valid=fr.valid & ~_taken(others, fr.valid.shape)), crowded, again)
        again.keep(np.isin(np.arange(len(self._t)), rows))
        return again

    def _one_marker_one_track(self, fr: _Frame, crowded: np.ndarray, meas: _Measurements) -> None:
        """Two tracks whose points are one marker (closer than ``n_sigma`` x their combined noise, at least
        ``one_marker_m``, at most a marker radius: no two marker centres are that close) split its blobs camera by
        camera: the track of a hidden marker, coasting on a widened gate, took a neighbour's blobs where they lay
        nearer its prediction in units of that gate. The marker stays with the track that measured it in the
        previous frame (else the confirmed one) if its prediction is the nearer too; that track takes the other's
        blobs where it has none and is measured again, and the other misses the frame. Two tracks alike on both
        counts are left as they are: in a fast swing neither prediction tells (the identity repair sorts them)."""
        t, cfg = self._t, self._cfg
        rows = meas.ok.nonzero()[0]
        rank = 2 * (t.since[rows] != 1) + (t.ident[rows] < 0)  # lower: the better claim
        weak = (rank > 0).nonzero()[0]  # (a pair of equal claims is left alone: one of two must be weaker)
        if rows.size < 2 or weak.size == 0:
            return
        X = meas.X[rows]
        gap = X[weak, None, :] - X[None, :, :]
        noise = _point_std(meas.cov[rows])
        limit = np.clip(cfg.n_sigma * np.hypot(noise[weak, None], noise[None, :]), cfg.one_marker_m,
                        cfg.marker_mm / 2000.0)
        w, j = np.nonzero((gap * gap).sum(axis=2) < limit * limit)
        i = weak[w]
        i, j = i[i != j], j[i != j]
        if i.size == 0:
            return
        miss = np.linalg.norm(X - t.x3[rows, :3], axis=1)
        first = rank[i] < rank[j]
        sure = (rank[i] != rank[j]) & ((miss[i] < miss[j]) == first)
        if not np.count_nonzero(sure):
            return
        i, j, first = i[sure], j[sure], first[sure]
        win, lose = np.where(first, i, j), np.where(first, j, i)
        top = ~np.isin(win, lose)  # (a marker claimed by three tracks, rare: the best one takes it)
        win, lose = win[top], lose[top]
        _, once = np.unique(lose, return_index=True)
        win, lose = rows[win[once]], rows[lose[once]]
        win, first_loss = np.unique(win, return_index=True)  # (a winner with two losers takes the first one's blobs)
        asg = np.where(meas.asg[win] >= 0, meas.asg[win], meas.asg[lose[first_loss]])
        meas.miss(lose, self._C)
        self._measure_again(fr, crowded, meas, win, asg)

    def _explained_elsewhere(self, fr: _Frame, meas: _Measurements) -> np.ndarray:
        """(K,) bool: tracks whose point rests on two cameras, one of them a clean blob that another output point of
        two views or more, a marker's diameter away at least (``marker_mm``: nearer, the two are one marker, which
        ``_one_marker_one_track`` gives to one of them), not seen in that camera and in front of it, projects onto
        (within ``explained_px`` or ``n_sigma`` x the blob's std). The blob is that point's third view, and the
        two-view point is a ghost (the sprint's forearm, markers 42 mm apart: the wrong pairing of two cameras' blobs
        has an epipolar distance of 0.14 px, and its point lay 19 mm off both markers). Two two-view points that each
        explain a blob of the other are both kept. One kernel call with numba
        (:func:`mocap.kernels.explained_elsewhere`)."""
        cfg = self._cfg
        if kernels.HAVE_NUMBA:
            return kernels.explained_elsewhere(meas.asg, meas.ok, meas.out, fr.merged, fr.D, fr.S, self._P,
                                               kernels.contiguous(meas.X), float(cfg.explained_px), float(cfg.n_sigma),
                                               cfg.marker_mm / 1000.0)
        K = len(meas.ok)
        used = meas.asg >= 0
        views = used.sum(axis=1)
        two = (meas.ok & (views == 2)).nonzero()[0]
        if two.size == 0:
            return np.zeros(K, dtype=bool)
        others = (meas.ok & meas.out & (views >= 2)).nonzero()[0]
        p_i, cams = np.nonzero(used[two])
        rows = two[p_i]  # (m,) a two-view track, once per camera it is seen in
        j = meas.asg[rows, cams]
        clean = ~fr.merged[cams, j]
        rows, cams, j = rows[clean], cams[clean], j[clean]
        proj, depth = project_ideal(self._P[cams], meas.X[others])  # (m, L, 2), (m, L)
        sigma = np.sqrt(0.5 * (fr.S[cams, j, 0, 0] + fr.S[cams, j, 1, 1]))  # (m,) px
        reach = np.maximum(cfg.explained_px, cfg.n_sigma * sigma)
        near = np.linalg.norm(proj - fr.D[cams, j][:, None], axis=2) < reach[:, None]
        apart = np.linalg.norm(meas.X[others][None, :] - meas.X[rows][:, None], axis=2) >= cfg.marker_mm / 1000.0
        near &= apart & (depth > 0) & (meas.asg[others[None, :], cams[:, None]] < 0)
        k, q = np.nonzero(near)
        explains = np.zeros((K, K), dtype=bool)  # [p, q]: q's point explains a blob of p's
        explains[rows[k], others[q]] = True
        return (explains & ~explains.T).any(axis=1)

    def _neighbour_shift(self, meas: _Measurements, play: np.ndarray) -> np.ndarray:
        """(K, 3) m: per track the median prediction error of the measured tracks within ``neighbour_m`` of it
        (itself included; zero with fewer than ``neighbour_min``). In a fast swing a whole segment is
        mispredicted alike, and a track's own error is wrong when it took a neighbour's detections.
        All zero when no shift can exceed ``gate_floor_m`` (the only ones the caller acts on): a median lies
        within its values' range, so no shift is longer than the per-axis largest errors' norm."""
        t = self._t
        good = meas.ok & play & (t.since == 1)
        shift = np.zeros((len(t), 3))
        if not np.count_nonzero(good):
            return shift
        y = meas.X[good] - t.x3[good, :3]
        top = np.abs(y).max(axis=0)
        if np.sqrt(top @ top) < self._cfg.gate_floor_m * (1.0 - 1e-9):  # (margin for the caller's rounding)
            return shift
        gap = t.x3[:, None, :3] - t.x3[None, good, :3]
        near = np.sqrt((gap * gap).sum(axis=2)) < self._cfg.neighbour_m  # (np.linalg.norm's sums, less overhead)
        cnt = near.sum(axis=1)
        rows = (play & (cnt >= self._cfg.neighbour_min)).nonzero()[0]
        if rows.size:  # per-row median of the near ones: NaN sorts last, so the middle of the first cnt
            srt = np.sort(np.where(near[rows, :, None], y[None], np.nan), axis=1)
            r, n = np.arange(rows.size), cnt[rows]
            shift[rows] = 0.5 * (srt[r, (n - 1) // 2] + srt[r, n // 2])
        return shift

    def _carried_shift(self, meas: _Measurements, play: np.ndarray, shift: np.ndarray) -> np.ndarray:
        """``shift`` (K, 3) m, the neighbours' correction, where it exceeds ``carry_m`` for a confirmed track
        measured in the previous frame: the place the turn of its steady attached neighbours, measured then and
        now, carries it to (:meth:`AttachedDistances.turns`, ``carry_neighbours`` or more), minus its prediction; a
        track without such neighbours (its distances broke: tracks stepping between a segment's markers) takes the
        turn of the nearest carried track within ``carry_reach_m``. A swinging segment turns: its markers'
        errors differ by the turn, which their median misses."""
        t, cfg = self._t, self._cfg
        fast = (shift * shift).sum(axis=1) > cfg.carry_m**2
        if not np.count_nonzero(fast):  # (most frames: no fast swing)
            return shift
        rows = (fast & play & (t.ident >= 0) & (t.since == 1)).nonzero()[0]
        here = (meas.ok & (t.ident >= 0)).nonzero()[0]
        if here.size < cfg.carry_neighbours or rows.size == 0:
            return shift
        before = ((t.ident >= 0) & (t.since == 1)).nonzero()[0]
        ok, R, a, b = self._attached.turns(t.ident[rows], t.ident[before], t.last_X[before], t.ident[here],
                                           meas.X[here], cfg.carry_neighbours)
        if not ok.any():
            return shift
        turned = ok.nonzero()[0]
        if not ok.all():  # the nearest carried track's turn, within reach
            rest = (~ok).nonzero()[0]
            gap = t.last_X[rows[rest], None] - t.last_X[rows[turned]][None]
            d2 = (gap * gap).sum(axis=2)
            near = d2.argmin(axis=1)
            reach = d2[np.arange(rest.size), near] < cfg.carry_reach_m**2
            R[rest[reach]], a[rest[reach]], b[rest[reach]] = R[turned[near[reach]]], a[turned[near[reach]]], \
                b[turned[near[reach]]]
            turned = np.concatenate([turned, rest[reach]])
        X = t.last_X[rows[turned]]
        shift = shift.copy()
        shift[rows[turned]] = np.einsum("nij,nj->ni", R[turned], X - a[turned]) + b[turned] - t.x3[rows[turned], :3]
        return shift

    def _search_regions(self, lock: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Predicted ideal pixels (K, C, 2), search radii (K, C), pixels, and predicted depths (K, C), m."""
        t, cfg = self._t, self._cfg
        if kernels.HAVE_NUMBA:
            return kernels.search_regions(t.x3, t.e3, t.since, t.x2, t.e2, kernels.contiguous(lock, bool), self._P,
                                          self._focal, self._dt, cfg.gate_scale, cfg.gate_floor_m, cfg.reid_max_m,
                                          cfg.gate_floor_px, cfg.gate_max_px)
        proj, depth = project_ideal(self._P, t.x3[:, :3])  # (C, K, 2), (C, K)
        depth = depth.T
        r3 = np.minimum(self._running.radius(*t.e3.T, t.since, self._dt, cfg.gate_floor_m), cfg.reid_max_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            r3px = r3[:, None] * self._focal[None, :] / depth
        r2 = self._running.radius(t.e2[..., 0], t.e2[..., 1], t.e2[..., 2], 1, self._dt, cfg.gate_floor_px)
        pred = np.where(lock[..., None], t.x2[..., :2], proj.swapaxes(0, 1))
        radius = np.clip(np.where(lock, r2, r3px), cfg.gate_floor_px, cfg.gate_max_px)
        pred[depth <= 0] = np.nan
        return pred, radius, depth

    def _merge_reach(self, focal: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Px: a marker's image diameter at ``depth`` (m) for a camera of ``focal`` (px), plus ``merge_px`` (arrays
        broadcast): two markers' images closer than this may be one merged blob."""
        return focal * self._cfg.marker_mm / 1000.0 / depth + self._cfg.merge_px

    def _crowded(self, pred: np.ndarray, play: np.ndarray, depth: np.ndarray, asg: np.ndarray) -> np.ndarray:
        """(K, C) bool: another track in play, seen by that camera within ``hidden_frames``, is predicted within a
        marker's image diameter + ``merge_px`` (a marker hidden from a camera merges with nothing in its image),
        and did not take a blob of its own there this frame (``asg`` (K, C)): two blobs are not one merged."""
        if kernels.HAVE_NUMBA:
            c = kernels.contiguous
            return kernels.crowded(c(pred), c(play, bool), c(self._t.unseen2 <= self._cfg.hidden_frames, bool),
                                   c(depth), c(asg, np.intp), self._focal, self._cfg.marker_mm, self._cfg.merge_px)
        p = np.ascontiguousarray(np.where(play[:, None, None], pred, np.nan).swapaxes(0, 1))  # (C, K, 2)
        seen = np.where((self._t.unseen2.T <= self._cfg.hidden_frames)[:, :, None], p, np.nan)  # (C, K, 2)
        d2 = dist2(p[:, :, None, :], seen[:, None, :, :])
        diag = np.arange(len(play))
        d2[:, diag, diag] = np.inf
        with np.errstate(invalid="ignore", divide="ignore"):
            reach = self._merge_reach(self._focal[:, None], depth.T)  # (C, K)
            close = np.flatnonzero(d2 < (reach * reach)[:, :, None])  # the few close pairs (flat: 2x faster)
        c, k = np.divmod(close, d2.shape[1] * d2.shape[2])
        k, j = np.divmod(k, d2.shape[2])
        own, other = asg[k, c], asg[j, c]
        merge = (own < 0) | (other < 0) | (own == other)
        crowded = np.zeros(asg.shape, dtype=bool)
        crowded[k[merge], c[merge]] = True
        return crowded

    def _clear_streaks(self, fr: _Frame, asg: np.ndarray, crowded: np.ndarray, depth: np.ndarray, lock: np.ndarray
                       ) -> None:
        """Motion blur: a fast marker's blob is a streak over the shutter time, as flat as two merged markers.
        A flat blob a track took alone (not ``crowded``), whose flattening a smear of at most ``smear_fraction``
        of that track's image motion per frame explains, is clean again (flag and variance), in place.

        A disc of image radius R (px) smeared over L px has roundness r = 1 / sqrt(1 + L^2 / (3 R^2)), so
        L = R sqrt(3 (1 / r^2 - 1)); the image velocity is the locked image filter's (``lock`` (K, C)).
        """
        cfg = self._cfg
        k, c = np.nonzero((asg >= 0) & lock & ~crowded)
        j = asg[k, c]
        flat = fr.merged[c, j] & (fr.roundness[c, j] < cfg.round_merged)
        if not np.count_nonzero(flat):
            return
        k, c, j = k[flat], c[flat], j[flat]
        r = fr.roundness[c, j]
        with np.errstate(divide="ignore", invalid="ignore"):  # a line-thin blob (r = 0) needs an endless smear
            radius = self._focal[c] * cfg.marker_mm / 2000.0 / depth[k, c]
            smear = radius * np.sqrt(3.0 * (1.0 / (r * r) - 1.0))
        v = self._t.x2[k, c, 2:4]
        motion = np.sqrt(v[:, 0] * v[:, 0] + v[:, 1] * v[:, 1]) * self._dt
        streak = (radius > 0) & (smear <= cfg.smear_fraction * motion)
        c, j = c[streak], j[streak]
        fr.merged[c, j] = False
        fr.S[c, j] /= cfg.merged_variance_scale

    def _measure(self, fr: _Frame, crowded: np.ndarray, meas: _Measurements) -> None:
        """Epipolar pruning, robust fusion and re-pick of the assigned detections ``meas.asg``; fills ``meas``."""
        cfg = self._cfg
        asg = meas.asg
        partial = None  # (K, C) the views of ``judged`` (the assigned blobs) that show their marker partly hidden
        assigned = asg >= 0
        if cfg.partial_area > 0:
            partial, appeared = self._leave_out_partly_hidden(fr, crowded, asg)
            judged = asg.copy()
        tri, extra, sigma = self._triangulate_views(fr, crowded, asg)
        if partial is not None:  # (a partly hidden blob left out is free, and near the point: not offered back)
            extra[self._partial_views(fr, extra, extra >= 0) | appeared] = -1
        more = (extra >= 0).any(axis=1).nonzero()[0]
        if more.size:
            asg[more] = np.where(extra[more] >= 0, extra[more], asg[more])
            sub = asg[more]
            inflate = np.where(crowded[more], cfg.merged_variance_scale, 1.0)[..., None, None]
            t2 = robust_triangulate(self._P, _gather(fr.D, sub).swapaxes(0, 1),
                                    (_gather(fr.S, sub) * inflate).swapaxes(0, 1), tri.X[more],
                                    cfg.outlier_sigma, self._outlier_px)
            tri.X[more], tri.cov[more], tri.rms_px[more], tri.used[more] = t2.X, t2.cov, t2.rms_px, t2.used
            asg[~tri.used] = -1
        if partial is not None:  # (the judgement of a blob holds all frame: only views that kept their blob)
            self._drop_partly_hidden_views(fr, crowded, asg, tri, partial & (asg == judged) & tri.used)
        split = self._deblend(fr, crowded, asg, tri) if cfg.deblend else np.zeros(asg.shape, dtype=bool)
        # A point leaning on a possibly merged blob is output only if it agrees with the prediction, within its
        # noise as its clean views give it: a merged blob's own (large) std must not widen the gate it is judged by.
        # A point from merged blobs alone never is: its filter may have followed those blobs' offset centroids.
        t = self._t
        suspect = crowded  # (views that are not clean, as merged blobs are not)
        if partial is not None and cfg.partial_suspect:
            suspect = crowded | (partial & (asg == judged) & tri.used)
        meas.ok, clean, meas.out = self._verdicts(fr, tri.X, tri.used, tri.depth, suspect, split, sigma, asg, t.x3,
                                                  t.e3)
        if cfg.withhold_merged_depth:
            meas.out[self._depth_on_merged_blobs(fr, asg, clean, tri, crowded)] = False
        meas.X, meas.cov, meas.rms_px = tri.X, tri.cov, tri.rms_px
        if cfg.dark_flux < 1:
            self._judge_dark_views(fr, asg, tri, suspect, split, sigma, meas)
        self._assigned_blobs |= assigned

    def _partial_views(self, fr: _Frame, asg: np.ndarray, views: np.ndarray) -> np.ndarray:
        """(K, C) bool: which of the ``views`` (K, C) bool of the detections ``asg`` (K, C) show their marker partly
        hidden (:meth:`_partly_hidden`)."""
        k, c = np.nonzero(views & (asg >= 0))
        out = np.zeros(asg.shape, dtype=bool)
        if k.size:
            part = self._partly_hidden(fr, k, c, asg[k, c])
            out[k[part], c[part]] = True
        return out

    def _appearing_views(self, fr: _Frame, asg: np.ndarray) -> np.ndarray:
        """(K, C) bool: assigned detections ``asg`` (K, C) of tracks measured in the previous frame, in cameras that
        had no blob of theirs then, whose light at the track's predicted depth is under ``appearing_light`` of their
        marker's there lately (:meth:`_light_of_views`), or, where none is known there yet, under
        ``appearing_borrowed`` of what the track's other views give this frame (:meth:`_light_levels`; blobs of
        ``partial_min_area`` px or more, not flagged merged): a marker coming out from behind something is partly
        hidden the first frame back."""
        t, cfg = self._t, self._cfg
        if not (self._light and cfg.appearing_light > 0):
            return np.zeros(asg.shape, dtype=bool)
        out = (asg >= 0) & (t.blob_unseen >= 2) & (t.since == 1)[:, None]
        k, c = np.nonzero(out)
        ratio, merged, _ = self._light_of_views(fr, k, c, asg[k, c], t.x3[k, :3])
        with np.errstate(invalid="ignore"):
            dark = ratio < cfg.appearing_light  # (unknown light, NaN: not dark)
        # (the views judged do not judge each other)
        dark |= self._darker_than_other_views(fr, asg, t.x3[:, :3], k, c, ratio, merged, out, cfg.appearing_borrowed)
        out[k, c] = dark
        return out

    def _darker_than_other_views(self, fr: _Frame, asg: np.ndarray, X: np.ndarray, k: np.ndarray, c: np.ndarray,
                                 ratio: np.ndarray, merged: np.ndarray, exclude: np.ndarray, bound: float
                                 ) -> np.ndarray:
        """(n,) bool: the views of tracks ``k`` (n,) in cameras ``c`` (n,) on their detections ``asg`` (K, C), of
        points ``X`` (K, 3) m, whose camera knows no light of the marker yet (``ratio`` (n,) NaN; not ``merged`` (n,),
        of ``partial_min_area`` px or more) and whose light is under ``bound`` (0: none) of the median of the point's
        other views (:meth:`_light_levels`; not ``exclude`` (K, C); False where there are none)."""
        out = np.zeros(len(k), dtype=bool)
        unknown = (~np.isfinite(ratio) & ~merged & (fr.area[c, asg[k, c]] >= self._cfg.partial_min_area)).nonzero()[0]
        if bound <= 0 or not unknown.size:
            return out
        rows, cams = k[unknown], c[unknown]
        level = self._light_levels(fr, asg[rows], X[rows])  # (n, C): the judged points' views only
        own = level[np.arange(rows.size), cams]
        others = np.where(exclude[rows], np.nan, level)
        others[np.arange(rows.size), cams] = np.nan
        with np.errstate(invalid="ignore"):  # (no other view: NaN, not darker)
            out[unknown] = own - nanmedian_columns(others.T) < math.log(bound)
        return out

    def _light_levels(self, fr: _Frame, asg: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(n, C) the log light of the detections ``asg`` (n, C) of points ``X`` (n, 3) m, moved to 1 m (x
        depth^power) and taken over their camera's gain (:meth:`_learn_camera_gains`); NaN where none, not measured
        or flagged merged. A marker's levels agree across its cameras where its blobs are whole."""
        P = self._P[:, 2]
        depth = X @ P[:, :3].T + P[:, 3]  # (n, C) m
        with np.errstate(invalid="ignore", divide="ignore"):
            level = np.log(_gather(fr.flux, asg)) + self._light_power * np.log(depth) - self._camera_gain
        return np.where((asg >= 0) & ~_gather(fr.merged, asg) & np.isfinite(level), level, np.nan)

    def _learn_camera_gains(self, fr: _Frame, meas: _Measurements) -> None:
        """Running average (``_CAMERA_GAIN_ALPHA`` per frame) of each camera's log light (:meth:`_light_levels`) over
        the median of the same points' in all their cameras, from this frame's measured points with three such
        views or more; a camera with fewer than three of them this frame keeps its gain."""
        ok = meas.ok.nonzero()[0]
        level = self._light_levels(fr, meas.asg[ok], meas.X[ok])
        level = level[np.isfinite(level).sum(axis=1) >= 3]
        if not len(level):
            return
        off = level - nanmedian_columns(level.T)[:, None]
        seen = np.isfinite(off)
        count = seen.sum(axis=0)
        mean = np.where(seen, off, 0.0).sum(axis=0) / np.maximum(count, 1)
        self._camera_gain += np.where(count >= 3, _CAMERA_GAIN_ALPHA * mean, 0.0)

    def _leave_out_partly_hidden(self, fr: _Frame, crowded: np.ndarray, asg: np.ndarray
                                 ) -> tuple[np.ndarray, np.ndarray]:
        """Assigned detections ``asg`` (K, C) of a marker partly hidden (:meth:`_partly_hidden`) or just coming back
        into a camera darker (:meth:`_appearing_views`) are left out (-1, in place) where two clean ones (not
        crowded, not flagged merged) remain. Returns (K, C) bool each: the partly hidden views still assigned, and
        the coming-back views left out."""
        partial = self._partial_views(fr, asg, asg >= 0)
        appearing = self._appearing_views(fr, asg)
        leave = partial | appearing
        if not np.count_nonzero(leave):
            return partial, appearing
        clean = (asg >= 0) & ~crowded & ~_gather(fr.merged, asg) & ~leave
        out = leave & (clean.sum(axis=1) >= 2)[:, None]
        asg[out] = -1
        return partial & ~out, appearing & out

    def _drop_partly_hidden_views(self, fr: _Frame, crowded: np.ndarray, asg: np.ndarray, tri: Triangulated,
                                  partial: np.ndarray) -> None:
        """Points standing on a view of their marker partly hidden (``partial`` (K, C), of their used views; see
        :meth:`_partly_hidden`) and on two clean views besides (not crowded, not flagged merged) are triangulated
        again without it, and keep the new point where every clean view stays in it. A partly hidden marker's
        centroid is off by up to 0.4 of a radius, often along another camera's epipolar line, where the consensus
        cannot see it; a point with fewer clean views keeps it (the view is all it has). ``asg`` (K, C) and ``tri``
        are updated in place."""
        cfg = self._cfg
        if not np.count_nonzero(partial):
            return
        clean = tri.used & ~crowded & ~_gather(fr.merged, asg) & ~partial
        rows = (partial.any(axis=1) & (clean.sum(axis=1) >= 2)).nonzero()[0]
        if rows.size == 0:
            return
        sub = np.where(partial[rows], -1, asg[rows])
        inflate = np.where(crowded[rows] & ~_gather(fr.merged, sub), cfg.merged_variance_scale, 1.0)[..., None, None]
        t2 = robust_triangulate(self._P, _gather(fr.D, sub).swapaxes(0, 1),
                                (_gather(fr.S, sub) * inflate).swapaxes(0, 1), tri.X[rows], cfg.outlier_sigma,
                                self._outlier_px)
        ok = np.isfinite(t2.X).all(axis=1) & ~(clean[rows] & ~t2.used).any(axis=1)
        rows = rows[ok]
        asg[rows] = np.where(t2.used[ok], sub[ok], -1)
        tri.X[rows], tri.cov[rows], tri.rms_px[rows], tri.used[rows] = t2.X[ok], t2.cov[ok], t2.rms_px[ok], t2.used[ok]
        tri.proj[:, rows], tri.depth[:, rows] = t2.proj[:, ok], t2.depth[:, ok]

    def _triangulate_views(self, fr: _Frame, crowded: np.ndarray, asg: np.ndarray
                           ) -> tuple[Triangulated, np.ndarray, np.ndarray]:
        """Epipolar pruning and robust triangulation of the assigned detections ``asg`` (K, C) (views dropped set to -1
        in place), and the free detections offered to the tracks' unused cameras. Returns the points, the re-picked
        detections (K, C) (-1: none) and the detections' centroid std (C, N) px. One kernel call with numba
        (:func:`mocap.kernels.measure_views`)."""
        cfg = self._cfg
        if kernels.HAVE_NUMBA:
            c = kernels.contiguous
            *fields, extra, sigma = kernels.measure_views(
                fr.D, fr.S, fr.merged, fr.valid, asg, c(crowded, bool), self._pairs_index, self._pairs_F, self._P,
                c(self._t.x3[:, :3]), float(cfg.epipolar_px), float(cfg.n_sigma), float(cfg.merged_variance_scale),
                float(cfg.outlier_sigma), float(self._outlier_px), GAUSS_NEWTON_STEPS, float(cfg.repick_px))
            return Triangulated(*fields), extra, sigma
        uv = _gather(fr.D, asg)
        sigma = np.sqrt(0.5 * (fr.S[..., 0, 0] + fr.S[..., 1, 1]))  # (C, N)
        supported, tested = epipolar_consistency(self._pairs, uv, cfg.epipolar_px, _gather(sigma, asg), cfg.n_sigma)
        asg[tested & ~supported] = -1
        uv[asg < 0] = np.nan
        suspect = crowded & ~_gather(fr.merged, asg)  # merged blobs are down-weighted already
        inflate = np.where(suspect, cfg.merged_variance_scale, 1.0)[..., None, None]
        tri = robust_triangulate(self._P, uv.swapaxes(0, 1), (_gather(fr.S, asg) * inflate).swapaxes(0, 1),
                                 self._t.x3[:, :3], cfg.outlier_sigma, self._outlier_px)
        asg[~tri.used] = -1
        free = fr.valid & ~fr.merged & ~_taken(asg, fr.valid.shape)
        return tri, repick(tri, fr.D, free, np.maximum(cfg.repick_px, cfg.n_sigma * sigma)), sigma

    def _depth_on_merged_blobs(self, fr: _Frame, asg: np.ndarray, clean: np.ndarray, tri: Triangulated,
                               crowded: np.ndarray) -> np.ndarray:
        """Tracks (indices) seen cleanly by one camera only (``clean`` (K, C)) whose other views (``asg`` (K, C))
        hold merged blobs that another live track's predicted image lies in too (within a marker's image diameter
        + ``merge_px``), that track holding no other blob there: two markers' blob, its centroid between them, up to
        a marker radius off. Their depth along the clean camera's ray rests on that centroid alone, and their filter
        follows its offset frame after frame until the drifted prediction "agrees" with the points (the lying
        markers.trc take replayed from its centroids: CLAVm output 7 mm off for 60 frames). A flat blob no other
        track explains (a streak, a sphere's oblique image), or one beside a partner's own blob (the parts of
        joined halos), is one marker's, and is left to the agreement test. A blob a ``crowded`` (K, C) track holds
        that is flatter than ``round_crowded`` allows counts as merged too, its partner the crowding track: two
        markers under a pixel apart, which the shape flag misses."""
        one_clean = clean.sum(axis=1) == 1
        if not np.count_nonzero(one_clean):  # (most frames)
            return np.zeros(0, dtype=np.intp)
        k, c = np.nonzero(one_clean[:, None] & tri.used & crowded)
        flat = np.unique(k[self._flat(fr, c, asg[k, c])]) if k.size else k
        merged_view = tri.used & _gather(fr.merged, asg)
        rows = (one_clean & merged_view.any(axis=1)).nonzero()[0]
        if rows.size == 0:
            return flat
        return np.union1d(flat, rows[self._shared(fr, asg, rows, merged_view[rows])])

    def _flat_and_shared(self, fr: _Frame, asg: np.ndarray, rows: np.ndarray, views: np.ndarray) -> np.ndarray:
        """(n,) bool: track ``rows[i]`` holds, in one of its ``views`` (n, C) bool, a blob flatter than
        ``round_crowded`` allows that another live track's image lies in too (:meth:`_shared`)."""
        r, c = np.nonzero(views)
        flat = self._flat(fr, c, asg[rows[r], c])
        if not np.count_nonzero(flat):  # (most frames)
            return np.zeros(len(rows), dtype=bool)
        flat_views = np.zeros(views.shape, dtype=bool)
        flat_views[r[flat], c[flat]] = True
        return self._shared(fr, asg, rows, flat_views)

    def _shared(self, fr: _Frame, asg: np.ndarray, rows: np.ndarray, views: np.ndarray) -> np.ndarray:
        """(n,) bool: track ``rows[i]`` holds, in one of its ``views`` (n, C) bool (blobs ``asg[rows]``; ``asg``
        (K, C) every track's this frame), a blob that another live track's predicted image lies in too (within a
        marker's image diameter + ``merge_px``), that track holding no other blob there."""
        t = self._t
        live = (t.since <= 1).nonzero()[0]
        proj, depth = project_ideal(self._P, t.x3[live, :3])  # (C, L, 2), (C, L)
        r_i, cams = np.nonzero(views)
        j = asg[rows[r_i], cams]  # (m,) the blobs
        blob = fr.D[cams, j]  # (m, 2) px
        reach = self._merge_reach(self._focal[cams, None], depth[cams])  # (m, L)
        partner = (np.linalg.norm(proj[cams] - blob[:, None], axis=2) < reach) & (live[None] != rows[r_i, None])
        own = asg[live[None], cams[:, None]]  # (m, L) the partners' blobs there
        partner &= (own < 0) | (own == j[:, None])  # (a partner with a blob of its own: two blobs, not one merged)
        shared = np.zeros(len(rows), dtype=bool)
        shared[r_i[partner.any(axis=1)]] = True
        return shared

    def _flat(self, fr: _Frame, cams: np.ndarray, blobs: np.ndarray) -> np.ndarray:
        """(n,) bool: blob ``blobs[i]`` of camera ``cams[i]`` is flatter than ``round_crowded`` x a sphere's image at
        its field angle."""
        secant = _secant_field_angle(fr.D[cams, blobs], self._centre[cams], self._focal_xy[cams])
        return fr.roundness[cams, blobs] < self._cfg.round_crowded / secant

    def _deblend(self, fr: _Frame, crowded: np.ndarray, asg: np.ndarray, tri: Triangulated) -> np.ndarray:
        """Two markers merged into one blob, one of them well measured elsewhere: the other's image is the blob's
        mirror image about it, 2 u_blob - u_partner (the union of two equal discs is symmetric about their midpoint).

        Where a track holds a shape-flagged merged blob in a camera and exactly one other track, with no blob of
        its own there, projects within a marker's image diameter + ``merge_px`` of it, and both are measured by
        two clean views or more, the one of them with exactly two clean views gets the mirrored position
        (covariance 4x the blob's unscaled one + ``deblend_px``^2) as a clean view and is triangulated again.
        The new point is kept only when its clean views and the mirrored one all stay in it and it lies in the
        track's own 3D gate: a wrong mirror (unequal blobs, a third marker, one marker partly hidden) fits the
        clean views badly. ``tri`` and ``asg`` are updated in place. Returns (K, C) bool: the views mirrored.
        """
        cfg = self._cfg
        out = np.zeros(asg.shape, dtype=bool)
        merged_view = _gather(fr.merged, asg)  # (crowded or not: a partner never seen there is not 'crowding')
        if not np.count_nonzero(merged_view):
            return out
        clean = tri.used & ~crowded & ~merged_view
        n_clean = clean.sum(axis=1)
        good = np.isfinite(tri.X).all(axis=1) & (n_clean >= 2)
        k_all, c_all = np.nonzero(merged_view & good[:, None])
        if k_all.size == 0 or not np.count_nonzero(n_clean == 2):
            return out
        partners = good.nonzero()[0]
        uvp, depth = project_ideal(self._P, tri.X[partners])  # (C, P, 2), (C, P)
        rows, blobs, new_uv, new_S = [], [], [], []
        for k, c in zip(k_all, c_all, strict=True):
            j = asg[k, c]
            if fr.S[c, j, 0, 0] + fr.S[c, j, 1, 1] > 2.0 * cfg.vague_px**2 * cfg.merged_variance_scale:
                continue  # a vague blob (cut by the border), not two markers' merge
            u = fr.D[c, j]
            reach = self._merge_reach(self._focal[c], depth[c])  # (P,)
            near = (np.linalg.norm(uvp[c] - u, axis=1) < reach) & (asg[partners, c] < 0) & (partners != k)
            if near.sum() != 1:
                continue
            p = partners[near.nonzero()[0][0]]
            for target, source in ((k, p), (p, k)):  # either may be the one with two clean views only
                if n_clean[target] == 2 and good[source] and (target, c) not in rows:
                    rows.append((target, c))
                    blobs.append(j)
                    new_uv.append(2.0 * u - uvp[c, np.searchsorted(partners, source)])  # (source is good: a partner)
                    new_S.append(4.0 * fr.S[c, j] / cfg.merged_variance_scale + np.eye(2) * cfg.deblend_px**2)
        if not rows:
            return out
        kk = np.array([k for k, _ in rows])
        cc = np.array([c for _, c in rows])
        todo = np.unique(kk)
        uv = _gather(fr.D, asg[todo])  # (n, C, 2)
        S = _gather(fr.S, asg[todo])
        where = np.searchsorted(todo, kk)
        uv[where, cc] = np.array(new_uv)
        S[where, cc] = np.array(new_S)
        still = crowded[todo].copy()  # (n, C) views still suspected of a merge: down-weighted as in _measure
        still[where, cc] = False
        inflate = np.where(still & ~_gather(fr.merged, asg[todo]), cfg.merged_variance_scale, 1.0)[..., None, None]
        t2 = robust_triangulate(self._P, uv.swapaxes(0, 1), (S * inflate).swapaxes(0, 1), tri.X[todo],
                                cfg.outlier_sigma, self._outlier_px)
        # Kept only where every clean view and every mirrored one stay in the point (a wrong mirror, the blob being
        # one marker partly hidden, fits the others badly) and the point stays in the track's own 3D gate.
        mirrored_views = np.zeros((len(todo), self._C), dtype=bool)
        mirrored_views[where, cc] = True
        with np.errstate(invalid="ignore"):
            ok = (np.isfinite(t2.X).all(axis=1) & ~((clean[todo] | mirrored_views) & ~t2.used).any(axis=1)
                  & (np.linalg.norm(t2.X - self._t.x3[todo, :3], axis=1) < self._radius3(todo)))
        todo = todo[ok]
        tri.X[todo], tri.cov[todo], tri.rms_px[todo], tri.used[todo] = t2.X[ok], t2.cov[ok], t2.rms_px[ok], t2.used[ok]
        tri.proj[:, todo], tri.depth[:, todo] = t2.proj[:, ok], t2.depth[:, ok]
        keep = np.isin(kk, todo)
        asg[kk[keep], cc[keep]] = np.array(blobs)[keep]  # (the partner's view of the shared blob is its own)
        asg[todo] = np.where(tri.used[todo], asg[todo], -1)
        out[kk[keep], cc[keep]] = True
        return out

    def _follow_residual_level(self, fr: _Frame, meas: _Measurements) -> None:
        """Running average (``error_alpha``) of each frame's median reprojection RMS (px) over its points with
        three or more clean cameras, and the camera rejection floor that follows it (``outlier_rms_factor``)."""
        cfg = self._cfg
        ok = meas.ok.nonzero()[0]
        rms = meas.rms_px[ok][(_clean_views(fr.merged, meas.asg[ok]) >= 3) & np.isfinite(meas.rms_px[ok])]
        if rms.size < 3:
            return
        self._rms_px += cfg.error_alpha * (quick_median(rms) - self._rms_px)
        self._outlier_px = max(cfg.outlier_min_px, cfg.outlier_rms_factor * self._rms_px)

    def _update(self, fr: _Frame, meas: _Measurements, idx: np.ndarray) -> None:
        """Kalman and running-error updates of tracks ``idx`` with their measurements (3D and image filters)."""
        if idx.size == 0:
            return
        t, dt = self._t, self._dt
        if kernels.HAVE_NUMBA:  # the same steps, in place
            c = kernels.contiguous
            kernels.update_tracks(idx, c(meas.X), c(meas.cov), c(meas.asg, np.intp), fr.D, fr.S, self._P, self._focal,
                                  dt, self._running.alpha, _IMAGE_VELOCITY_STD, _IMAGE_ACCEL_STD, t.since, t.hits,
                                  t.x3, t.P3, t.e3, t.last_X, t.last_v, t.noise, t.x2, t.P2, t.e2, t.last_uv,
                                  t.last_uvv, t.lock2, t.unseen2)
        else:
            self._update_numpy(fr, meas, idx)
        kk, cc = np.nonzero(meas.asg[idx] >= 0)
        t.blob_unseen[idx[kk], cc] = 0
        if self._blobs_followed:
            self._follow_blobs(fr, idx[kk], cc, meas.asg[idx[kk], cc])

    def _update_numpy(self, fr: _Frame, meas: _Measurements, idx: np.ndarray) -> None:
        """:meth:`_update`'s filter steps without numba."""
        t, dt = self._t, self._dt
        X = meas.X[idx]
        cov = meas.cov[idx]
        R = cov + np.eye(3) * 1e-12
        consecutive = t.since[idx] == 1
        prior = t.x3[idx]
        x_new, P_new, _, _ = update_position(prior, t.P3[idx], X, R)
        # Running prediction errors (paper 004), from consecutive frames only.
        v_meas = (X - t.last_X[idx]) / dt
        a_meas = (v_meas - t.last_v[idx]) / dt
        dev = (np.concatenate([X, v_meas, a_meas], axis=1) - prior).reshape(-1, 3, 3)  # y, velocity, accel errors
        err = np.sqrt((dev * dev).sum(axis=2))
        e3 = t.e3[idx]
        err = np.where(np.isfinite(err), err, e3)
        t.e3[idx] = np.where(consecutive[:, None], self._running.step(e3, err), e3)
        t.x3[idx], t.P3[idx] = x_new, P_new
        t.last_v[idx] = np.where(consecutive[:, None], v_meas, np.nan)
        t.last_X[idx] = X
        t.noise[idx] = _point_std(cov)
        t.hits[idx] = np.where(consecutive, t.hits[idx] + 1, 1)
        t.since[idx] = 0
        # Image filters of the cameras used.
        asg = meas.asg[idx]
        seen = asg >= 0
        kk, cc = np.nonzero(seen)
        tk = idx[kk]
        det = asg[kk, cc]
        z = fr.D[cc, det]
        Rz = fr.S[cc, det]
        locked = t.lock2[tk, cc]
        x2 = t.x2[tk, cc]
        x2n, P2n, _, _ = update_position(x2, t.P2[tk, cc], z, Rz)
        uvv = (z - t.last_uv[tk, cc]) / dt
        uva = (uvv - t.last_uvv[tk, cc]) / dt
        dev2 = (np.concatenate([z, uvv, uva], axis=1) - x2).reshape(-1, 3, 2)
        err2 = np.sqrt(dev2[..., 0] * dev2[..., 0] + dev2[..., 1] * dev2[..., 1])  # (the sum over 2, ~3x faster)
        e2 = t.e2[tk, cc]
        fin = np.isfinite(err2)
        e2 = np.where(locked[:, None] & fin, self._running.step(e2, np.where(fin, err2, 0.0)), e2)
        nl = (~locked).nonzero()[0]
        if nl.size:  # (re)start image filters from the projected 3D state
            _, J = reprojection_jacobians(self._P, t.x3[tk[nl], :3])  # (C, n, 2, 3)
            vel = (J[cc[nl], np.arange(nl.size)] @ t.x3[tk[nl], 3:6, None])[..., 0]
            x2n[nl], P2n[nl] = init_state(z[nl], Rz[nl], vel, _IMAGE_VELOCITY_STD, _IMAGE_ACCEL_STD)
            e2[nl] = self._e2_from_3d(tk[nl], cc[nl])
        t.x2[tk, cc], t.P2[tk, cc], t.e2[tk, cc] = x2n, P2n, e2
        t.last_uvv[tk, cc] = np.where(locked[:, None], uvv, 0.0)
        t.last_uv[tk, cc] = z
        t.lock2[idx] = seen
        t.unseen2[tk, cc] = 0

    def _expected_blobs(self) -> np.ndarray:
        """(K, C, 4) each track's blob expected in each camera (:func:`_blob_at_depth` at the depth of the track's last
        point): area px, roundness, flux grey levels and its deviation (NaN: none)."""
        t = self._t
        if kernels.HAVE_NUMBA:
            return kernels.expected_blobs(t.blob, t.last_X, self._P, self._light_power)
        return _blob_at_depth(t.blob, t.last_X @ self._P[:, 2, :3].T + self._P[:, 2, 3], self._light_power)

    def _fit_light_power(self) -> None:
        """How a blob's light falls with its depth, 1 / depth^power, fitted to the take's own blobs: the slope of the
        log light ratios over the log depth ratios of each track's successive clean views in a camera (least squares
        through 0, each ratio's miss of the power so far clipped to ``_FLUX_STEP_CLIP``), drawn towards 4 by
        ``_FLUX_DEPTH_PRIOR`` (a retroreflector lit from beside the lens, as ``mocap synth`` draws it; its thresholded
        blobs fit 3.5-3.7). A renderer that draws every marker at one height, or saturated blobs, give about 2: a fixed
        4 then took whole blobs coming nearer for darker ones."""
        if not self._light:  # (no pairs yet)
            return
        xx, xy = self._light_fit
        power = (_FLUX_DEPTH_PRIOR * _FLUX_DEPTH_POWER - xy) / (_FLUX_DEPTH_PRIOR + xx)
        self._light_power = min(max(float(power), _FLUX_DEPTH_RANGE[0]), _FLUX_DEPTH_RANGE[1])

    def _partial(self, area: np.ndarray, roundness: np.ndarray, merged: np.ndarray, expected: np.ndarray
                 ) -> np.ndarray:
        """(n,) bool: blobs of ``area`` (px), ``roundness`` and ``merged`` flag (n,) each, where the marker's blob
        is ``expected`` (n, 2) (area px, roundness; NaN: unknown), show the marker partly hidden: smaller by more than
        ``partial_area`` / sqrt(area) (the pixel count's spread) and no rounder by ``partial_round`` / sqrt(area) (a
        motion streak that shortens), or flatter by that and no larger (a streak or a merge grows). Its centroid is
        off towards the visible part, up to 0.4 of a radius. Blobs flagged merged are not judged."""
        cfg = self._cfg
        with np.errstate(invalid="ignore", divide="ignore"):
            area_ratio = area / expected[:, 0]
            round_ratio = roundness / expected[:, 1]
            spread = 1.0 / np.sqrt(expected[:, 0])
            out = (((area_ratio < 1.0 - cfg.partial_area * spread) & (round_ratio < 1.0 + cfg.partial_round * spread))
                   | ((round_ratio < 1.0 - cfg.partial_round * spread) & (area_ratio < 1.0)))
        return out & ~merged & (expected[:, 0] >= cfg.partial_min_area)

    def _partly_hidden(self, fr: _Frame, tracks: np.ndarray, cams: np.ndarray, blobs: np.ndarray) -> np.ndarray:
        """(n,) bool: blob ``blobs[i]`` of camera ``cams[i]`` is track ``tracks[i]``'s marker partly hidden there
        (:meth:`_partial`, against :meth:`_expected_blobs` as of the frame's start)."""
        cfg = self._cfg
        if kernels.HAVE_NUMBA:
            c = kernels.contiguous
            return kernels.partly_hidden(self._expect, fr.area, fr.roundness, fr.merged, c(tracks, np.intp),
                                         c(cams, np.intp), c(blobs, np.intp), float(cfg.partial_area),
                                         float(cfg.partial_round), float(cfg.partial_min_area))
        return self._partial(fr.area[cams, blobs], fr.roundness[cams, blobs], fr.merged[cams, blobs],
                             self._expect[tracks, cams])

    def _follow_blobs(self, fr: _Frame, tracks: np.ndarray, cams: np.ndarray, blobs: np.ndarray) -> None:
        """Running averages (``blob_alpha``) of each track's blob per camera, from its views this frame: the area
        (scaled to depth) and roundness from views neither flagged merged nor partly hidden (:meth:`_partial`); the
        light (flux, scaled to depth) and its mean absolute relative deviation from views neither merged nor darker
        (:meth:`_dark`). A blob judged partly hidden (or darker) more than ``partial_frames`` times in a row is the
        marker's blob now (an exposure change, another marker taken, a lasting cover): that average starts again
        from it."""
        cfg = self._cfg
        t = self._t
        if kernels.HAVE_NUMBA:
            c = kernels.contiguous
            kernels.follow_blobs(t.blob, t.cut_run, t.dark_run, t.last_X, self._P, fr.area, fr.roundness, fr.flux,
                                 fr.merged, c(tracks, np.intp), c(cams, np.intp), c(blobs, np.intp),
                                 float(cfg.blob_alpha), float(cfg.partial_area), float(cfg.partial_round),
                                 float(cfg.partial_min_area), int(cfg.partial_frames), self._dark_settings(),
                                 self._light_power, float(_FLUX_STEP_CLIP), self._light_fit)
            return
        depth = np.einsum("nj,nj->n", self._P[cams, 2, :3], t.last_X[tracks]) + self._P[cams, 2, 3]
        expected = _blob_at_depth(t.blob[tracks, cams], depth, self._light_power)
        area, roundness, merged = fr.area[cams, blobs], fr.roundness[cams, blobs], fr.merged[cams, blobs]
        flux = fr.flux[cams, blobs]
        a = cfg.blob_alpha
        # the light, at this depth
        dark = self._dark(self._light_ratio(flux, expected), merged, expected)
        run = np.where(dark, t.dark_run[tracks, cams] + 1, 0)
        dark_lasting = run > cfg.partial_frames
        t.dark_run[tracks, cams] = np.where(dark_lasting, 0, run)
        light, deviation = expected[:, 2], expected[:, 3]
        take = ~merged & (~dark | dark_lasting) & np.isfinite(flux) & np.isfinite(depth)
        step = take & np.isfinite(light) & ~dark_lasting
        with np.errstate(invalid="ignore", divide="ignore"):
            off = np.abs(flux / light - 1.0)
        deviation = np.where(step, np.where(np.isfinite(deviation), deviation + a * (off - deviation), off), deviation)
        light = np.where(step, light + a * (flux - light), np.where(take, flux, light))
        # the power of the depth the light falls with: successive clean views
        record = t.blob[tracks, cams]
        with np.errstate(invalid="ignore", divide="ignore"):
            x = np.log(depth / record[:, 6])
            y = np.log(flux / record[:, 5])
            pair = take & ~dark_lasting & np.isfinite(x) & np.isfinite(y)
            y = np.clip(y + self._light_power * x, -_FLUX_STEP_CLIP, _FLUX_STEP_CLIP) - self._light_power * x
        self._light_fit += (np.sum(x[pair] * x[pair]), np.sum(x[pair] * y[pair]))
        record[take, 5], record[take, 6] = flux[take], depth[take]
        # the area and roundness
        cut = self._partial(area, roundness, merged, expected)
        run = np.where(cut, t.cut_run[tracks, cams] + 1, 0)
        lasting = run > cfg.partial_frames
        t.cut_run[tracks, cams] = np.where(lasting, 0, run)
        take = ~merged & (~cut | lasting) & np.isfinite(depth)
        expected[lasting, 0] = np.nan  # (starts again)
        fresh = ~np.isfinite(expected[:, 0])
        record[take] = np.stack([
            np.where(fresh, area, expected[:, 0] + a * (area - expected[:, 0])),
            np.where(fresh, roundness, expected[:, 1] + a * (roundness - expected[:, 1])),
            depth, record[:, 3], record[:, 4], record[:, 5], record[:, 6]], axis=1)[take]
        # the light kept at the record's depth
        kept = np.isfinite(light)
        record[kept & ~np.isfinite(record[:, 2]), 2] = depth[kept & ~np.isfinite(record[:, 2])]
        with np.errstate(invalid="ignore", divide="ignore"):
            record[kept, 3] = light[kept] * (depth[kept] / record[kept, 2]) ** self._light_power
        record[:, 4] = deviation
        t.blob[tracks, cams] = record

    def _judge_dark_views(self, fr: _Frame, asg: np.ndarray, tri: Triangulated, suspect: np.ndarray,
                          split: np.ndarray, sigma: np.ndarray, meas: _Measurements) -> None:
        """``meas.withheld`` (K,): the output points the written trajectories leave out (:meth:`withheld`), judged by
        their blobs' light against their marker's blob there lately (:meth:`_expected_blobs` as of the frame's start):
        points that would not be output if their clean views (used, not ``suspect``) that hold less light
        (:meth:`_dark`) counted as no clean view (a two-view point leaning on such a view, off its prediction: a cut
        blob's centroid lies along the other camera's epipolar line as often as not, and nothing else tells); and
        points with fewer than two clean views besides a view holding less than ``dim_light`` of the marker's light:
        a blob flagged merged (flat because cut, not because two markers merged, whose light adds up), or a clean one
        (so dim it is cut, whatever the prediction says: at 50 Hz a serve's prediction lets 2-3 mm through)."""
        meas.withheld = np.zeros(len(asg), dtype=bool)
        if not self._light:  # (no blob carried its light yet: centroid files, older logs)
            return
        k, c = np.nonzero(tri.used & (asg >= 0))
        if k.size == 0:
            return
        ratio, merged, dark = self._light_of_views(fr, k, c, asg[k, c], tri.X[k])
        dark |= self._darker_than_other_views(fr, np.where(tri.used, asg, -1), tri.X, k, c, ratio, merged,
                                              np.zeros(asg.shape, dtype=bool), self._cfg.dark_borrowed)
        dark &= ~suspect[k, c]
        dim = (ratio < self._cfg.dim_light) & (merged | ~suspect[k, c])  # (NaN: not judged)
        if np.count_nonzero(dim):
            rows = np.unique(k[dim])
            views = np.zeros(asg.shape, dtype=bool)
            views[k[dim], c[dim]] = True
            clean = tri.used[rows] & ~suspect[rows] & ~_gather(fr.merged, asg[rows]) & ~views[rows]
            lean = rows[clean.sum(axis=1) < 2]
            meas.withheld[lean] = meas.out[lean]
        if not np.count_nonzero(dark):
            return
        rows = np.unique(k[dark])
        views = np.zeros(asg.shape, dtype=bool)
        views[k[dark], c[dark]] = True
        meas.withheld[rows] |= meas.out[rows] & ~self._verdicts(
            fr, tri.X[rows], tri.used[rows], tri.depth[:, rows], (suspect | views)[rows], split[rows], sigma,
            asg[rows], self._t.x3[rows], self._t.e3[rows])[2]

    def _leans_on_dark_views(self, fr: _Frame, rows: np.ndarray, det: np.ndarray, X: np.ndarray) -> np.ndarray:
        """(n,) bool: the points ``X`` (n, 3) m from the free detections ``det`` (n, C) (two clean views at least:
        :meth:`_new_markers`), re-acquiring the tracks ``rows`` (n,) or starting tracks that may inherit their lost
        identities, that keep fewer than two clean views once their darker views (:meth:`_dark`, against those
        tracks' blobs lately, at the point's depth) count as none. A marker coming back from behind something is
        cut in the frames it comes out; these points are not judged by :meth:`_judge_dark_views`, and are withheld
        the same way."""
        lean = np.zeros(len(rows), dtype=bool)
        if not self._light or self._cfg.dark_flux >= 1:
            return lean
        k, c = np.nonzero(det >= 0)
        _, merged, dark = self._light_of_views(fr, rows[k], c, det[k, c], X[k])
        if np.count_nonzero(dark):
            clean = np.zeros(det.shape, dtype=bool)
            clean[k, c] = ~merged & ~dark
            lean = clean.sum(axis=1) < 2
        return lean

    def _verdicts(self, fr: _Frame, X: np.ndarray, used: np.ndarray, depth: np.ndarray, suspect: np.ndarray,
                  split: np.ndarray, sigma: np.ndarray, asg: np.ndarray, x3: np.ndarray, e3: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The verdicts on measured points ``X`` (K, 3) m from their ``used`` views (K, C) (detections ``asg``,
        ``depth`` (C, K) m there): ``ok`` (K,) finite; ``clean`` (K, C) the used views that are not ``suspect`` nor
        merged, or ``split``; ``out`` (K,): two clean views, or one and a point that agrees with the prediction ``x3``
        (within ``gate_scale`` x the running error ``e3``, clipped to ``suspect_m`` and ``n_sigma`` x the clean
        views' noise, from ``sigma`` (C, N) px). One kernel call with numba (:func:`mocap.kernels.measured_points`)."""
        cfg = self._cfg
        if kernels.HAVE_NUMBA:
            return kernels.measured_points(X, used, kernels.contiguous(suspect, bool), split, fr.merged, sigma, asg,
                                           kernels.contiguous(depth), self._focal, x3, e3, float(cfg.gate_scale),
                                           float(cfg.suspect_m[0]), float(cfg.suspect_m[1]), float(cfg.n_sigma))
        ok = np.isfinite(X).all(axis=1)
        clean = used & ((~suspect & ~_gather(fr.merged, asg)) | split)
        with np.errstate(invalid="ignore", divide="ignore"):  # the point's own noise, m (NaN without a clean view)
            noise = (np.where(clean, _gather(sigma, asg) * depth.T / self._focal, 0.0).sum(axis=1)
                     / clean.sum(axis=1))
        high = np.fmax(cfg.suspect_m[1], cfg.n_sigma * noise)
        agree = np.linalg.norm(X - x3[:, :3], axis=1) < np.clip(cfg.gate_scale * e3[:, 0], cfg.suspect_m[0], high)
        return ok, clean, ok & ((clean.sum(axis=1) >= 2) | (agree & clean.any(axis=1)))

    def _light_ratio(self, flux: np.ndarray, expected: np.ndarray) -> np.ndarray:
        """(n,) blobs' ``flux`` (n,) grey levels over their marker's blob's light ``expected`` (n, 4)
        (:meth:`_expected_blobs`); NaN where either is unknown or the blob is expected smaller than
        ``partial_min_area`` (not judged)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(expected[:, 0] >= self._cfg.partial_min_area, flux / expected[:, 2], np.nan)

    def _light_of_views(self, fr: _Frame, tracks: np.ndarray, cams: np.ndarray, blobs: np.ndarray, X: np.ndarray
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The views of tracks ``tracks`` (n,) in cameras ``cams`` (n,) on blobs ``blobs`` (n,) measuring points ``X``
        (n, 3) m, judged by their light: the :meth:`_light_ratio` against the track's blob there lately
        (:meth:`_expected_blobs`, at the track's last point) moved to the point's depth (as 1 / depth^power: at 50 Hz
        a hand swinging towards a camera changes its light by a fifth in a frame), the blobs' ``merged`` flags and
        which are darker (:meth:`_dark`); (n,) each."""
        expected = self._expect[tracks, cams]
        merged = fr.merged[cams, blobs]
        P = self._P[cams, 2]
        last = np.einsum("nj,nj->n", P[:, :3], self._t.last_X[tracks]) + P[:, 3]
        here = np.einsum("nj,nj->n", P[:, :3], X) + P[:, 3]
        ratio = self._light_ratio(fr.flux[cams, blobs], expected) * (here / last) ** self._light_power
        return ratio, merged, self._dark(ratio, merged, expected)

    def _dark(self, ratio: np.ndarray, merged: np.ndarray, expected: np.ndarray) -> np.ndarray:
        """(n,) bool: blobs whose light ``ratio`` (n,) to their marker's blob (:meth:`_light_ratio`; NaN: not judged)
        is under 1 by more than ``dark_flux`` (or ``dark_spread`` times the light's running deviation, ``expected``
        (n, 4) column 3, up to ``dark_max``), and not flagged ``merged`` (n,): the marker partly hidden, its centroid
        off towards the part seen."""
        cfg = self._cfg
        tolerance = np.fmin(np.fmax(cfg.dark_flux, cfg.dark_spread * expected[:, 3]), cfg.dark_max)
        with np.errstate(invalid="ignore"):
            return (ratio < 1.0 - tolerance) & ~merged

    def _dark_settings(self) -> np.ndarray:
        """The kernels' (4,) ``dark_flux``, ``dark_spread``, ``dark_max``, ``partial_min_area``."""
        cfg = self._cfg
        return np.array([cfg.dark_flux, cfg.dark_spread, cfg.dark_max, cfg.partial_min_area])

    def _e2_from_3d(self, tracks: np.ndarray, cams: np.ndarray) -> np.ndarray:
        """(n, 3) image running errors seeded from the tracks' 3D ones, scaled by f / depth."""
        X = self._t.x3[tracks, :3]
        depth = np.einsum("nj,nj->n", self._P[cams, 2, :3], X) + self._P[cams, 2, 3]
        return self._t.e3[tracks] * (self._focal[cams] / np.maximum(depth, 1e-6))[:, None]

    def _radius3(self, tracks: np.ndarray) -> np.ndarray:
        """(n,) 3D search radius of ``tracks``, m (widens with the frames since their last measurement)."""
        t, cfg = self._t, self._cfg
        return np.minimum(self._running.radius(*t.e3[tracks].T, t.since[tracks], self._dt, cfg.gate_floor_m),
                          cfg.reid_max_m)

    def _new_markers(self, fr: _Frame, free: np.ndarray, meas: _Measurements) -> None:
        """Points from the free detections: re-acquire missed tracks, or start tentative tracks."""
        t = self._t
        pts = self._new_points(fr, free)
        if len(pts.X) == 0:
            return
        # 1) Tracks that missed this frame but still search: re-acquire them directly.
        missing = ((t.since >= 1) & self._in_play()).nonzero()[0]
        predicted, radius = self._search_again(missing)
        match = reidentify(pts.X, predicted, radius, allowed=self._attached_allow(pts.X, missing))
        got = (match >= 0).nonzero()[0]
        clean_view = (pts.det >= 0) & ~_gather(fr.merged, pts.det)  # (P, C)
        n_clean = clean_view.sum(axis=1)
        clean = n_clean >= 2
        if got.size:
            rows = missing[match[got]]
            out = clean[got]
            if self._cfg.withhold_merged_depth:  # two clean views, one a flat blob another track lies in
                asg = meas.asg.copy()
                asg[rows] = pts.det[got]
                out &= ~self._flat_and_shared(fr, asg, rows, clean_view[got] & (n_clean[got] == 2)[:, None])
            withheld = out & self._leans_on_dark_views(fr, rows, pts.det[got], pts.X[got])
            meas.put(rows, _Measurements(np.ones(got.size, dtype=bool), out, pts.X[got], pts.cov[got],
                                         pts.rms_px[got], pts.det[got], withheld, *_Measurements.unwritten(got.size)))
            self._update(fr, meas, rows)
        # 2) Tracks start only from points two clean cameras support: two blobs of merged markers (or a merged
        #    blob and a reflection) match across cameras at a point between the markers, which then moves.
        rest = ((match < 0) & clean).nonzero()[0]
        if rest.size == 0:
            return
        # Identities not measured this frame: a tentative track inherits one if confirmed (_lifecycle).
        lost = ((t.ident >= 0) & (t.since >= 1)).nonzero()[0]
        cand = np.full(rest.size, -1, dtype=np.intp)
        lean = np.zeros(rest.size, dtype=bool)
        if lost.size:
            predicted, last = t.x3[lost, :3], t.last_X[lost]
            if self._cfg.attached_check and self._cfg.carry_lost:
                carried, X = self._carried(lost)
                predicted, last = np.where(carried[:, None], X, predicted), X
            radius = self._radius3(lost)
            match = reidentify(pts.X[rest], predicted, radius, last,
                               self._attached_allow(pts.X[rest], lost, (predicted, last, radius)))
            cand = np.where(match >= 0, t.ident[lost[np.maximum(match, 0)]], -1)
            has = (match >= 0).nonzero()[0]  # (judged by the light of the lost marker they may be)
            lean[has] = self._leans_on_dark_views(fr, lost[match[has]], pts.det[rest[has]], pts.X[rest[has]])
        self._start(fr, pts.subset(rest), cand, meas, lean)

    def _carried(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the unmeasured confirmed tracks ``rows`` (n,) are if they moved rigidly with the steady neighbours
        they had when last measured, as those measured this frame say (:meth:`AttachedDistances.carried`): (n,) bool
        (carried) and (n, 3) m (their last positions where not)."""
        t = self._t
        here = ((t.ident >= 0) & (t.since == 0)).nonzero()[0]
        return self._attached.carried(t.ident[rows], t.last_X[rows], t.ident[here], t.last_X[here],
                                      self._cfg.carry_neighbours)

    def _search_again(self, missing: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the tracks ``missing`` (m,), unmeasured this frame and still searching, are looked for among the
        new points, and how far, m: (m, 3), (m,). The coasting prediction and the widened search radius; for a
        confirmed track two or more frames into its gap that its steady neighbours carry (``carry_in_play``), the
        carried place and the one-frame radius (the carry leaves no extrapolation to widen it for)."""
        t, cfg = self._t, self._cfg
        predicted, radius = t.x3[missing, :3], self._radius3(missing)
        if not (cfg.attached_check and cfg.carry_in_play):
            return predicted, radius
        long = ((t.ident[missing] >= 0) & (t.since[missing] >= 2)).nonzero()[0]
        if long.size == 0:
            return predicted, radius
        rows = missing[long]
        carried, X = self._carried(rows)
        if not carried.any():
            return predicted, radius
        near = self._running.radius(*t.e3[rows].T, 1, self._dt, cfg.gate_floor_m)
        predicted, radius = predicted.copy(), radius.copy()
        predicted[long[carried]] = X[carried]
        radius[long[carried]] = np.minimum(radius[long[carried]], near[carried])
        return predicted, radius

    def _new_points(self, fr: _Frame, free: np.ndarray) -> NewPoints:
        """New points from the free detections (C, N) bool that pair with a fresh one, apart from the markers
        measured this frame; the free detections no such point uses join the memory of unexplained ones.

        A detection a point uses is not remembered: if that point dies (a ghost that took a marker's blob in one
        camera), the marker's blobs pair again in the next frame instead of waiting out the memory.
        """
        t, cfg = self._t, self._cfg
        if len(self._clutter) == self._clutter.maxlen:
            self._clutter.clear()
        fresh = free & ~self._known_clutter(fr.D, free)
        unexplained = free.copy()
        pts = NewPoints.none(self._C)
        if np.count_nonzero(fresh) and free.sum() >= 2 and len(self._pairs):
            pts = new_points(self._P, self._pairs, fr.D, fr.S, free, self._sizes, cfg.epipolar_px, cfg.support_px,
                             cfg.new_min_views, cfg.outlier_sigma, self._outlier_px, fresh, cfg.n_sigma)
            measured = t.since == 0
            if len(pts.X) and np.count_nonzero(measured):  # duplicates of markers measured this frame
                d = np.linalg.norm(pts.X[:, None] - t.x3[None, measured, :3], axis=2)
                pts = pts.subset(d.min(axis=1) > cfg.min_separation_m)
            k, c = np.nonzero(pts.det >= 0)
            unexplained[c, pts.det[k, c]] = False
        self._clutter.append(np.where(unexplained[..., None], fr.D, np.nan)[:, unexplained.any(axis=0)])
        return pts

    def _known_clutter(self, D: np.ndarray, which: np.ndarray) -> np.ndarray:
        """(C, N) bool: the detections ``which`` (C, N) within ``clutter_px`` of a remembered one (see ``_new_points``).

        Free detections that stay put (fixed or flickering reflections, a marker seen by one camera)
        were already examined for new markers and left unexplained; they are only paired with fresh
        detections again.
        Only the detections asked about are compared (the free ones: a few per frame, not all N).
        """
        out = np.zeros(D.shape[:2], dtype=bool)
        if not self._clutter or not np.count_nonzero(which):
            return out
        old = np.concatenate(self._clutter, axis=1)  # (C, M, 2), NaN where not free
        cc, nn = np.nonzero(which)
        if kernels.HAVE_NUMBA:
            out[cc, nn] = kernels.near_any(D, cc, nn, old, self._cfg.clutter_px**2)
            return out
        with np.errstate(invalid="ignore"):
            out[cc, nn] = (dist2(D[cc, nn][:, None, :], old[cc]) < self._cfg.clutter_px**2).any(axis=1)
        return out

    def _start(self, fr: _Frame, pts: NewPoints, cand: np.ndarray, meas: _Measurements, lean: np.ndarray) -> None:
        """Append tentative tracks at new points ``pts`` (and their measurements to ``meas``); ``cand`` (n,) the lost
        identity each may inherit (-1: none), ``lean`` (n,) the points that lean on blobs darker than that
        identity's (:meth:`_leans_on_dark_views`; withheld from the written trajectories)."""
        n, C, cfg = len(pts.X), self._C, self._cfg
        x3, P3 = init_state(pts.X, pts.cov + np.eye(3) * 1e-12, velocity_std=cfg.new_track_speed,
                            accel_std=cfg.new_track_speed * self._fps)
        uid = np.arange(self._next_uid, self._next_uid + n)
        self._next_uid += n
        if self._next_uid > len(self._uid_ident):
            grown = np.full(max(2 * len(self._uid_ident), self._next_uid), -1, dtype=np.intp)
            grown[: len(self._uid_ident)] = self._uid_ident
            self._uid_ident = grown
        e3 = np.zeros((n, 3))
        e3[:, 0] = cfg.new_track_speed * self._dt / cfg.gate_scale  # first gate: new_track_speed x dt
        used = pts.det >= 0
        k, c = np.nonzero(used)
        z = fr.D[c, pts.det[k, c]]
        x2 = np.zeros((n, C, 6))
        P2 = np.broadcast_to(np.eye(6), (n, C, 6, 6)).copy()
        x2[k, c], P2[k, c] = init_state(z, fr.S[c, pts.det[k, c]], None, _IMAGE_VELOCITY_STD, _IMAGE_ACCEL_STD)
        last_uv = np.zeros((n, C, 2))
        last_uv[k, c] = z
        i = np.zeros(n, dtype=np.intp)
        new = _Tracks(uid, i - 1, cand, i + 1, i.copy(), x3, P3, e3, pts.X.copy(), np.full((n, 3), np.nan), x2, P2,
                      used, np.zeros((n, C), dtype=np.intp), np.zeros((n, C, 3)), last_uv,
                      np.zeros((n, C, 2)), ~pts.strong, pts.X.copy(), _point_std(pts.cov),
                      np.full((n, C, _BLOB_FIELDS), np.nan), np.zeros((n, C), dtype=np.intp),
                      np.zeros((n, C), dtype=np.intp), np.zeros((n, C), dtype=np.intp))
        base = len(self._t)
        self._t.extend(new)
        self._t.e2[base + k, c] = self._e2_from_3d(base + k, c)
        out = _clean_views(fr.merged, pts.det) >= 2  # (all: _new_markers starts only such points)
        meas.extend(_Measurements(np.ones(n, dtype=bool), out, pts.X, pts.cov, pts.rms_px, pts.det,
                                  out & lean, *_Measurements.unwritten(n)))

    def _lifecycle(self, meas: _Measurements) -> None:
        """Confirm tentative tracks, drop failed tentative ones and retired identities."""
        t, cfg = self._t, self._cfg
        t.lock2[t.since > 0] = False
        tentative = t.ident < 0
        # A track born from a weak point must have moved, or stand still with its neighbours: fixed
        # reflections that happen to match across two cameras make a static point wherever they are.
        if np.count_nonzero(t.weak):
            # (the difference of two points: sqrt(2) x their std; sqrt(3) x the RMS std bounds the depth's)
            noise = np.sqrt(6.0) * t.noise
            t.weak &= np.linalg.norm(t.last_X - t.origin, axis=1) <= np.maximum(cfg.weak_motion_m,
                                                                                cfg.weak_motion_sigma * noise)
        idle, busy = self._neighbour_motion(t.weak & (t.since == 0))
        confirm = (tentative & (t.since == 0) & (t.hits >= cfg.confirm_frames) & (~t.weak | idle)).nonzero()[0]
        # A static point confirmed that way is a reflection once its neighbours move and it does not:
        # it is retired and its output withdrawn.
        retire = busy & (t.ident >= 0)
        self._uid_ident[t.uid[retire]] = -1
        for k in confirm:  # rare: once per new identity
            owner = ((t.ident == t.cand[k]) & (t.since >= 1)).nonzero()[0] if t.cand[k] >= 0 else []
            if len(owner):
                retire[owner] = True
                t.ident[k] = t.cand[k]
            else:
                t.ident[k] = self._n_ident
                self._n_ident += 1
            self._uid_ident[t.uid[k]] = t.ident[k]
        retire |= tentative & (t.since > 0) & (t.ident < 0)
        retire |= (t.ident >= 0) & (t.since > self._keep_lost)
        if np.count_nonzero(retire):
            t.keep(~retire)
            meas.keep(~retire)

    def _neighbour_motion(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(K,) bool twice, for the tracks in ``rows`` (K,) bool: ``idle``, the confirmed tracks measured within
        ``neighbour_m`` (at least ``neighbour_min``) move less than ``weak_motion_m`` over ``confirm_frames``
        (median speed); ``busy``, they move more than twice that while the track itself moves less than half."""
        t, cfg = self._t, self._cfg
        idle, busy = np.zeros(len(t), dtype=bool), np.zeros(len(t), dtype=bool)
        ref = (t.ident >= 0) & (t.since == 0) & ~t.weak
        if not np.count_nonzero(rows) or ref.sum() < cfg.neighbour_min:
            return idle, busy
        k = rows.nonzero()[0]
        gap = t.x3[k, None, :3] - t.x3[None, ref, :3]
        near = (gap * gap).sum(axis=2) < cfg.neighbour_m**2  # (k, R)
        enough = near.sum(axis=1) >= cfg.neighbour_min
        k, near = k[enough], near[enough]
        if k.size == 0:
            return idle, busy
        step = np.linalg.norm(t.x3[:, 3:6], axis=1) * cfg.confirm_frames * self._dt  # (K,) m over the window
        typical = np.nanmedian(np.where(near, step[ref][None], np.nan), axis=1)
        idle[k] = typical < cfg.weak_motion_m
        busy[k] = (typical > 2 * cfg.weak_motion_m) & (step[k] < 0.5 * cfg.weak_motion_m)
        return idle, busy

    def _record(self, frame_index: int, fr: _Frame, meas: _Measurements) -> FrameResult:
        t = self._t
        rows = (meas.out & (t.since == 0)).nonzero()[0]
        X, asg = meas.X[rows], meas.asg[rows]
        if np.count_nonzero(meas.withheld):
            withheld = rows[meas.withheld[rows]]
            self._withheld.append((np.full(len(withheld), frame_index), meas.X[withheld]))
        written = rows[np.isfinite(meas.written[rows, 0])]
        if written.size:
            self._rewritten.append((np.full(written.size, frame_index), meas.X[written], meas.written[written],
                                    meas.written_residual[written], meas.written_mask[written]))
        bounds = list(accumulate(fr.counts, initial=0))  # all cameras' detections in one flat array
        if kernels.HAVE_NUMBA:
            res, mask, flat = kernels.frame_record(X, kernels.contiguous(asg, np.intp), meas.rms_px[rows],
                                                   t.ident[rows], self._P, self._focal, np.array(bounds))
            self._records.append(frame=frame_index, uid=t.uid[rows], pos=X, res=res, mask=mask)
            conf = t.ident[rows] >= 0
            assignments = [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
            return FrameResult(frame_index, t.ident[rows][conf], X[conf], res[conf], mask[conf], assignments)
        used = asg >= 0
        res, mask = self._residual_and_mask(X, used, meas.rms_px[rows])
        self._records.append(frame=frame_index, uid=t.uid[rows], pos=X, res=res, mask=mask)
        conf = t.ident[rows] >= 0
        ids = t.ident[rows][conf]
        flat = np.full(bounds[-1], -1, dtype=np.intp)
        kk, cc = np.nonzero(used[conf])
        flat[np.array(bounds)[cc] + asg[conf][kk, cc]] = ids[kk]
        assignments = [flat[a:b] for a, b in zip(bounds[:-1], bounds[1:], strict=True)]
        return FrameResult(frame_index, ids, X[conf], res[conf], mask[conf], assignments)


def _secant_field_angle(xy: np.ndarray, centre: np.ndarray, focal_xy: np.ndarray) -> np.ndarray:
    """(...) 1 / cos(field angle) at ideal pixel ``xy`` (..., 2) of a camera with principal point ``centre`` and
    focal lengths ``focal_xy`` (each broadcast to (..., 2)), px: a sphere's image there has axis ratio cos."""
    ray = (xy - centre) / focal_xy
    return np.sqrt(1.0 + ray[..., 0] * ray[..., 0] + ray[..., 1] * ray[..., 1])  # (~3x faster than a sum)


def _blob_at_depth(blob: np.ndarray, depth: np.ndarray, power: float) -> np.ndarray:
    """(..., 4) a track's blob record (..., 7) (:attr:`_Tracks.blob`) seen at ``depth`` (...) m: its area scaled as
    1 / depth^2 (the image of a sphere), its roundness, its flux scaled as 1 / depth^``power`` and the flux's
    deviation. NaN where there is none."""
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = blob[..., 2] / depth
        return np.stack([blob[..., 0] * ratio * ratio, blob[..., 1], blob[..., 3] * ratio**power, blob[..., 4]],
                        axis=-1)


def _gather(values: np.ndarray, asg: np.ndarray) -> np.ndarray:
    """Per-detection ``values`` (C, N, ...) picked by ``asg`` (K, C) -> (K, C, ...). Where -1: False for booleans,
    NaN for (C, N, 2) positions; other arrays get detection 0's value there (the callers mask those views)."""
    C, N = values.shape[:2]
    if N == 0:
        fill = np.nan if values.dtype.kind == "f" else 0
        return np.full(asg.shape + values.shape[2:], fill, dtype=values.dtype)
    flat = np.maximum(asg, 0)
    flat += np.arange(0, C * N, N)  # (row of camera c in the (C N, ...) view)
    got = values.reshape((C * N,) + values.shape[2:]).take(flat, axis=0)
    if values.dtype == bool:
        return got & (asg >= 0)
    if values.ndim == 3:
        got[asg < 0] = np.nan
    return got


def _clean_views(merged: np.ndarray, det: np.ndarray) -> np.ndarray:
    """(K,) cameras whose detection ``det`` (K, C), -1: none, is not flagged in ``merged`` (C, N)."""
    return ((det >= 0) & ~_gather(merged, det)).sum(axis=1)


def _point_std(cov: np.ndarray) -> np.ndarray:
    """(K,) RMS std, m, of points with covariances ``cov`` (K, 3, 3) m^2."""
    return np.sqrt((cov[:, 0, 0] + cov[:, 1, 1] + cov[:, 2, 2]) / 3.0)  # (np.trace's sum, without its overhead)


def _taken(asg: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(C, N) bool: detections used by some track in ``asg`` (K, C)."""
    taken = np.zeros(shape, dtype=bool)
    kk, cc = np.nonzero(asg >= 0)
    taken[cc, asg[kk, cc]] = True
    return taken
