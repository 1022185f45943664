"""Engine arrays <-> ROS 2 messages: pure functions, no node, no physics.

Every builder takes numpy arrays in SI units (REP 103) and returns a ready-to-publish rclpy
message; every reader returns numpy arrays. Nothing here publishes, logs or keeps state.

Message cost:

- ``point_cloud_msg`` packs the whole cloud into one float32 buffer with numpy: no per-point
  Python object. It is the message to send the mesh state in at the full rate.
- ``shape_msgs/Mesh`` and ``visualization_msgs/Marker`` hold one Python object per vertex or per
  point (``geometry_msgs/Point``, ``shape_msgs/MeshTriangle``); that is what the message types
  allow. We build those objects without the generated ``__init__`` (which costs 2 to 3 times
  more) when the generated class has the slots we expect, and with the public constructor
  otherwise. Send the topology as Mesh once (transient-local) and the Marker decimated.

Stamps: every ``stamp`` argument may be a ``builtin_interfaces/Time`` message, an ``int`` of
nanoseconds, or anything with ``to_msg()`` (``rclpy.time.Time``).
"""
from __future__ import annotations

import array
import math
import sys
from collections.abc import Iterable, Mapping, Sequence

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, PoseStamped, Vector3, WrenchStamped
from nav_msgs.msg import Path
from sensor_msgs.msg import PointCloud2, PointField
from shape_msgs.msg import Mesh, MeshTriangle
from std_msgs.msg import ColorRGBA, Header
from visualization_msgs.msg import Marker

__all__ = [
    'DIAGNOSTIC_LEVELS',
    'POINT_CLOUD_FIELDS',
    'decimation_stride',
    'diagnostic_array_msg',
    'header',
    'needle_shape_msg',
    'ns_to_stamp',
    'point_cloud_arrays',
    'point_cloud_msg',
    'pose_from_msg',
    'qos_to_dict',
    'stamp_to_ns',
    'surface_marker_msg',
    'surface_mesh_msg',
    'wrench_msg',
]

_NS_PER_S = 1_000_000_000
_INT32_MAX = 2**31 - 1

#: Names of the PointCloud2 fields, in order; each is FLOAT32, so point_step is 24 bytes.
POINT_CLOUD_FIELDS = ('x', 'y', 'z', 'ux', 'uy', 'uz')

#: diagnostic_msgs/DiagnosticStatus levels by name (the message's ``byte`` constants as ints).
DIAGNOSTIC_LEVELS = {'OK': 0, 'WARN': 1, 'ERROR': 2, 'STALE': 3}

# PointField datatype -> numpy type (sensor_msgs/PointField constants).
_POINT_FIELD_DTYPES = {
    PointField.INT8: np.int8, PointField.UINT8: np.uint8,
    PointField.INT16: np.int16, PointField.UINT16: np.uint16,
    PointField.INT32: np.int32, PointField.UINT32: np.uint32,
    PointField.FLOAT32: np.float32, PointField.FLOAT64: np.float64,
}


# --------------------------------------------------------------------------------------------
# time stamps


def stamp_to_ns(stamp) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time`` (or of anything with sec and nanosec)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def ns_to_stamp(ns: int) -> Time:
    """``builtin_interfaces/Time`` for a count of nanoseconds (0 <= ns, sec fits in int32)."""
    ns = int(ns)
    if ns < 0:
        raise ValueError(f'stamp: {ns} ns is negative; expected nanoseconds >= 0')
    sec, nanosec = divmod(ns, _NS_PER_S)
    if sec > _INT32_MAX:
        raise ValueError(f'stamp: {ns} ns is beyond builtin_interfaces/Time (int32 seconds)')
    return Time(sec=sec, nanosec=nanosec)


def _as_stamp(stamp) -> Time:
    if isinstance(stamp, Time):
        return stamp
    if isinstance(stamp, (int, np.integer)):
        return ns_to_stamp(int(stamp))
    if hasattr(stamp, 'to_msg'):  # rclpy.time.Time
        return stamp.to_msg()
    raise TypeError(
        f'stamp: got {type(stamp).__name__}; expected builtin_interfaces/Time, int nanoseconds '
        'or rclpy.time.Time')


