"""Foxglove-ready MCAP logs: written live while a take is processed, read back for re-runs.

Topics (protobuf, Foxglove schemas; ``camN`` is each camera's name):

=======================  ==========================  =================================================
topic                    schema                      content
=======================  ==========================  =================================================
``/tf``                  foxglove.FrameTransform     world -> camera pose, once per camera at time 0
``/camN/calibration``    foxglove.CameraCalibration  intrinsics, once at time 0
``/camN/centroids``      foxglove.PointCloud         every 2D blob with all its fields, float64:
                                                     x, y, area, roundness, cov_xx, cov_xy, cov_yx,
                                                     cov_yy, merged (0/1), flux, cut (0/1) -- what
                                                     a re-run reads (logs without flux: NaN; without
                                                     cut: none cut)
``/camN/detections``     foxglove.ImageAnnotations   centroids as points, marker identities as text
                                                     at their reprojection in the cameras that saw them
``/markers``             foxglove.SceneUpdate        one sphere per identity, colour by identity,
                                                     metadata residual_mm and cameras (count)
``/markers/cloud``       foxglove.PointCloud         x, y, z (m), residual_mm (float64), id,
                                                     camera_mask (uint32) -- what trajectory readers read
=======================  ==========================  =================================================

Per-frame messages have log_time = publish_time = the frame's capture time (frame / fps, ns)
and MCAP sequence = frame index. Metadata records: ``take`` (the caller's take facts),
``mocap.log`` (fps, camera names) and, written on close, ``mocap.markers`` (identity -> label)
and ``mocap.frames``. The calibration file is the attachment ``calibration.toml``.

A log is written to ``<path>.partial`` in zstd chunks and renamed to ``<path>`` on a clean
close, so an existing file is never replaced by a half-written one; after a crash the
``.partial`` file is readable up to its last complete chunk.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.ImageAnnotations_pb2 import ImageAnnotations
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from mcap.reader import make_reader
from mcap.records import Attachment, Channel, Message, Metadata
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer
from mcap_protobuf.schema import register_schema

from mocap.atomic import check_output_path
from mocap.camera import Rig, parse_rig, rig_to_toml
from mocap.detections import Detections
from mocap.errors import MocapError
from mocap.export import foxglove as fx
from mocap.export.common import identity_colors
from mocap.trajectories import Trajectories

__all__ = ["McapLogger", "McapTake", "write_mcap", "read_mcap_take", "read_mcap_trajectories", "default_label"]

log = logging.getLogger(__name__)

CALIBRATION_ATTACHMENT = "calibration.toml"
CENTROID_LAYOUT = [(name, "<f8") for name in
                   ("x", "y", "area", "roundness", "cov_xx", "cov_xy", "cov_yx", "cov_yy", "merged", "flux", "cut")]
MARKER_LAYOUT = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("residual_mm", "<f8"), ("id", "<u4"),
                 ("camera_mask", "<u4")]
_TEXT_OFFSET_PX = np.array([8.0, -8.0])
_PALETTE = identity_colors(np.arange(256))


def default_label(identity: int) -> str:
    """Label of a marker identity when the caller gives none: ``M001`` for identity 0, as the tracker names it
    (:meth:`mocap.tracker.Tracker.finish`), so the live log and an unrepaired C3D agree."""
    return f"M{identity + 1:03d}"


def _frame_time_ns(frame_index: int, fps: float) -> int:
    return round(frame_index * 1e9 / fps)


def _topic(camera: str, what: str) -> str:
    return f"/{camera}/{what}"


# ====================================================================== writing
class McapLogger:
    """Logs a take to MCAP frame by frame (see the module docstring for topics).

    Use as a context manager, or call :meth:`close` when the take is done (and :meth:`abort` on
    failure, which keeps the readable ``.partial`` file and leaves ``path`` alone).

    Args:
        path: output ``.mcap``; its folder must exist.
        rig: the calibrated cameras (None: trajectories only, no camera topics).
        fps: frame rate, Hz; frame k is logged at k / fps seconds.
        calibration_toml: calibration text, stored as the attachment ``calibration.toml``.
        metadata: take facts, stored as the MCAP metadata record ``take`` (values as strings).
        labels: identity k is called ``labels[k]``; other identities :func:`default_label`.
        chunk_size: bytes of messages per zstd chunk (what a crash can lose at most).
    """

    def __init__(self, path: str | os.PathLike, rig: Rig | None, fps: float, calibration_toml: str = "",
                 metadata: dict[str, Any] | None = None, labels: Sequence[str] | None = None,
                 chunk_size: int = 1024 * 1024) -> None:
        self.path = check_output_path(path)
        if not np.isfinite(fps) or fps <= 0:
            raise MocapError(f"{self.path}: frame rate must be a positive number, got {fps}")
        self.partial_path = self.path.with_name(self.path.name + ".partial")
        self.rig, self.fps = rig, float(fps)
        self._labels = list(labels or [])
        self._label_bytes: dict[int, bytes] = {}
        self._label_width = 0
        self._frames = (None, None, 0)  # first, last, count
        self._file: IO[bytes] | None = open(self.partial_path, "wb")  # noqa: SIM115 - closed in close()/abort()
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="mocap")
        self._channels: dict[str, int] = {}
        cameras = rig.names if rig is not None else []
        self._writer.add_metadata("take", {str(k): str(v) for k, v in (metadata or {}).items()})
        self._writer.add_metadata("mocap.log", {"fps": repr(self.fps), "cameras": json.dumps(cameras)})
        if calibration_toml:
            self._writer.add_attachment(0, 0, CALIBRATION_ATTACHMENT, "application/toml", calibration_toml.encode())
        self._centroids = [fx.PointCloudLayout(name, CENTROID_LAYOUT) for name in cameras]
        self._cloud = fx.PointCloudLayout(fx.WORLD_FRAME, MARKER_LAYOUT)
        for cam in rig or []:
            self._write("/tf", FrameTransform, fx.frame_transform(cam, 0).SerializeToString(), 0, 0)
            self._write(_topic(cam.name, "calibration"), CameraCalibration,
                        fx.camera_calibration(cam, 0).SerializeToString(), 0, 0)

    # ------------------------------------------------------------------ plumbing
    def _write(self, topic: str, schema: type, payload: bytes, t_ns: int, sequence: int) -> None:
        channel = self._channels.get(topic)
        if channel is None:
            schema_id = register_schema(self._writer, schema)
            channel = self._writer.register_channel(topic=topic, message_encoding="protobuf", schema_id=schema_id)
            self._channels[topic] = channel
        self._writer.add_message(channel_id=channel, log_time=t_ns, data=payload, publish_time=t_ns,
                                 sequence=sequence)

    def _label_rows(self, ids: np.ndarray) -> np.ndarray:
        """(K, w) uint8 space-padded labels of ``ids`` (one width for the whole log, so entity ids are stable)."""
        for identity in ids.tolist():
            if identity not in self._label_bytes:
                label = self._labels[identity] if 0 <= identity < len(self._labels) else default_label(identity)
                self._label_bytes[identity] = label.encode("utf-8")
                self._label_width = max(self._label_width, len(self._label_bytes[identity]),
                                        max((len(s.encode()) for s in self._labels), default=0))
        width = self._label_width
        joined = b"".join(self._label_bytes[i].ljust(width) for i in ids.tolist())
        return np.frombuffer(joined, dtype=np.uint8).reshape(len(ids), width)

    # ------------------------------------------------------------------ per frame
    def log_frame(self, frame_index: int, detections: Sequence[Detections], ids: np.ndarray, positions: np.ndarray,
                  residuals_mm: np.ndarray, camera_masks: np.ndarray) -> None:
        """Log one frame.

        Args:
            frame_index: frame number in the take (sets the log time, frame_index / fps).
            detections: one :class:`Detections` per camera, in rig order (empty list without a rig).
            ids: (K,) integer marker identities reconstructed in this frame.
            positions: (K, 3) metres, world frame (rows with NaN are skipped).
            residuals_mm: (K,) triangulation residuals, mm.
            camera_masks: (K,) uint32, bit c set when camera c saw the marker.
        """
        if self._file is None:
            raise RuntimeError("McapLogger.log_frame after close")
        n_cams = len(self._centroids)
        if len(detections) != n_cams:
            raise ValueError(f"log_frame: {len(detections)} detection sets for {n_cams} cameras")
        t = _frame_time_ns(frame_index, self.fps)
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        keep = np.isfinite(positions).all(axis=1)
        ids, positions = ids[keep], positions[keep]
        residuals = np.asarray(residuals_mm, dtype=np.float64).reshape(-1)[keep]
        masks = np.asarray(camera_masks, dtype=np.uint32).reshape(-1)[keep]
        labels = self._label_rows(ids)
        colors = _PALETTE[ids % len(_PALETTE)]
        for c, (layout, det) in enumerate(zip(self._centroids, detections, strict=True)):
            name = layout.frame_id
            table = np.column_stack([det.xy, det.area, det.roundness, det.cov.reshape(-1, 4), det.merged, det.flux,
                                     det.cut])
            self._write(_topic(name, "centroids"), PointCloud, layout.encode(t, table.tobytes()), t, frame_index)
            seen = (masks >> np.uint32(c)) & 1 == 1
            uv = self.rig[c].project(positions[seen]) + _TEXT_OFFSET_PX if seen.any() else np.zeros((0, 2))
            self._write(_topic(name, "detections"), ImageAnnotations,
                        fx.image_annotations(t, det.xy, uv, labels[seen], colors[seen]), t, frame_index)
        residual_text = fx.padded_strings([f"{r:.2f}" for r in residuals.tolist()], "right")
        cameras_text = fx.padded_strings([str(n) for n in np.bitwise_count(masks).tolist()], "right")
        self._write("/markers", SceneUpdate,
                    fx.scene_update(t, labels, positions, colors, residual_text, cameras_text), t, frame_index)
        cloud = np.empty(len(ids), dtype=self._cloud.dtype)
        cloud["x"], cloud["y"], cloud["z"] = positions.T
        cloud["residual_mm"], cloud["id"], cloud["camera_mask"] = residuals, ids, masks
        self._write("/markers/cloud", PointCloud, self._cloud.encode(t, cloud.tobytes()), t, frame_index)
        first, _, count = self._frames
        self._frames = (frame_index if first is None else first, frame_index, count + 1)

    # ------------------------------------------------------------------ ending
    def _finish(self) -> None:
        ids = sorted(set(self._label_bytes) | set(range(len(self._labels))))
        labels = [self._label_bytes[i].decode() if i in self._label_bytes else self._labels[i] for i in ids]
        self._writer.add_metadata("mocap.markers", {"ids": json.dumps(ids), "labels": json.dumps(labels)})
        first, last, count = self._frames
        self._writer.add_metadata("mocap.frames", {"first": str(first if first is not None else 0),
                                                   "last": str(last if last is not None else -1),
                                                   "count": str(count)})
        self._writer.finish()
        self._file.close()
        self._file = None

    def close(self) -> None:
        """Finish the file (summary, index) and move it onto ``path``."""
        if self._file is not None:
            self._finish()
            os.replace(self.partial_path, self.path)

    def abort(self) -> None:
        """Finish the file but keep it as ``<path>.partial``: ``path`` is left as it was."""
        if self._file is not None:
            self._finish()
            log.warning("%s: the run stopped early; the log so far is in %s", self.path, self.partial_path)

    def __enter__(self) -> McapLogger:
        return self

    def __exit__(self, exc_type: Any, exc: Any, tb: Any) -> None:
        if exc_type is None:
            self.close()
        else:
            self.abort()


def write_mcap(traj: Trajectories, path: str | os.PathLike, rig: Rig | None = None) -> None:
    """Write trajectories as a Foxglove-ready MCAP (``/markers``, ``/markers/cloud``; cameras if ``rig``).

    Marker k of ``traj`` is identity k. The file appears at ``path`` only when complete.
    """
    meta = {**traj.metadata, "camera_names": json.dumps(traj.camera_names)}
    with McapLogger(path, rig, traj.fps, rig_to_toml(rig) if rig is not None else "", meta, traj.labels) as logger:
        no_dets = [Detections.empty()] * (len(rig) if rig is not None else 0)
        valid = traj.valid
        for f in range(traj.n_frames):
            ids = np.flatnonzero(valid[f])
            logger.log_frame(traj.first_frame + f, no_dets, ids, traj.positions[f, ids], traj.residuals[f, ids],
                             traj.camera_masks[f, ids])


# ====================================================================== reading
@dataclass
class _Scan:
    """What one pass over a log's records found."""

    attachments: dict[str, bytes] = field(default_factory=dict)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    topics: dict[int, str] = field(default_factory=dict)
    sequences: dict[str, tuple[int, int]] = field(default_factory=dict)  # topic -> (first, last)
    truncated: bool = False


