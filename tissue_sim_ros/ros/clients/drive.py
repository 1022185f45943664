"""``tissue-sim drive``: a scripted straight insertion and retraction on ``needle/pose``.

For trying the node without a robot::

    tissue_sim_node &                         # or with --ros-args --params-file ...
    tissue-sim drive --speed-mm-s 5 --depth-mm 20

The needle keeps the scene's initial orientation (the default scene: base +z along world -z,
pointing down) and moves along its axis: from the scene's initial pose (where the node's needle
is after a start or ``~/reset``) to the start pose (``--start-height-mm``: tip that far above the
entry surface; default: where the scene puts it), down until the tip is ``--depth-mm`` below the
entry surface, holds ``--hold-s``, and comes back up to the start pose at the same speed. Poses
are published at ``--rate-hz`` stamped with the publishing time, once the node itself takes them
(it publishes its wrench and subscribes to the poses; another subscriber does not start the
drive), then the command waits until the node has acknowledged them (reliable QoS) and exits.

The entry surface is where the needle axis meets the tissue surface under the tip
(``Scene.start_gap_m``); the start pose is computed from the scene file, which is loaded (not
stepped) for that. ``--travel-mm`` gives the tip's travel from the start pose instead of
``--depth-mm`` (travel = start height + depth).
"""
from __future__ import annotations

import math
import sys
import time
from dataclasses import dataclass

import numpy as np

__all__ = ['DriveStart', 'insertion_trajectory', 'scene_start', 'pose_message',
           'publish_trajectory', 'run_drive', 'wait_for_node']


@dataclass(frozen=True)
class DriveStart:
    """Where a scripted insertion begins, from a scene."""

    initial_position: np.ndarray  # needle base at start/reset [m]
    orientation: np.ndarray  # x y z w
    axis: np.ndarray  # needle axis (base +z) in the world
    length_m: float
    gap_m: float  # tip to entry surface along the axis at the initial pose [m]
    frame_id: str


def _axis(orientation) -> np.ndarray:
    """The needle axis (base +z) of a quaternion x y z w: the engine's rule,
    engine.needle.pose.needle_axis."""
    from tissue_sim_ros.engine.needle.pose import needle_axis  # light: numpy only, no numba
    return needle_axis(orientation)


def scene_start(scene_file: str | None = None, resolve_auto=None) -> DriveStart:
    """The needle's initial pose and its tip's distance to the surface along the axis in a scene
    (``Scene.start_gap_m``, the rule every command uses); ``resolve_auto``: as
    ``Scene.from_file``'s (the command line passes the analysis layer's)."""
    from tissue_sim_ros.engine.scene.scene import Scene
    scene = Scene.from_file(scene_file or None, resolve_auto=resolve_auto)
    position, orientation = scene.needle_pose
    return DriveStart(position, orientation, _axis(orientation), float(scene.spec['needle']['length_m']),
                      scene.start_gap_m, scene.mesh_frame_id)


def insertion_trajectory(start: DriveStart, speed_m_s: float, depth_m: float, hold_s: float,
                         rate_hz: float, start_gap_m: float | None = None):
    """(times [s] from 0, base positions (k, 3) [m]) of the scripted motion, sampled at rate_hz.

    Waypoints: initial pose -> start pose (tip ``start_gap_m`` above the surface; default the
    scene's gap) -> tip ``depth_m`` below the surface -> hold -> start pose; straight segments
    at ``speed_m_s``. The last sample is the start pose.
    """
    for name, value, low in (('speed_m_s', speed_m_s, 0.0), ('rate_hz', rate_hz, 0.0)):
        if not (math.isfinite(value) and value > low):
            raise ValueError(f'{name}: {value}; expected a finite number > {low}')
    if not (math.isfinite(depth_m) and depth_m >= 0):
        raise ValueError(f'depth_m: {depth_m}; expected a finite depth >= 0')
    if not (math.isfinite(hold_s) and hold_s >= 0):
        raise ValueError(f'hold_s: {hold_s}; expected a finite time >= 0')
    gap = start.gap_m if start_gap_m is None else float(start_gap_m)
    if not (math.isfinite(gap) and gap >= 0):
        raise ValueError(f'start_gap_m: {start_gap_m}; expected a height >= 0 above the surface')
    p_init = np.asarray(start.initial_position, dtype=np.float64)
    p_start = p_init + (start.gap_m - gap) * start.axis
    p_bottom = p_start + (gap + depth_m) * start.axis
    waypoints = [(p_init, 0.0), (p_start, None), (p_bottom, None), (p_bottom, hold_s),
                 (p_start, None)]
    times = [0.0]
    points = [p_init]
    for p, duration in waypoints[1:]:
        if duration is None:
            duration = float(np.linalg.norm(p - points[-1])) / speed_m_s
        times.append(times[-1] + duration)
        points.append(p)
    times = np.array(times)
    points = np.array(points)
    n = int(math.floor(times[-1] * rate_hz + 1e-9)) + 1
    t = np.arange(n) / rate_hz
    if t[-1] < times[-1]:
        t = np.append(t, times[-1])
    positions = np.stack([np.interp(t, times, points[:, j]) for j in range(3)], axis=1)
    return t, positions


