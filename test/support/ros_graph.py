"""The node in a robot's ROS graph, in process (the node and a client, each spun by its own executor
thread, on this process's private domain); the robot as an independent TF broadcaster process; the
node's log and its engine trace replayed with other poses. (rclpy is imported where it is needed.)"""

import textwrap
import threading
import time

import numpy as np
from scipy.spatial.transform import Rotation

from support.ros_clients import DOMAIN_ID

NS = 1_000_000_000
DOWN = np.array([1.0, 0.0, 0.0, 0.0])
COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}
#: the tissue registered 0.4 m from the robot's base and rotated; the needle 150 mm along tool0
REGISTRATION = (
    [0.4, -0.05, 0.02],
    Rotation.from_euler('zyx', [35.0, 8.0, -4.0], degrees=True).as_quat().tolist(),
)
OFFSET_M = 0.15


def make_scene():
    from tissue_sim_ros.engine.scene.scene import Scene

    return Scene.from_file(None, mesh=COARSE)


class Graph:
    """The node and a client node in one process, each spun by its own executor thread."""

    def __init__(self, **params):
        import rclpy
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.parameter import Parameter
        from rclpy.qos import QoSProfile, ReliabilityPolicy
        from std_srvs.srv import Trigger

        from tissue_sim_ros.ros import node as node_mod
        from tissue_sim_ros.ros.node_main import make_executor

        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.ctx = rclpy.Context()
        rclpy.init(context=self.ctx, domain_id=DOMAIN_ID)
        params.setdefault('prediction.workers', -1)
        self.scene = make_scene()
        self.node = node_mod.TissueSimNode(
            scene=self.scene,
            context=self.ctx,
            parameter_overrides=[Parameter(k, value=v) for k, v in params.items()],
        )
        self.client = rclpy.create_node('graph_client', context=self.ctx)
        self.wrenches, self.ready = [], []
        self.client.create_subscription(
            WrenchStamped, 'needle/wrench', lambda m: self.wrenches.append(m), reliable
        )
        self.pose_pub = self.client.create_publisher(PoseStamped, 'needle/pose', reliable)
        self.register = self.client.create_client(Trigger, '/tissue_sim/register_needle')
        self._stops = []
        for node, executor in (
            (self.client, SingleThreadedExecutor(context=self.ctx)),
            (self.node, make_executor(self.node.config.executor, context=self.ctx)),
        ):
            executor.add_node(node)
            stop = threading.Event()
            thread = threading.Thread(target=self._spin, args=(executor, stop), daemon=True)
            thread.start()
            self._stops.append((stop, thread))
        self.wait(lambda: self.pose_pub.get_subscription_count() and self.wrenches, 'the node ticking')

    @staticmethod
    def _spin(executor, stop):
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)

    @staticmethod
    def wait(condition, what, timeout=20.0):
        deadline = time.monotonic() + timeout
        while not condition():
            assert time.monotonic() < deadline, f'{what}: not within {timeout} s'
            time.sleep(0.01)

    def publish_pose(self, position, stamp_ns, orientation=DOWN, frame_id='world'):
        from geometry_msgs.msg import PoseStamped

        from tissue_sim_ros.ros.messages.conversions import ns_to_stamp

        msg = PoseStamped()
        msg.header.frame_id, msg.header.stamp = frame_id, ns_to_stamp(stamp_ns)
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in position)
        o = msg.pose.orientation
        o.x, o.y, o.z, o.w = (float(c) for c in orientation)
        self.pose_pub.publish(msg)

    def call(self, client, request, timeout=10.0):
        assert client.wait_for_service(timeout_sec=timeout)
        future = client.call_async(request)
        self.wait(future.done, 'the service answer', timeout)
        return future.result()

    def close(self):
        import rclpy

        for stop, thread in self._stops:
            stop.set()
            thread.join(timeout=5)
        self.node.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.ctx)