def _open(path: Path) -> IO[bytes]:
    try:
        return open(path, "rb")  # noqa: SIM115 - the callers close it
    except FileNotFoundError:
        raise MocapError(f"{path}: MCAP file not found") from None
    except OSError as exc:
        raise MocapError(f"{path}: cannot open ({exc.strerror})") from None


def _records(path: Path, scan: _Scan) -> Iterator[Any]:
    """Every record of the log in file order (chunks opened); sets ``scan.truncated`` at an early end."""
    with _open(path) as f:
        try:
            for record in StreamReader(f).records:
                if isinstance(record, Channel):
                    scan.topics[record.id] = record.topic
                yield record
        except Exception as exc:  # noqa: BLE001 - mcap, struct or zstd errors at a cut-short or damaged tail
            if not scan.topics:
                raise MocapError(f"{path}: not a readable MCAP log ({type(exc).__name__} {exc}); the file is empty, "
                                 f"cut short before its first frame, or not an MCAP file") from None
            scan.truncated = True


def _scan(path: Path) -> _Scan:
    """Attachments and metadata from the summary of a complete log, else from a full pass."""
    scan = _Scan()
    try:
        with _open(path) as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            if summary is not None and summary.metadata_indexes:
                scan.attachments = {a.name: a.data for a in reader.iter_attachments()}
                scan.metadata = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
                scan.topics = {c.id: c.topic for c in summary.channels.values()}
                if "mocap.frames" in scan.metadata:
                    return scan
    except MocapError:
        raise
    except Exception:  # noqa: BLE001 - no usable summary (log cut short): fall back to a full pass
        scan = _Scan()
    for record in _records(path, scan):
        if isinstance(record, Attachment):
            scan.attachments[record.name] = record.data
        elif isinstance(record, Metadata):
            scan.metadata[record.name] = dict(record.metadata)
        elif isinstance(record, Message):
            topic = scan.topics.get(record.channel_id, "")
            lo, hi = scan.sequences.get(topic, (record.sequence, record.sequence))
            scan.sequences[topic] = (min(lo, record.sequence), max(hi, record.sequence))
    if scan.truncated:
        log.warning("%s: the log ends early (the run that wrote it did not finish); using what it holds", path)
    return scan


