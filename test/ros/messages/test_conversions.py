"""Engine arrays <-> ROS messages: checked against the message definitions, not against the code.

Independent references: the float32 rounding of numpy, the byte layout read back with
np.frombuffer / struct, rclpy's own (de)serialization, the messages' own constants, and messages
built through the public constructors."""

import math
import struct

import numpy as np
import pytest

pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time  # noqa: E402
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus  # noqa: E402
from geometry_msgs.msg import Point, PoseStamped  # noqa: E402
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from sensor_msgs.msg import PointCloud2, PointField  # noqa: E402
from shape_msgs.msg import Mesh, MeshTriangle  # noqa: E402
from visualization_msgs.msg import Marker  # noqa: E402

from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


@pytest.fixture
def rng():
    return np.random.default_rng(20261121)


def test_stamp_round_trip_and_split():
    stamp = cv.ns_to_stamp(1_700_000_001_500_000_123)
    assert (stamp.sec, stamp.nanosec) == (1_700_000_001, 500_000_123)
    assert cv.stamp_to_ns(stamp) == 1_700_000_001_500_000_123
    assert cv.stamp_to_ns(Time(sec=3, nanosec=999_999_999)) == 3_999_999_999
    with pytest.raises(ValueError, match='negative'):
        cv.ns_to_stamp(-1)
    with pytest.raises(ValueError, match='int32'):
        cv.ns_to_stamp(2**31 * 10**9)


def test_header_accepts_rclpy_time_and_ns():
    from rclpy.time import Time as RclpyTime
    h1 = cv.header('a', RclpyTime(nanoseconds=5_000_000_007))
    h2 = cv.header('a', 5_000_000_007)
    assert (h1.stamp.sec, h1.stamp.nanosec) == (5, 7) == (h2.stamp.sec, h2.stamp.nanosec)
    with pytest.raises(TypeError, match='stamp'):
        cv.header('a', 1.5)


def test_pose_from_msg():
    msg = PoseStamped()
    msg.header.frame_id = 'base'
    msg.header.stamp = Time(sec=12, nanosec=34)
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = 0.1, -0.2, 0.3
    q = np.array([1.0, 2.0, 3.0, 4.0]) / math.sqrt(30.0)
    (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
     msg.pose.orientation.w) = q.tolist()
    position, quaternion, frame, stamp_ns = cv.pose_from_msg(msg)
    assert position.dtype == np.float64 and position.shape == (3,)
    assert quaternion.dtype == np.float64 and quaternion.shape == (4,)
    np.testing.assert_array_equal(position, [0.1, -0.2, 0.3])
    np.testing.assert_array_equal(quaternion, q)  # x y z w order
    assert frame == 'base' and stamp_ns == 12 * 10**9 + 34


def test_pose_from_msg_passes_nan_through():  # validation belongs to the engine
    msg = PoseStamped()
    msg.pose.position.x = float('nan')
    position, _, _, _ = cv.pose_from_msg(msg)
    assert math.isnan(position[0])


def test_wrench_msg_values_and_round_trip():
    msg = cv.wrench_msg([1.5, -2.0, 3.25], np.array([0.01, 0.02, -0.03]), 'needle_base',
                        7_000_000_001)
    back = deserialize_message(serialize_message(msg), type(msg))
    assert back.header.frame_id == 'needle_base'
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (7, 1)
    f, t = back.wrench.force, back.wrench.torque
    assert (f.x, f.y, f.z) == (1.5, -2.0, 3.25)
    assert (t.x, t.y, t.z) == (0.01, 0.02, -0.03)


@pytest.mark.parametrize('field, force, torque', [
    ('force', [float('nan'), 0, 0], [0, 0, 0]),
    ('force', [0, float('inf'), 0], [0, 0, 0]),
    ('torque', [0, 0, 0], [0, 0, -float('inf')]),
    ('torque', [0, 0, 0], [float('nan')] * 3),
])
def test_wrench_msg_refuses_non_finite_naming_the_field(field, force, torque):
    with pytest.raises(ValueError, match=rf'^{field}:'):
        cv.wrench_msg(force, torque, 'needle', 0)


def test_wrench_msg_refuses_bad_shape():
    with pytest.raises(ValueError, match='force: shape'):
        cv.wrench_msg([1, 2], [0, 0, 0], 'needle', 0)


