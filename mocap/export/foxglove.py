"""Foxglove protobuf messages built from numpy arrays.

Static messages (camera poses and calibrations, point-cloud layouts) are built with the
``foxglove_schemas_protobuf`` classes. The per-frame messages repeat one fixed-size
sub-message per point or marker, so they are packed with numpy straight into protobuf wire
format (every field written, doubles as fixed64), and the class-built constant parts are
concatenated in front: protobuf parsers merge concatenated encodings of one message. The
result decodes with the Foxglove classes (tested field by field), without building one Python
object per point.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import numpy as np
from foxglove_schemas_protobuf.CameraCalibration_pb2 import CameraCalibration
from foxglove_schemas_protobuf.Color_pb2 import Color
from foxglove_schemas_protobuf.FrameTransform_pb2 import FrameTransform
from foxglove_schemas_protobuf.PackedElementField_pb2 import PackedElementField
from foxglove_schemas_protobuf.PointCloud_pb2 import PointCloud
from foxglove_schemas_protobuf.PointsAnnotation_pb2 import PointsAnnotation
from scipy.spatial.transform import Rotation

from mocap.camera import Camera

__all__ = [
    "timestamp", "frame_transform", "camera_calibration", "PointCloudLayout",
    "scene_update", "image_annotations", "padded_strings", "WORLD_FRAME",
]

WORLD_FRAME = "world"
_FIXED64, _LEN, _VARINT = 1, 2, 0
_NUMPY_TYPES = {PackedElementField.FLOAT64: "<f8", PackedElementField.FLOAT32: "<f4",
                PackedElementField.UINT32: "<u4", PackedElementField.INT32: "<i4",
                PackedElementField.UINT16: "<u2", PackedElementField.INT16: "<i2",
                PackedElementField.UINT8: "u1", PackedElementField.INT8: "i1"}


# ------------------------------------------------------------------ wire format
@functools.lru_cache(maxsize=4096)
def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte, value = value & 0x7F, value >> 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


@functools.lru_cache(maxsize=256)
def _key(field: int, wire: int) -> bytes:
    return _varint(field << 3 | wire)


def _field(field: int, payload: bytes) -> bytes:
    """A length-delimited field (sub-message, string or bytes)."""
    return _key(field, _LEN) + _varint(len(payload)) + payload


def _doubles(*fields: int) -> list[bytes]:
    """The keys of consecutive double fields, to interleave with 8-byte values."""
    return [_key(f, _FIXED64) for f in fields]


def timestamp(field: int, t_ns: int) -> bytes:
    """A ``google.protobuf.Timestamp`` field of ``t_ns`` nanoseconds."""
    seconds, nanos = divmod(int(t_ns), 1_000_000_000)
    return _field(field, _key(1, _VARINT) + _varint(seconds) + _key(2, _VARINT) + _varint(nanos))


def _pack(n: int, parts: Sequence[bytes | np.ndarray]) -> np.ndarray:
    """(n, stride) uint8: ``n`` fixed-size records, each the concatenation of ``parts``.

    A ``bytes`` part is the same in every record; an (n,) array part is written as little-endian
    float64 per record; an (n, w) uint8 array part is copied as w raw bytes per record.
    """
    template = bytearray()
    columns = []
    for part in parts:
        if isinstance(part, bytes):
            template += part
        else:
            column = np.ascontiguousarray(part, dtype="<f8").view(np.uint8).reshape(n, 8) if part.ndim == 1 else part
            columns.append((len(template), column))
            template += bytes(column.shape[1])
    out = np.empty((n, len(template)), dtype=np.uint8)
    out[:] = np.frombuffer(template, dtype=np.uint8)
    for offset, column in columns:
        out[:, offset:offset + column.shape[1]] = column
    return out


def padded_strings(values: Sequence[str], align: str = "left") -> np.ndarray:
    """(n, w) uint8: UTF-8 strings padded with spaces to a common width (so records stay fixed-size)."""
    encoded = [v.encode("utf-8") for v in values]
    width = max((len(e) for e in encoded), default=0)
    padded = [e.ljust(width) if align == "left" else e.rjust(width) for e in encoded]
    return np.frombuffer(b"".join(padded), dtype=np.uint8).reshape(len(values), width)


def _string_field(field: int, strings: np.ndarray) -> list[bytes | np.ndarray]:
    """Parts of a fixed-width string field for :func:`_pack`, from (n, w) uint8."""
    return [_key(field, _LEN) + _varint(strings.shape[1]), strings]


def _color(field: int, rgba: np.ndarray) -> list[bytes | np.ndarray]:
    """Parts of a ``foxglove.Color`` field from (n, 4) floats."""
    keys = _doubles(1, 2, 3, 4)
    return [_key(field, _LEN) + _varint(36), keys[0], rgba[:, 0], keys[1], rgba[:, 1], keys[2], rgba[:, 2],
            keys[3], rgba[:, 3]]


# ------------------------------------------------------------------ static messages
def frame_transform(camera: Camera, t_ns: int) -> FrameTransform:
    """World -> camera transform for Foxglove: the camera frame's pose in the world (OpenCV optical axes)."""
    msg = FrameTransform(parent_frame_id=WORLD_FRAME, child_frame_id=camera.name)
    msg.timestamp.FromNanoseconds(int(t_ns))
    msg.translation.x, msg.translation.y, msg.translation.z = camera.center.tolist()
    q = Rotation.from_matrix(camera.R.T).as_quat()  # camera -> world rotation, (x, y, z, w)
    msg.rotation.x, msg.rotation.y, msg.rotation.z, msg.rotation.w = q.tolist()
    return msg