def header(frame_id: str, stamp) -> Header:
    """``std_msgs/Header`` for a frame and a stamp (Time message, int ns, rclpy Time)."""
    if not isinstance(frame_id, str):
        raise TypeError(f'frame_id: got {type(frame_id).__name__}; expected str')
    return Header(stamp=_as_stamp(stamp), frame_id=frame_id)


# --------------------------------------------------------------------------------------------
# array checks


def _vector3(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,):
        raise ValueError(f'{name}: shape {v.shape}; expected (3,)')
    if not np.isfinite(v).all():
        raise ValueError(f'{name}: {v.tolist()} is not finite; refusing to publish NaN or inf')
    return v


def _points(name: str, value, n: int | None = None) -> np.ndarray:
    a = np.asarray(value, dtype=np.float64)
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f'{name}: shape {a.shape}; expected (n, 3)')
    if n is not None and a.shape[0] != n:
        raise ValueError(f'{name}: {a.shape[0]} rows; expected {n} (one per vertex)')
    return a


def _triangles(name: str, value, n_vertices: int) -> np.ndarray:
    t = np.asarray(value)
    if t.ndim != 2 or t.shape[1] != 3:
        raise ValueError(f'{name}: shape {t.shape}; expected (k, 3)')
    if t.size and not np.issubdtype(t.dtype, np.integer):
        raise ValueError(f'{name}: dtype {t.dtype}; expected integer vertex indices')
    if t.size and (t.min() < 0 or t.max() >= n_vertices):
        bad = np.flatnonzero(((t < 0) | (t >= n_vertices)).any(axis=1))
        raise ValueError(
            f'{name}: rows {bad[:10].tolist()} index vertices outside [0, {n_vertices})')
    return t


# --------------------------------------------------------------------------------------------
# fast construction of the small per-element messages


def _has_slots(cls, names: Iterable[str]) -> bool:
    slots = getattr(cls, '__slots__', ())
    return all(name in slots for name in names)


# The generated classes (rosidl_generator_py, Jazzy) keep each field in a slot named '_<field>'
# plus '_check_fields'; the public constructor runs a Python setter per field. Filling the slots
# directly gives the same message (a test compares the serialized bytes) in a third of the time.
# Any other layout falls back to the constructor.
_FAST_POINT = _has_slots(Point, ('_x', '_y', '_z', '_check_fields'))
_FAST_TRIANGLE = _has_slots(MeshTriangle, ('_vertex_indices', '_check_fields'))
_FAST_CLOUD_DATA = _has_slots(PointCloud2, ('_data',))


def _point_list(xyz: np.ndarray) -> list:
    """One geometry_msgs/Point per row of an (n, 3) float64 array."""
    rows = np.ascontiguousarray(xyz, dtype=np.float64).tolist()
    if not _FAST_POINT:
        return [Point(x=x, y=y, z=z) for x, y, z in rows]
    new = Point.__new__
    out = []
    append = out.append
    for x, y, z in rows:
        p = new(Point)
        p._check_fields = False
        p._x = x
        p._y = y
        p._z = z
        append(p)
    return out


def _triangle_list(triangles: np.ndarray) -> list:
    """One shape_msgs/MeshTriangle per row; each holds a row view of one private uint32 copy."""
    tri = np.array(triangles, dtype=np.uint32, order='C', copy=True)
    if not _FAST_TRIANGLE:
        return [MeshTriangle(vertex_indices=row) for row in tri]
    new = MeshTriangle.__new__
    out = []
    append = out.append
    for row in tri:
        m = new(MeshTriangle)
        m._check_fields = False
        m._vertex_indices = row
        append(m)
    return out


# --------------------------------------------------------------------------------------------
# pose in, wrench out


def pose_from_msg(msg: PoseStamped) -> tuple[np.ndarray, np.ndarray, str, int]:
    """(position (3,) m, quaternion (4,) x y z w, frame_id, stamp in ns) of a PoseStamped.

    No validation beyond types: NaN, non-unit quaternions and frames are judged by the engine.
    """
    p = msg.pose.position
    q = msg.pose.orientation
    position = np.array((p.x, p.y, p.z), dtype=np.float64)
    quaternion = np.array((q.x, q.y, q.z, q.w), dtype=np.float64)
    return position, quaternion, msg.header.frame_id, stamp_to_ns(msg.header.stamp)


