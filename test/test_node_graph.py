"""The node in a robot's ROS graph: TF in (an independent broadcaster process moving tool0 at 1 kHz),
TF out, registration of the tissue and of the needle's start, readiness, replay of a registered run.

Truths: poses composed by hand with scipy's Rotation from the broadcaster's motion (the node's TF
code is not used for them), the engine run through the node's own trace with those poses instead of
the node's, the replay command, the poses the test itself sent.
"""

import os
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

rclpy = pytest.importorskip('rclpy')
pytest.importorskip('tf2_msgs.msg')

from geometry_msgs.msg import PoseStamped  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: E402
from std_msgs.msg import Bool  # noqa: E402
from std_srvs.srv import Trigger  # noqa: E402
from tf2_msgs.msg import TFMessage  # noqa: E402
from geometry_msgs.msg import WrenchStamped  # noqa: E402

from tissue_sim_ros.ros import node as node_mod  # noqa: E402
from tissue_sim_ros.ros.messages.conversions import ns_to_stamp  # noqa: E402

DOMAIN_ID = 40 + os.getpid() % 20
NS = 1_000_000_000
DOWN = np.array([1.0, 0.0, 0.0, 0.0])
COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(
    depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
)
#: the tissue registered 0.4 m from the robot's base and rotated; the needle 150 mm along tool0
REGISTRATION = (
    [0.4, -0.05, 0.02],
    Rotation.from_euler('zyx', [35.0, 8.0, -4.0], degrees=True).as_quat().tolist(),
)
OFFSET_M = 0.15


def make_scene():
    from tissue_sim_ros.engine.scene.scene import Scene

    return Scene.from_file(None, mesh=COARSE)


@pytest.fixture(autouse=True)
def _private_ros(monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))


class Graph:
    """The node and a client node in one process, each spun by its own executor thread."""

    def __init__(self, **params):
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
            WrenchStamped, 'needle/wrench', lambda m: self.wrenches.append(m), RELIABLE
        )
        self.pose_pub = self.client.create_publisher(PoseStamped, 'needle/pose', RELIABLE)
        self.register = self.client.create_client(Trigger, '/tissue_sim/register_needle')
        self._stops = []
        from tissue_sim_ros.ros.node_main import make_executor

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
        for stop, thread in self._stops:
            stop.set()
            thread.join(timeout=5)
        self.node.destroy_node()
        self.client.destroy_node()
        rclpy.shutdown(context=self.ctx)


@pytest.fixture
def graph():
    made = []

    def make(**params):
        made.append(Graph(**params))
        return made[-1]

    yield make
    for g in made:
        g.close()


def homogeneous(position, orientation):
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(orientation).as_matrix()
    m[:3, 3] = position
    return m


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


