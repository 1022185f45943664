"""Delivery stalls of the pose stream (ros.loop.pose_input): a burst of poses that arrive long
after their stamps is told apart from a publisher that paused; an empty payload from another
process stalls a reliable subscription, and the node reports it in /diagnostics."""
import os
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest

from tissue_sim_ros.ros.loop.pose_input import PoseInput, PoseInputLimits

MS = 1_000_000
Q = [0.0, 0.0, 0.0, 1.0]


def _feed(pose_input, stamps_ms, receipts_ms):
    for stamp, receipt in zip(stamps_ms, receipts_ms):
        pose_input.offer([0.0, 0.0, 0.1], Q, 'world', int(stamp * MS), int(receipt * MS))


def test_a_late_burst_is_a_stall_and_a_pause_is_not():
    pose_input = PoseInput(PoseInputLimits(stale_after_s=0.5))
    stamps = np.arange(0, 1000, 10.0)
    _feed(pose_input, stamps, stamps + 1.0)                       # on time
    assert pose_input.delivery_stalls == 0
    _feed(pose_input, stamps + 3000, stamps + 3001)               # a 2 s pause, then on time again
    assert pose_input.delivery_stalls == 0 and pose_input.last_stall_ns is None
    held = np.arange(4000, 5000, 10.0)                            # stamped on time, held up a second
    _feed(pose_input, held, np.full(held.size, 5020.0))
    assert pose_input.delivery_stalls == 1 and pose_input.last_stall_ns == 5020 * MS
    assert pose_input.delivery_stall_max_s == pytest.approx(1.02)
    _feed(pose_input, stamps + 6000, stamps + 6001)
    _feed(pose_input, [7100.0, 7110.0], [7800.0, 7800.0])        # a second stall
    assert pose_input.delivery_stalls == 2


_PUBLISHER = textwrap.dedent('''
    import sys, time
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.serialization import serialize_message
    rclpy.init()
    node = rclpy.create_node('robot')
    pub = node.create_publisher(PoseStamped, 'needle/pose', QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE))
    z = float(sys.argv[1])
    deadline = time.monotonic() + 120
    while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    time.sleep(0.5)
    for i in range(300):
        if i == 100:
            pub.publish(b'')          # an empty payload: a buggy bridge
        msg = PoseStamped()
        msg.header.frame_id = 'world'
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.pose.position.z = z
        msg.pose.orientation.x = 1.0
        msg.pose.orientation.w = 0.0
        pub.publish(serialize_message(msg))
        time.sleep(0.01)
    time.sleep(1.0)
''')


def test_the_node_reports_a_stall_after_an_empty_payload(tmp_path):
    pytest.importorskip('rclpy')
    from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context, private_ros_env
    domain = 160 + os.getpid() % 30
    with NodeProcess(['diagnostics_rate_hz:=2.0'], tmp_path / 'node.log', domain) as node, \
            client_context(domain) as context:
        import rclpy
        import rclpy.executors
        from diagnostic_msgs.msg import DiagnosticArray
        client = rclpy.create_node('watcher', context=context)
        statuses = {}
        client.create_subscription(DiagnosticArray, '/diagnostics',
                                   lambda msg: statuses.update({s.name: {kv.key: kv.value for kv in s.values}
                                                                for s in msg.status}), 10)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(client)
        deadline = time.monotonic() + 300                 # the node up (a first start compiles)
        while 'tissue_sim: input' not in statuses:
            executor.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline and node.returncode is None, node.last_log_line()
        robot = subprocess.Popen([sys.executable, '-c', _PUBLISHER, '0.159'], env=private_ros_env(domain))
        reported = lambda: int(statuses['tissue_sim: input'].get('delivery_stalls', 0)) > 0  # noqa: E731
        while robot.poll() is None and not reported():
            executor.spin_once(timeout_sec=0.05)
        deadline = time.monotonic() + 10.0
        while not reported():
            executor.spin_once(timeout_sec=0.05)
            assert time.monotonic() < deadline, f'no stall reported: {statuses["tissue_sim: input"]}'
        robot.wait(timeout=30)
        node.stop()
    values = statuses['tissue_sim: input']
    assert int(values['delivery_stalls']) >= 1 and float(values['delivery_stall_max_s']) > 0.5