def camera_calibration(camera: Camera, t_ns: int) -> CameraCalibration:
    """Intrinsics in ROS/Foxglove form: plumb_bob (k1 k2 p1 p2 k3), rational_polynomial (8) or kannala_brandt."""
    dist = camera.distortions.tolist()
    if camera.fisheye:
        model = "kannala_brandt"
    elif len(dist) == 8:
        model = "rational_polynomial"
    else:
        model, dist = "plumb_bob", (dist + [0.0])[:5]
    K = camera.matrix
    msg = CameraCalibration(frame_id=camera.name, width=camera.size[0], height=camera.size[1],
                            distortion_model=model, D=dist, K=K.ravel().tolist(), R=np.eye(3).ravel().tolist(),
                            P=np.hstack([K, np.zeros((3, 1))]).ravel().tolist())
    msg.timestamp.FromNanoseconds(int(t_ns))
    return msg


class PointCloudLayout:
    """A ``foxglove.PointCloud`` layout with named, typed fields; encodes and decodes rows.

    Args:
        frame_id: coordinate frame of the points.
        fields: (name, numpy dtype string) pairs, in record order; x, y, z are what Foxglove draws.
    """

    def __init__(self, frame_id: str, fields: Sequence[tuple[str, str]]) -> None:
        self.frame_id = frame_id
        self.dtype = np.dtype([(name, np.dtype(kind).newbyteorder("<")) for name, kind in fields])
        types = {np.dtype(v): k for k, v in _NUMPY_TYPES.items()}
        header = PointCloud(frame_id=frame_id, point_stride=self.dtype.itemsize)
        header.pose.orientation.w = 1.0
        for name in self.dtype.names:
            header.fields.add(name=name, offset=self.dtype.fields[name][1], type=types[self.dtype[name]])
        self._header = header.SerializeToString()

    def encode(self, t_ns: int, data: bytes) -> bytes:
        """Serialized PointCloud at time ``t_ns`` of ``data``, the points packed as :attr:`dtype` records."""
        if len(data) % self.dtype.itemsize:
            raise ValueError(f"{len(data)} bytes of point data is not whole {self.dtype.itemsize}-byte points")
        return self._header + timestamp(1, t_ns) + _field(6, data)

    @staticmethod
    def decode(payload: bytes) -> np.ndarray:
        """A serialized PointCloud -> structured array of its points (a copy, writable)."""
        msg = PointCloud.FromString(payload)
        dtype = np.dtype({"names": [f.name for f in msg.fields],
                          "formats": [_NUMPY_TYPES[f.type] for f in msg.fields],
                          "offsets": [f.offset for f in msg.fields], "itemsize": msg.point_stride})
        return np.frombuffer(msg.data, dtype=dtype).copy()