def wrench_msg(force, torque, frame_id: str, stamp) -> WrenchStamped:
    """WrenchStamped (N, N m) expressed in ``frame_id``; refuses NaN/inf naming the field."""
    f = _vector3('force', force)
    t = _vector3('torque', torque)
    msg = WrenchStamped(header=header(frame_id, stamp))
    msg.wrench.force = Vector3(x=float(f[0]), y=float(f[1]), z=float(f[2]))
    msg.wrench.torque = Vector3(x=float(t[0]), y=float(t[1]), z=float(t[2]))
    return msg


def needle_shape_msg(positions, quaternions, frame_id: str, stamp) -> Path:
    """nav_msgs/Path of the needle's centreline from the base to the tip: a pose per point
    (position [m], the needle's frame there as a quaternion x y z w, its +z along the needle),
    every pose stamped ``stamp`` in ``frame_id``; refuses NaN/inf naming the point."""
    xyz = _points('positions', positions)
    q = np.asarray(quaternions, dtype=np.float64).reshape(-1, 4)
    for name, values in (('positions', xyz), ('quaternions', q)):
        finite = np.all(np.isfinite(values), axis=1)
        if len(values) != len(xyz) or not finite.all():
            raise ValueError(f'{name}: expected {len(xyz)} finite rows, one per point of the needle'
                             + ('' if len(values) != len(xyz) else f' (row {int(np.argmin(finite))} is not)'))
    msg = Path(header=header(frame_id, stamp))
    for (x, y, z), (qx, qy, qz, qw) in zip(xyz.tolist(), q.tolist()):
        pose = PoseStamped(header=header(frame_id, stamp))
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = x, y, z
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = qx, qy, qz, qw
        msg.poses.append(pose)
    return msg


# --------------------------------------------------------------------------------------------
# mesh state as a point cloud


def _point_fields() -> list:
    return [PointField(name=name, offset=4 * i, datatype=PointField.FLOAT32, count=1)
            for i, name in enumerate(POINT_CLOUD_FIELDS)]


def point_cloud_msg(positions, displacement, frame_id: str, stamp) -> PointCloud2:
    """PointCloud2 of every vertex: fields x y z ux uy uz, FLOAT32, point_step 24, height 1.

    Built from one (n, 6) float32 buffer; the values are the float64 inputs rounded to float32.
    Refuses non-finite values (after the float32 conversion, so overflow counts too) naming the
    field, so ``is_dense`` is always true.
    """
    pos = _points('positions', positions)
    disp = _points('displacement', displacement, n=pos.shape[0])
    n = pos.shape[0]
    buf = np.empty((n, 6), dtype=np.float32)
    with np.errstate(over='ignore'):  # overflow gives inf, refused just below
        for j in range(3):  # column by column: 2.5x faster than buf[:, :3] = pos (loop of 3)
            buf[:, j] = pos[:, j]
            buf[:, 3 + j] = disp[:, j]
    finite = np.isfinite(buf)
    if not finite.all():
        for name, cols in (('positions', slice(0, 3)), ('displacement', slice(3, 6))):
            bad = np.flatnonzero(~finite[:, cols].all(axis=1))
            if bad.size:
                raise ValueError(
                    f'{name}: rows {bad[:10].tolist()} are not finite in float32; '
                    'refusing to publish NaN or inf')
    data = array.array('B')
    data.frombytes(buf.reshape(-1).view(np.uint8))  # one memcpy, no per-point object
    msg = PointCloud2(header=header(frame_id, stamp))
    msg.height = 1
    msg.width = n
    msg.fields = _point_fields()
    msg.is_bigendian = sys.byteorder == 'big'
    msg.point_step = 24
    msg.row_step = 24 * n
    if _FAST_CLOUD_DATA:
        msg._data = data  # the setter would copy the array once more
    else:
        msg.data = data
    msg.is_dense = True
    return msg