def _cloud_inputs(rng, n):
    positions = rng.uniform(-0.05, 0.05, (n, 3)) + np.array([0.1, 0.2, 0.3])
    displacement = rng.normal(0.0, 1e-3, (n, 3))
    return positions, displacement


def test_point_cloud_layout_matches_the_message_definition(rng):
    positions, displacement = _cloud_inputs(rng, 257)
    msg = cv.point_cloud_msg(positions, displacement, 'tissue', 42)
    assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'ux', 'uy', 'uz']
    assert [f.offset for f in msg.fields] == [0, 4, 8, 12, 16, 20]
    assert all(f.datatype == PointField.FLOAT32 and f.count == 1 for f in msg.fields)
    assert (msg.height, msg.width, msg.point_step, msg.row_step) == (1, 257, 24, 24 * 257)
    assert msg.is_dense and not msg.is_bigendian
    assert msg.header.frame_id == 'tissue' and cv.stamp_to_ns(msg.header.stamp) == 42
    # read the bytes independently: little-endian float32, 6 per point
    raw = bytes(msg.data)
    assert len(raw) == 257 * 24
    table = np.frombuffer(raw, dtype='<f4').reshape(257, 6)
    np.testing.assert_array_equal(table[:, :3], positions.astype(np.float32))
    np.testing.assert_array_equal(table[:, 3:], displacement.astype(np.float32))
    assert struct.unpack_from('<f', raw, 24 * 5 + 16)[0] == np.float32(displacement[5, 1])


def test_point_cloud_round_trip_exact_in_float32(rng):
    positions, displacement = _cloud_inputs(rng, 10_000)
    msg = cv.point_cloud_msg(positions, displacement, 'tissue', 1)
    back = deserialize_message(serialize_message(msg), PointCloud2)
    for m in (msg, back):
        p, u = cv.point_cloud_arrays(m)
        assert p.dtype == np.float64 and p.shape == (10_000, 3)
        np.testing.assert_array_equal(p, positions.astype(np.float32).astype(np.float64))
        np.testing.assert_array_equal(u, displacement.astype(np.float32).astype(np.float64))
    # float32 rounding is really there (the test would not notice a float64 layout otherwise)
    assert not np.array_equal(cv.point_cloud_arrays(msg)[0], positions)


def test_point_cloud_empty():
    msg = cv.point_cloud_msg(np.zeros((0, 3)), np.zeros((0, 3)), 'tissue', 0)
    assert msg.width == 0 and len(msg.data) == 0
    p, u = cv.point_cloud_arrays(msg)
    assert p.shape == (0, 3) and u.shape == (0, 3)


@pytest.mark.parametrize('field', ['positions', 'displacement'])
def test_point_cloud_refuses_non_finite(rng, field):
    positions, displacement = _cloud_inputs(rng, 20)
    target = positions if field == 'positions' else displacement
    target[7, 2] = np.nan
    with pytest.raises(ValueError, match=rf'^{field}: rows \[7\]'):
        cv.point_cloud_msg(positions, displacement, 'tissue', 0)


def test_point_cloud_refuses_float32_overflow(rng):
    positions, displacement = _cloud_inputs(rng, 5)
    positions[2, 0] = 1e300  # finite in float64, inf in float32
    with pytest.raises(ValueError, match='positions'):
        cv.point_cloud_msg(positions, displacement, 'tissue', 0)


def test_point_cloud_refuses_mismatched_rows(rng):
    with pytest.raises(ValueError, match='displacement: 4 rows; expected 5'):
        cv.point_cloud_msg(np.zeros((5, 3)), np.zeros((4, 3)), 'tissue', 0)