def pose_message(frame_id: str, orientation):
    """A PoseStamped in ``frame_id`` with the orientation (x y z w) a scripted motion keeps."""
    from geometry_msgs.msg import PoseStamped
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(c) for c in orientation)
    return msg


def publish_trajectory(publisher, message, times, positions, now_ns, *,
                       repeat_for_s: float | None = None, cycle_s: float | None = None) -> list[int]:
    """Publish ``message`` at ``positions[k]`` at ``times[k]`` seconds from now, each stamped
    ``now_ns()`` as it goes out; the stamps, in order.

    With ``repeat_for_s`` the schedule starts over every ``cycle_s`` (default: its length plus one
    sample period) until that many seconds have passed, for a benchmark's steady stream.
    """
    from tissue_sim_ros.ros.messages.conversions import ns_to_stamp
    if cycle_s is None:
        cycle_s = times[-1] + (times[1] - times[0] if len(times) > 1 else 0.0)
    position = message.pose.position
    sent = []
    t0 = time.monotonic()
    k = 0
    while (k < len(times)) if repeat_for_s is None else (time.monotonic() - t0 < repeat_for_s):
        cycle, i = divmod(k, len(times))
        delay = t0 + cycle * cycle_s + times[i] - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        stamp = now_ns()
        message.header.stamp = ns_to_stamp(stamp)
        position.x, position.y, position.z = (float(c) for c in positions[i])
        publisher.publish(message)
        sent.append(stamp)
        k += 1
    return sent


def wait_for_node(node, pub, wrenches: list, wrench_topic: str, timeout_s: float) -> bool:
    """Spin ``node`` until the tissue_sim node itself takes the poses, not merely anyone: a
    wrench has arrived on ``wrench_topic`` (the node ticks), the node that publishes it
    subscribes to ``pub``'s topic, and ``pub`` is matched with every subscriber the graph shows
    there (a monitor subscribed first must not start the drive before the node is connected).
    False after ``timeout_s``."""
    import rclpy
    deadline = time.monotonic() + timeout_s
    topic = pub.topic_name
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.02)
        if not wrenches:
            continue
        sources = {(i.node_name, i.node_namespace) for i in node.get_publishers_info_by_topic(wrench_topic)}
        takers = node.get_subscriptions_info_by_topic(topic)
        node_takes_poses = bool(sources & {(i.node_name, i.node_namespace) for i in takers})
        if node_takes_poses and pub.get_subscription_count() >= len(takers):
            return True
    return False


def run_drive(speed_mm_s: float, depth_mm: float, *, start_height_mm: float | None = None,
              rate_hz: float = 100.0, hold_s: float = 0.5, scene_file: str | None = None,
              topic: str = 'needle/pose', frame_id: str | None = None,
              wait_for_node_s: float = 10.0, args=None, resolve_auto=None,
              wrench_topic: str = 'needle/wrench') -> int:
    """Publish the scripted insertion once the node itself takes the poses (:func:`wait_for_node`);
    0 when every pose was sent and acknowledged."""
    import rclpy
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from rclpy.signals import SignalHandlerOptions

    start = scene_start(scene_file, resolve_auto)
    t, positions = insertion_trajectory(
        start, speed_mm_s * 1e-3, depth_mm * 1e-3, hold_s, rate_hz,
        None if start_height_mm is None else start_height_mm * 1e-3)
    frame = frame_id or start.frame_id
    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.SIGINT)
    try:
        node = rclpy.create_node('tissue_sim_drive')
        pub = node.create_publisher(PoseStamped, topic, QoSProfile(
            depth=max(10, int(rate_hz)), reliability=ReliabilityPolicy.RELIABLE))
        wrenches = []
        node.create_subscription(WrenchStamped, wrench_topic, wrenches.append, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE))
        if not wait_for_node(node, pub, wrenches, wrench_topic, wait_for_node_s):
            print(f'tissue-sim drive: no tissue_sim node on {pub.topic_name} after {wait_for_node_s:g} s '
                  f'(none publishes {wrench_topic} and takes the poses); is tissue_sim_node running '
                  '(same ROS_DOMAIN_ID)?', file=sys.stderr)
            return 1
        print(f'drive: {len(t)} poses on {pub.topic_name} over {t[-1]:.2f} s: down '
              f'{np.linalg.norm(positions - positions[0], axis=1).max() * 1e3:.1f} mm at '
              f'{speed_mm_s:g} mm/s to {depth_mm:g} mm below the surface, hold {hold_s:g} s, back')
        clock = node.get_clock()
        publish_trajectory(pub, pose_message(frame, start.orientation), t, positions,
                           lambda: clock.now().nanoseconds)
        acked = pub.wait_for_all_acked(Duration(seconds=5.0))
        if not acked:
            print('tissue-sim drive: the node did not acknowledge every pose within 5 s',
                  file=sys.stderr)
            return 1
        return 0
    except KeyboardInterrupt:
        print('tissue-sim drive: interrupted', file=sys.stderr)
        return 130
    finally:
        rclpy.try_shutdown()
