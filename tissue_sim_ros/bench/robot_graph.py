"""``tissue-sim bench robot-graph``: the node in a robot's graph, paired figures.

Two comparisons on one node (the default scene, in this process, its executor on a thread), each
run in pairs, alternating, so that the machine's load falls on both sides alike:

- **TF input against the pose topic**: the same straight insertion (the needle base down at
  ``--speed-mm-s`` from the scene's start), fed by a separate process at ``--rate-hz`` either as
  ``base_link -> tool0`` on /tf (the tissue registered 0.4 m away and turned, the needle 150 mm
  along tool0) or as ``needle/pose`` in the tissue frame. The figure is the node's own input
  latency (a pose's receipt to the first wrench computed with it; the diagnostics'
  ``latency_ms_*``), p50 and p99 per run;
- **the action against the topic pair**: the same candidate path asked on ``plan/candidate`` and as
  a ``~/predict_path`` goal, alternately; the figure is the client's time from the request to the
  answer, and the wrench's arrival interval at the client while the goals run (p50, p99).

Prints one table per comparison; asserts nothing.
"""

from __future__ import annotations

import os
import subprocess
import sys
import threading
import time

import numpy as np

__all__ = ['feed', 'main']

_NS = 1_000_000_000
_REGISTRATION = ([0.4, -0.05, 0.02], [0.0, 0.0, 0.3007058, 0.9537170])
_OFFSET_M = 0.15


def _matrix(position, orientation):
    from scipy.spatial.transform import Rotation

    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(orientation).as_matrix()
    m[:3, 3] = position
    return m


