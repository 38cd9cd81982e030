"""sensor_msgs/PointCloud2 <-> NumPy structured arrays, without sensor_msgs_py.

The readers take any object with the PointCloud2 attributes (``fields``, ``point_step``,
``row_step``, ``width``, ``height``, ``is_bigendian``, ``data``): rclpy messages and rosbags
messages alike. Every inconsistency raises :class:`ValueError` with a readable message, never a
NumPy error deep inside.

Correspondence clouds (topic ``correspondences``): fields ``u, v`` (measured, i.e. distorted,
pixel coordinates) and ``x, y, z`` (map frame, metres), float32 or float64; optional ``id``
(uint32) and ``score`` (float32/float64, higher is better). Keypoint clouds (topic
``keypoints``): ``u, v`` and ``id``.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

__all__ = [
    "CLOUD_REASONS",
    "DATATYPE_NAMES",
    "FLOAT32",
    "FLOAT64",
    "INT8",
    "INT16",
    "INT32",
    "UINT8",
    "UINT16",
    "UINT32",
    "CloudError",
    "Correspondences",
    "Keypoints",
    "array_to_cloud",
    "cloud_to_array",
    "correspondence_array",
    "correspondence_cloud",
    "dtype_to_fields",
    "fields_to_dtype",
    "keypoint_array",
    "keypoint_cloud",
    "pack_cloud",
    "read_correspondences",
    "read_keypoints",
]

# sensor_msgs/PointField datatypes
INT8, UINT8, INT16, UINT16, INT32, UINT32, FLOAT32, FLOAT64 = range(1, 9)
_DT_TO_NP = {
    INT8: "i1",
    UINT8: "u1",
    INT16: "i2",
    UINT16: "u2",
    INT32: "i4",
    UINT32: "u4",
    FLOAT32: "f4",
    FLOAT64: "f8",
}
_NP_TO_DT = {v: k for k, v in _DT_TO_NP.items()}
DATATYPE_NAMES = {
    INT8: "int8",
    UINT8: "uint8",
    INT16: "int16",
    UINT16: "uint16",
    INT32: "int32",
    UINT32: "uint32",
    FLOAT32: "float32",
    FLOAT64: "float64",
}

FLOAT_TYPES = (FLOAT32, FLOAT64)

#: every ``CloudError.reason``
CLOUD_REASONS = ("missing_fields", "wrong_field_type", "truncated", "bad_layout")
INDEX_TYPES = (UINT32, INT32, UINT16, UINT8)


class CloudError(ValueError):
    """A PointCloud2 that cannot be decoded. ``reason``: one of :data:`CLOUD_REASONS`."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def _dt_name(dt: int) -> str:
    return DATATYPE_NAMES.get(dt, f"unknown({dt})")


def fields_to_dtype(fields: Sequence[Any], point_step: int, is_bigendian: bool = False) -> np.dtype:
    """Structured dtype (itemsize ``point_step``) from a list of PointField-like objects
    (layouts seen before come from a cache: a camera sends the same layout every frame).

    Raises:
        CloudError (a ValueError): ``wrong_field_type`` for an unknown datatype;
        ``bad_layout`` for a duplicate or empty name, a field beyond ``point_step`` (offset,
        size ``count`` x datatype), two fields that overlap (a ``v`` at the offset of ``u``
        would make every ``v`` equal its ``u``), or ``point_step <= 0``.
    """
    layout = tuple((str(f.name), int(f.offset), int(f.datatype), int(f.count)) for f in fields)
    return _layout_dtype(layout, int(point_step), bool(is_bigendian))