def point_cloud_arrays(msg) -> tuple[np.ndarray, np.ndarray]:
    """(positions (n, 3), displacement (n, 3)) float64 from a PointCloud2 with x..uz fields.

    Reads any field layout (offsets, datatypes, padding, row_step, endianness) by name, so it
    works on clouds from other producers and on messages decoded from MCAP without rclpy
    (``mcap_ros2`` or ``rosbags`` objects: ``data`` may be bytes, array or numpy array).
    """
    fields = {f.name: f for f in msg.fields}
    missing = [name for name in POINT_CLOUD_FIELDS if name not in fields]
    if missing:
        raise ValueError(f'fields: {missing} missing; expected {list(POINT_CLOUD_FIELDS)}')
    order = '>' if msg.is_bigendian else '<'
    names, formats, offsets = [], [], []
    for name in POINT_CLOUD_FIELDS:
        f = fields[name]
        if f.datatype not in _POINT_FIELD_DTYPES or f.count != 1:
            raise ValueError(
                f'fields.{name}: datatype {f.datatype} count {f.count}; expected a scalar')
        names.append(name)
        formats.append(np.dtype(_POINT_FIELD_DTYPES[f.datatype]).newbyteorder(order))
        offsets.append(f.offset)
    point_type = np.dtype(
        {'names': names, 'formats': formats, 'offsets': offsets, 'itemsize': msg.point_step})
    height, width, row_step = int(msg.height), int(msg.width), int(msg.row_step)
    try:
        raw = memoryview(msg.data).cast('B')
    except TypeError:  # a list of ints
        raw = memoryview(bytes(msg.data))
    if len(raw) < height * row_step or row_step < width * msg.point_step:
        raise ValueError(
            f'data: {len(raw)} bytes for {height} rows of {row_step} bytes '
            f'({width} points of {msg.point_step})')
    rows = np.frombuffer(raw, dtype=np.uint8, count=height * row_step).reshape(height, row_step)
    points = np.ascontiguousarray(rows[:, :width * msg.point_step]).view(point_type).reshape(-1)
    positions = np.stack([points[k].astype(np.float64) for k in ('x', 'y', 'z')], axis=1)
    displacement = np.stack([points[k].astype(np.float64) for k in ('ux', 'uy', 'uz')], axis=1)
    return positions, displacement


# --------------------------------------------------------------------------------------------
# surface: topology as shape_msgs/Mesh, decimated Marker for RViz


def surface_mesh_msg(positions, triangles) -> Mesh:
    """shape_msgs/Mesh of the surface: one Point per vertex, one MeshTriangle per triangle.

    Indices are checked against the vertex count. Mesh has no header: the frame is the mesh
    frame parameter of the node (send it on a transient-local topic, once per topology).
    """
    pos = _points('positions', positions)
    tri = _triangles('triangles', triangles, pos.shape[0])
    if not np.isfinite(pos).all():
        bad = np.flatnonzero(~np.isfinite(pos).all(axis=1))
        raise ValueError(f'positions: rows {bad[:10].tolist()} are not finite')
    msg = Mesh()
    msg.vertices = _point_list(pos)
    msg.triangles = _triangle_list(tri)
    return msg


