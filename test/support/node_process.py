"""The node as a separate process (its console script) and a client in this process: start and
stop, a private ROS domain each, the log read back against what the client received."""

import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402

from support.paths import ROOT  # noqa: E402
from support.ros_clients import call_service, diag_values, subscribe_node_outputs, wait_until  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402

BIN = Path(sys.executable).parent
NS = 1_000_000_000
TOPIC_TYPES = {
    '/needle/wrench': 'geometry_msgs/msg/WrenchStamped',
    '/needle/shape': 'nav_msgs/msg/Path',
    '/tissue/nodes': 'sensor_msgs/msg/PointCloud2',
    '/tissue/surface': 'shape_msgs/msg/Mesh',
    '/tissue/marker': 'visualization_msgs/msg/Marker',
    '/diagnostics': 'diagnostic_msgs/msg/DiagnosticArray',
    '/needle/pose': 'geometry_msgs/msg/PoseStamped',
    '/tissue_sim/reset/_service_event': 'std_srvs/srv/Trigger_Event',   # channels from the start,
    '/tissue_sim/pause/_service_event': 'std_srvs/srv/SetBool_Event',   # messages per call
    '/tissue_sim/engine_trace': 'std_msgs/msg/Float64MultiArray',        # recorded, one per tick
    '/plan/candidate': 'nav_msgs/msg/Path',                             # channels from the start,
    '/plan/prediction': 'trajectory_msgs/msg/JointTrajectory',          # messages per request
    '/tf': 'tf2_msgs/msg/TFMessage', '/tf_static': 'tf2_msgs/msg/TFMessage',     # TF out
    '/tissue_sim/ready': 'std_msgs/msg/Bool',
    '/tissue_sim/set_tissue_pose/_service_event': 'tissue_sim_msgs/srv/SetTissuePose_Event',
    '/tissue_sim/register_needle/_service_event': 'std_srvs/srv/Trigger_Event',
}
_DOMAINS = iter(range(110 + os.getpid() % 40 * 2, 232))
SCENE_OVERRIDE = os.environ.get('TISSUE_SIM_TEST_SCENE') or None


def ros_env(domain_id):
    env = dict(os.environ)
    env.update(ROS_DOMAIN_ID=str(domain_id), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               PYTHONUNBUFFERED='1')
    return env


def start_node(tmp_path, domain_id, scene, *params):
    args = [str(BIN / 'tissue_sim_node'), '--ros-args', '--params-file',
            str(ROOT / 'config' / 'tissue_sim.yaml'), '-p', f'scene_file:={scene}']
    for p in params:
        args += ['-p', p]
    log = open(tmp_path / f'node_{domain_id}.log', 'w')  # noqa: SIM115
    proc = subprocess.Popen(args, env=ros_env(domain_id), stdout=log, stderr=subprocess.STDOUT)
    proc.log_path = tmp_path / f'node_{domain_id}.log'
    return proc


def stop_node(proc, sig, timeout=20):
    proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        raise