@functools.lru_cache(maxsize=64)
def _layout_dtype(layout: tuple, point_step: int, is_bigendian: bool) -> np.dtype:
    """:func:`fields_to_dtype` of ``layout``, ``((name, offset, datatype, count), ...)``
    (an invalid layout raises, and is not cached)."""
    if point_step <= 0:
        raise CloudError("bad_layout", f"point_step must be > 0, got {point_step}")
    order = ">" if is_bigendian else "<"
    names, formats, offsets, spans = [], [], [], []
    for name, offset, dt, count in layout:
        if not name:
            raise CloudError("bad_layout", "PointCloud2 field with an empty name")
        if name in names:
            raise CloudError("bad_layout", f"duplicate PointCloud2 field {name!r}")
        if dt not in _DT_TO_NP:
            raise CloudError(
                "wrong_field_type", f"field {name!r} has unknown PointField datatype {dt}"
            )
        count = max(count, 1)
        base = np.dtype(order + _DT_TO_NP[dt])
        size = count * base.itemsize  # (checked before NumPy sees a huge count)
        if offset < 0 or offset + size > point_step:
            raise CloudError(
                "bad_layout",
                f"field {name!r} (offset {offset}, {size} "
                f"bytes) does not fit in point_step {point_step}",
            )
        for other, (a, b) in zip(names, spans, strict=True):
            if offset < b and a < offset + size:
                raise CloudError(
                    "bad_layout",
                    f"fields {other!r} (bytes {a}-{b - 1}) and "
                    f"{name!r} (bytes {offset}-{offset + size - 1}) overlap",
                )
        names.append(name)
        formats.append(base if count == 1 else np.dtype((base, (count,))))
        offsets.append(offset)
        spans.append((offset, offset + size))
    return np.dtype(
        {"names": names, "formats": formats, "offsets": offsets, "itemsize": point_step}
    )


def dtype_to_fields(dtype: np.dtype) -> list[tuple[str, int, int, int]]:
    """Structured dtype -> list of ``(name, offset, datatype, count)`` tuples.

    Raises:
        ValueError: a field type PointCloud2 cannot carry (e.g. int64, complex, strings).
    """
    out = []
    for name in dtype.names or ():
        fmt, offset = dtype.fields[name][:2]
        count = 1
        if fmt.subdtype is not None:
            fmt, shape = fmt.subdtype
            count = int(np.prod(shape))
        key = fmt.kind + str(fmt.itemsize)
        if key not in _NP_TO_DT:
            raise ValueError(f"field {name!r}: dtype {fmt} cannot be stored in a PointCloud2")
        out.append((name, int(offset), _NP_TO_DT[key], count))
    return out


def cloud_to_array(msg: Any, names: Sequence[str] | None = None) -> np.ndarray:
    """PointCloud2 (rclpy or rosbags) -> 1-D structured array of ``width * height`` points.

    Args:
        msg: the cloud.
        names: decode only the fields of these names (the others, whatever their datatype,
            offset or name, are ignored); ``None``: every field.
    Raises:
        CloudError (a ValueError): ``truncated`` (less data than the layout needs),
        ``bad_layout`` (row_step too small, negative size, see :func:`fields_to_dtype`),
        ``wrong_field_type``.
    """
    fields = list(msg.fields)
    if names is not None:
        fields = [f for f in fields if str(f.name) in names]
    width, height = int(msg.width), int(msg.height)
    point_step, row_step = int(msg.point_step), int(msg.row_step)
    n = width * height
    if width < 0 or height < 0:
        raise CloudError("bad_layout", f"invalid cloud size {width}x{height}")
    data = msg.data
    if isinstance(data, np.ndarray):
        buf = np.ascontiguousarray(data, dtype=np.uint8).reshape(-1)
    elif isinstance(data, (bytes, bytearray, memoryview)) or hasattr(data, "buffer_info"):
        buf = np.frombuffer(memoryview(data).cast("B"), dtype=np.uint8)
    else:  # a list of ints
        buf = np.asarray(data, dtype=np.uint8).reshape(-1)
    if n == 0:
        if point_step <= 0:  # an empty cloud may come with an empty layout
            return np.zeros(0, dtype=[("u", "f4"), ("v", "f4")])
        return np.zeros(0, dtype=fields_to_dtype(fields, point_step, msg.is_bigendian))
    dtype = fields_to_dtype(fields, point_step, bool(msg.is_bigendian))
    if row_step < width * point_step:
        raise CloudError(
            "bad_layout", f"row_step {row_step} < width {width} * point_step {point_step}"
        )
    need = row_step * (height - 1) + width * point_step
    if len(buf) < need:
        raise CloudError(
            "truncated",
            f"truncated PointCloud2: {len(buf)} bytes of data, "
            f"expected {row_step * height} ({height} rows x row_step {row_step})",
        )
    if row_step == width * point_step:
        return np.frombuffer(buf[: n * point_step].tobytes(), dtype=dtype, count=n)
    rows = [buf[i * row_step : i * row_step + width * point_step] for i in range(height)]
    return np.frombuffer(np.concatenate(rows).tobytes(), dtype=dtype, count=n)


