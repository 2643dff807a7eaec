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
   point's reprojection, and the point is recomputed.
5. **Update** the filters and the running errors with the measurements.
6. **New markers** from the detections no track used: all-pairs epipolar matching, triangulation,
   multi-view support. A point near a track that missed this frame re-acquires it; a point inside
   the (widening) search radius of a lost identity starts a tentative track that inherits that
   identity when confirmed; any other starts a tentative track that gets a new identity after
   ``confirm_frames`` consecutive frames. Lost identities are kept ``keep_lost_s`` seconds.

The output position of a marker in a frame is its multi-view triangulation (not the filter state);
its residual is the RMS reprojection error back-projected to the marker's depth (px * depth / f).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from mocap.camera import Rig
from mocap.detections import Detections
from mocap.ekf import RunningError, ca_process_noise, ca_transition, init_state, position_jacobian, predict, update
from mocap.errors import MocapError
from mocap.fusion import new_points, reidentify, repick, robust_triangulate
from mocap.geometry import reprojection_jacobians
from mocap.pairs import camera_pairs
from mocap.stereo import assign, epipolar_consistency, gate
from mocap.trajectories import Trajectories

__all__ = ["TrackerConfig", "FrameResult", "Tracker"]


@dataclass
class TrackerConfig:
    """Every setting of the tracker (distances in metres or ideal pixels, times in frames or seconds).

    Attributes:
        confirm_frames: consecutive frames a new marker must be seen before it gets an identity.
        coast_frames: frames after its last measurement a track still searches its own gates.
        keep_lost_s: seconds a lost identity waits for re-identification before it is retired.
        jerk_std_3d: process noise of the 3D filters, std of the jerk, m/s^3.
        jerk_std_2d: process noise of the 2D image filters, std of the jerk, px/s^3.
        error_alpha: smoothing factor of the running prediction errors (paper 004).
        gate_scale: search radius = gate_scale x the running prediction error (+ floor).
        gate_floor_m: smallest 3D search radius, m.
        gate_floor_px: smallest 2D search radius, pixels.
        gate_max_px: largest 2D search radius, pixels.
        new_track_speed: speed assumed for the first prediction of a new track, m/s (its first gate).
        reid_max_m: largest re-identification radius of a lost identity, m.
        epipolar_px: largest symmetric epipolar distance of two views of one marker, pixels.
        outlier_sigma: a camera is rejected from a point beyond this many centroid stds ...
        outlier_min_px: ... and beyond this many pixels.
        repick_px: a free detection this close to a point's reprojection joins the point, pixels.
        support_px: a free detection this close to a new point's reprojection supports it, pixels.
        new_min_views: cameras that must support a new marker (fewer when fewer cameras frame it).
        min_separation_m: a new point closer than this to a measured track is that track's, not new.
        merged_variance_scale: centroid variance multiplier of blobs flagged as merged markers.
    """

    confirm_frames: int = 4
    coast_frames: int = 3
    keep_lost_s: float = 10.0
    jerk_std_3d: float = 200.0
    jerk_std_2d: float = 50000.0
    error_alpha: float = 0.3
    gate_scale: float = 3.0
    gate_floor_m: float = 0.01
    gate_floor_px: float = 3.0
    gate_max_px: float = 200.0
    new_track_speed: float = 3.0
    reid_max_m: float = 0.5
    epipolar_px: float = 2.0
    outlier_sigma: float = 6.0
    outlier_min_px: float = 0.6
    repick_px: float = 1.5
    support_px: float = 2.0
    new_min_views: int = 3
    min_separation_m: float = 0.012
    merged_variance_scale: float = 100.0

    def __post_init__(self) -> None:
        for name in ("confirm_frames", "new_min_views"):
            if getattr(self, name) < 1:
                raise MocapError(f"tracker setting {name} = {getattr(self, name)} must be >= 1")
        for name in ("epipolar_px", "gate_scale", "gate_floor_m", "gate_floor_px", "gate_max_px", "repick_px",
                     "support_px", "outlier_min_px", "reid_max_m"):
            if not getattr(self, name) > 0:
                raise MocapError(f"tracker setting {name} = {getattr(self, name)} must be > 0")
        if not 0 < self.error_alpha <= 1:
            raise MocapError(f"tracker setting error_alpha = {self.error_alpha} must be in (0, 1]")