def test_point_cloud_arrays_reads_a_foreign_layout(rng):
    """Another producer's cloud: fields reordered, float64 positions, padding, 2 rows."""
    n_rows, width = 2, 3
    n = n_rows * width
    positions, displacement = _cloud_inputs(rng, n)
    layout = np.dtype({'names': ['ux', 'uy', 'uz', 'x', 'y', 'z', 'intensity'],
                       'formats': ['<f4'] * 3 + ['<f8'] * 3 + ['<f4'],
                       'offsets': [0, 4, 8, 16, 24, 32, 40], 'itemsize': 48})
    table = np.zeros(n, dtype=layout)
    for k, name in enumerate(('x', 'y', 'z')):
        table[name] = positions[:, k]
        table['u' + name] = displacement[:, k]
    row_step = 48 * width + 8  # padded rows
    raw = bytearray(row_step * n_rows)
    for r in range(n_rows):
        raw[r * row_step:r * row_step + 48 * width] = table[r * width:(r + 1) * width].tobytes()
    msg = PointCloud2(height=n_rows, width=width, point_step=48, row_step=row_step,
                      is_bigendian=False, is_dense=True)
    types = [PointField.FLOAT32] * 3 + [PointField.FLOAT64] * 3 + [PointField.FLOAT32]
    msg.fields = [PointField(name=nm, offset=off, datatype=dt, count=1)
                  for nm, off, dt in zip(layout.names, [0, 4, 8, 16, 24, 32, 40], types)]
    msg.data = bytes(raw)
    p, u = cv.point_cloud_arrays(msg)
    np.testing.assert_array_equal(p, positions)  # float64 fields: exact
    np.testing.assert_array_equal(u, displacement.astype(np.float32).astype(np.float64))


def test_point_cloud_arrays_names_missing_fields():
    msg = PointCloud2(height=1, width=0, point_step=12, row_step=0)
    msg.fields = [PointField(name=c, offset=4 * i, datatype=PointField.FLOAT32, count=1)
                  for i, c in enumerate('xyz')]
    with pytest.raises(ValueError, match=r"\['ux', 'uy', 'uz'\] missing"):
        cv.point_cloud_arrays(msg)


def _surface(rng, n_vertices, n_triangles):
    positions = rng.uniform(-0.05, 0.05, (n_vertices, 3))
    triangles = rng.integers(0, n_vertices, (n_triangles, 3))
    return positions, triangles


@pytest.mark.parametrize('fast', [True, False])
def test_surface_mesh_values_and_same_bytes_as_public_constructors(rng, monkeypatch, fast):
    if fast and not (cv._FAST_POINT and cv._FAST_TRIANGLE):
        pytest.skip('generated message classes without the expected slots: constructor path')
    monkeypatch.setattr(cv, '_FAST_POINT', fast)
    monkeypatch.setattr(cv, '_FAST_TRIANGLE', fast)
    positions, triangles = _surface(rng, 50, 80)
    msg = cv.surface_mesh_msg(positions, triangles)
    reference = Mesh(
        vertices=[Point(x=float(x), y=float(y), z=float(z)) for x, y, z in positions],
        triangles=[MeshTriangle(vertex_indices=np.array(t, dtype=np.uint32)) for t in triangles])
    assert serialize_message(msg) == serialize_message(reference)
    back = deserialize_message(serialize_message(msg), Mesh)
    np.testing.assert_array_equal([(v.x, v.y, v.z) for v in back.vertices], positions)
    np.testing.assert_array_equal([t.vertex_indices for t in back.triangles], triangles)


def test_surface_mesh_message_does_not_alias_the_input(rng):
    positions = rng.uniform(size=(8, 3))
    triangles = np.array([[1, 2, 3], [4, 5, 6]], dtype=np.uint32)  # already the wire dtype
    msg = cv.surface_mesh_msg(positions, triangles)
    triangles[:] = 0  # the caller reuses its array
    assert [t.vertex_indices.tolist() for t in msg.triangles] == [[1, 2, 3], [4, 5, 6]]


def test_surface_mesh_refuses_bad_indices(rng):
    positions, triangles = _surface(rng, 10, 6)
    triangles[4, 1] = 10
    with pytest.raises(ValueError,
                       match=r'triangles: rows \[4\] index vertices outside \[0, 10\)'):
        cv.surface_mesh_msg(positions, triangles)
    triangles[4, 1] = -1
    with pytest.raises(ValueError, match=r'rows \[4\]'):
        cv.surface_mesh_msg(positions, triangles)


