"""The node's per-tick messages written into their CDR bytes, against rclpy's own serialization.

The second formulation is rclpy: each writer's bytes, decoded by ``deserialize_message``, must
be the message built through the public constructors (and for the trace, through the generated
std_msgs classes). CDR padding bytes are unspecified, so the comparison is of messages."""

import math

import numpy as np
import pytest

pytest.importorskip('rclpy')

from geometry_msgs.msg import WrenchStamped  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import PointCloud2  # noqa: E402
from std_msgs.msg import Float64MultiArray, MultiArrayDimension  # noqa: E402
from visualization_msgs.msg import Marker  # noqa: E402

from tissue_sim_ros.ros.loop.trace import (COLUMNS, HEADER_SIZE, RESET, advance_row, decode, event_row)  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402
from tissue_sim_ros.ros.messages.cdr_bytes import (CloudBytes, NeedleShapeBytes, SurfaceMarkerBytes, TraceBytes,
                                                   WrenchBytes)  # noqa: E402

STAMPS = (0, 7, 1_700_000_000_123_456_789, 2**31 * 1_000_000_000 - 1)


@pytest.mark.parametrize('frame_id', ['needle', 'a', 'needle_base_link_2', ''])
def test_wrench_bytes_decode_to_the_wrench_message(frame_id):
    rng = np.random.default_rng(len(frame_id))
    writer = WrenchBytes(frame_id, serialize_message)
    for stamp in STAMPS:
        force, torque = rng.normal(size=3), 1e-3 * rng.normal(size=3)
        got = deserialize_message(writer.serialized(force, torque, stamp), WrenchStamped)
        assert got == cv.wrench_msg(force, torque, frame_id, stamp)
    assert got.header.stamp.sec == STAMPS[-1] // 1_000_000_000 and got.wrench.torque.z == torque[2]


def test_wrench_bytes_refuse_what_is_not_finite_naming_the_field():
    writer = WrenchBytes('needle', serialize_message)
    with pytest.raises(ValueError, match='torque'):
        writer.serialized([0.0, 1.0, 2.0], [0.0, math.nan, 0.0], 5)
    with pytest.raises(ValueError, match='force'):
        writer.serialized([math.inf, 1.0, 2.0], [0.0, 0.0, 0.0], 5)
    with pytest.raises(ValueError, match='force'):           # 2 + 4 values are not 3 + 3
        writer.serialized([0.0, 1.0], [0.0, 0.0, 0.0, 0.0], 5)


@pytest.mark.parametrize('n', [0, 1, 50, 2916])
def test_cloud_bytes_decode_to_the_cloud_message(n):
    rng = np.random.default_rng(n)
    writer = CloudBytes(n, 'world', serialize_message)
    for stamp in STAMPS[:3]:
        positions, displacement = rng.normal(size=(n, 3)), 1e-3 * rng.normal(size=(n, 3))
        got = deserialize_message(writer.serialized(positions, displacement, stamp), PointCloud2)
        assert got == cv.point_cloud_msg(positions, displacement, 'world', stamp)
    if n:
        p, u = cv.point_cloud_arrays(got)
        assert np.array_equal(u, displacement.astype(np.float32))


def test_cloud_bytes_refuse_what_is_not_finite_in_float32_naming_the_rows():
    rng = np.random.default_rng(6)
    writer = CloudBytes(50, 'world', serialize_message)
    positions, displacement = rng.normal(size=(50, 3)), 1e-3 * rng.normal(size=(50, 3))
    displacement[17, 1] = 1e39                                         # inf in float32
    with pytest.raises(ValueError, match='rows \\[17\\]'):
        writer.serialized(positions, displacement, 0)


def _trace_message(stamp_ns, index, rows) -> Float64MultiArray:
    """The trace as the generated classes build it (the layout engine_trace documents)."""
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    data = [float(sec), float(nanosec), float(index)]
    for row in rows:
        data += [float(x) for x in row[:-1]] + [math.nan if row[-1] is None else (row[-1] - stamp_ns) / 1e9]
    msg = Float64MultiArray()
    msg.layout.data_offset = HEADER_SIZE
    msg.layout.dim = [MultiArrayDimension(label='rows', size=len(rows), stride=len(rows) * len(COLUMNS)),
                      MultiArrayDimension(label=','.join(COLUMNS), size=len(COLUMNS), stride=len(COLUMNS))]
    msg.data = data
    return msg


