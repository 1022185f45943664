"""Messages of every node topic with values that depend on their index, recorded and checked."""

import shutil

import numpy as np
import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402

from tissue_sim_ros.io import mcap as ml  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402

T0 = 1_700_000_000_000_000_000  # ns
PERIOD = 20_000_000  # 50 Hz

WRENCH = 'geometry_msgs/msg/WrenchStamped'
CLOUD = 'sensor_msgs/msg/PointCloud2'
MESH = 'shape_msgs/msg/Mesh'
MARKER = 'visualization_msgs/msg/Marker'
DIAG = 'diagnostic_msgs/msg/DiagnosticArray'
POSE = 'geometry_msgs/msg/PoseStamped'

TOPICS = {
    'needle/wrench': (WRENCH, {'reliability': 'reliable', 'durability': 'volatile', 'depth': 10}),
    'tissue/nodes': (CLOUD, {'reliability': 'reliable', 'durability': 'volatile', 'depth': 2}),
    'tissue/surface': (MESH, {'reliability': 'reliable', 'durability': 'transient_local',
                              'depth': 1}),
    'tissue/marker': (MARKER, {'reliability': 'reliable', 'depth': 1}),
    '/diagnostics': (DIAG, {'reliability': 'reliable', 'depth': 10}),
    'needle/pose': (POSE, None),
}


def _pose(i):
    from geometry_msgs.msg import PoseStamped
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = cv.ns_to_stamp(T0 + i * PERIOD)
    msg.pose.position.z = -0.001 * i
    msg.pose.orientation.w = 1.0
    return msg


def _sample(topic, i, rng_seed=7):
    """The i-th message of a topic, with values that depend on i."""
    rng = np.random.default_rng(rng_seed + i)
    stamp = T0 + i * PERIOD
    positions = rng.uniform(-0.02, 0.02, (40, 3))
    triangles = np.arange(60).reshape(20, 3) % 40
    if topic == 'needle/wrench':
        return cv.wrench_msg([0.1 * i, -0.2, 1.5 + i], [0.0, 0.001 * i, 0.0], 'needle', stamp)
    if topic == 'tissue/nodes':
        return cv.point_cloud_msg(positions, positions * 1e-2, 'tissue', stamp)
    if topic == 'tissue/surface':
        return cv.surface_mesh_msg(positions, triangles)
    if topic == 'tissue/marker':
        return cv.surface_marker_msg(positions, triangles, 'tissue', stamp, max_triangles=8)
    if topic == '/diagnostics':
        return cv.diagnostic_array_msg(stamp, [('engine', i % 4, f'tick {i}', {'i': i})])
    return _pose(i)


def _record(path, n=5, **kwargs):
    """Record n messages per topic (log time T0 + k*PERIOD, topics interleaved); return them."""
    written = []
    meta = {'scene': 'mesh: cube\nyoung_modulus_pa: 3000\n', 'parameters': 'publish_rate_hz: 50'}
    with ml.McapRecorder(path, metadata=meta, **kwargs) as rec:
        for topic, (type_name, qos) in TOPICS.items():
            rec.add_topic(topic, type_name, qos)
        for i in range(n):
            for j, topic in enumerate(TOPICS):
                data = serialize_message(_sample(topic, i))
                log_time = T0 + i * PERIOD + j * 1000
                rec.write(topic, data, log_time, publish_time_ns=log_time - 500)
                written.append((topic, TOPICS[topic][0], log_time, data, i))
    return written


def _check_values(topic, msg, i):
    """Field values of a decoded message (rosbags or mcap_ros2 object) against _sample(i)."""
    ref = _sample(topic, i)
    if topic == 'needle/wrench':
        f = msg.wrench.force
        assert (f.x, f.y, f.z) == (ref.wrench.force.x, ref.wrench.force.y, ref.wrench.force.z)
        assert msg.wrench.torque.y == ref.wrench.torque.y
        assert msg.header.frame_id == 'needle'
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == \
            (ref.header.stamp.sec, ref.header.stamp.nanosec)
    elif topic == 'tissue/nodes':
        assert bytes(msg.data) == bytes(ref.data)
        assert [f.name for f in msg.fields] == ['x', 'y', 'z', 'ux', 'uy', 'uz']
        p, u = cv.point_cloud_arrays(msg)
        p_ref, u_ref = cv.point_cloud_arrays(ref)
        np.testing.assert_array_equal(p, p_ref)
        np.testing.assert_array_equal(u, u_ref)
    elif topic == 'tissue/surface':
        got = [(v.x, v.y, v.z) for v in msg.vertices]
        assert got == [(v.x, v.y, v.z) for v in ref.vertices]
        assert [list(t.vertex_indices) for t in msg.triangles] == \
            [t.vertex_indices.tolist() for t in ref.triangles]
    elif topic == 'tissue/marker':
        assert msg.type == 11 and len(msg.points) == len(ref.points) == 3 * 7
        assert [(p.x, p.y, p.z) for p in msg.points] == [(p.x, p.y, p.z) for p in ref.points]
    elif topic == '/diagnostics':
        status = msg.status[0]
        level = status.level
        level = level[0] if isinstance(level, (bytes, bytearray)) else int(level)
        assert level == i % 4
        assert status.message == f'tick {i}'
        assert [(kv.key, kv.value) for kv in status.values] == [('i', str(i))]
    else:
        assert msg.pose.position.z == -0.001 * i and msg.header.frame_id == 'world'


def _snapshot(path, dst):
    """What a hard kill would leave now: the bytes the OS holds for the file."""
    shutil.copyfile(path, dst)
    return dst