@pytest.mark.parametrize('n_triangles, max_triangles', [
    (1, 2000), (1999, 2000), (2000, 2000), (2001, 2000), (20000, 2000), (20001, 2000),
    (7, 3), (100, 1),
])
def test_marker_decimation_bound_and_rule(rng, n_triangles, max_triangles):
    positions, triangles = _surface(rng, 300, n_triangles)
    msg = cv.surface_marker_msg(positions, triangles, 'tissue', 5, max_triangles)
    kept = len(msg.points) // 3
    assert len(msg.points) % 3 == 0
    assert kept <= max_triangles
    stride = math.ceil(n_triangles / max_triangles)
    assert kept == len(range(0, n_triangles, stride))  # every stride-th triangle, nothing else
    if n_triangles <= max_triangles:
        assert kept == n_triangles
    expected = positions[triangles[::stride].reshape(-1)]
    np.testing.assert_array_equal([(p.x, p.y, p.z) for p in msg.points], expected)


def test_marker_fields_for_rviz(rng):
    positions, triangles = _surface(rng, 20, 10)
    msg = cv.surface_marker_msg(positions, triangles, 'tissue', 9, 100, ns='s', marker_id=3,
                                color=(0.1, 0.2, 0.3, 0.4))
    back = deserialize_message(serialize_message(msg), Marker)
    assert back.type == Marker.TRIANGLE_LIST and back.action == Marker.ADD
    assert (back.ns, back.id, back.header.frame_id) == ('s', 3, 'tissue')
    assert back.pose.orientation.w == 1.0  # a zero quaternion makes RViz reject the marker
    assert (back.scale.x, back.scale.y, back.scale.z) == (1.0, 1.0, 1.0)
    assert back.color.a == pytest.approx(0.4) and len(back.colors) == 0
    assert len(back.points) == 30


def test_marker_refuses_zero_budget(rng):
    positions, triangles = _surface(rng, 5, 3)
    with pytest.raises(ValueError, match='max_triangles'):
        cv.surface_marker_msg(positions, triangles, 'tissue', 0, 0)


def test_diagnostic_levels_match_the_message_constants():
    msg = cv.diagnostic_array_msg(3_000_000_000, [
        ('engine', 'OK', 'stable', {'step_time_ms': 1.234567, 'substeps': 4}),
        ('timing', 'warn', 'overrun', {'overruns': 2}),
        ('needle', 2, 'bad pose', {'nan_poses': 1, 'ignored': True}),
        ('pose input', DiagnosticStatus.STALE, 'no pose', {}, 'robot-1'),
    ])
    back = deserialize_message(serialize_message(msg), DiagnosticArray)
    assert back.header.stamp.sec == 3
    levels = [s.level for s in back.status]
    assert levels == [DiagnosticStatus.OK, DiagnosticStatus.WARN, DiagnosticStatus.ERROR,
                      DiagnosticStatus.STALE]
    assert [s.name for s in back.status] == ['engine', 'timing', 'needle', 'pose input']
    assert back.status[3].hardware_id == 'robot-1'
    values = {kv.key: kv.value for kv in back.status[0].values}
    assert values == {'step_time_ms': '1.23457', 'substeps': '4'}
    assert {kv.key: kv.value for kv in back.status[2].values}['ignored'] == 'true'


@pytest.mark.parametrize('level', ['FATAL', 4, -1, True, 1.0])
def test_diagnostic_bad_level_refused(level):
    with pytest.raises(ValueError, match=r'statuses\[0\]\.level'):
        cv.diagnostic_array_msg(0, [('x', level, '', {})])


def test_qos_to_dict_from_rclpy_profile():
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rclpy.duration import Duration
    profile = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         reliability=ReliabilityPolicy.RELIABLE,
                         deadline=Duration(seconds=2, nanoseconds=5))
    d = cv.qos_to_dict(profile)
    assert d['durability'] == 'transient_local' and d['reliability'] == 'reliable'
    assert d['history'] == 'keep_last' and d['depth'] == 1
    assert d['deadline_ns'] == 2_000_000_005


def test_a_figure_that_does_not_exist_is_never_written_as_nan():
    from tissue_sim_ros.ros.messages.conversions import diagnostic_array_msg
    msg = diagnostic_array_msg(0, [('x', 'OK', '', {'a': float('nan'), 'b': 1.5, 'c': float('inf')})])
    assert [kv.value for kv in msg.status[0].values] == ['not available', '1.5', 'not available']
