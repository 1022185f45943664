"""The node in process: the node and a client in one process, each spun by its own executor
thread, talking through DDS on a private domain; straight descents published at their stamps."""

import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from std_srvs.srv import SetBool, Trigger  # noqa: E402

from support.ros_clients import (DOMAIN_ID, call_service, diag_values,  # noqa: E402
                                 subscribe_node_outputs, wait_until)
from tissue_sim_ros.ros import node as node_mod  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402
from tissue_sim_ros.ros.node_main import make_executor  # noqa: E402

NS = 1_000_000_000
DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # needle base +z along world -z

# the scene: the engine's own, the default liver sample on a coarse mesh (a few ms per tick)
COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


def make_scene():
    from tissue_sim_ros.engine.scene.scene import Scene
    return Scene.from_file(None, mesh=COARSE)


_SHARED = []


def shared_scene():
    """One scene for tests that never step it (parameter refusals)."""
    if not _SHARED:
        _SHARED.append(make_scene())
    return _SHARED[0]


class Harness:
    """The node and a client node, each with its own executor thread, on a private context."""

    def __init__(self, scene=None, slow_down=None, **params):
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=DOMAIN_ID)
        params.setdefault('prediction.workers', -1)     # no worker processes unless a test asks
        overrides = [Parameter(k, value=v) for k, v in params.items()]
        self.scene = scene if scene is not None else make_scene()
        self.node = node_mod.TissueSimNode(scene=self.scene, context=self.ctx, slow_down=slow_down,
                                           parameter_overrides=overrides)
        self.client = rclpy.create_node('test_client', context=self.ctx)
        self.received = {k: [] for k in ('wrench', 'nodes', 'surface', 'marker', 'diag', 'targets', 'log')}
        self._lock = threading.Lock()
        reliable = subscribe_node_outputs(self.client, self._keeper, rosout=True)
        self.pose_pub = self.client.create_publisher(PoseStamped, 'needle/pose', reliable)
        self.clock_pub = self.client.create_publisher(Clock, '/clock', reliable)
        self.reset_client = self.client.create_client(Trigger, '/tissue_sim/reset')
        self.pause_client = self.client.create_client(SetBool, '/tissue_sim/pause')
        self.published = []  # (stamp_ns, position, frame_id, kind) of every pose sent
        self._stops, self._threads = [None, None], [None, None]
        self._start(1, self.client)
        # the node's executor starts once every output is matched: the client gets every tick
        deadline = time.monotonic() + 10
        node = self.node
        pubs = [node.wrench_pub, node.nodes_pub, node.diagnostics_pub, node.marker_pub]
        while not (all(p.get_subscription_count() for p in pubs)
                   and self.pose_pub.get_subscription_count()):
            assert time.monotonic() < deadline, 'node and client did not discover each other'
            time.sleep(0.01)
        self._start(0, self.node)

    def _start(self, i, node):
        # the node on the executor its parameter names (the events executor by default)
        ex = (make_executor(node.config.executor, context=self.ctx) if node is self.node
              else SingleThreadedExecutor(context=self.ctx))
        ex.add_node(node)
        stop = threading.Event()
        t = threading.Thread(target=self._spin, args=(ex, stop), daemon=True)
        t.start()
        self._stops[i], self._threads[i] = stop, t

    def _keeper(self, key):
        def keep(msg):
            with self._lock:
                self.received[key].append((time.monotonic(), msg))
        return keep

    @staticmethod
    def _spin(executor, stop):
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    def stop_node(self, drain_s=0.3):
        """Stop the node's executor, close the node (its recording), let the client drain: every
        tick's wrench is waited for, then ``drain_s`` more for the other topics' last messages."""
        self._stops[0].set()
        self._threads[0].join(timeout=5)
        self.node.close()
        self.wait_until(lambda: len(self.get('wrench')), lambda n: n >= self.node.ticks,
                        what="every tick's wrench")
        time.sleep(drain_s)

    def get(self, key):
        with self._lock:
            return list(self.received[key])

    def wait_for(self, key, count, timeout=10.0):
        deadline = time.monotonic() + timeout
        while len(self.received[key]) < count:
            if time.monotonic() > deadline:
                raise AssertionError(f'{key}: {len(self.received[key])} messages after {timeout} s; '
                                     f'expected {count}')
            time.sleep(0.01)
        return self.get(key)

    def wait_matched(self, timeout=10.0):
        deadline = time.monotonic() + timeout
        while self.pose_pub.get_subscription_count() == 0 or not self.received['surface']:
            assert time.monotonic() < deadline, 'node and client did not discover each other'
            time.sleep(0.01)

    def now_ns(self):
        return self.client.get_clock().now().nanoseconds

    def publish_pose(self, position, stamp_ns, orientation=DOWN, frame_id='world', kind='good'):
        msg = PoseStamped()
        msg.header.frame_id = frame_id
        msg.header.stamp = TimeMsg(sec=int(stamp_ns // NS), nanosec=int(stamp_ns % NS))
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in position)
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = (float(c) for c in orientation)
        self.pose_pub.publish(msg)
        self.published.append((stamp_ns, np.array(position, dtype=float), frame_id, kind))

    def call(self, client, request, timeout=5.0):
        return call_service(client, request, timeout)

    wait_until = staticmethod(wait_until)

    def diagnostics_now(self):
        """Ask the node for diagnostics now (on its executor thread's terms: via the timer
        callback would wait up to a period; the statuses are computed from counters only)."""
        before = len(self.received['diag'])
        self.node.publish_diagnostics()
        msgs = self.wait_for('diag', before + 1)
        return diag_values(msgs[-1][1])

    def close(self):
        for stop, t in zip(self._stops, self._threads):
            stop.set()
            t.join(timeout=5)
        self.node.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.ctx)


def straight_descent(start, speed, duration, rate_hz, t0_ns, lead_s=0.05):
    """(stamps_ns, positions) of a straight descent along -z, stamped lead_s in the future."""
    n = int(duration * rate_hz) + 1
    t = np.arange(n) / rate_hz
    positions = np.array(start)[None, :] + np.outer(speed * t, [0.0, 0.0, -1.0])
    stamps = t0_ns + int(lead_s * NS) + (t * NS).astype(np.int64)
    return stamps, positions


def publish_at_stamps(h, stamps, positions, lead_s=0.05):
    """Publish each pose lead_s before its stamp (wall clock = node clock here)."""
    for s, p in zip(stamps, positions):
        delay = (s - int(lead_s * NS) - h.now_ns()) / NS
        if delay > 0:
            time.sleep(delay)
        h.publish_pose(p, int(s))


def node_log(path):
    """(wrench stamps ns, wrench values (k, 6), engine traces) from a node's MCAP log."""
    from tissue_sim_ros.io.mcap import read_log
    from tissue_sim_ros.ros.loop.trace import decode
    stamps, values, traces = [], [], []
    for m in read_log(path, topics=['/needle/wrench', '/tissue_sim/engine_trace']):
        if m.topic == '/needle/wrench':
            f, t = m.message.wrench.force, m.message.wrench.torque
            stamps.append(cv.stamp_to_ns(m.message.header.stamp))
            values.append([f.x, f.y, f.z, t.x, t.y, t.z])
        else:
            traces.append(decode(m.message.data))
    return np.array(stamps, dtype=np.int64), np.array(values), traces