@dataclass
class PackedCloud:
    """Layout and bytes of a PointCloud2 (for building rclpy or rosbags messages)."""

    fields: list  # (name, offset, datatype, count)
    point_step: int
    width: int
    data: bytes

    @property
    def row_step(self) -> int:
        return self.point_step * self.width


def pack_cloud(arr: np.ndarray) -> PackedCloud:
    """Structured array -> little-endian packed fields and bytes (height 1)."""
    arr = np.asarray(arr).reshape(-1)
    if arr.dtype.names is None:
        raise ValueError("pack_cloud needs a structured array")
    dtype = arr.dtype
    le = np.dtype(
        {
            "names": list(dtype.names),
            "formats": [dtype.fields[nm][0].newbyteorder("<") for nm in dtype.names],
            "offsets": [dtype.fields[nm][1] for nm in dtype.names],
            "itemsize": dtype.itemsize,
        }
    )
    arr = arr.astype(le, copy=False)
    return PackedCloud(dtype_to_fields(le), le.itemsize, len(arr), arr.tobytes())


def array_to_cloud(arr: np.ndarray, frame_id: str = "", stamp: Any = None) -> Any:
    """Structured array -> rclpy ``sensor_msgs/PointCloud2`` (height 1, little endian, dense
    only if every float is finite). ``stamp``: a ``builtin_interfaces/Time`` or int nanoseconds."""
    from sensor_msgs.msg import PointCloud2, PointField

    packed = pack_cloud(arr)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    if stamp is not None:
        if isinstance(stamp, (int, np.integer)):
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp), 1_000_000_000)
        else:
            msg.header.stamp = stamp
    msg.height = 1
    msg.width = packed.width
    msg.fields = [
        PointField(name=nm, offset=off, datatype=dt, count=c) for nm, off, dt, c in packed.fields
    ]
    msg.is_bigendian = False
    msg.point_step = packed.point_step
    msg.row_step = packed.row_step
    msg.data = packed.data
    msg.is_dense = is_dense(arr)
    return msg


def is_dense(arr: np.ndarray) -> bool:
    """True if every float field of the structured array is finite (PointCloud2 ``is_dense``)."""
    for nm in arr.dtype.names:
        if arr.dtype.fields[nm][0].kind == "f" and not np.isfinite(arr[nm]).all():
            return False
    return True


# ---------------------------------------------------------------- typed views
@dataclass
class Correspondences:
    """Decoded ``correspondences`` cloud. Arrays are float64 (ids uint32/int64)."""

    uv: np.ndarray  # (N, 2) measured pixels
    xyz: np.ndarray  # (N, 3) map frame, metres
    ids: np.ndarray | None  # (N,)
    scores: np.ndarray | None  # (N,)

    def __len__(self):
        return len(self.uv)


@dataclass
class Keypoints:
    """Decoded ``keypoints`` cloud."""

    uv: np.ndarray  # (N, 2)
    ids: np.ndarray  # (N,) int64
    scores: np.ndarray | None

    def __len__(self):
        return len(self.uv)


def _field_types(msg, names) -> dict:
    """name -> datatype of the fields called one of ``names`` (the others are not read)."""
    return {str(f.name): int(f.datatype) for f in msg.fields if str(f.name) in names}


def _check_fields(msg, required: dict, optional: dict) -> dict:
    types = _field_types(msg, set(required) | set(optional))
    missing = [nm for nm in required if nm not in types]
    if missing:
        raise CloudError(
            "missing_fields", f"missing field(s) {missing}; the cloud has {sorted(types)}"
        )
    for spec in (required, optional):
        for nm, allowed in spec.items():
            if nm in types and types[nm] not in allowed:
                raise CloudError(
                    "wrong_field_type",
                    f"field {nm!r} has type {_dt_name(types[nm])}; "
                    f"expected one of {[_dt_name(a) for a in allowed]}",
                )
    return types


def _column(arr, name):
    col = arr[name]
    if col.ndim > 1:  # count > 1: take the first element
        col = col[:, 0]
    return col