def feed(mode: str, start, speed: float, seconds: float, rate_hz: float) -> None:
    """A robot in its own process: the needle base down from ``start`` at ``speed`` in the tissue
    frame for ``seconds``, as /tf (``mode`` 'tf') or needle/pose ('pose'), at ``rate_hz``."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, TransformStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from scipy.spatial.transform import Rotation
    from tf2_msgs.msg import TFMessage

    rclpy.init()
    node = rclpy.create_node('robot')
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    publisher = node.create_publisher(
        TFMessage if mode == 'tf' else PoseStamped, '/tf' if mode == 'tf' else 'needle/pose', reliable
    )
    while publisher.get_subscription_count() == 0:
        time.sleep(0.01)
    time.sleep(0.2)
    base_tissue, tool_needle = _matrix(*_REGISTRATION), _matrix([0.0, 0.0, _OFFSET_M], [0, 0, 0, 1])
    t0, period = time.time_ns(), int(_NS / rate_hz)
    for k in range(int(seconds * rate_hz) + 1):
        stamp = t0 + k * period
        delay = (stamp - time.time_ns()) / _NS
        if delay > 0:
            time.sleep(delay)
        needle = _matrix(np.asarray(start) + [0.0, 0.0, -speed * k / rate_hz], [1.0, 0.0, 0.0, 0.0])
        sec, nanosec = divmod(stamp, _NS)
        if mode == 'tf':
            tool = base_tissue @ needle @ np.linalg.inv(tool_needle)
            t = TransformStamped()
            t.header.frame_id, t.child_frame_id = 'base_link', 'tool0'
            t.header.stamp.sec, t.header.stamp.nanosec = sec, nanosec
            tr, r = t.transform.translation, t.transform.rotation
            tr.x, tr.y, tr.z = (float(c) for c in tool[:3, 3])
            r.x, r.y, r.z, r.w = (float(c) for c in Rotation.from_matrix(tool[:3, :3]).as_quat())
            publisher.publish(TFMessage(transforms=[t]))
        else:
            msg = PoseStamped()
            msg.header.frame_id = 'world'
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in needle[:3, 3])
            msg.pose.orientation.x = 1.0
            msg.pose.orientation.w = 0.0
            publisher.publish(msg)
    time.sleep(0.3)
    rclpy.shutdown()


def _percentiles(values) -> str:
    values = np.asarray(values, dtype=float)
    return (
        f'{np.percentile(values, 50):6.2f} {np.percentile(values, 99):6.2f}'
        if values.size
        else '  none   none'
    )


def main(
    rounds: int = 3,
    seconds: float = 1.2,
    speed_mm_s: float = 20.0,
    rate_hz: float = 1000.0,
    goals: int = 6,
    stream=None,
) -> dict:
    import rclpy
    from geometry_msgs.msg import WrenchStamped
    from nav_msgs.msg import Path
    from rclpy.action import ActionClient
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.parameter import Parameter
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from tissue_sim_msgs.action import PredictPath
    from trajectory_msgs.msg import JointTrajectory

    from tissue_sim_ros.ros.diagnostics import Ring
    from tissue_sim_ros.ros.node import TissueSimNode
    from tissue_sim_ros.ros.node_main import make_executor
    from tissue_sim_ros.ros.predictions import path_msg

    stream = sys.stdout if stream is None else stream
    domain = 150 + os.getpid() % 50
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    os.environ.update(ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
    rclpy.init(domain_id=domain)
    node = TissueSimNode(
        parameter_overrides=[
            Parameter(k, value=v)
            for k, v in {
                'input.source': 'tf',
                'input.tf_frame': 'tool0',
                'input.tf_offset_position_m': [0.0, 0.0, _OFFSET_M],
                'registration.parent_frame_id': 'base_link',
                'registration.tissue_position_m': _REGISTRATION[0],
                'registration.tissue_orientation_xyzw': _REGISTRATION[1],
                'input.max_rate_hz': 1000.0,
                'prediction.workers': 1,
            }.items()
        ]
    )
    client = rclpy.create_node('bench_client')
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    arrivals, answers = [], []
    client.create_subscription(
        WrenchStamped, 'needle/wrench', lambda m: arrivals.append(time.monotonic()), reliable
    )
    client.create_subscription(
        JointTrajectory, 'plan/prediction', lambda m: answers.append(time.monotonic()), reliable
    )
    ask = client.create_publisher(Path, 'plan/candidate', reliable)
    action = ActionClient(client, PredictPath, '/tissue_sim/predict_path')
    stop = threading.Event()
    for n, executor in ((node, make_executor(node.config.executor)), (client, SingleThreadedExecutor())):
        executor.add_node(n)
        threading.Thread(
            target=lambda e=executor: [e.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set, True)],
            daemon=True,
        ).start()
    start = node.scene.needle_pose[0]
    figures = {'tf': [], 'pose': []}
    try:
        while not (
            node.readiness.state == 'ready'
            and action.server_is_ready()
            and node.predictions.workers_state == 'warm'
        ):
            time.sleep(0.05)
        for _ in range(rounds):
            for mode in ('tf', 'pose'):
                node.engine.reset()
                time.sleep(0.6)  # the input goes stale: a fresh stream
                node._stats.rings['latency_s'] = ring = Ring(10_000)
                subprocess.run(
                    [
                        sys.executable,
                        '-c',
                        'import sys; from tissue_sim_ros.bench.robot_graph import feed; '
                        f'feed({mode!r}, {start.tolist()!r}, {speed_mm_s * 1e-3}, {seconds}, {rate_hz})',
                    ],
                    env=env,
                    check=True,
                    timeout=120,
                )
                figures[mode].append(ring.array() * 1e3)
        print(
            f'input latency [ms], receipt to the first wrench with it ({rounds} paired runs, {rate_hz:g} Hz, '
            f'{speed_mm_s:g} mm/s for {seconds:g} s)\n  run  source          p50    p99',
            file=stream,
        )
        for k in range(rounds):
            for mode in ('tf', 'pose'):
                label = 'tf (tool0)' if mode == 'tf' else 'needle/pose'
                print(f'  {k + 1:3d}  {label:12s} {_percentiles(figures[mode][k])}', file=stream)
        for mode in ('tf', 'pose'):
            print(
                f'  all  {"tf (tool0)" if mode == "tf" else "needle/pose":12s} '
                f'{_percentiles(np.concatenate(figures[mode]))}',
                file=stream,
            )
        times = np.arange(41) * 0.05
        topic_s, action_s, during = [], [], []
        node.engine.reset()
        for k in range(goals):
            path = path_msg(
                (k + 1) * _NS + np.round(times * _NS).astype(np.int64),
                start - np.outer(0.004 * times, [0, 0, 1]),
                np.tile([1.0, 0, 0, 0], (41, 1)),
                'world',
            )
            before = len(answers)
            t0 = time.monotonic()
            ask.publish(path)
            while len(answers) == before:
                time.sleep(0.001)
            topic_s.append(answers[-1] - t0)
            first = len(arrivals)
            t0 = time.monotonic()
            sent = action.send_goal_async(PredictPath.Goal(path=path))
            while not sent.done():
                time.sleep(0.001)
            result = sent.result().get_result_async()
            while not result.done():
                time.sleep(0.001)
            action_s.append(time.monotonic() - t0)
            during.extend(np.diff(arrivals[first:]) * 1e3)
        print(
            f'\npredictions of a 2 s path (41 poses), {goals} each, alternating: request to answer [ms]\n'
            f'  topic pair   {_percentiles(np.array(topic_s) * 1e3)}\n  action       '
            f'{_percentiles(np.array(action_s) * 1e3)}\n'
            f'wrench arrival interval while the goals ran [ms]: {_percentiles(during)}',
            file=stream,
        )
        return {'latency_ms': figures, 'topic_s': topic_s, 'action_s': action_s, 'interval_ms': during}
    finally:
        stop.set()
        time.sleep(0.2)
        node.destroy_node()
        client.destroy_node()
        rclpy.try_shutdown()
