"""Registration (ros/registration.py): the tissue's pose in the robot's frame and the needle's start
where the robot is (~/register_needle, registration.needle_at_first_pose).

Truths: the poses the test itself sent, the replay command on the node's log (bit for bit), the
values given to the registration.
"""

import time

import numpy as np
import pytest

from support.ros_graph import NS
from tissue_sim_ros.errors import PoseError
from tissue_sim_ros.ros.registration import Registration, needle_start_rule


def test_registration_takes_a_pose_and_refuses_bad_ones_by_field():
    registration = Registration('world', '', np.zeros(3), np.array([0, 0, 0, 1.0]))
    assert registration.transform is None
    with pytest.raises(PoseError, match='pose.header.frame_id'):
        registration.set_tissue_pose('', (0, 0, 0), (0, 0, 0, 1))
    with pytest.raises(PoseError, match='pose.pose.orientation'):
        registration.set_tissue_pose('base_link', (0, 0, 0), (0, 0, 0, 2))
    with pytest.raises(PoseError, match='pose.pose.position'):
        registration.set_tissue_pose('base_link', (np.nan, 0, 0), (0, 0, 0, 1))
    text = registration.set_tissue_pose('base_link', (0.4, 0, 0), (0, 0, 0.7071068, 0.7071068))
    parent, position, orientation = registration.transform
    assert parent == 'base_link' and position.tolist() == [0.4, 0, 0] and 'base_link' in text
    assert abs(np.linalg.norm(orientation) - 1.0) < 1e-15
    with pytest.raises(PoseError, match='no needle pose received yet'):
        needle_start_rule(None, 'world')
    p, q = needle_start_rule((1, np.array([0.0, 0, 0.2]), np.array([1.0, 0, 0, 0])), 'world')
    assert p.tolist() == [0, 0, 0.2] and q.tolist() == [1, 0, 0, 0]


def test_a_robot_80_mm_away_is_refused_until_registered_and_the_replay_places_it_again(graph, tmp_path):
    from std_srvs.srv import Trigger

    from tissue_sim_ros.analysis import replay

    g = graph(**{'recording.directory': str(tmp_path), 'input.stale_after_s': 0.2})
    initial = g.scene.needle_pose[0]
    away = initial + [0.0, 0.0, 0.08]
    for _ in range(30):  # 0.3 s of the robot holding still, 80 mm away
        g.publish_pose(away, time.time_ns())
        time.sleep(0.01)
    g.wait(lambda: g.node.input.counts['jump'] >= 25, 'the jumps counted')
    assert g.node.input.accepted == 0 and np.allclose(g.scene.needle_pose[0], initial)  # refused, as before
    answer = g.call(g.register, Trigger.Request())
    assert answer.success, answer.message
    np.testing.assert_allclose(g.scene.needle_pose[0], away)
    # from there down at 60 mm/s to 6 mm past the surface (the scene's gap is under the initial pose)
    depth = 0.08 + g.scene.start_gap_m + 0.006
    t0 = time.time_ns()
    for k in range(int(depth / 0.06 * 100) + 1):
        g.publish_pose(away + [0.0, 0.0, -0.06 * k / 100], t0 + k * 10_000_000)
        time.sleep(max(0.0, (t0 + k * 10_000_000 - time.time_ns()) / NS))
    g.wait(lambda: g.scene.tip_depth > 0.004, 'the tip in the tissue', 10)
    reset = g.call(g.client.create_client(Trigger, '/tissue_sim/reset'), Trigger.Request())
    assert reset.success and np.allclose(
        g.scene.needle_pose[0], away
    )  # the registered start is the start now
    g.node.close()
    summary = replay.main(g.node.recording_path, tmp_path / 'replay')
    assert summary['mode'] == 'exact' and summary['max_abs_difference_n'] == 0.0  # bit for bit
    assert summary['ticks'] > 50


def test_needle_at_first_pose_and_readiness(graph):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import Bool

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)
    g = graph(**{'registration.needle_at_first_pose': True})
    late = []
    g.client.create_subscription(Bool, '/tissue_sim/ready', late.append, latched)
    g.wait(lambda: late, 'the latched ~/ready')
    assert late[-1].data is True
    status = {name: values for name, _, _, values in g.node.diagnostics_statuses(time.time_ns())}
    assert status['tissue_sim: engine']['ready'] == 'ready'
    away = g.scene.needle_pose[0] + [0.03, -0.01, 0.08]
    g.publish_pose(away, time.time_ns())
    g.wait(lambda: np.allclose(g.scene.needle_pose[0], away), 'the needle at the first pose')
    assert g.node.input.bad_total == 0
