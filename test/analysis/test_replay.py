"""tissue-sim replay (analysis/replay.py): a node log run through the engine again gives every
recorded wrench, and its motion drives another model."""

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from support.ros_harness import node_log, publish_at_stamps, straight_descent  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


def test_tissue_sim_replay_reproduces_a_node_log_and_drives_another_model(harness, tmp_path):
    """`tissue-sim replay LOG`: with the log's own scene (from its metadata: the scene given to
    the node in code here, not a file) every recorded wrench again, same stamps, to 1e-9 N; the
    output log holds the node's topics and types (rosbags reads it). With --set the same motion
    drives another model: the same ticks, a different but finite wrench."""
    from rosbags.highlevel import AnyReader
    from tissue_sim_ros.analysis import replay
    h = harness(**{'recording.directory': str(tmp_path / 'logs')})
    start = h.scene.needle_pose[0]
    stamps, positions = straight_descent(start, 0.02, 1.2, 100.0, h.now_ns())
    publish_at_stamps(h, stamps, positions)
    h.stop_node()
    log = h.node.recording_path
    recorded = np.array([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z, w.wrench.torque.x,
                          w.wrench.torque.y, w.wrench.torque.z] for _, w in h.get('wrench')])
    summary = replay.main(log, tmp_path / 'exact')
    assert summary['mode'] == 'exact' and summary['ticks'] >= len(recorded)
    assert summary['max_abs_difference_n'] <= 1e-9 and np.abs(recorded).max() > 0.05
    with AnyReader([tmp_path / 'exact' / 'replay.mcap']) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == {'/needle/wrench': 'geometry_msgs/msg/WrenchStamped', '/needle/shape': 'nav_msgs/msg/Path',
                         '/tissue/nodes': 'sensor_msgs/msg/PointCloud2',
                         '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray'}
        wrench_conn = [c for c in reader.connections if c.topic == '/needle/wrench']
        replayed = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=wrench_conn)]
        shape_conn = [c for c in reader.connections if c.topic == '/needle/shape']
        shapes = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=shape_conn)]
    # the shape's last pose is the tip replay.csv gives; the rigid needle's tip went straight down
    exact_rows = np.loadtxt(tmp_path / 'exact' / 'replay.csv', delimiter=',', skiprows=1)
    tips = np.array([[p.x, p.y, p.z] for p in (s.poses[-1].pose.position for s in shapes)])
    np.testing.assert_allclose(tips, exact_rows[:, 13:16], rtol=1e-8, atol=1e-12)       # (9 digits)
    assert np.all(exact_rows[:, 16] == 0.0) and np.ptp(tips[:, :2], axis=0).max() < 1e-12
    assert tips[0, 2] - tips[-1, 2] > 0.01
    logged_stamps, logged, _ = node_log(log)
    np.testing.assert_array_equal([cv.stamp_to_ns(w.header.stamp) for w in replayed], logged_stamps)
    np.testing.assert_allclose([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z] for w in replayed],
                               logged[:, :3], rtol=0, atol=1e-9)
    other = replay.main(log, tmp_path / 'linear', sets=['model.geometric=false', 'model.physical.law=none'])
    assert other['mode'] == 'motion' and other['ticks'] == summary['ticks']
    rows = np.loadtxt(tmp_path / 'linear' / 'replay.csv', delimiter=',', skiprows=1)
    assert np.isfinite(rows).all() and 1e-4 < other['max_abs_difference_n'] < 20.0
    for name in ('replay.png', 'replay.json', 'replay.md'):
        assert (tmp_path / 'linear' / name).stat().st_size > 100
