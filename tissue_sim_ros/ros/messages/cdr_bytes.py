"""The node's per-tick messages written straight into their CDR bytes: the wrench, the mesh
state's point cloud, the needle's shape, the engine trace and the surface marker.

Why: in the running node, building these as rclpy message objects and serializing them would
take most of the executor thread's time a tick (ten times what the same calls take on a quiet
core, since the physics leaves the interpreter's data out of the caches between ticks), while
their layouts are fixed. Each writer here serializes one message through rclpy when it is made, with
sentinel values, finds where the stamp and the values lie, and checks the layout (little-endian
plain CDR, as ROS 2's rmw layers write it); each call then writes the stamp and the values into
those bytes. They decode to the message rclpy would serialize for the same values (the tests
compare field by field; the CDR padding bytes are whatever rclpy's serializer left there), and
the node publishes and records the same bytes.
"""
from __future__ import annotations

import math
import struct

import numpy as np

from tissue_sim_ros.ros.messages import conversions as cv
from tissue_sim_ros.ros.loop.trace import COLUMNS, HEADER_SIZE, encode
from tissue_sim_ros.units import NS_PER_S

__all__ = ['CloudBytes', 'NeedleShapeBytes', 'SurfaceMarkerBytes', 'TraceBytes', 'WrenchBytes']

_STAMP = struct.Struct('<iI')
_UINT32 = struct.Struct('<I')
_SIX_DOUBLES = struct.Struct('<6d')
_SEVEN_DOUBLES = struct.Struct('<7d')
_SENTINEL = 1.2345678901234567e-301


def _little_endian(data: bytes, what: str) -> None:
    if data[:2] != b'\x00\x01':
        raise ValueError(f'{what}: encapsulation {bytes(data[:4])!r}, expected little-endian plain CDR')


def _find_once(data: bytes, pattern: bytes, what: str) -> int:
    at = data.find(pattern)
    if at < 0 or data.find(pattern, at + 1) >= 0:
        raise ValueError(f'unexpected {what} serialization: its marker is not found exactly once')
    return at


def _stamp(stamp) -> tuple[int, int]:
    """(sec, nanosec) of a stamp in any form conversions takes (ns, Time, rclpy Time)."""
    t = cv._as_stamp(stamp)
    return t.sec, t.nanosec


class WrenchBytes:
    """geometry_msgs/WrenchStamped in ``frame_id`` as CDR bytes (``serialize``: rclpy's
    serialize_message, passed in)."""

    def __init__(self, frame_id: str, serialize):
        self.frame_id = frame_id
        values = [_SENTINEL * (1 + k) for k in range(6)]
        data = serialize(cv.wrench_msg(values[:3], values[3:], frame_id, 0))
        _little_endian(data, 'WrenchStamped')
        self._values_at = _find_once(data, _SIX_DOUBLES.pack(*values), 'WrenchStamped')
        self._data = bytearray(data)

    def serialized(self, force, torque, stamp_ns: int) -> bytes:
        """The message of :func:`conversions.wrench_msg` (force [N], torque [N m]), serialized;
        refuses NaN or inf naming the field, as that function does."""
        try:
            values = (*map(float, force), *map(float, torque))
            good = len(force) == 3 and len(torque) == 3 and all(map(math.isfinite, values))
        except (TypeError, ValueError):
            good = False
        if not good:
            cv.wrench_msg(force, torque, self.frame_id, stamp_ns)      # raises, naming the field
            raise ValueError(f'force {force!r}, torque {torque!r}: expected 3 finite values each')
        _STAMP.pack_into(self._data, 4, *_stamp(stamp_ns))
        _SIX_DOUBLES.pack_into(self._data, self._values_at, *values)
        return bytes(self._data)


