"""A node whose scene has several needles: needle/<name>/pose in, needle/<name>/wrench out.

Truths: which needle was driven (each wrench topic carries its own needle's load and the other
stays at zero while it is out of the tissue), the tick count (every needle's wrench every tick),
the engine's own run of the same poses (the driven needle's wrench), the pose rules per needle.
"""
import os
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from geometry_msgs.msg import PoseStamped, WrenchStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from tissue_sim_ros.engine.scene.scene import Scene  # noqa: E402
from tissue_sim_ros.ros.node import TissueSimNode, needle_topics  # noqa: E402
from tissue_sim_ros.ros.node_main import make_executor  # noqa: E402

DOMAIN_ID = 10 + os.getpid() % 40
MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
NEEDLES = [{'name': 'biopsy', 'initial_position_m': [0.0, 0.0, 0.159]},
           {'name': 'fixation', 'initial_position_m': [0.006, 0.0, 0.159]}]
DOWN = (1.0, 0.0, 0.0, 0.0)
NS = 1_000_000_000


def test_one_needle_keeps_todays_topics_and_several_get_their_own():
    assert needle_topics(['needle']) == [('needle/pose', 'needle/wrench')]
    assert needle_topics(['a', 'b']) == [('needle/a/pose', 'needle/a/wrench'), ('needle/b/pose', 'needle/b/wrench')]


@pytest.fixture
def two_needle_node(monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    node = TissueSimNode(scene=Scene.from_file(None, mesh=MESH, needles=NEEDLES), context=ctx,
                         parameter_overrides=[Parameter('prediction.workers', value=-1)])
    client = rclpy.create_node('needles_client', context=ctx)
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    received = {name: [] for name in ('biopsy', 'fixation')}
    for name in received:
        client.create_subscription(WrenchStamped, f'needle/{name}/wrench', received[name].append, reliable)
    publishers = {name: client.create_publisher(PoseStamped, f'needle/{name}/pose', reliable) for name in received}
    stop = threading.Event()
    threads = []
    for n, executor in ((node, make_executor(node.config.executor, context=ctx)),
                        (client, SingleThreadedExecutor(context=ctx))):
        executor.add_node(n)
        thread = threading.Thread(target=lambda e=executor: [e.spin_once(timeout_sec=0.05)
                                                             for _ in iter(stop.is_set, True)], daemon=True)
        thread.start()
        threads.append(thread)
    deadline = time.monotonic() + 10
    while not all(p.get_subscription_count() for p in publishers.values()) or \
            not all(p.get_subscription_count() for p in node.wrench_pubs):
        assert time.monotonic() < deadline, 'node and client did not match'
        time.sleep(0.01)
    yield node, client, publishers, received
    stop.set()
    for thread in threads:
        thread.join(timeout=5)
    node.destroy_node()
    client.destroy_node()
    rclpy.shutdown(context=ctx)


def _pose(position, stamp_ns):
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = TimeMsg(sec=int(stamp_ns // NS), nanosec=int(stamp_ns % NS))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in position)
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = DOWN
    return msg


def test_each_needle_is_driven_by_its_topic_and_reports_on_its_own(two_needle_node):
    node, client, publishers, received = two_needle_node
    start = np.array(NEEDLES[1]['initial_position_m'])
    speed, rate_hz, seconds = 0.01, 100.0, 1.6          # 16 mm: the tip 7 mm into the tissue
    t0 = client.get_clock().now().nanoseconds
    ticks0 = node.ticks
    for k in range(int(seconds * rate_hz) + 1):
        target = t0 + int(k / rate_hz * NS)
        while client.get_clock().now().nanoseconds < target:
            time.sleep(0.0005)
        publishers['fixation'].publish(_pose(start + [0.0, 0.0, -speed * k / rate_hz], target))
    time.sleep(0.5)
    ticks = node.ticks - ticks0
    fixation = np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for m in received['fixation']])
    biopsy = np.array([[m.wrench.force.x, m.wrench.force.y, m.wrench.force.z] for m in received['biopsy']])
    # every needle's wrench every tick (the client started listening before the node's first one)
    assert abs(len(fixation) - len(biopsy)) <= 1 and len(fixation) >= ticks
    assert np.abs(fixation[-5:, 2]).min() > 0.2, 'the driven needle should carry the load'
    np.testing.assert_array_equal(biopsy, 0.0)          # the other one never touched the tissue
    assert received['fixation'][-1].header.frame_id == 'needle_fixation'
    assert [n.phase for n in node.scene.needles] == ['approach', 'contact']
    # a jump on one needle's topic is refused for that needle alone, counted in its own status
    publishers['biopsy'].publish(_pose([0.0, 0.0, 0.12], client.get_clock().now().nanoseconds))
    time.sleep(0.3)
    statuses = {s[0]: s[3] for s in node.diagnostics_statuses(client.get_clock().now().nanoseconds)}
    assert statuses['tissue_sim: input biopsy']['bad_input.jump'] == 1
    assert statuses['tissue_sim: input fixation']['bad_input.jump'] == 0
    assert statuses['tissue_sim: input fixation']['poses_accepted'] == int(seconds * rate_hz) + 1
    assert node.get_parameter('needles.names').value == ['biopsy', 'fixation']
