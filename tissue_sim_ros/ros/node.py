"""Console script ``tissue_sim_node``: the ROS 2 node (needle pose in, wrench and mesh out).

::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml
    tissue_sim_node --help            # the parameters, their defaults, ranges and meaning

Node ``tissue_sim``; its topics, their types and QoS: :mod:`tissue_sim_ros.ros.topics`.

Services: ``~/reset`` (std_srvs/srv/Trigger) puts the tissue at rest and the needle at its
initial pose; ``~/pause`` (std_srvs/srv/SetBool) freezes (true) or resumes (false) the
simulation; while paused the node keeps publishing the frozen state.

Timing: a timer on the node clock (``use_sim_time`` is honoured) calls :meth:`TissueSimNode.tick`
``engine.slices_per_tick`` times per tick; each slice advances the engine to the newest pose's
stamp and the tick's last slice publishes (:mod:`~tissue_sim_ros.ros.tick_schedule`). The engine is
one :class:`~tissue_sim_ros.engine.driver.SimulationDriver`: a pose it refuses holds the needle,
and a divergence (``SimulationDiverged`` or a non-finite state) is logged at ERROR and, by
``on_divergence``, reset to rest or held until ``~/reset`` (the last finite wrench republished).

Bad input never stops the node and never reaches a topic as NaN: see ``BAD_INPUT_KINDS`` in
:mod:`~tissue_sim_ros.ros.pose_input`, plus ``malformed`` (a payload that does not decode as a
PoseStamped); each kind logged once and counted in diagnostics. Input work is bounded: received
poses are queued as bytes and at most ``MAX_POSES_PER_SLICE`` of the newest are decoded per slice
(the rest counted as backlog), so no rate of input can hold up a tick.

Recording: see :mod:`~tissue_sim_ros.ros.node_recording`. The file is closed with its summary on a
normal exit, SIGINT and SIGTERM; after SIGKILL only the last chunk is lost.
"""
from __future__ import annotations

import sys
import time

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import Marker

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.ros import conversions as cv
from tissue_sim_ros.ros.node_diagnostics import NodeStats, diagnostics_statuses
from tissue_sim_ros.ros.node_recording import (every_kth_tick, node_log_topics, open_node_log,
                                               record_service_call)
from tissue_sim_ros.ros.parameter_declaration import declare_parameters
from tissue_sim_ros.ros.parameters import (NODE_NAME, PARAMETERS, ConfigError, NodeConfig,
                                           help_text as _help_text, load_scene, make_config)
from tissue_sim_ros.ros.pose_input import PoseInput
from tissue_sim_ros.ros.pose_receiver import PoseReceiver
from tissue_sim_ros.ros.tick_schedule import TickSchedule
from tissue_sim_ros.ros.topics import (DIAGNOSTICS_QOS, MARKER_QOS, NODES_QOS, SURFACE_QOS,
                                       WRENCH_QOS, pose_qos)
from tissue_sim_ros.units import NS_PER_S

__all__ = ['NODE_NAME', 'PARAMETERS', 'ConfigError', 'NodeConfig', 'TissueSimNode', 'main']

#: Received poses are decoded at most this many per slice, the newest; older ones waiting at the
#: same slice count as backlog (they are recorded all the same). A 1 kHz stream brings 5 a slice.
MAX_POSES_PER_SLICE = 64


def _decode_pose(data: bytes):
    return cv.pose_from_msg(deserialize_message(data, PoseStamped))


def help_text() -> str:
    return _help_text(__doc__.split('\n\n')[0].strip())