class CloudBytes:
    """sensor_msgs/PointCloud2 of ``n_points`` vertices (fields x y z ux uy uz, float32, the
    layout of :func:`conversions.point_cloud_msg`) as CDR bytes, its data written through a
    float32 view of them: a tick makes no cloud but the bytes it publishes."""

    def __init__(self, n_points: int, frame_id: str, serialize):
        n = int(n_points)
        self.frame_id = frame_id
        marker = np.full((max(n, 1), 3), 1.5e38, dtype=np.float64)[:n]
        data = serialize(cv.point_cloud_msg(marker, marker, frame_id, 0))
        _little_endian(data, 'PointCloud2')
        start = len(data) - 1 - 24 * n                   # the data, then is_dense (one byte)
        if data[-1] != 1 or _UINT32.unpack_from(data, start - 4)[0] != 24 * n or start % 4 or \
                (n and np.frombuffer(data, np.float32, 6 * n, start).tolist() != [np.float32(1.5e38)] * 6 * n):
            raise ValueError('unexpected PointCloud2 serialization')
        self._data = bytearray(data)
        self._view = np.frombuffer(self._data, dtype=np.float32, count=6 * n, offset=start).reshape(n, 6)

    def serialized(self, positions, displacement, stamp_ns: int) -> bytes:
        """The cloud of ``positions`` and ``displacement`` ((n, 3) float64, rounded to float32),
        serialized; refuses values that are not finite in float32, naming the rows, as
        :func:`conversions.point_cloud_msg` does."""
        view = self._view
        with np.errstate(over='ignore', invalid='ignore'):
            for j in range(3):   # column by column: 2.5x faster than view[:, :3] = positions
                view[:, j] = positions[:, j]
                view[:, 3 + j] = displacement[:, j]
            total = float(np.sum(view, dtype=np.float64))
        if not math.isfinite(total):           # which rows: the full check names them
            cv.point_cloud_msg(positions, displacement, self.frame_id, stamp_ns)
            raise ValueError('positions, displacement: not finite in float32')
        _STAMP.pack_into(self._data, 4, *_stamp(stamp_ns))
        return bytes(self._data)