# the broadcaster: its own process, rclpy and the generated TFMessage, scipy for the maths; it moves
# the needle base straight down at SPEED in the tissue frame and publishes base_link -> tool0 at 1 kHz
BROADCASTER = textwrap.dedent('''
    import sys, time, numpy as np, rclpy
    from scipy.spatial.transform import Rotation
    from tf2_msgs.msg import TFMessage
    from geometry_msgs.msg import TransformStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    start, speed = np.array(eval(sys.argv[1])), float(sys.argv[2])
    seconds, offset = float(sys.argv[3]), float(sys.argv[4])
    reg_p, reg_q = eval(sys.argv[5])
    def m(p, q):
        h = np.eye(4); h[:3, :3] = Rotation.from_quat(q).as_matrix(); h[:3, 3] = p; return h
    base_tissue, tool_needle = m(reg_p, reg_q), m([0, 0, offset], [0, 0, 0, 1])
    rclpy.init(); node = rclpy.create_node('robot')
    pub = node.create_publisher(TFMessage, '/tf', QoSProfile(depth=100,
                                                             reliability=ReliabilityPolicy.RELIABLE))
    while pub.get_subscription_count() == 0: time.sleep(0.01)
    time.sleep(0.2)
    t0 = time.time_ns(); print(t0, flush=True)
    k = 0
    while True:
        stamp = t0 + k * 1_000_000
        if stamp > t0 + seconds * 1e9: break
        delay = (stamp - time.time_ns()) / 1e9
        if delay > 0: time.sleep(delay)
        needle = m(start + [0, 0, -speed * (stamp - t0) / 1e9], [1, 0, 0, 0])
        tool = base_tissue @ needle @ np.linalg.inv(tool_needle)
        t = TransformStamped(); t.header.frame_id, t.child_frame_id = 'base_link', 'tool0'
        t.header.stamp.sec, t.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
        tr, r = t.transform.translation, t.transform.rotation
        tr.x, tr.y, tr.z = (float(c) for c in tool[:3, 3])
        r.x, r.y, r.z, r.w = (float(c) for c in Rotation.from_matrix(tool[:3, :3]).as_quat())
        pub.publish(TFMessage(transforms=[t])); k += 1
    time.sleep(0.3); rclpy.shutdown()
''')


def truth_times(z, clocks, start_z, speed, t0, seconds):
    """The motion's time [s from t0] of each engine pose: its clock time, or the broadcaster stamp (a
    whole ms) the input held: the newest when the clock had passed it (a late stream), the oldest when
    the clock was before it (PoseInput.pose_at never extrapolates); the caller checks the pose is the
    motion's at that time."""
    at_clock = np.clip((clocks - t0) / NS, 0.0, seconds)
    held = np.round((start_z - z) / speed * 1000.0) / 1000.0  # the nearest 1 ms stamp
    on_clock = np.abs(start_z - speed * at_clock - z) < 1e-9
    assert np.all(on_clock | ((held >= 0) & (held <= seconds))), 'a pose neither at its clock nor a held stamp'
    return np.where(on_clock, at_clock, held)


def replay_wrenches(traces, threads):
    """The wrench of each traced tick from a fresh scene run through the trace, and the index of
    the first tick whose state has a puncture (len: none)."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.ros.loop.trace import TraceReplayer

    scene = make_scene()
    scene.model.set_threads(threads)
    replayer = TraceReplayer(SimulationDriver(scene, wrench_frame='needle', on_divergence='reset'),
                             DegradationLadder(scene))
    wrenches, punctured = [], len(traces)
    for k, tick in enumerate(traces):
        wrenches.append(np.concatenate(replayer.apply(tick)[:2]))
        if scene.puncture_events and punctured == len(traces):
            punctured = k
    return np.array(wrenches), punctured


def node_log(path):
    from tissue_sim_ros.io.mcap import read_log
    from tissue_sim_ros.ros.loop.trace import decode

    out = {'wrench': [], 'trace': [], 'tf': [], 'tf_static': []}
    for m in read_log(path, topics=['/needle/wrench', '/tissue_sim/engine_trace', '/tf', '/tf_static']):
        key = {
            '/needle/wrench': 'wrench',
            '/tissue_sim/engine_trace': 'trace',
            '/tf': 'tf',
            '/tf_static': 'tf_static',
        }[m.topic]
        out[key].append(decode(m.message.data) if key == 'trace' else m.message)
    return out