def _fps(path: Path, scan: _Scan) -> float:
    try:
        return float(scan.metadata["mocap.log"]["fps"])
    except (KeyError, ValueError):
        raise MocapError(f"{path}: no 'mocap.log' metadata with the frame rate; this MCAP was not written by "
                         f"mocap (or was cut before its first frame)") from None


@dataclass
class McapTake:
    """A take log opened for a re-run of the 3D stage from its logged 2D centroids.

    Attributes:
        path: the log.
        rig: cameras from the ``calibration.toml`` attachment.
        fps: frame rate, Hz.
        first_frame: first logged frame.
        n_frames: last logged frame + 1.
        metadata: the log's metadata records, by name.
        truncated: the log was cut short (its final frame may be incomplete and is then skipped).
    """

    path: Path
    rig: Rig
    fps: float
    first_frame: int
    n_frames: int
    metadata: dict[str, dict[str, str]]
    truncated: bool

    @property
    def camera_names(self) -> list[str]:
        return self.rig.names

    def centroids(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, list[Detections]]]:
        """Yield ``(frame_index, detections per camera in rig order)`` for logged frames in [start, stop).

        The blobs are bit-exact copies of what was logged (all fields, float64).
        """
        stop = self.n_frames if stop is None else stop
        topic_camera = {_topic(name, "centroids"): c for c, name in enumerate(self.rig.names)}
        scan = _Scan()
        frame, dets = -1, [None] * len(self.rig)
        for record in _records(self.path, scan):
            if not isinstance(record, Message):
                continue
            c = topic_camera.get(scan.topics.get(record.channel_id, ""))
            if c is None or not start <= record.sequence < stop:
                if c is not None and record.sequence >= stop:
                    break
                continue
            if record.sequence != frame:
                frame, dets = record.sequence, [None] * len(self.rig)
            dets[c] = _detections(fx.PointCloudLayout.decode(record.data))
            if all(d is not None for d in dets):
                yield frame, dets
                frame = -1
        if scan.truncated and frame >= 0:
            log.warning("%s: frame %d is incomplete at the end of the log and was skipped", self.path, frame)