def decimation_stride(n_triangles: int, max_triangles: int) -> int:
    """Stride s so that every s-th triangle (0, s, 2s, ...) gives at most max_triangles."""
    if max_triangles < 1:
        raise ValueError(f'max_triangles: {max_triangles}; expected >= 1')
    return max(1, -(-n_triangles // max_triangles))  # ceil division


def surface_marker_msg(
    positions,
    triangles,
    frame_id: str,
    stamp,
    max_triangles: int = 2000,
    *,
    ns: str = 'tissue_surface',
    marker_id: int = 0,
    color: Sequence[float] = (0.9, 0.55, 0.5, 1.0),
) -> Marker:
    """visualization_msgs/Marker TRIANGLE_LIST of the surface, for RViz.

    Decimated to at most ``max_triangles`` by keeping every s-th triangle (s = ceil(k / max)),
    in the order given: cheap, deterministic, evenly spread over the triangle list, but it
    leaves holes; it is a preview, not the geometry (that is the Mesh and the PointCloud2).
    One colour for the whole marker (``colors`` left empty), identity pose, unit scale.
    """
    pos = _points('positions', positions)
    tri = _triangles('triangles', triangles, pos.shape[0])
    stride = decimation_stride(tri.shape[0], int(max_triangles))
    kept = tri[::stride]
    corners = pos[kept.reshape(-1)]  # (3 * kept, 3): the TRIANGLE_LIST point order
    if not np.isfinite(corners).all():
        raise ValueError('positions: surface vertices are not finite; refusing to publish')
    if len(color) != 4:
        raise ValueError(f'color: {list(color)}; expected (r, g, b, a)')
    msg = Marker(header=header(frame_id, stamp))
    msg.ns = ns
    msg.id = int(marker_id)
    msg.type = Marker.TRIANGLE_LIST
    msg.action = Marker.ADD
    msg.pose.orientation.w = 1.0
    msg.scale = Vector3(x=1.0, y=1.0, z=1.0)
    r, g, b, a = (float(c) for c in color)
    msg.color = ColorRGBA(r=r, g=g, b=b, a=a)
    msg.points = _point_list(corners)
    return msg


# --------------------------------------------------------------------------------------------
# diagnostics


def _level(name: str, level) -> int:
    if isinstance(level, (bytes, bytearray)) and len(level) == 1:
        value = level[0]
    elif isinstance(level, str) and level.upper() in DIAGNOSTIC_LEVELS:
        value = DIAGNOSTIC_LEVELS[level.upper()]
    elif isinstance(level, (int, np.integer)) and not isinstance(level, bool):
        value = int(level)
    else:
        raise ValueError(
            f'{name}.level: {level!r}; expected one of {list(DIAGNOSTIC_LEVELS)} or 0..3')
    if value not in DIAGNOSTIC_LEVELS.values():
        raise ValueError(f'{name}.level: {value}; expected 0 (OK) .. 3 (STALE)')
    return value


def _format_value(value) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return 'true' if value else 'false'
    if isinstance(value, (float, np.floating)):
        # a figure that does not exist says so (the statuses write 'none yet'); never 'nan'
        return f'{float(value):.6g}' if math.isfinite(value) else 'not available'
    return str(value)


def diagnostic_array_msg(stamp, statuses: Iterable[Sequence]) -> DiagnosticArray:
    """DiagnosticArray from ``(name, level, message, {key: value})`` tuples.

    ``level`` is 'OK'/'WARN'/'ERROR'/'STALE' (any case), 0..3, or the message's byte constant.
    An optional fifth item is the hardware_id. Values become strings: floats with 6
    significant digits (a non-finite one 'not available'), bools as true/false, the rest with
    ``str``.
    """
    msg = DiagnosticArray(header=header('', stamp))
    out = []
    for i, item in enumerate(statuses):
        if len(item) not in (4, 5):
            raise ValueError(
                f'statuses[{i}]: {len(item)} items; expected (name, level, message, values'
                '[, hardware_id])')
        name, level, message, values = item[:4]
        if not isinstance(values, Mapping):
            raise ValueError(f'statuses[{i}].values: {type(values).__name__}; expected a dict')
        status = DiagnosticStatus()
        status.level = bytes((_level(f'statuses[{i}]', level),))
        status.name = str(name)
        status.message = str(message)
        status.hardware_id = str(item[4]) if len(item) == 5 else ''
        status.values = [KeyValue(key=str(k), value=_format_value(v)) for k, v in values.items()]
        out.append(status)
    msg.status = out
    return msg


# --------------------------------------------------------------------------------------------
# QoS as the recorder wants it


def qos_to_dict(profile) -> dict:
    """A plain dict of an ``rclpy.qos.QoSProfile`` for ``McapRecorder.add_topic``.

    Policies by lower-case name ('reliable', 'transient_local', 'keep_last', ...), depth, and
    durations in nanoseconds (0 = unspecified, the rclpy default).
    """
    def ns(duration) -> int:
        return int(getattr(duration, 'nanoseconds', duration))
    return {
        'history': profile.history.name.lower(),
        'depth': int(profile.depth),
        'reliability': profile.reliability.name.lower(),
        'durability': profile.durability.name.lower(),
        'deadline_ns': ns(profile.deadline),
        'lifespan_ns': ns(profile.lifespan),
        'liveliness': profile.liveliness.name.lower(),
        'liveliness_lease_duration_ns': ns(profile.liveliness_lease_duration),
        'avoid_ros_namespace_conventions': bool(profile.avoid_ros_namespace_conventions),
    }
