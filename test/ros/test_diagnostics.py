"""The node's rolling statistics and its /diagnostics values (ros/diagnostics.py), without ROS:
a ring's percentiles are numpy's over the last n values, missed ticks follow the stated rule,
and the input status says what a PoseInput counted. Truth: numpy, the rule's arithmetic, and the
poses offered here."""
import time

import numpy as np
import pytest

from tissue_sim_ros.ros.diagnostics import NodeStats, Ring, _input_status
from tissue_sim_ros.ros.loop.pose_input import PoseInput, PoseInputLimits
import math
import os
import subprocess
import sys
import textwrap

NS = 1_000_000_000
DOWN = [1.0, 0.0, 0.0, 0.0]


def test_a_ring_keeps_the_last_n_values_and_their_percentiles():
    ring = Ring(10)
    assert ring.percentile(50) is None                # nothing yet: no figure, not NaN
    values = np.random.default_rng(5).normal(size=25)
    for k, value in enumerate(values, 1):
        ring.add(value)
        last = values[max(0, k - 10):k]
        assert sorted(ring.array()) == sorted(last)
        assert ring.percentile(99) == pytest.approx(np.percentile(last, 99), rel=1e-15)


def test_a_gap_of_more_than_one_and_a_half_periods_is_missed_ticks_and_input_caused_them():
    stats = NodeStats(50.0)                                  # 20 ms ticks
    for wall in (0.0, 0.02, 0.04, 0.069):                     # a 29 ms gap: within 1.5 periods
        stats.tick_started(wall)
    assert stats.missed_ticks == 0
    stats.tick_started(0.129)                                 # 60 ms: two ticks missed
    stats.input_done(0.004)
    stats.input_done(0.008)                                   # 12 ms of pose callbacks...
    stats.tick_started(0.209)                                 # ...in an 80 ms gap: three more
    assert (stats.missed_ticks, stats.missed_for_input) == (5, 3)
    np.testing.assert_allclose(stats.rings['tick_interval_s'].array(), [0.02, 0.02, 0.029, 0.06, 0.08])
    np.testing.assert_allclose(stats.rings['input_s'].array(), [0, 0, 0, 0, 0, 0.012])


def test_the_input_status_counts_what_the_pose_input_judged():
    stats = NodeStats(50.0)
    stats.window = {'bad0': 0, 'wall0': time.perf_counter()}
    poses = PoseInput(PoseInputLimits(expected_frame_id='world', stale_after_s=0.5))
    name, level, message, values = _input_status('tissue_sim', NS, stats, poses)
    assert (name, level, values['poses_received']) == ('tissue_sim: input', 'OK', 0) and 'no pose yet' in message
    poses.offer([0.0, 0.0, 0.16], DOWN, 'world', NS, NS)
    poses.offer([0.0, 0.0, 0.16], DOWN, 'map', NS + 10_000_000, NS + 10_000_000)
    poses.offer([np.nan, 0.0, 0.16], DOWN, 'world', NS + 20_000_000, NS + 20_000_000)
    name, level, message, values = _input_status('tissue_sim', NS + 30_000_000, stats, poses)
    assert (level, values['poses_received'], values['poses_accepted']) == ('WARN', 3, 1)
    assert (values['bad_input.wrong_frame'], values['bad_input.non_finite'], values['bad_input.jump']) == (1, 1, 0)
    assert message.startswith('2 bad poses in the last')
    assert values['last_pose_age_s'] == pytest.approx(0.03) and not values['stale']
    stats.window['bad0'] = poses.bad_total                    # a new window: no new bad pose
    level, message = _input_status('tissue_sim', 2 * NS, stats, poses)[1:3]
    assert level == 'WARN' and message.startswith('no pose for 1 s')


def _numbers_or_words(values):
    """{key: the value as a float, or the text when it is not a number}."""
    out = {}
    for key, value in values.items():
        try:
            out[key] = float(value)
        except ValueError:
            out[key] = value
    return out


def test_no_diagnostic_value_is_nan_before_the_first_pose(harness):
    h = harness(**{'prediction.workers': 1})
    statuses = h.diagnostics_now()
    assert {'tissue_sim: engine', 'tissue_sim: input'} <= set(statuses)
    for name, (_, _, values) in statuses.items():
        for key, value in _numbers_or_words(values).items():
            assert not (isinstance(value, float) and math.isnan(value)), f'{name} {key} = {values[key]!r}'
            assert str(values[key]).lower() not in ('nan', '-nan', 'inf', '-inf'), f'{name} {key}'
    inputs = statuses['tissue_sim: input'][2]
    assert inputs['latency_ms_p50'] == inputs['latency_ms_p99'] == inputs['last_pose_age_s'] == 'none yet'
    if 'tissue_sim: predictions' in statuses:
        assert statuses['tissue_sim: predictions'][2]['real_time_factor_median'] == 'none yet'


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