def replay_wrenches(traces, threads, rows=None):
    """The wrench of each traced tick from a fresh scene run through the trace (its rows, or
    ``rows(tick)``), and the index of the first tick whose state has a puncture (len: none)."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.ros.loop.trace import TickTrace, TraceReplayer

    scene = make_scene()
    scene.model.set_threads(threads)
    replayer = TraceReplayer(SimulationDriver(scene, wrench_frame='needle', on_divergence='reset'),
                             DegradationLadder(scene))
    wrenches, punctured = [], len(traces)
    for k, tick in enumerate(traces):
        fed = tick if rows is None else TickTrace(tick.stamp_ns, tick.published_index, rows(tick))
        wrenches.append(np.concatenate(replayer.apply(fed)[:2]))
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


def test_tf_input_gives_the_wrench_of_the_same_motion_in_the_tissue_frame(graph, tmp_path):
    speed, seconds = 0.005, 1.2                  # from 1 mm above the surface to 5 mm past it
    g = graph(**{'recording.directory': str(tmp_path), 'input.source': 'tf', 'input.tf_frame': 'tool0',
                 'input.tf_offset_position_m': [0.0, 0.0, OFFSET_M], 'registration.needle_at_first_pose': True,
                 'registration.parent_frame_id': 'base_link', 'registration.tissue_position_m': REGISTRATION[0],
                 'registration.tissue_orientation_xyzw': REGISTRATION[1]})
    start = g.scene.needle_pose[0] - [0.0, 0.0, g.scene.start_gap_m - 0.001]
    robot = subprocess.run(
        [
            sys.executable,
            '-c',
            BROADCASTER,
            repr(start.tolist()),
            str(speed),
            str(seconds),
            str(OFFSET_M),
            repr(REGISTRATION),
        ],
        capture_output=True,
        text=True,
        timeout=60,
        env=dict(os.environ),
    )
    assert robot.returncode == 0, robot.stderr
    t0 = int(robot.stdout.split()[0])
    time.sleep(0.3)
    values = g.node.diagnostics_statuses(time.time_ns())
    g.node.close()
    log = node_log(g.node.recording_path)
    # every wrench the node sent is in the log; its frame is on TF, under the registered tissue
    statics = {t.child_frame_id: t for msg in log['tf_static'] for t in msg.transforms}
    assert (
        statics['world'].header.frame_id == 'base_link' and statics['needle_tip'].header.frame_id == 'needle'
    )
    assert statics['needle_tip'].transform.translation.z == pytest.approx(g.scene.needle.geometry.length_m)
    ours = [t for msg in log['tf'] for t in msg.transforms if t.child_frame_id == 'needle']
    robot_tf = [t for msg in log['tf'] for t in msg.transforms if t.child_frame_id == 'tool0']
    assert len(ours) == len(log['wrench']) and all(t.header.frame_id == 'world' for t in ours)
    assert len(robot_tf) >= 0.9 * seconds * 1000  # the robot's 1 kHz TF, recorded as received
    # the truth: the needle base straight down at `speed` from `start`, in the tissue frame; every
    # pose the engine went to (the trace) is that motion at the advance's clock time, or, where the
    # clock was outside the transforms received (the input holds, never extrapolates), at one of
    # the broadcaster's 1 ms stamps
    rows = np.concatenate([t.rows for t in log['trace']])
    clocks = np.concatenate([t.clock_ns() for t in log['trace']])
    moving = (rows[:, 0] == 0) & ~np.isnan(rows[:, 3])
    assert moving.sum() > 40
    when = truth_times(rows[moving, 5], clocks[moving], start[2], speed, t0, seconds)
    expected = start + np.outer(speed * when, [0.0, 0.0, -1.0])
    np.testing.assert_allclose(rows[moving, 3:6], expected, rtol=0, atol=1e-9)
    angle = np.array(
        [(Rotation.from_quat(q) * Rotation.from_quat(DOWN).inv()).magnitude() for q in rows[moving, 6:10]]
    )
    assert angle.max() < 1e-9
    # the same motion fed as poses in the tissue frame (the hand-made ones), on the node's own schedule
    # of advances: the node's wrenches to 1e-9 N, up to the capsule's puncture. The puncture's substep
    # moves with the last bit of a pose (the hand-made poses differ from the node's by 1e-16 m), so
    # after it the two runs differ by a substep's worth of force: compared up to the first puncture of
    # either run, the node's own poses replayed giving the node's puncture tick
    recorded = np.array([[w.wrench.force.x, w.wrench.force.y, w.wrench.force.z, w.wrench.torque.x,
                          w.wrench.torque.y, w.wrench.torque.z] for w in log['wrench']])
    own, own_punctured = replay_wrenches(log['trace'], g.node.engine.threads)
    np.testing.assert_array_equal(own, recorded)             # the trace reproduces the node exactly

    def hand_made(tick):
        fed = tick.rows.copy()
        advance = (fed[:, 0] == 0) & ~np.isnan(fed[:, 3])
        when = truth_times(fed[advance, 5], tick.clock_ns()[advance], start[2], speed, t0, seconds)
        fed[advance, 3:6] = start + np.outer(speed * when, [0.0, 0.0, -1.0])
        fed[advance, 6:10] = DOWN
        return fed
    fed, fed_punctured = replay_wrenches(log['trace'], g.node.engine.threads, hand_made)
    before = min(own_punctured, fed_punctured)
    np.testing.assert_allclose(fed[:before], recorded[:before], rtol=0, atol=1e-9)
    assert np.abs(recorded[:before, 2]).max() > 0.5, 'the needle should have loaded the tissue before the puncture'
    statuses = {name: values for name, _, _, values in values}
    inputs = statuses['tissue_sim: input']
    print(f"\nTF input: {inputs['poses_received']} poses from TF, latency p50 {inputs['latency_ms_p50']} ms, "
          f"p99 {inputs['latency_ms_p99']} ms")
    assert inputs['source'] == 'tf: tool0 in world'


def test_a_robot_80_mm_away_is_refused_until_registered_and_the_replay_places_it_again(graph, tmp_path):
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
    g = graph(**{'registration.needle_at_first_pose': True})
    late = []
    g.client.create_subscription(Bool, '/tissue_sim/ready', late.append, LATCHED)
    g.wait(lambda: late, 'the latched ~/ready')
    assert late[-1].data is True
    status = {name: values for name, _, _, values in g.node.diagnostics_statuses(time.time_ns())}
    assert status['tissue_sim: engine']['ready'] == 'ready'
    away = g.scene.needle_pose[0] + [0.03, -0.01, 0.08]
    g.publish_pose(away, time.time_ns())
    g.wait(lambda: np.allclose(g.scene.needle_pose[0], away), 'the needle at the first pose')
    assert g.node.input.bad_total == 0


def test_the_console_script_node_says_ready_and_serves_the_registration(tmp_path):
    """tissue_sim_node as a child process (its own interpreter imports the built interfaces):
    NodeProcess waits on ~/ready, then ~/set_tissue_pose answers and /tf_static carries it."""
    from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context
    from tissue_sim_msgs.srv import SetTissuePose

    with NodeProcess(
        ['prediction.workers:=-1', 'registration.parent_frame_id:=base_link'],
        tmp_path / 'node.log',
        domain_id=DOMAIN_ID + 20,
    ) as process:
        started = process.wait_until_ready(timeout_s=180)
        with client_context(process.domain_id) as context:
            client = rclpy.create_node('registrar', context=context)
            statics = []
            client.create_subscription(TFMessage, '/tf_static', statics.append, LATCHED)
            service = client.create_client(SetTissuePose, '/tissue_sim/set_tissue_pose')
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(client)
            assert service.wait_for_service(timeout_sec=10)
            request = SetTissuePose.Request()
            request.pose.pose.position.x, request.pose.pose.orientation.w = 0.4, 1.0
            answer = service.call_async(request)
            executor.spin_until_future_complete(answer, timeout_sec=10)
            assert answer.result().success and 'base_link' in answer.result().message
            deadline = time.monotonic() + 10
            while not any(
                t.child_frame_id == 'world' and t.transform.translation.x == 0.4
                for m in statics
                for t in m.transforms
            ):
                assert time.monotonic() < deadline, 'the new registration on /tf_static'
                executor.spin_once(timeout_sec=0.05)
            client.destroy_node()
    print(f'\nthe node said ready {started:.1f} s after its start')