def read_correspondences(msg: Any) -> Correspondences:
    """Decode a correspondences cloud. Only the fields ``u, v, x, y, z, id, score`` are read;
    other fields are ignored. Non-finite rows are kept (the caller drops and counts them).

    Raises:
        CloudError (a ValueError) with ``reason``: ``missing_fields``, ``wrong_field_type``,
        ``truncated`` or ``bad_layout`` (see :func:`cloud_to_array`).
    """
    types = _check_fields(
        msg, {k: FLOAT_TYPES for k in "uvxyz"}, {"id": INDEX_TYPES, "score": FLOAT_TYPES}
    )
    arr = cloud_to_array(msg, set(types))
    uv = np.stack([_column(arr, "u"), _column(arr, "v")], axis=1).astype(np.float64)
    xyz = np.stack([_column(arr, k) for k in "xyz"], axis=1).astype(np.float64)
    ids = _column(arr, "id").astype(np.int64) if "id" in types else None
    scores = _column(arr, "score").astype(np.float64) if "score" in types else None
    return Correspondences(uv, xyz, ids, scores)


def read_keypoints(msg: Any) -> Keypoints:
    """Decode a keypoints cloud (``u, v, id`` [+ ``score``]; other fields are ignored).
    Raises CloudError like :func:`read_correspondences`."""
    types = _check_fields(
        msg, {"u": FLOAT_TYPES, "v": FLOAT_TYPES, "id": INDEX_TYPES}, {"score": FLOAT_TYPES}
    )
    arr = cloud_to_array(msg, set(types))
    uv = np.stack([_column(arr, "u"), _column(arr, "v")], axis=1).astype(np.float64)
    ids = _column(arr, "id").astype(np.int64)
    scores = _column(arr, "score").astype(np.float64) if "score" in types else None
    return Keypoints(uv, ids, scores)


def correspondence_array(
    uv: np.ndarray,
    xyz: np.ndarray,
    ids: np.ndarray | None = None,
    scores: np.ndarray | None = None,
    dtype: str = "f4",
) -> np.ndarray:
    """Build the structured array of a correspondences cloud (u, v, x, y, z [, id] [, score])."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    xyz = np.asarray(xyz, dtype=float).reshape(-1, 3)
    if len(uv) != len(xyz):
        raise ValueError(f"{len(uv)} pixels but {len(xyz)} points")
    fields = [(k, dtype) for k in "uvxyz"]
    if ids is not None:
        fields.append(("id", "<u4"))
    if scores is not None:
        fields.append(("score", "<f4"))
    arr = np.zeros(len(uv), dtype=fields)
    arr["u"], arr["v"] = uv[:, 0], uv[:, 1]
    arr["x"], arr["y"], arr["z"] = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    if ids is not None:
        arr["id"] = ids
    if scores is not None:
        arr["score"] = scores
    return arr


def keypoint_array(
    uv: np.ndarray, ids: np.ndarray, scores: np.ndarray | None = None, dtype: str = "f4"
) -> np.ndarray:
    """Structured array of a keypoints cloud (u, v, id [, score])."""
    uv = np.asarray(uv, dtype=float).reshape(-1, 2)
    fields = [("u", dtype), ("v", dtype), ("id", "<u4")]
    if scores is not None:
        fields.append(("score", "<f4"))
    arr = np.zeros(len(uv), dtype=fields)
    arr["u"], arr["v"], arr["id"] = uv[:, 0], uv[:, 1], ids
    if scores is not None:
        arr["score"] = scores
    return arr


def correspondence_cloud(
    uv: np.ndarray,
    xyz: np.ndarray,
    ids: np.ndarray | None = None,
    scores: np.ndarray | None = None,
    frame_id: str = "",
    stamp: Any = None,
    dtype: str = "f4",
) -> Any:
    """rclpy PointCloud2 of correspondences."""
    return array_to_cloud(correspondence_array(uv, xyz, ids, scores, dtype), frame_id, stamp)


def keypoint_cloud(
    uv: np.ndarray,
    ids: np.ndarray,
    scores: np.ndarray | None = None,
    frame_id: str = "",
    stamp: Any = None,
    dtype: str = "f4",
) -> Any:
    """rclpy PointCloud2 of keypoints."""
    return array_to_cloud(keypoint_array(uv, ids, scores, dtype), frame_id, stamp)