class NeedleShapeBytes:
    """nav_msgs/Path of a needle's ``n_points`` centreline poses in ``frame_id``
    (:func:`conversions.needle_shape_msg`) as CDR bytes: the stamps and the seven doubles of each
    pose written into the bytes serialized once with sentinel values."""

    def __init__(self, n_points: int, frame_id: str, serialize):
        n = int(n_points)
        self.frame_id = frame_id
        values = np.array([[_SENTINEL * (2 + 7 * k + j) for j in range(7)] for k in range(n)]).reshape(n, 7)
        data = serialize(cv.needle_shape_msg(values[:, :3], values[:, 3:], frame_id, 0))
        _little_endian(data, 'Path')
        self._pose_at = [_find_once(data, _SEVEN_DOUBLES.pack(*row), 'Path') for row in values]
        stamps = serialize(cv.needle_shape_msg(np.zeros((n, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
                                               frame_id, 0x5A5A5A5A * NS_PER_S))
        marker = _STAMP.pack(0x5A5A5A5A, 0)
        self._stamp_at = [4] + self._stamp_offsets(stamps, marker, n)
        self._data = bytearray(data)
        # the poses and their stamps written at once through byte indices: CDR aligns each pose's
        # doubles to 8 from the payload's start, so with some frame_id lengths the poses are not
        # evenly spaced (every other one is 4 bytes further on)
        self._bytes = np.frombuffer(self._data, dtype=np.uint8)
        self._pose_bytes = np.add.outer(np.array(self._pose_at), np.arange(56))
        self._stamp_bytes = np.add.outer(np.array(self._stamp_at[1:], dtype=np.int64), np.arange(8))
        self._values = np.empty((n, 7), dtype='<f8')
        self._stamps = np.empty((n, 2), dtype='<u4')

    @staticmethod
    def _stamp_offsets(data: bytes, marker: bytes, n: int) -> list:
        """Where each pose's stamp lies (the message's own is at 4)."""
        found, at = [], data.find(marker, 5)
        while at >= 0:
            found.append(at)
            at = data.find(marker, at + 1)
        if len(found) != n:
            raise ValueError('unexpected Path serialization: a pose stamp is not found once per pose')
        return found

    def serialized(self, positions, quaternions, stamp_ns: int) -> bytes:
        """The shape of :func:`conversions.needle_shape_msg` (positions (n, 3) [m], quaternions
        (n, 4)), serialized; refuses NaN or inf naming the row, as that function does."""
        values = np.hstack([np.asarray(positions, dtype=np.float64), np.asarray(quaternions, dtype=np.float64)])
        if values.shape != (len(self._pose_at), 7) or not np.all(np.isfinite(values)):
            cv.needle_shape_msg(positions, quaternions, self.frame_id, stamp_ns)   # raises, naming it
            raise ValueError(f'positions, quaternions: expected {len(self._pose_at)} finite poses')
        sec, nanosec = _stamp(stamp_ns)
        _STAMP.pack_into(self._data, 4, sec, nanosec)
        self._stamps[:] = (sec, nanosec)
        self._values[:] = values
        self._bytes[self._stamp_bytes] = self._stamps.view(np.uint8)
        self._bytes[self._pose_bytes] = self._values.view(np.uint8)
        return bytes(self._data)


class TraceBytes:
    """One tick's engine trace (:mod:`~tissue_sim_ros.ros.loop.trace`) as the CDR bytes of a
    std_msgs/Float64MultiArray whose layout names the columns (dimensions 'rows' and the
    columns joined by commas, ``data_offset`` the trace header's size)."""

    def __init__(self, serialize):
        from std_msgs.msg import Float64MultiArray, MultiArrayDimension
        rows_marker, stride_marker, offset_marker = 0x5A5A5A01, 0x5A5A5A02, 0x5A5A5A03
        msg = Float64MultiArray()
        msg.layout.data_offset = offset_marker
        msg.layout.dim = [MultiArrayDimension(label='rows', size=rows_marker, stride=stride_marker),
                          MultiArrayDimension(label=','.join(COLUMNS), size=len(COLUMNS), stride=len(COLUMNS))]
        msg.data = [_SENTINEL]
        data = serialize(msg)
        _little_endian(data, 'Float64MultiArray')
        self._rows_at = _find_once(data, struct.pack('<II', rows_marker, stride_marker), 'Float64MultiArray')
        offset_at = _find_once(data, _UINT32.pack(offset_marker), 'Float64MultiArray')
        self._count_at = offset_at + 4          # the data's length follows data_offset (both uint32)
        self._data_at = _find_once(data, struct.pack('<d', _SENTINEL), 'Float64MultiArray')
        if len(data) != self._data_at + 8 or _UINT32.unpack_from(data, self._count_at)[0] != 1 or \
                not 0 <= self._data_at - self._count_at - 4 < 8:
            raise ValueError('unexpected Float64MultiArray serialization')
        self._prefix = bytearray(data[:self._data_at])
        _UINT32.pack_into(self._prefix, offset_at, HEADER_SIZE)

    def serialized(self, stamp_ns: int, published_index: int, rows) -> bytes:
        """The trace of ``rows`` (engine_trace rows) published with state ``published_index``."""
        values = encode(stamp_ns, published_index, rows)
        prefix = self._prefix
        _UINT32.pack_into(prefix, self._rows_at, len(rows))
        _UINT32.pack_into(prefix, self._rows_at + 4, len(rows) * len(COLUMNS))
        _UINT32.pack_into(prefix, self._count_at, len(values))
        return bytes(prefix) + struct.pack(f'<{len(values)}d', *values)


class SurfaceMarkerBytes:
    """The surface marker as CDR bytes, built without a Python object per point: the marker of
    :func:`conversions.surface_marker_msg` is serialized once per topology with sentinel
    corners, and each :meth:`serialized` call writes the corners (float64, the TRIANGLE_LIST
    order) and the stamp into those bytes: a numpy gather, not milliseconds of Python objects a
    marker. ``serialize``: rclpy's serialize_message (passed in)."""

    def __init__(self, triangles, n_vertices: int, frame_id: str, max_triangles: int, serialize):
        tri = cv._triangles('triangles', triangles, n_vertices)
        self.corners = np.ascontiguousarray(tri[::cv.decimation_stride(tri.shape[0], int(max_triangles))]
                                            .reshape(-1), dtype=np.int64)
        sentinel = np.full((max(n_vertices, 1), 3), _SENTINEL)
        data = bytearray(serialize(cv.surface_marker_msg(sentinel, triangles, frame_id, 0, max_triangles)))
        _little_endian(data, 'Marker')
        start = data.find(np.float64(_SENTINEL).tobytes())
        count = len(self.corners)
        if start < 4 or _UINT32.unpack_from(data, start - 4)[0] != count:
            raise ValueError('unexpected Marker serialization')
        self._data = data
        self._points = np.frombuffer(data, dtype=np.float64, count=3 * count, offset=start).reshape(count, 3)

    def serialized(self, positions, stamp) -> bytearray:
        """The marker's bytes with ``positions`` (n, 3) and ``stamp`` (valid until the next call)."""
        corners = np.take(positions, self.corners, axis=0)
        if not np.isfinite(corners).all():
            raise ValueError('positions: surface vertices are not finite; refusing to publish')
        self._points[:] = corners
        _STAMP.pack_into(self._data, 4, *_stamp(stamp))
        return self._data