@dataclass
class FrameResult:
    """The confirmed markers measured in one frame.

    Attributes:
        frame_index: the frame.
        ids: (K,) identity index (column of the output; label ``M{id+1:03d}``).
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


class _Records:
    """Growable columns of per-frame measurements (amortised doubling; no per-frame objects)."""

    def __init__(self) -> None:
        self.n = 0
        self.frame = np.zeros(1024, dtype=np.int64)
        self.uid = np.zeros(1024, dtype=np.int64)
        self.pos = np.zeros((1024, 3))
        self.res = np.zeros(1024, dtype=np.float32)
        self.mask = np.zeros(1024, dtype=np.uint32)

    def append(self, frame: int, uid: np.ndarray, pos: np.ndarray, res: np.ndarray, mask: np.ndarray) -> None:
        k = len(uid)
        if self.n + k > len(self.frame):
            size = max(2 * len(self.frame), self.n + k)
            for name in ("frame", "uid", "pos", "res", "mask"):
                old = getattr(self, name)
                new = np.zeros((size,) + old.shape[1:], dtype=old.dtype)
                new[: self.n] = old[: self.n]
                setattr(self, name, new)
        s = slice(self.n, self.n + k)
        self.frame[s] = frame
        self.uid[s] = uid
        self.pos[s] = pos
        self.res[s] = res
        self.mask[s] = mask
        self.n += k


# Prior std of a (re)started image filter's velocity (px/s) and acceleration (px/s^2); the gates come from
# the running errors, so these only set the first gains.
_IMAGE_VELOCITY_STD = 1e3
_IMAGE_ACCEL_STD = 1e5

# Per-track arrays, first axis = track; kept in step by _keep() when tracks are removed.
_TRACK_FIELDS = ("uid", "ident", "cand", "hits", "since", "x3", "P3", "e3", "last_X", "last_v",
                 "x2", "P2", "lock2", "e2", "last_uv", "last_uvv")


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
        self._cfg = config or TrackerConfig()
        cfg = self._cfg
        self._dt = dt = 1.0 / self._fps
        C = len(rig)
        self._C = C
        self._P = rig.projection_matrices()
        self._pairs = camera_pairs(rig)
        self._focal = np.array([0.5 * (c.matrix[0, 0] + c.matrix[1, 1]) for c in rig.cameras])
        self._sizes = np.array([c.size for c in rig.cameras], dtype=float)
        self._F3, self._Q3 = ca_transition(dt, 3), ca_process_noise(dt, 3, cfg.jerk_std_3d)
        self._F2, self._Q2 = ca_transition(dt, 2), ca_process_noise(dt, 2, cfg.jerk_std_2d)
        self._H3, self._H2 = position_jacobian(3), position_jacobian(2)
        self._running = RunningError(cfg.error_alpha, cfg.gate_scale)
        self._keep_lost = max(1, int(round(cfg.keep_lost_s * self._fps)))
        # Track state (K live tracks).
        self.uid = np.zeros(0, dtype=np.int64)  # unique per track start, keys the records
        self.ident = np.zeros(0, dtype=np.intp)  # identity, -1 while tentative
        self.cand = np.zeros(0, dtype=np.intp)  # lost identity a tentative track may inherit, -1: none
        self.hits = np.zeros(0, dtype=np.intp)  # consecutive measured frames
        self.since = np.zeros(0, dtype=np.intp)  # frames since the last measurement (0: this frame)
        self.x3 = np.zeros((0, 9))
        self.P3 = np.zeros((0, 9, 9))
        self.e3 = np.zeros((0, 3))  # running errors: position m, velocity m/s, acceleration m/s^2
        self.last_X = np.zeros((0, 3))
        self.last_v = np.zeros((0, 3))  # last measured velocity (finite differences), NaN: unknown
        self.x2 = np.zeros((0, C, 6))
        self.P2 = np.zeros((0, C, 6, 6))
        self.lock2 = np.zeros((0, C), dtype=bool)  # image filter found the marker in the previous frame
        self.e2 = np.zeros((0, C, 3))  # running image errors: px, px/s, px/s^2
        self.last_uv = np.zeros((0, C, 2))
        self.last_uvv = np.zeros((0, C, 2))
        self._next_uid = 0
        self._uid_ident = np.full(256, -1, dtype=np.intp)
        self._n_ident = 0
        self._records = _Records()
        self._first: int | None = None
        self._last = -1

    # ------------------------------------------------------------------ public API
    def step(self, frame_index: int, detections: list[Detections]) -> FrameResult:
        """Track one frame: ``detections`` holds one :class:`Detections` per camera, rig order."""
        if len(detections) != self._C:
            raise MocapError(f"frame {frame_index}: {len(detections)} detection sets for {self._C} cameras")
        if self._first is None:
            self._first = frame_index
        self._last = max(self._last, frame_index)
        cfg, C = self._cfg, self._C
        D, S, valid, merged, counts = self._prepare(detections)
        self.since += 1
        self._predict()
        K = len(self.uid)
        asg = np.full((K, C), -1, dtype=np.intp)
        play = (self.since - 1 <= cfg.coast_frames) & ((self.ident >= 0) | (self.since == 1))
        if K and D.shape[1]:
            pred, radius = self._search_regions()
            q = gate(pred, radius, D)
            conf = np.flatnonzero(play & (self.ident >= 0))
            tent = np.flatnonzero(play & (self.ident < 0))
            asg[conf] = assign(q[conf], valid)
            if tent.size:
                taken = np.zeros_like(valid)
                taken[np.nonzero(asg[conf] >= 0)[1], asg[conf][asg[conf] >= 0]] = True
                asg[tent] = assign(q[tent], valid & ~taken)
        measured = self._measure(asg, D, S, valid, merged)
        self._update_filters(measured)
        taken = np.zeros_like(valid)
        kk, cc = np.nonzero(asg >= 0)
        taken[cc, asg[kk, cc]] = True
        self._new_markers(D, S, valid & ~taken, measured)
        self._lifecycle()
        return self._record(frame_index, counts)

    def predicted_rois(self) -> list[np.ndarray]:
        """Per camera (K, 4) int ``x0, y0, x1, y1`` search windows (distorted pixels) for the next frame."""
        cfg = self._cfg
        live = (self.since <= cfg.coast_frames) & ((self.ident >= 0) | (self.since == 0))
        out = []
        if not live.any():
            return [np.zeros((0, 4), dtype=np.int64) for _ in range(self._C)]
        x3, P3 = predict(self.x3[live], self.P3[live], self._F3, self._Q3)
        since = self.since[live] + 1
        r3 = self._running.radius(*self.e3[live].T, since, self._dt, cfg.gate_floor_m)
        r3 = np.minimum(r3, cfg.reid_max_m)
        for c, cam in enumerate(self._rig.cameras):
            uv = cam.project(x3[:, :3])
            depth = cam.world_to_camera(x3[:, :3])[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.clip(r3 * self._focal[c] / depth, cfg.gate_floor_px, cfg.gate_max_px) + 2.0
            ok = np.isfinite(uv).all(axis=1) & (depth > 0)
            box = np.concatenate([uv[ok] - r[ok, None], uv[ok] + r[ok, None]], axis=1)
            w, h = cam.size
            box = np.clip(np.round(box), 0, [w - 1, h - 1, w - 1, h - 1]).astype(np.int64)
            out.append(box)
        return out

    def finish(self) -> Trajectories:
        """All frames stepped so far as :class:`Trajectories` (one column per confirmed identity)."""
        first = self._first if self._first is not None else 0
        F = max(self._last - first + 1, 0)
        M = self._n_ident
        pos = np.full((F, M, 3), np.nan)
        res = np.full((F, M), np.nan)
        mask = np.zeros((F, M), dtype=np.uint32)
        rec = self._records
        n = rec.n
        ident = self._uid_ident[rec.uid[:n]]
        ok = ident >= 0
        rows = rec.frame[:n][ok] - first
        cols = ident[ok]
        pos[rows, cols] = rec.pos[:n][ok]
        res[rows, cols] = rec.res[:n][ok]
        mask[rows, cols] = rec.mask[:n][ok]
        labels = [f"M{i + 1:03d}" for i in range(M)]
        return Trajectories(labels, self._fps, pos, res, mask, self._rig.names, first,
                            {"tracker": "mocap.tracker", "identities": M})

    # ------------------------------------------------------------------ stages
    def _prepare(self, detections: list[Detections]
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, list[int]]:
        """Padded ideal-pixel detections ``D`` (C, N, 2), covariances (C, N, 2, 2), valid, merged (C, N)."""
        counts = [len(d) for d in detections]
        N = max(counts, default=0)
        C = self._C
        D = np.full((C, N, 2), np.nan)
        S = np.broadcast_to(np.eye(2), (C, N, 2, 2)).copy()
        merged = np.zeros((C, N), dtype=bool)
        for c, (cam, det) in enumerate(zip(self._rig.cameras, detections, strict=True)):
            n = counts[c]
            if n:
                D[c, :n] = cam.undistort(det.xy)
                S[c, :n] = det.cov
                merged[c, :n] = det.merged
        valid = np.isfinite(D).all(axis=2)
        S[merged] *= self._cfg.merged_variance_scale
        return D, S, valid, merged, counts

    def _predict(self) -> None:
        K, C = len(self.uid), self._C
        if K == 0:
            return
        self.x3, self.P3 = predict(self.x3, self.P3, self._F3, self._Q3)
        x2, P2 = predict(self.x2.reshape(K * C, 6), self.P2.reshape(K * C, 6, 6), self._F2, self._Q2)
        self.x2, self.P2 = x2.reshape(K, C, 6), P2.reshape(K, C, 6, 6)

    def _search_regions(self) -> tuple[np.ndarray, np.ndarray]:
        """Predicted ideal pixels (K, C, 2) and search radii (K, C), pixels."""
        cfg = self._cfg
        proj, _ = reprojection_jacobians(self._P, self.x3[:, :3])  # (C, K, 2)
        depth = np.einsum("cj,kj->kc", self._P[:, 2, :3], self.x3[:, :3]) + self._P[:, 2, 3]
        r3 = self._running.radius(*self.e3.T, self.since, self._dt, cfg.gate_floor_m)
        r3 = np.minimum(r3, cfg.reid_max_m)
        with np.errstate(divide="ignore", invalid="ignore"):
            r3px = r3[:, None] * self._focal[None, :] / depth
        r2 = self._running.radius(*np.moveaxis(self.e2, 2, 0), np.ones_like(self.lock2, dtype=np.intp),
                                  self._dt, cfg.gate_floor_px)
        pred = np.where(self.lock2[..., None], self.x2[..., :2], proj.swapaxes(0, 1))
        radius = np.clip(np.where(self.lock2, r2, r3px), cfg.gate_floor_px, cfg.gate_max_px)
        pred[depth <= 0] = np.nan
        return pred, radius

    def _measure(self, asg: np.ndarray, D: np.ndarray, S: np.ndarray, valid: np.ndarray, merged: np.ndarray
                 ) -> dict[str, np.ndarray]:
        """Epipolar pruning + robust fusion + re-pick; fills ``asg`` (K, C) in place with the cameras used."""
        cfg, C = self._cfg, self._C
        K = len(asg)
        cams = np.arange(C)[None, :]
        uv = np.where((asg >= 0)[..., None], D[cams, np.maximum(asg, 0)], np.nan)  # (K, C, 2)
        supported, tested = epipolar_consistency(self._pairs, uv, cfg.epipolar_px)
        asg[tested & ~supported] = -1
        uv[asg < 0] = np.nan
        cov = S[cams, np.maximum(asg, 0)]
        tri = robust_triangulate(self._P, uv.swapaxes(0, 1), cov.swapaxes(0, 1), self.x3[:, :3],
                                 cfg.outlier_sigma, cfg.outlier_min_px)
        asg[~tri.used] = -1
        if K and D.shape[1]:
            free = valid & ~merged
            kk, cc = np.nonzero(asg >= 0)
            free[cc, asg[kk, cc]] = False
            extra = repick(tri, D, free, cfg.repick_px)
            more = (extra >= 0).any(axis=1)
            if more.any():
                asg[more] = np.where(extra[more] >= 0, extra[more], asg[more])
                sub = asg[more]
                uv2 = np.where((sub >= 0)[..., None], D[cams, np.maximum(sub, 0)], np.nan)
                cov2 = S[cams, np.maximum(sub, 0)]
                t2 = robust_triangulate(self._P, uv2.swapaxes(0, 1), cov2.swapaxes(0, 1), tri.X[more],
                                        cfg.outlier_sigma, cfg.outlier_min_px)
                idx = np.flatnonzero(more)
                tri.X[idx], tri.cov[idx], tri.rms_px[idx], tri.used[idx] = t2.X, t2.cov, t2.rms_px, t2.used
                tri.depth[:, idx] = t2.depth
                asg[~tri.used] = -1
        ok = np.isfinite(tri.X).all(axis=1)
        with np.errstate(invalid="ignore"):
            scale = np.where(tri.used, tri.depth.T / self._focal[None, :], 0.0).sum(axis=1)
            scale = scale / np.maximum(tri.used.sum(axis=1), 1)
        bits = (tri.used.astype(np.uint32) << np.arange(C, dtype=np.uint32)[None, :]).sum(axis=1)
        return {"ok": ok, "X": tri.X, "cov": tri.cov, "res_mm": tri.rms_px * scale * 1000.0,
                "mask": bits.astype(np.uint32), "asg": asg, "D": D, "S": S}

    def _update_filters(self, m: dict[str, np.ndarray]) -> None:
        """Kalman and running-error updates of the measured tracks (3D and image filters)."""
        ok = m["ok"]
        self._last_measure = m
        if not ok.any():
            return
        dt, C = self._dt, self._C
        idx = np.flatnonzero(ok)
        X = m["X"][idx]
        R = m["cov"][idx] + np.eye(3) * 1e-12
        consecutive = self.since[idx] == 1
        x_prior = self.x3[idx]
        x_new, P_new, y, _ = update(x_prior, self.P3[idx], X, x_prior[:, :3], self._H3, R)
        # Running errors (paper 004) from consecutive frames only.
        v_meas = (X - self.last_X[idx]) / dt
        a_meas = (v_meas - self.last_v[idx]) / dt
        err = np.stack([np.linalg.norm(y, axis=1), np.linalg.norm(v_meas - x_prior[:, 3:6], axis=1),
                        np.linalg.norm(a_meas - x_prior[:, 6:9], axis=1)], axis=1)
        err = np.where(np.isfinite(err), err, self.e3[idx])
        e3 = np.where(consecutive[:, None], self._running.step(self.e3[idx], err), self.e3[idx])
        self.x3[idx], self.P3[idx], self.e3[idx] = x_new, P_new, e3
        self.last_v[idx] = np.where(consecutive[:, None], v_meas, np.nan)
        self.last_X[idx] = X
        self.hits[idx] = np.where(consecutive, self.hits[idx] + 1, 1)
        self.since[idx] = 0
        # Image filters of the cameras used.
        asg = m["asg"][idx]
        kk, cc = np.nonzero(asg >= 0)
        tk = idx[kk]
        z = m["D"][cc, asg[kk, cc]]
        Rz = m["S"][cc, asg[kk, cc]]
        locked = self.lock2[tk, cc]
        x2, P2 = self.x2[tk, cc], self.P2[tk, cc]
        x2n, P2n, y2, _ = update(x2, P2, z, x2[:, :2], self._H2, Rz)
        uvv = (z - self.last_uv[tk, cc]) / dt
        uva = (uvv - self.last_uvv[tk, cc]) / dt
        err2 = np.stack([np.linalg.norm(y2, axis=1), np.linalg.norm(uvv - x2[:, 2:4], axis=1),
                         np.linalg.norm(uva - x2[:, 4:6], axis=1)], axis=1)
        e2 = self.e2[tk, cc]
        e2 = np.where(locked[:, None] & np.isfinite(err2), self._running.step(e2, np.nan_to_num(err2)), e2)
        if (~locked).any():  # (re)start image filters from the projected 3D state
            nl = ~locked
            _, J = reprojection_jacobians(self._P, self.x3[tk[nl], :3])  # (C, n, 2, 3)
            Jn = J[cc[nl], np.arange(nl.sum())]
            vel = (Jn @ self.x3[tk[nl], 3:6, None])[..., 0]
            x0, P0 = init_state(z[nl], Rz[nl], vel, _IMAGE_VELOCITY_STD, _IMAGE_ACCEL_STD)
            x2n[nl], P2n[nl] = x0, P0
            e2[nl] = self._e2_from_3d(tk[nl], cc[nl])
        self.x2[tk, cc], self.P2[tk, cc], self.e2[tk, cc] = x2n, P2n, e2
        self.last_uvv[tk, cc] = np.where(locked[:, None], uvv, 0.0)
        self.last_uv[tk, cc] = z
        lock = np.zeros((len(self.uid), C), dtype=bool)
        lock[tk, cc] = True
        self.lock2 = lock

    def _e2_from_3d(self, tracks: np.ndarray, cams: np.ndarray) -> np.ndarray:
        """(n, 3) image running errors seeded from the tracks' 3D ones, scaled by f / depth."""
        X = self.x3[tracks, :3]
        depth = np.einsum("nj,nj->n", self._P[cams, 2, :3], X) + self._P[cams, 2, 3]
        return self.e3[tracks] * (self._focal[cams] / np.maximum(depth, 1e-6))[:, None]

    def _new_markers(self, D: np.ndarray, S: np.ndarray, free: np.ndarray, m: dict[str, np.ndarray]) -> None:
        """Points from the free detections: re-acquire missed tracks, or start tentative tracks."""
        cfg = self._cfg
        if free.sum() < 2 or len(self._pairs) == 0:
            return
        pts = new_points(self._P, self._pairs, D, S, free, self._sizes, cfg.epipolar_px, cfg.support_px,
                         cfg.new_min_views, cfg.outlier_sigma, cfg.outlier_min_px)
        if len(pts.X) == 0:
            return
        measured = self.since == 0
        if measured.any():  # duplicates of markers already measured this frame
            d = np.linalg.norm(pts.X[:, None] - self.x3[measured, None, :3].swapaxes(0, 1), axis=2)
            far = d.min(axis=1) > cfg.min_separation_m
            pts.X, pts.cov, pts.rms_px, pts.det = pts.X[far], pts.cov[far], pts.rms_px[far], pts.det[far]
        if len(pts.X) == 0:
            return
        # 1) tracks that missed this frame but are still searching: re-acquire directly.
        missing = np.flatnonzero((self.since >= 1) & (self.since - 1 <= cfg.coast_frames)
                                 & ((self.ident >= 0) | (self.since == 1)))
        r = self._radius3(missing)
        match = reidentify(pts.X, self.x3[missing, :3], r)
        got = match >= 0
        if got.any():
            self._accept(missing[match[got]], pts, np.flatnonzero(got), D, S)
        rest = np.flatnonzero(~got)
        if rest.size == 0:
            return
        # 2) lost identities: a tentative track that inherits the identity when confirmed.
        lost = np.flatnonzero((self.ident >= 0) & (self.since - 1 > cfg.coast_frames))
        cand = np.full(rest.size, -1, dtype=np.intp)
        if lost.size:
            match = reidentify(pts.X[rest], self.x3[lost, :3], self._radius3(lost))
            cand = np.where(match >= 0, self.ident[lost[np.maximum(match, 0)]], -1)
        self._start(pts.X[rest], pts.cov[rest], cand, pts.det[rest], pts.rms_px[rest])

    def _radius3(self, tracks: np.ndarray) -> np.ndarray:
        r = self._running.radius(*self.e3[tracks].T, self.since[tracks], self._dt, self._cfg.gate_floor_m)
        return np.minimum(r, self._cfg.reid_max_m)

    def _accept(self, tracks: np.ndarray, pts, rows: np.ndarray, D: np.ndarray, S: np.ndarray) -> None:
        """Measure ``tracks`` with new points ``rows`` (re-acquisition after a miss)."""
        C = self._C
        K = len(self.uid)
        asg = np.full((K, C), -1, dtype=np.intp)
        asg[tracks] = pts.det[rows]
        X = np.full((K, 3), np.nan)
        X[tracks] = pts.X[rows]
        cov = np.full((K, 3, 3), np.nan)
        cov[tracks] = pts.cov[rows]
        used = asg >= 0
        depth = np.einsum("cj,kj->kc", self._P[:, 2, :3], np.nan_to_num(X)) + self._P[:, 2, 3]
        scale = np.where(used, depth / self._focal[None, :], 0.0).sum(axis=1) / np.maximum(used.sum(axis=1), 1)
        res = np.full(K, np.nan)
        res[tracks] = pts.rms_px[rows] * scale[tracks] * 1000.0
        bits = (used.astype(np.uint32) << np.arange(C, dtype=np.uint32)[None, :]).sum(axis=1).astype(np.uint32)
        ok = np.zeros(K, dtype=bool)
        ok[tracks] = True
        self._merge_measurements({"ok": ok, "X": X, "cov": cov, "res_mm": res, "mask": bits, "asg": asg,
                                  "D": D, "S": S})

    def _merge_measurements(self, m: dict[str, np.ndarray]) -> None:
        """Apply extra measurements ``m`` (tracks re-acquired from new points) after the main ones."""
        prev = self._last_measure
        lock = self.lock2.copy()
        self._update_filters(m)
        self.lock2 |= lock
        ok = m["ok"]
        for key in ("X", "cov", "res_mm", "mask", "asg"):
            prev[key][ok] = m[key][ok]
        prev["ok"] = prev["ok"] | ok
        self._last_measure = prev

    def _start(self, X: np.ndarray, cov: np.ndarray, cand: np.ndarray, det: np.ndarray, rms: np.ndarray) -> None:
        """Append tentative tracks at points ``X`` (n, 3)."""
        n, C = len(X), self._C
        cfg = self._cfg
        x3, P3 = init_state(X, cov + np.eye(3) * 1e-12, velocity_std=cfg.new_track_speed,
                            accel_std=cfg.new_track_speed * self._fps)
        uid = np.arange(self._next_uid, self._next_uid + n)
        self._next_uid += n
        if self._next_uid > len(self._uid_ident):
            grow = np.full(max(2 * len(self._uid_ident), self._next_uid), -1, dtype=np.intp)
            grow[: len(self._uid_ident)] = self._uid_ident
            self._uid_ident = grow
        e3 = np.zeros((n, 3))
        e3[:, 0] = cfg.new_track_speed * self._dt / cfg.gate_scale
        new = {
            "uid": uid, "ident": np.full(n, -1, dtype=np.intp), "cand": cand, "hits": np.ones(n, dtype=np.intp),
            "since": np.zeros(n, dtype=np.intp), "x3": x3, "P3": P3, "e3": e3, "last_X": X,
            "last_v": np.full((n, 3), np.nan), "x2": np.zeros((n, C, 6)), "P2": np.broadcast_to(
                np.eye(6), (n, C, 6, 6)).copy(), "lock2": np.zeros((n, C), dtype=bool),
            "e2": np.zeros((n, C, 3)), "last_uv": np.zeros((n, C, 2)), "last_uvv": np.zeros((n, C, 2)),
        }
        for name in _TRACK_FIELDS:
            setattr(self, name, np.concatenate([getattr(self, name), new[name]]))
        prev = self._last_measure
        D, S = prev["D"], prev["S"]
        bits = ((det >= 0).astype(np.uint32) << np.arange(C, dtype=np.uint32)[None, :]).sum(axis=1)
        used = det >= 0
        depth = np.einsum("cj,kj->kc", self._P[:, 2, :3], X) + self._P[:, 2, 3]
        scale = np.where(used, depth / self._focal[None, :], 0.0).sum(axis=1) / np.maximum(used.sum(axis=1), 1)
        for key, value in (("ok", np.ones(n, dtype=bool)), ("X", X), ("cov", cov), ("res_mm", rms * scale * 1e3),
                           ("mask", bits.astype(np.uint32)), ("asg", det)):
            prev[key] = np.concatenate([prev[key], value])
        # Image filters start at the detections.
        k, c = np.nonzero(used)
        z = D[c, det[k, c]]
        x0, P0 = init_state(z, S[c, det[k, c]], velocity_std=_IMAGE_VELOCITY_STD, accel_std=_IMAGE_ACCEL_STD)
        base = len(self.uid) - n
        self.x2[base + k, c], self.P2[base + k, c] = x0, P0
        self.e2[base + k, c] = self._e2_from_3d(base + k, c)
        self.last_uv[base + k, c] = z
        self.lock2[base + k, c] = True

    def _lifecycle(self) -> None:
        """Confirm tentative tracks, drop failed tentative ones and retired identities."""
        cfg = self._cfg
        tentative = self.ident < 0
        confirm = np.flatnonzero(tentative & (self.since == 0) & (self.hits >= cfg.confirm_frames))
        retire = np.zeros(len(self.uid), dtype=bool)
        for k in confirm:  # rare: once per new identity
            c = self.cand[k]
            owner = np.flatnonzero(self.ident == c) if c >= 0 else np.zeros(0, dtype=np.intp)
            if c >= 0 and owner.size and self.since[owner[0]] - 1 > cfg.coast_frames:
                retire[owner] = True
                self.ident[k] = c
            else:
                self.ident[k] = self._n_ident
                self._n_ident += 1
            self._uid_ident[self.uid[k]] = self.ident[k]
        retire |= tentative & (self.since > 0) & (self.ident < 0)
        retire |= (self.ident >= 0) & (self.since > self._keep_lost)
        if retire.any():
            keep = ~retire
            for name in _TRACK_FIELDS:
                setattr(self, name, getattr(self, name)[keep])
            prev = self._last_measure
            for key in ("ok", "X", "cov", "res_mm", "mask", "asg"):
                prev[key] = prev[key][keep]

    def _record(self, frame_index: int, counts: list[int]) -> FrameResult:
        m = self._last_measure
        ok = m["ok"] & (self.since == 0)
        self._records.append(frame_index, self.uid[ok], m["X"][ok], m["res_mm"][ok], m["mask"][ok])
        conf = ok & (self.ident >= 0)
        ids = self.ident[conf]
        assignments = [np.full(n, -1, dtype=np.intp) for n in counts]
        asg = m["asg"][conf]
        for c in range(self._C):
            has = asg[:, c] >= 0
            assignments[c][asg[has, c]] = ids[has]
        return FrameResult(frame_index, ids.copy(), m["X"][conf].copy(), m["res_mm"][conf].copy(),
                           m["mask"][conf].copy(), assignments)