class Client:
    """Subscribes to every output, publishes poses, calls the services; its own context."""

    def __init__(self, domain_id):
        self._env_before = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
        os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'  # read when the context starts
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=domain_id)
        self.node = rclpy.create_node('test_process_client', context=self.ctx)
        self.received = {k: [] for k in ('wrench', 'nodes', 'surface', 'marker', 'diag', 'targets')}
        self.lock = threading.Lock()
        reliable = subscribe_node_outputs(self.node, self._keeper)
        self.pose_pub = self.node.create_publisher(PoseStamped, 'needle/pose', reliable)
        self.reset_client = self.node.create_client(Trigger, '/tissue_sim/reset')
        self.pause_client = self.node.create_client(SetBool, '/tissue_sim/pause')
        self.published = 0
        self.executor = SingleThreadedExecutor(context=self.ctx)
        self.executor.add_node(self.node)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _keeper(self, key):
        def keep(msg):
            t = time.monotonic()
            with self.lock:
                self.received[key].append((t, msg))
        return keep

    def _spin(self):
        while not self.stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def get(self, key):
        with self.lock:
            return list(self.received[key])

    def wait_ready(self, proc, timeout=60):
        deadline = time.monotonic() + timeout
        while not (self.get('surface') and self.pose_pub.get_subscription_count()):
            if proc.poll() is not None:
                raise AssertionError(f'node exited with {proc.returncode}:\n'
                                     f'{proc.log_path.read_text()[-3000:]}')
            assert time.monotonic() < deadline, 'the node did not come up'
            time.sleep(0.02)

    def wait_for(self, key, since, count, timeout=10.0):
        """Wait until `count` messages on `key` arrived after the first `since`; the new ones.

        The windows below are counted in messages, not wall time: on a loaded 2-core CI runner a
        fixed sleep caught 11 wrenches where 25 were due, and the rate has its own test."""
        deadline = time.monotonic() + timeout
        while len(self.get(key)) < since + count:
            assert time.monotonic() < deadline, f'{len(self.get(key)) - since} of {count} {key}'
            time.sleep(0.02)
        return self.get(key)[since:]

    wait_until = staticmethod(wait_until)

    def poses_judged(self, timeout=10.0):
        """The node's diagnostics once it has judged every pose this client sent."""
        return self.wait_until(self.next_diagnostics, lambda d: int(d['tissue_sim: input'][2]['poses_received'])
                               >= self.published, timeout, 'every pose sent judged')

    def now_ns(self):
        return self.node.get_clock().now().nanoseconds

    def pose(self, position, orientation, stamp_ns=None, frame_id='world'):
        msg = PoseStamped()
        stamp = self.now_ns() if stamp_ns is None else int(stamp_ns)
        msg.header.stamp = TimeMsg(sec=stamp // NS, nanosec=stamp % NS)
        msg.header.frame_id = frame_id
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in position)
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = (float(c) for c in orientation)
        self.pose_pub.publish(msg)
        self.published += 1

    def call(self, client, request, timeout=10.0):
        return call_service(client, request, timeout)

    def next_diagnostics(self, timeout=3.0):
        """The first /diagnostics message received from now on, as {name: (level, msg, values)}."""
        n = len(self.get('diag'))
        deadline = time.monotonic() + timeout
        while len(self.get('diag')) <= n:
            assert time.monotonic() < deadline, 'no diagnostics'
            time.sleep(0.02)
        return diag_values(self.get('diag')[n][1])

    def close(self):
        self.stop.set()
        self.thread.join(timeout=10)
        # destroying the node under a spinning executor crashed the test process once (SIGSEGV in
        # rcl): the spinner must have stopped, and the executor lets go of the node first
        assert not self.thread.is_alive(), 'the client executor did not stop spinning'
        self.executor.shutdown(timeout_sec=1.0)
        self.node.destroy_node()
        rclpy.shutdown(context=self.ctx)
        if self._env_before is None:
            os.environ.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
        else:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = self._env_before


def wrench_array(items):
    return np.array([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z,
                      w.wrench.torque.x, w.wrench.torque.y, w.wrench.torque.z] for _, w in items])


def play(client, times, positions, orientation):
    t0 = time.monotonic()
    for t, p in zip(times, positions):
        delay = t0 + t - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        client.pose(p, orientation)


_STAMPED = {'/needle/wrench': 'wrench', '/tissue/nodes': 'nodes', '/tissue/marker': 'marker',
            '/diagnostics': 'diag'}


def wait_for_the_log(client, logs, timeout=10.0):
    """After the node exited: wait until ``client`` holds the last message of each stamped topic of
    the node's log in the folder ``logs`` (what was still on its way when the node stopped)."""
    from tissue_sim_ros.io import mcap as ml
    paths = sorted(Path(logs).glob('*.mcap'))
    if len(paths) != 1:
        return                                           # the tests say what is wrong
    last = {}
    for m in ml.read_log(paths[0], topics=list(_STAMPED), allow_truncated=True):
        last[_STAMPED[m.topic]] = cv.stamp_to_ns(m.message.header.stamp)

    def newest():
        return {key: cv.stamp_to_ns(client.get(key)[-1][1].header.stamp) if client.get(key) else None
                for key in last}
    client.wait_until(newest, lambda got: all(got[k] is not None and got[k] >= s for k, s in last.items()),
                      timeout, 'the messages the log ends with')


def check_log_against_received(path, received, published_poses, reset_calls=0, pause_calls=0):
    """The log read by rosbags holds exactly what the client received, stamp for stamp.

    The node publishes from its first tick, before the client has discovered it: messages
    stamped before the first one the client received are in the log but not in the client's
    lists, so the comparison starts there. The surface (transient local) and the poses (sent
    after matching) are compared whole. Returns rosbags' count per topic.
    """
    from rosbags.highlevel import AnyReader
    with AnyReader([path]) as reader:
        assert {c.topic: c.msgtype for c in reader.connections} == TOPIC_TYPES
        counts = {c.topic: c.msgcount for c in reader.connections}
        for topic, key in _STAMPED.items():
            conn = [c for c in reader.connections if c.topic == topic]
            logged = [cv.stamp_to_ns(reader.deserialize(raw, c.msgtype).header.stamp)
                      for c, _, raw in reader.messages(connections=conn)]
            got = [cv.stamp_to_ns(m.header.stamp) for _, m in received[key]]
            assert got, topic
            assert [s for s in logged if s >= got[0]] == got, topic
    assert counts['/tissue_sim/engine_trace'] == counts['/needle/wrench']
    assert counts['/tissue/surface'] == len(received['surface'])
    assert counts['/needle/pose'] == published_poses
    # two events per service call: request received, response sent
    assert counts['/tissue_sim/reset/_service_event'] == 2 * reset_calls
    assert counts['/tissue_sim/pause/_service_event'] == 2 * pause_calls
    return counts