def test_trace_bytes_decode_to_the_trace_message():
    """One writer, ticks of 4, 0 and 1 advances (the prefix rewritten each call)."""
    writer = TraceBytes(serialize_message)
    for k, n_rows in enumerate([4, 0, 1]):
        stamp = 5_000_000_007 + k * 20_000_000
        rows = [advance_row(i + 1, 0.0125, np.array([0.1, 0.2, -0.3 * i]), np.array([0.0, 0.0, 0.0, 1.0]),
                            10 + i, stamp - 1000 * i) for i in range(n_rows)] + [event_row(RESET, n_rows + 1)]
        got = deserialize_message(writer.serialized(stamp, 3 + k, rows), Float64MultiArray)
        want = _trace_message(stamp, 3 + k, rows)
        assert got.layout == want.layout
        assert np.array_equal(np.array(got.data), np.array(want.data), equal_nan=True)
        trace = decode(got.data)
        assert trace.stamp_ns == stamp and trace.published_index == 3 + k
        assert trace.rows.shape == (n_rows + 1, len(COLUMNS))


def test_marker_bytes_decode_to_the_marker_message_at_each_stamp_and_state():
    """SurfaceMarkerBytes writes corners and stamp into bytes serialized once: decoded, they are
    the message surface_marker_msg builds object by object."""
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    rng = np.random.default_rng(5)
    mesh = box_mesh((0.02, 0.03, 0.01), (4, 5, 3))
    triangles = mesh.surface_triangles()
    marker = SurfaceMarkerBytes(triangles, mesh.n_nodes, 'world', 40, serialize_message)
    for stamp in (0, 1_700_000_000_123_456_789, 42):
        positions = mesh.rest_positions + 1e-3 * rng.normal(size=mesh.rest_positions.shape)
        got = deserialize_message(bytes(marker.serialized(positions, stamp)), Marker)
        want = deserialize_message(serialize_message(cv.surface_marker_msg(
            positions, triangles, 'world', stamp, max_triangles=40)), Marker)
        assert got == want and len(got.points) == 3 * len(triangles[::cv.decimation_stride(len(triangles), 40)])
    with pytest.raises(ValueError, match='not finite'):
        marker.serialized(np.full_like(mesh.rest_positions, np.nan), 0)


@pytest.mark.parametrize('n, frame_id', [(1, 'world'), (2, 'world'), (61, 'mesh_frame_7'), (36, '')])
def test_needle_shape_bytes_decode_to_the_path_message(n, frame_id):
    rng = np.random.default_rng(n)
    writer = NeedleShapeBytes(n, frame_id, serialize_message)
    for stamp in STAMPS:
        positions = rng.normal(size=(n, 3))
        quaternions = rng.normal(size=(n, 4))
        quaternions /= np.linalg.norm(quaternions, axis=1)[:, None]
        got = deserialize_message(writer.serialized(positions, quaternions, stamp), Path)
        assert got == cv.needle_shape_msg(positions, quaternions, frame_id, stamp)
    assert len(got.poses) == n and got.poses[-1].header.stamp.sec == STAMPS[-1] // 1_000_000_000
    assert got.poses[-1].pose.orientation.w == quaternions[-1, 3]


def test_needle_shape_bytes_refuse_what_is_not_finite_or_of_another_size():
    writer = NeedleShapeBytes(3, 'world', serialize_message)
    good_q = np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    positions = np.zeros((3, 3))
    positions[1, 2] = math.nan
    with pytest.raises(ValueError, match=r'positions: .*row 1'):
        writer.serialized(positions, good_q, 5)
    with pytest.raises(ValueError, match='3 finite'):
        writer.serialized(np.zeros((4, 3)), np.tile([0.0, 0.0, 0.0, 1.0], (4, 1)), 5)