class TissueSimNode(Node):
    """The ``tissue_sim`` node. ``scene``: an engine scene to use instead of loading
    ``scene_file`` (tests inject one); other keyword arguments go to ``rclpy.node.Node``.

    Raises ConfigError (a parameter refused, or the scene file not loaded) from the constructor.
    """

    def __init__(self, *, scene=None, node_name: str = NODE_NAME, **node_kwargs):
        super().__init__(node_name, **node_kwargs)
        self._recorder, self._closed = None, False
        try:
            self._set_up(scene)
        except BaseException:
            # a half-built node left to the garbage collector takes its logger's /rosout
            # registration with it whenever it is collected, even from a later node of that name
            self.destroy_node()
            raise

    def _set_up(self, scene) -> None:
        values = declare_parameters(self)
        self.scene = scene if scene is not None else load_scene(values['scene_file'])
        self.config = cfg = make_config(values, getattr(self.scene, 'mesh_frame_id', None))
        self.driver = SimulationDriver(self.scene, wrench_frame=cfg.wrench_frame,
                                       on_divergence=cfg.on_divergence)
        self.input = PoseInput(cfg.input_limits, reference_pose=self.scene.needle_pose)
        self.schedule = TickSchedule(cfg.period_s, cfg.slices_per_tick)
        self._stats = NodeStats(cfg.publish_rate_hz, cfg.slices_per_tick)
        self.paused, self.ticks, self._service_calls = False, 0, 0
        self._logged_kinds: set[str] = set()
        self._received = PoseReceiver(limit=MAX_POSES_PER_SLICE)
        self._topology_version, self._triangles = None, None
        self._pending_receipts: list[int] = []
        self.wrench_pub = self.create_publisher(WrenchStamped, 'needle/wrench', WRENCH_QOS)
        self.nodes_pub = self.create_publisher(PointCloud2, 'tissue/nodes', NODES_QOS)
        self.surface_pub = self.create_publisher(Mesh, 'tissue/surface', SURFACE_QOS)
        self.marker_pub = (self.create_publisher(Marker, 'tissue/marker', MARKER_QOS)
                           if cfg.marker_rate_hz > 0 else None)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self.pose_qos = pose_qos(cfg.input_reliability)
        self.pose_sub = self.create_subscription(PoseStamped, 'needle/pose', self._on_pose,
                                                 self.pose_qos, raw=True)
        self.reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self.pause_srv = self.create_service(SetBool, '~/pause', self._on_pause)
        if cfg.recording_directory:
            self._start_recording()
        self._publish_surface(self._now_ns())
        self._tick_timer = self.create_timer(self.schedule.slice_s, self.tick)
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        # the marker (milliseconds of Python objects) goes out from a tick, after its wrench and
        # cloud: a timer of its own could fire just before a tick and delay it
        self._marker_every = every_kth_tick(cfg.publish_rate_hz, cfg.marker_rate_hz)
        self._record_nodes_every = every_kth_tick(cfg.publish_rate_hz, cfg.recording_nodes_rate_hz)
        self._diagnostics_timer = self.create_timer(1.0 / cfg.diagnostics_rate_hz,
                                                    self.publish_diagnostics)
        self.get_logger().info(
            f'ticking at {cfg.publish_rate_hz:g} Hz ({cfg.slices_per_tick} engine slices per tick) '
            f'on {cfg.scene_file or "the default scene"}; wrench in {cfg.wrench_frame_id!r}, mesh '
            f'in {cfg.frame_id!r}' + (f'; recording to {self._recorder.path}' if self._recorder
                                      else '; not recording'))

    stats = property(lambda self: self._stats.rings)
    divergences = property(lambda self: self.driver.divergences)
    held = property(lambda self: self.driver.held)
    simulated_s = property(lambda self: self.driver.simulated_s)
    dropped_time_s = property(lambda self: self.schedule.dropped_time_s)
    missed_ticks = property(lambda self: self.schedule.missed_ticks)
    deadline_overruns = property(lambda self: self.schedule.deadline_overruns)

    recording_path = property(lambda self: None if self._recorder is None else self._recorder.path)

    def _start_recording(self) -> None:
        self._recorder = open_node_log(self.config, scene_text=getattr(self.scene, 'text', ''),
                                       node_name=self.get_name(),
                                       node_fqn=self.get_fully_qualified_name(),
                                       topics=node_log_topics(self, cv.qos_to_dict))

    def _event_topic(self, service) -> str:
        return self.resolve_service_name(service.srv_name) + '/_service_event'

    def _record_call(self, service, srv_type, request, response) -> None:
        if self._recorder is not None:
            self._service_calls += 1
            record_service_call(self._recorder, self._event_topic(service), srv_type, request,
                                response, self._now_ns(), self._service_calls, serialize_message)

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _publish(self, publisher, msg, now_ns: int | None = None, record: bool = True) -> None:
        """Publish; when recording, serialize once and publish and record the same bytes."""
        if self._recorder is None or not record:
            publisher.publish(msg)
            return
        data = serialize_message(msg)
        publisher.publish(data)
        self._recorder.write(publisher.topic_name, data, self._now_ns() if now_ns is None else now_ns)

    def _log_once(self, kind: str, text: str, level: str = 'warning') -> None:
        if kind not in self._logged_kinds:
            self._logged_kinds.add(kind)
            getattr(self.get_logger(), level)(f'{text} (logged once for {kind}; counted in diagnostics)')

    def _on_pose(self, data: bytes) -> None:
        """A pose as received: recorded as is, queued for the next slice to decode."""
        wall0 = time.perf_counter()
        receipt_ns = self._now_ns()
        if self._recorder is not None:
            self._recorder.write(self.pose_sub.topic_name, data, receipt_ns)
        self._received.add(receipt_ns, data)
        self._stats.input_s += time.perf_counter() - wall0

    def _take_poses(self) -> None:
        """Take every pose waiting in the subscription (the executor takes one per wait: when
        ticks overrun the timer is ready at every wait), then decode the newest few."""
        handle = getattr(self.pose_sub, 'handle', None)
        if handle is not None and hasattr(handle, 'take_message'):
            for _ in range(self._received.queue.maxlen):
                with handle:
                    taken = handle.take_message(PoseStamped, True)
                if taken is None:
                    break
                self._on_pose(taken[0])
        wall0 = time.perf_counter()
        self._pending_receipts += self._received.decode_into(self.input, _decode_pose, self._log_once)
        self._stats.input_s += time.perf_counter() - wall0

    def tick(self) -> None:
        """One slice of a tick: advance the engine as far as the received poses reach, then, after
        the tick's last slice, publish the wrench and the cloud stamped with the tick time."""
        wall0 = time.perf_counter()
        self._take_poses()  # before the slice time: a pose taken now is older than it
        now_ns = self._now_ns()
        timer = self._tick_timer
        until_next = timer.time_until_next_call()
        publish = self.schedule.ends_tick(now_ns, until_next, timer.timer_period_ns)
        if publish:
            self._stats.tick_started(self.schedule.tick_started(wall0, self._stats.input_s))
        if self.paused or self.driver.held:
            self.schedule.hold(now_ns)
        else:
            newest = self.input.newest()
            to_ns = self.schedule.slice_target_ns(now_ns, None if newest is None else newest[0])
            deadline = self.schedule.slice_deadline(wall0, until_next, publish, self._sim_time)
            clock = self.schedule.engine_clock_ns
            if clock is None or to_ns > clock:
                self._advance_engine(to_ns, self.schedule.advance_to(to_ns), deadline)
            elif self.driver.behind:  # what a deadline left
                self._advance_engine(clock, 0.0, deadline)
        if publish:
            self._publish_tick(now_ns, wall0)
        else:
            self._stats.tick_work_s += time.perf_counter() - wall0

    def _advance_engine(self, to_ns: int, advance_s: float, deadline: float | None) -> None:
        """Advance the engine by ``advance_s`` to the pose at ``to_ns``; no substep starts that
        would end past ``deadline`` (perf_counter s), the rest is left to the next slice."""
        target = self.input.pose_at(to_ns) or (None, None)
        step0 = time.perf_counter()
        outcome = self.driver.advance(advance_s, target[0], target[1], deadline=deadline)
        self._stats.advanced(to_ns, advance_s, outcome.substeps, time.perf_counter() - step0)
        if outcome.refused is not None:
            self.input.count('engine_refused')
            self._log_once('engine_refused',
                           f'the engine refused the needle pose, holding the needle: {outcome.refused}')
        if outcome.diverged is not None:
            self._after_divergence(outcome.diverged)

    def _publish_tick(self, now_ns: int, wall0: float) -> None:
        """The tick's outputs (wrench, cloud, surface after a topology change, marker) and its
        statistics; ``wall0``: when its last slice started."""
        driver, held = self.driver, self.driver.held
        self._publish(self.wrench_pub, cv.wrench_msg(driver.force, driver.torque,
                                                     self.config.wrench_frame_id, now_ns))
        publish_ns = self._now_ns()
        if not held:
            record = bool(self._record_nodes_every) and self.ticks % self._record_nodes_every == 0
            self._publish(self.nodes_pub, cv.point_cloud_msg(
                driver.deformed_positions(), driver.displacement, self.config.frame_id, now_ns),
                publish_ns, record=record)
            if self.scene.topology_version != self._topology_version:
                self._publish_surface(publish_ns)
        for receipt in self._pending_receipts:
            self._stats.rings['latency_s'].add((publish_ns - receipt) / NS_PER_S)
        self._pending_receipts.clear()
        if self._marker_every and self.ticks % self._marker_every == 0:
            self._publish_marker(now_ns)
        work = self._stats.tick_work_s + (time.perf_counter() - wall0)
        self._stats.tick(work, self.schedule.tick_done(work), not (self.paused or held))
        self.ticks += 1

    def _after_divergence(self, exc: Exception) -> None:
        then = ('hold: the last finite wrench is republished until ~/reset' if self.driver.held else
                f'reset: tissue back at rest, needle at its initial pose (divergence '
                f'{self.driver.divergences})')
        self.get_logger().error(f'simulation diverged: {exc}; on_divergence = {then}',
                                throttle_duration_sec=1.0)
        if not self.driver.held:
            self.input.reset(self.scene.needle_pose)

    def _publish_surface(self, now_ns: int) -> None:
        scene = self.scene
        self._topology_version = scene.topology_version
        self._triangles = scene.surface_triangles()
        self._publish(self.surface_pub, cv.surface_mesh_msg(scene.rest_positions, self._triangles),
                      now_ns)

    def _publish_marker(self, now_ns: int) -> None:
        if self.driver.held or self._triangles is None:
            return
        self._publish(self.marker_pub, cv.surface_marker_msg(
            self.driver.deformed_positions(), self._triangles, self.config.frame_id, now_ns,
            max_triangles=self.config.marker_max_triangles), now_ns)

    def _on_reset(self, request, response):
        self.driver.reset()
        self.input.reset(self.scene.needle_pose)
        self.get_logger().info('~/reset: tissue at rest, needle at its initial pose')
        if self.scene.topology_version != self._topology_version:
            self._publish_surface(self._now_ns())
        response.success = True
        response.message = (f'reset: simulated time {self.scene.time:g} s, needle at '
                            f'{[round(float(x), 6) for x in self.scene.needle_pose[0]]} m; poses '
                            f'farther than input.max_jump_m from it are refused')
        self._record_call(self.reset_srv, Trigger, request, response)
        return response

    def _on_pause(self, request, response):
        was, self.paused = self.paused, bool(request.data)
        response.success = True
        response.message = (f'{"paused" if self.paused else "running"} at simulated time '
                            f'{self.scene.time:.6g} s' + ('' if was != self.paused else ' (unchanged)'))
        self.get_logger().info(f'~/pause: {response.message}')
        self._record_call(self.pause_srv, SetBool, request, response)
        return response

    def diagnostics_statuses(self, now_ns: int) -> list:
        """The DiagnosticStatus tuples (name, level, message, values) of this moment."""
        return diagnostics_statuses(self.get_name(), now_ns, stats=self._stats,
                                    schedule=self.schedule, driver=self.driver,
                                    pose_input=self.input, paused=self.paused, ticks=self.ticks,
                                    recorder=self._recorder)

    def publish_diagnostics(self) -> None:
        now_ns = self._now_ns()
        self._publish(self.diagnostics_pub,
                      cv.diagnostic_array_msg(now_ns, self.diagnostics_statuses(now_ns)), now_ns)
        self._stats.new_window(self.driver.simulated_s, self._now_ns(), self.input.bad_total)

    def close(self) -> None:
        """Stop the timers and close the recording (its summary written). Idempotent."""
        if self._closed:
            return
        self._closed = True
        for timer in (getattr(self, '_tick_timer', None), getattr(self, '_diagnostics_timer', None)):
            if timer is not None:
                timer.cancel()
        if self._recorder is not None:
            path = self._recorder.path
            self._recorder.close()
            self.get_logger().info(f'recording closed: {path}')

    def destroy_node(self):
        self.close()
        return super().destroy_node()


def main(argv=None) -> int:
    """Run the node until SIGINT or SIGTERM; 0 on a clean stop, 2 on a refused parameter."""
    from tissue_sim_ros.ros.node_main import run
    return run(TissueSimNode, help_text, argv)


if __name__ == '__main__':
    sys.exit(main())