# ------------------------------------------------------------------ per-frame messages
_SPHERE_SIZE_M = 0.014
_WORLD = _field(2, WORLD_FRAME.encode())


def scene_update(t_ns: int, labels: np.ndarray, positions: np.ndarray, colors: np.ndarray,
                 residual_text: np.ndarray, cameras_text: np.ndarray) -> bytes:
    """A ``foxglove.SceneUpdate``: delete all entities, then one sphere entity per marker.

    Args:
        labels: (K, w) uint8 padded entity ids (:func:`padded_strings`).
        positions: (K, 3) metres, world frame.
        colors: (K, 4) RGBA.
        residual_text, cameras_text: (K, w) uint8 padded metadata values ("residual_mm", "cameras").
    """
    stamp = timestamp(1, t_ns)
    deletion = _field(1, stamp + _key(2, _VARINT) + _varint(1))  # type ALL
    K = len(positions)
    if K == 0:
        return deletion
    d = _doubles(1, 2, 3, 4)
    unit = np.ones(K)
    size = np.full(K, _SPHERE_SIZE_M)
    sphere = [
        _key(9, _LEN) + _varint(109),
        _key(1, _LEN) + _varint(40),  # pose
        _key(1, _LEN) + _varint(27), d[0], positions[:, 0], d[1], positions[:, 1], d[2], positions[:, 2],
        _key(2, _LEN) + _varint(9), d[3], unit,  # orientation w = 1
        _key(2, _LEN) + _varint(27), d[0], size, d[1], size, d[2], size,
        *_color(3, colors),
    ]
    body = [stamp + _WORLD, *_string_field(3, labels),
            *_key_value(6, "residual_mm", residual_text), *_key_value(6, "cameras", cameras_text), *sphere]
    records = _pack(K, body)
    prefix = _key(2, _LEN) + _varint(records.shape[1])
    return deletion + _pack(K, [prefix, records]).tobytes()


def _key_value(field: int, key: str, values: np.ndarray) -> list[bytes | np.ndarray]:
    """Parts of a ``foxglove.KeyValuePair`` field with a constant key and (n, w) padded values."""
    key_bytes = _field(1, key.encode())
    value_parts = _string_field(2, values)
    inner = len(key_bytes) + len(value_parts[0]) + values.shape[1]
    return [_key(field, _LEN) + _varint(inner) + key_bytes, *value_parts]


_POINTS_STYLE = PointsAnnotation(type=PointsAnnotation.POINTS, thickness=6.0,
                                 outline_color=Color(r=0.2, g=1.0, b=0.3, a=1.0),
                                 fill_color=Color(r=0.2, g=1.0, b=0.3, a=1.0)).SerializeToString()
_TEXT_FONT_PX = 14.0


def image_annotations(t_ns: int, centroids: np.ndarray, text_xy: np.ndarray, texts: np.ndarray,
                      text_colors: np.ndarray) -> bytes:
    """A ``foxglove.ImageAnnotations``: 2D centroids as one POINTS annotation, identities as texts.

    Args:
        centroids: (N, 2) pixels.
        text_xy: (K, 2) pixel positions of the identity labels.
        texts: (K, w) uint8 padded label strings.
        text_colors: (K, 4) RGBA.
    """
    stamp = timestamp(1, t_ns)
    d = _doubles(1, 2)
    points = _pack(len(centroids), [_key(3, _LEN) + _varint(18), d[0], centroids[:, 0], d[1], centroids[:, 1]])
    out = [timestamp(5, t_ns), _field(2, stamp + _POINTS_STYLE + points.tobytes())]
    K = len(text_xy)
    if K:
        size = np.full(K, _TEXT_FONT_PX)
        body = _pack(K, [stamp, _key(2, _LEN) + _varint(18), d[0], text_xy[:, 0], d[1], text_xy[:, 1],
                         *_string_field(3, texts), _key(4, _FIXED64), size, *_color(5, text_colors)])
        out.append(_pack(K, [_key(3, _LEN) + _varint(body.shape[1]), body]).tobytes())
    return b"".join(out)