def _detections(points: np.ndarray) -> Detections:
    have = points.dtype.names
    cols = [points[name] if name in have else np.full(len(points), np.nan) for name, _ in CENTROID_LAYOUT]
    return Detections(np.column_stack(cols[:2]), cols[2], cols[3], np.column_stack(cols[4:8]).reshape(-1, 2, 2),
                      cols[8] != 0, cols[9], cols[10] == 1)  # (logs without the cut flag: NaN, none cut)


def read_mcap_take(path: str | os.PathLike) -> McapTake:
    """Open a log written by :class:`McapLogger` for :meth:`McapTake.centroids` (also a cut-short ``.partial``).

    Raises:
        MocapError: not an MCAP file, no calibration attachment, or no frames.
    """
    path = Path(path)
    scan = _scan(path)
    fps = _fps(path, scan)
    if CALIBRATION_ATTACHMENT not in scan.attachments:
        raise MocapError(f"{path}: no '{CALIBRATION_ATTACHMENT}' attachment; this log cannot be re-run "
                         f"(it was written without cameras)")
    rig = parse_rig(scan.attachments[CALIBRATION_ATTACHMENT].decode("utf-8"), f"{path}:{CALIBRATION_ATTACHMENT}")
    frames = scan.metadata.get("mocap.frames")
    if frames is not None:
        first, last = int(frames["first"]), int(frames["last"])
    else:
        spans = [scan.sequences.get(_topic(n, "centroids"), (0, -1)) for n in rig.names]
        first, last = min(lo for lo, _ in spans), min(hi for _, hi in spans)
    if last < first:
        raise MocapError(f"{path}: the log holds no frames")
    return McapTake(path, rig, fps, first, last + 1, scan.metadata, scan.truncated)


