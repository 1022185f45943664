"""Received poses as bytes (ros/loop/pose_receiver.py): a malformed payload is skipped and counted."""

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from geometry_msgs.msg import PoseStamped  # noqa: E402


@pytest.mark.parametrize('payload', [b'\x00', bytes(range(7)), bytes(np.random.default_rng(3).integers(0, 256, 64, dtype=np.uint8)),
                                     b'\x00\x01\x00\x00' + b'\xff' * 40, None])
def test_a_malformed_pose_payload_is_skipped_counted_and_the_log_stays_readable(harness, tmp_path, payload):
    """One payload that is not a PoseStamped (random bytes, a CDR header and garbage, a valid
    message cut short) killed the node (an RMWError from deserialize_message) and then the log's
    own reader. Now it is counted as malformed, the node ticks on, and the log reads back."""
    from rclpy.serialization import serialize_message
    from tissue_sim_ros.io import mcap as ml
    h = harness(**{'recording.directory': str(tmp_path), 'diagnostics_rate_hz': 0.01})
    if payload is None:  # a valid message cut short
        good = PoseStamped()
        good.header.frame_id = 'world'
        payload = serialize_message(good)[:30]
    h.publish_pose(h.scene.needle_pose[0], h.now_ns())
    h.pose_pub.publish(payload)
    h.publish_pose(h.scene.needle_pose[0], h.now_ns())
    before = len(h.get('wrench'))
    h.wait_for('wrench', before + 10)
    values = h.diagnostics_now()['tissue_sim: input'][2]
    assert int(values['bad_input.malformed']) == 1
    assert int(values['poses_accepted']) == 2
    path = h.node.recording_path
    h.node.close()
    poses = list(ml.read_log(path, topics=['/needle/pose']))
    assert len(poses) == 2  # the undecodable one is skipped, the good ones read