def read_mcap_trajectories(path: str | os.PathLike) -> Trajectories:
    """Read the 3D markers of a log (``/markers/cloud``) into :class:`Trajectories`.

    Identities become markers in increasing id order, named by the ``mocap.markers`` metadata
    (else :func:`default_label`). Positions, residuals and camera masks are exact copies.
    """
    path = Path(path)
    scan = _scan(path)
    fps = _fps(path, scan)
    clouds: list[tuple[int, np.ndarray]] = []
    for record in _records(path, scan):
        if isinstance(record, Message) and scan.topics.get(record.channel_id) == "/markers/cloud":
            clouds.append((record.sequence, fx.PointCloudLayout.decode(record.data)))
    markers = scan.metadata.get("mocap.markers")
    if markers is not None:
        ids = np.asarray(json.loads(markers["ids"]), dtype=np.int64)
        labels = list(json.loads(markers["labels"]))
    else:
        ids = np.unique(np.concatenate([c["id"] for _, c in clouds])) if clouds else np.zeros(0, np.int64)
        labels = [default_label(int(i)) for i in ids]
    first = min(s for s, _ in clouds) if clouds else 0
    F = max(s for s, _ in clouds) - first + 1 if clouds else 0
    positions = np.full((F, len(ids), 3), np.nan)
    residuals = np.full((F, len(ids)), np.nan)
    masks = np.zeros((F, len(ids)), dtype=np.uint32)
    for seq, cloud in clouds:
        col = np.searchsorted(ids, cloud["id"])
        positions[seq - first, col] = np.column_stack([cloud["x"], cloud["y"], cloud["z"]])
        residuals[seq - first, col] = cloud["residual_mm"]
        masks[seq - first, col] = cloud["camera_mask"]
    take = scan.metadata.get("take", {})
    cameras = json.loads(scan.metadata.get("mocap.log", {}).get("cameras", "[]")) or json.loads(
        take.get("camera_names", "[]"))
    meta = {**{k: v for k, v in take.items() if k != "camera_names"}, "units": "m"}
    return Trajectories(labels, fps, positions, residuals, masks, cameras, first, meta)
