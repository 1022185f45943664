"""Console script ``tissue_sim_node``: the ROS 2 node (needle pose in, wrench and mesh out).

::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml
    tissue_sim_node --help            # the parameters, their defaults, ranges and meaning

Node ``tissue_sim``; its topics, their types and QoS: :mod:`tissue_sim_ros.ros.messages.topics`.

Predictions: ``plan/candidate`` -> ``plan/prediction`` and the action ``~/predict_path``
(:mod:`~.predictions`, :mod:`~.prediction_action`). Services: :mod:`~.services`. TF out and in,
registration, readiness (``~/ready``): :mod:`~.tf_out`, :mod:`~.tf_in`, :mod:`~.registration`,
:mod:`~.readiness`.

Timing (:mod:`~tissue_sim_ros.ros.loop.engine_thread`, :mod:`~tissue_sim_ros.ros.loop.tick_thread`): the
engine advances on its own thread toward the newest pose within a budget of each tick; the tick
publishes the latest state every period and never waits for the physics (with ``use_sim_time`` it
is lock-step); lag is bounded (``engine.max_lag_s``), the degradation ladder steps down and up, and
a divergence is logged at ERROR and reset or held by ``on_divergence``.

Bad input never stops the node and never reaches a topic as NaN (``BAD_INPUT_KINDS`` in
:mod:`~tissue_sim_ros.ros.loop.pose_input`, each logged once and counted in diagnostics); received
poses are queued as bytes and decoded a bounded number per engine cycle, so no rate of input can
hold up a tick. ``tissue/nodes`` is built only while it has a subscriber, and at its own rate for
the log. ``use_sim_time`` is read at start; a change at run time is refused.

Recording: see :mod:`~tissue_sim_ros.ros.recording`. The file is closed with its summary on a
normal exit, SIGINT and SIGTERM; after SIGKILL only the last chunk is lost.
"""
from __future__ import annotations

import sys
import threading
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray, PoseStamped, WrenchStamped
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.event_handler import PublisherEventCallbacks, UnsupportedEventTypeError
from rclpy.parameter import Parameter
from rclpy.node import Node
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import PointCloud2
from shape_msgs.msg import Mesh
from std_msgs.msg import Bool
from tf2_msgs.msg import TFMessage
from visualization_msgs.msg import Marker

from tissue_sim_ros.engine.ladder import DegradationLadder
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.ladder_probe import cached_probe_errors
from tissue_sim_ros.ros.messages import conversions as cv
from tissue_sim_ros.ros.loop.engine_thread import EngineLoop
from tissue_sim_ros.ros.messages.cdr_bytes import CloudBytes, SurfaceMarkerBytes, TraceBytes, WrenchBytes
from tissue_sim_ros.ros.diagnostics import NodeStats, diagnostics_statuses
from tissue_sim_ros.ros.prediction_action import start_predictions
from tissue_sim_ros.ros.readiness import Readiness
from tissue_sim_ros.ros.registration import Registration
from tissue_sim_ros.ros.services import NodeServices
from tissue_sim_ros.ros.messages.needle_shape import NeedleShapes
from tissue_sim_ros.ros.targets import targets_msg, targets_status
from tissue_sim_ros.ros.tf_in import TfInput, transforms_of
from tissue_sim_ros.ros.tf_out import TfFrames, needle_frames
from tissue_sim_ros.ros.recording import (every_kth_tick, node_log_topics, open_node_log,
                                               record_service_call)
from tissue_sim_ros.ros.parameter_declaration import declare_parameters
from tissue_sim_ros.ros.parameters import (NODE_NAME, PARAMETERS, NodeConfig, help_text as _help_text,
                                           load_scene, make_config)
from tissue_sim_ros.errors import ConfigError
from tissue_sim_ros.ros.loop.pose_input import PoseInput
from tissue_sim_ros.ros.messages.pose_cdr import decode_pose
from tissue_sim_ros.ros.loop.tick_thread import TickThread
from tissue_sim_ros.ros.messages.topics import (DIAGNOSTICS_QOS, MARKER_QOS, NODES_QOS, READY_QOS,
                                                SURFACE_QOS, TF_QOS, TF_STATIC_QOS, WRENCH_QOS, needle_topics,
                                                pose_qos)
from tissue_sim_ros.units import NS_PER_S

__all__ = ['NODE_NAME', 'PARAMETERS', 'ConfigError', 'NodeConfig', 'TissueSimNode', 'main']


def help_text() -> str:
    return _help_text(__doc__.split('\n\n')[0].strip())


class TissueSimNode(Node):
    """The ``tissue_sim`` node. ``scene``: an engine scene to use instead of loading
    ``scene_file`` (tests inject one); ``slow_down``: see EngineLoop (tests); other keyword
    arguments go to ``rclpy.node.Node``.

    Raises ConfigError (a parameter refused, or the scene file not loaded) from the constructor.
    """

    def __init__(self, *, scene=None, node_name: str = NODE_NAME, slow_down=None, resolve_auto=None,
                 **node_kwargs):
        super().__init__(node_name, **node_kwargs)
        self._recorder, self._closed, self.engine = None, False, None
        self.predictions = self.action_server = None
        try:
            self._set_up(scene, slow_down, resolve_auto)
        except BaseException:
            # a half-built node left to the garbage collector takes its logger's /rosout
            # registration with it whenever it is collected, even from a later node of that name
            self.destroy_node()
            raise

    def _set_up(self, scene, slow_down, resolve_auto) -> None:
        values = declare_parameters(self)
        self.scene = scene if scene is not None else load_scene(values['scene_file'], resolve_auto)
        self.config = cfg = make_config(values, getattr(self.scene, 'mesh_frame_id', None))
        self.driver = SimulationDriver(self.scene, wrench_frame=cfg.wrench_frame,
                                       on_divergence=cfg.on_divergence)
        threads = cfg.threads_for(self.scene.mesh.n_elements)
        self.scene.model.set_threads(threads)
        self.input = PoseInput(cfg.input_limits, reference_pose=None if cfg.needle_at_first_pose
                               else self.scene.needle_pose)
        self.other_inputs = [PoseInput(cfg.input_limits, reference_pose=(n.position.copy(), n.orientation.copy()))
                             for n in self.scene.needles[1:]]
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        # the node clock, read once per pose and a few times a tick: without sim time rclpy's ROS
        # clock is the system clock (CLOCK_REALTIME), read here directly (0.1 us against 2.5 us
        # through Clock.now's Time object); use_sim_time is read once, at start, as the engine does
        self._now_ns = self._ros_now_ns if self._sim_time else time.time_ns
        self.add_on_set_parameters_callback(self._keep_use_sim_time)
        self._logged_kinds: set[str] = set()
        self.engine = EngineLoop(
            self.driver, self.input, period_s=cfg.period_s, now_ns=self._now_ns,
            decode=self._decode_input, log_once=self._log_once, log=self._log,
            budget_fraction=cfg.budget_fraction, max_lag_s=cfg.max_lag_s,
            ladder=DegradationLadder(self.scene) if cfg.ladder else None, threads=threads,
            sim_time=self._sim_time, slow_down=slow_down, other_inputs=self.other_inputs)
        self.engine.place_at_first_pose = cfg.needle_at_first_pose
        self._stats = NodeStats(cfg.publish_rate_hz)
        self._set_up_tf(cfg)
        self.ticks, self._service_calls = 0, 0
        self._topology_version, self._marker = None, None
        self._positions = np.empty_like(self.scene.rest_positions)
        self.needle_topics = needle_topics(self.scene.needle_names)
        self.wrench_pubs = [self.create_publisher(WrenchStamped, wrench, WRENCH_QOS) for _, wrench in self.needle_topics]
        self.wrench_pub = self.wrench_pubs[0]
        self._wrench_frames = [cfg.wrench_frame_id if len(self.wrench_pubs) == 1 or cfg.wrench_frame == 'world'
                               else f'{cfg.wrench_frame_id}_{name}' for name in self.scene.needle_names]
        # tissue/nodes' subscribers: kept by the publisher's matched events, and read again with
        # the diagnostics (1 Hz) where a middleware gives no such events
        self._nodes_subscribers = 0
        try:
            self.nodes_pub = self.create_publisher(
                PointCloud2, 'tissue/nodes', NODES_QOS,
                event_callbacks=PublisherEventCallbacks(matched=self._on_nodes_matched))
        except UnsupportedEventTypeError:
            self.nodes_pub = self.create_publisher(PointCloud2, 'tissue/nodes', NODES_QOS)
        self.surface_pub = self.create_publisher(Mesh, 'tissue/surface', SURFACE_QOS)
        self.marker_pub = (self.create_publisher(Marker, 'tissue/marker', MARKER_QOS)
                           if cfg.marker_rate_hz > 0 else None)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', DIAGNOSTICS_QOS)
        self.targets_pub = self.create_publisher(PoseArray, 'tissue/targets', NODES_QOS)
        self.shapes = NeedleShapes(self.scene.needle_names, [n.shape_size for n in self.scene.needles],
                                   cfg.frame_id, lambda kind, topic: self.create_publisher(kind, topic, WRENCH_QOS),
                                   serialize_message)
        self._target_positions = np.zeros((len(self.scene.targets), 3))
        self._target_figures = self.scene.targets.relative_to_needle(self.scene.targets.rest, self.scene.needle.tip,
                                                                     self.scene.needle.axis)
        self.declare_parameter('targets.names', self.scene.targets.names or Parameter.Type.STRING_ARRAY,
                               ParameterDescriptor(description="the scene's targets, in the order of "
                                                   'tissue/targets (from the scene file)', read_only=True))
        self.prediction_pub = self.candidate_sub = None
        if cfg.prediction_workers >= 0:
            start_predictions(self, cfg)
        self.pose_qos = pose_qos(cfg.input_reliability)
        self.pose_subs = [self.create_subscription(PoseStamped, pose, lambda data, k=k: self._on_pose(data, k),
                                                   self.pose_qos, raw=True)
                          for k, (pose, _) in enumerate(self.needle_topics)]
        self.pose_sub = self.pose_subs[0]
        self.declare_parameter('needles.names', self.scene.needle_names,
                               ParameterDescriptor(description='the needles, from the scene file: each has '
                                                   'needle/<name>/pose and /wrench when there are several',
                                                   read_only=True))
        self.node_services = NodeServices(self)
        services = self.node_services.services
        self.reset_srv, self.pause_srv = services['~/reset'], services['~/pause']
        self.ready_pub = self.create_publisher(Bool, '~/ready', READY_QOS)
        self.readiness = Readiness(lambda ready: self._publish(self.ready_pub, Bool(data=ready)))
        self.trace_topic = self.resolve_topic_name('~/engine_trace')
        if cfg.recording_directory:
            self._start_recording()
        self._cloud = CloudBytes(self.scene.rest_positions.shape[0], cfg.frame_id, serialize_message)
        self._wrench_bytes = [WrenchBytes(frame, serialize_message) for frame in self._wrench_frames]
        self._trace_bytes = TraceBytes(serialize_message)
        self._publish_surface(self._now_ns())
        self.publish_static_transforms()
        self.readiness.starting()
        # the marker (milliseconds of Python objects) and the recorded cloud: every k-th tick
        self._marker_every = every_kth_tick(cfg.publish_rate_hz, cfg.marker_rate_hz)
        self._record_nodes_every = every_kth_tick(cfg.publish_rate_hz, cfg.recording_nodes_rate_hz)
        self._stats.new_window(self.engine, None, 0)
        self.engine.start()
        if self.engine.ladder is not None:
            self._measure_ladder(self.engine.ladder)
        self._ticker = None
        if self._sim_time:                     # the ticks follow /clock
            self._tick_timer = self.create_timer(cfg.period_s, self.tick)
        else:                                  # ticking from the executor's first spin, as a timer
            self._ticker = TickThread(cfg.period_s, self.tick, self._tick_failed)
            self._tick_timer = self.create_timer(cfg.period_s, self._start_ticking)
        self._diagnostics_timer = self.create_timer(1.0 / cfg.diagnostics_rate_hz,
                                                    self.publish_diagnostics)
        self.get_logger().info(
            f'ticking at {cfg.publish_rate_hz:g} Hz on {cfg.scene_file or "the default scene"} '
            f'({self.scene.mesh.n_elements} tetrahedra, {threads} engine thread(s), budget '
            f'{100 * cfg.budget_fraction:.0f} % of a tick); wrench in {cfg.wrench_frame_id!r}, '
            f'mesh in {cfg.frame_id!r}' + (f'; recording to {self._recorder.path}' if self._recorder
                                           else '; not recording') +
            ('; predictions off' if self.predictions is None else
             f'; predictions on plan/candidate and ~/predict_path: {self.predictions.workers} worker(s) x '
             f'{self.predictions.threads} thread(s)'))

    def _set_up_tf(self, cfg) -> None:
        """TF out (the frames the messages name) and in (the robot's tree), the tissue's registration."""
        scene = self.scene
        self.tf_frames = TfFrames(cfg.frame_id, needle_frames(cfg.needle_frame_id, scene.needle_names),
                                  [n.geometry.length_m for n in scene.needles], scene.targets.names,
                                  [n.rod is not None for n in scene.needles])
        self.tf_input = TfInput(cfg.frame_id, tf_frame=cfg.tf_frame if cfg.input_source == 'tf' else None,
                                offset=cfg.tf_offset, timeout_s=cfg.tf_timeout_s,
                                own_frames=self.tf_frames.own_frames)
        self.registration = Registration(cfg.frame_id, cfg.registration_parent, *cfg.tissue_pose,
                                         tolerance=cfg.input_limits.unit_quaternion_tolerance)
        self.tf_pub = self.create_publisher(TFMessage, '/tf', TF_QOS) if cfg.tf_publish else None
        self.tf_static_pub = self.create_publisher(TFMessage, '/tf_static',
                                                   TF_STATIC_QOS) if cfg.tf_publish else None
        self._needle_poses = (np.zeros((len(scene.needles), 3)), np.zeros((len(scene.needles), 4)))
        self.tf_subs = [self.create_subscription(TFMessage, topic, lambda data, s=static: self._on_tf(data,
                                                                                                      s),
                                                 qos, raw=True)
                        for topic, qos, static in (('/tf', TF_QOS, False), ('/tf_static', TF_STATIC_QOS,
                                                                            True))]

    def _decode_input(self, data):
        """(position, orientation, frame, stamp ns) of a pose as bytes or made from TF (a tuple; a TF
        failure raises); one in another frame brought into the tissue frame by TF (engine thread)."""
        if isinstance(data, Exception):
            raise data
        position, orientation, frame_id, stamp_ns = data if isinstance(data, tuple) else decode_pose(data)
        expected = self.config.input_limits.expected_frame_id
        if frame_id == expected or frame_id not in self.tf_input.buffer.frames():
            return position, orientation, frame_id, stamp_ns      # (a frame TF does not know: wrong_frame)
        position, orientation, _, stamp_ns = self.tf_input.to_tissue(position, orientation, frame_id,
                                                                     stamp_ns)
        return position, orientation, expected, stamp_ns

    def _on_tf(self, data: bytes, static: bool) -> None:
        """/tf or /tf_static: recorded, into the TF buffer (the node's own skipped); a pose with TF input."""
        receipt_ns = self._now_ns()
        transforms = transforms_of(deserialize_message(data, TFMessage))
        registered = static and self.registration.transform is not None
        if all(child in self.tf_frames.own_frames or (registered and child == self.config.frame_id)
               for _, child, *_ in transforms):
            return                                     # the node's own broadcast, recorded as sent
        if self._recorder is not None:
            self._recorder.write(self.tf_subs[static].topic_name, data, receipt_ns)
        pose = self.tf_input.receive(transforms, static)
        if pose is not None:
            self.engine.submit(receipt_ns, pose)

    def publish_static_transforms(self) -> None:
        """/tf_static: the registration (also into the TF input's buffer) and the needle tips."""
        registration = self.registration.transform
        now_ns = self._now_ns()
        if registration is not None:
            parent, position, orientation = registration
            self.tf_input.receive([(parent, self.config.frame_id, now_ns, position, orientation)],
                                  static=True)
        if self.tf_static_pub is not None:
            self._publish(self.tf_static_pub, self.tf_frames.static_msg(now_ns, registration), now_ns)

    def _measure_ladder(self, ladder) -> None:
        """The ladder's errors (engine.ladder_probe): from the cache, or measured on a copy of the
        scene in a background thread (first start of a scene)."""
        def measure():
            try:
                ladder.predicted_errors = cached_probe_errors(self.scene, DegradationLadder)
            except Exception as exc:  # noqa: BLE001 - the ladder works without its predictions
                self._log('warning', f'the degradation ladder\'s errors were not measured: {exc}')
                ladder.predicted_errors = [None] * len(ladder.rungs)
        threading.Thread(target=measure, name='tissue_sim-ladder-probe', daemon=True).start()

    stats = property(lambda self: self._stats.rings)
    divergences = property(lambda self: self.driver.divergences)
    held = property(lambda self: self.driver.held)
    paused = property(lambda self: self.engine.paused)
    missed_ticks = property(lambda self: self._stats.missed_ticks)
    recording_path = property(lambda self: None if self._recorder is None else self._recorder.path)

    def _start_recording(self) -> None:
        self._recorder = open_node_log(self.config, scene_text=getattr(self.scene, 'text', ''),
                                       scene_spec=getattr(self.scene, 'spec', None),
                                       engine_threads=self.engine.threads, node_name=self.get_name(),
                                       node_fqn=self.get_fully_qualified_name(),
                                       topics=node_log_topics(self, cv.qos_to_dict))

    def _event_topic(self, service) -> str:
        return self.resolve_service_name(service.srv_name) + '/_service_event'

    def _record_call(self, service, srv_type, request, response) -> None:
        if self._recorder is not None:
            self._service_calls += 1
            record_service_call(self._recorder, self._event_topic(service), srv_type, request,
                                response, self._now_ns(), self._service_calls, serialize_message)

    def _on_nodes_matched(self, info) -> None:
        self._nodes_subscribers = info.current_count

    def _keep_use_sim_time(self, parameters) -> SetParametersResult:
        """use_sim_time is read at start (the engine's pacing and the node clock are chosen
        then): a change at run time is refused, naming the value."""
        for parameter in parameters:
            if parameter.name == 'use_sim_time' and parameter.value != self._sim_time:
                return SetParametersResult(
                    successful=False, reason=f'use_sim_time = {parameter.value!r}: read at start '
                    f'(now {self._sim_time}); restart the node to change it')
        return SetParametersResult(successful=True)

    def _ros_now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _publish(self, publisher, msg, now_ns: int | None = None, record: bool = True) -> None:
        """Publish a message or its CDR bytes; when recording, serialize once and publish and
        record the same bytes."""
        if self._recorder is None or not record:
            publisher.publish(msg)
            return
        data = msg if isinstance(msg, bytes) else serialize_message(msg)
        publisher.publish(data)
        self._recorder.write(publisher.topic_name, data, self._now_ns() if now_ns is None else now_ns)

    def _log(self, level: str, text: str) -> None:
        # one call site per severity: rclpy refuses a call site whose severity changes
        logger = self.get_logger()
        if level == 'error':
            logger.error(text)
        elif level == 'warning':
            logger.warning(text)
        else:
            logger.info(text)

    def _start_ticking(self) -> None:
        self._tick_timer.cancel()
        if not self._closed:
            self._ticker.start()

    def _tick_failed(self, exc: Exception) -> None:
        self._stats.tick_errors += 1
        self._log_once('tick_failed', f'a tick failed and was skipped ({type(exc).__name__}: {exc}); the '
                       'next ticks go on', 'error')

    def _log_once(self, kind: str, text: str, level: str = 'warning') -> None:
        if kind not in self._logged_kinds:
            self._logged_kinds.add(kind)
            self._log(level, f'{text} (logged once for {kind}; counted in diagnostics)')

    def _on_pose(self, data: bytes, needle: int = 0) -> None:
        """A pose as received (of needle index ``needle``): recorded as is, handed to the engine."""
        wall0 = time.perf_counter()
        receipt_ns = self._now_ns()
        if self._recorder is not None:
            self._recorder.write(self.pose_subs[needle].topic_name, data, receipt_ns)
        self.engine.submit(receipt_ns, data, needle)
        self._stats.input_done(time.perf_counter() - wall0)

    def tick(self) -> None:
        """Publish the latest state, stamped with the tick time, and open the engine's next
        budget window (with sim time: first wait until the engine reached the tick)."""
        wall0 = time.perf_counter()
        now_ns = self._now_ns()
        self._stats.tick_started(wall0)
        self.engine.tick(wait=self._sim_time)
        snap = self.engine.latest()
        for k, publisher in enumerate(self.wrench_pubs):
            self._publish(publisher, self._wrench_bytes[k].serialized(snap.forces[k], snap.torques[k], now_ns))
        publish_ns = self._now_ns()
        if not snap.held:
            self.shapes.publish(snap, now_ns, self._publish)
            # the cloud is built only for a subscriber or the log: unsubscribed, it would be a
            # third of the tick's work (the publish alone about 100 us of thread time, 70 kB a tick)
            record = self._recorder is not None and bool(self._record_nodes_every) and \
                self.ticks % self._record_nodes_every == 0
            marker = bool(self._marker_every) and self.ticks % self._marker_every == 0
            if record or marker or self._nodes_subscribers:
                np.add(self.scene.rest_positions, snap.displacement, out=self._positions)
            if record or self._nodes_subscribers:
                data = self._cloud.serialized(self._positions, snap.displacement, now_ns)
                if self._nodes_subscribers:
                    self.nodes_pub.publish(data)
                if record:
                    self._recorder.write(self.nodes_pub.topic_name, data, publish_ns)
            if snap.topology_version != self._topology_version:
                self._publish_surface(publish_ns)
            if marker:
                self._publish_marker(now_ns)
            if len(self._target_positions):
                targets = self.scene.targets
                targets.positions(snap.displacement, out=self._target_positions)
                self._target_figures = targets.relative_to_needle(self._target_positions, snap.tip, snap.axis)
                self._publish(self.targets_pub, targets_msg(self._target_positions, self.config.frame_id, now_ns),
                              publish_ns)
        if self.tf_pub is not None and not snap.held:
            self._publish(self.tf_pub, self.tf_frames.dynamic_msg(
                now_ns, snap.positions, snap.orientations, self._target_positions,
                zip(snap.shape_positions, snap.shape_quaternions)), publish_ns)
        if self.ticks == 0:
            self.readiness.ticking()
        for receipt in self.engine.take_receipts(snap.index):
            self._stats.rings['latency_s'].add((publish_ns - receipt) / NS_PER_S)
        if self._recorder is not None:
            trace = self._trace_bytes.serialized(now_ns, snap.index, self.engine.take_trace())
            self._recorder.write(self.trace_topic, trace, now_ns)
        else:
            self.engine.take_trace()
        self._stats.tick_done(time.perf_counter() - wall0)
        self.ticks += 1

    def _publish_surface(self, now_ns: int) -> None:
        scene = self.scene
        self._topology_version = scene.topology_version
        triangles = scene.surface_triangles()
        self._publish(self.surface_pub, cv.surface_mesh_msg(scene.rest_positions, triangles), now_ns)
        if self.marker_pub is not None:
            self._marker = SurfaceMarkerBytes(triangles, len(scene.rest_positions), self.config.frame_id,
                                              self.config.marker_max_triangles, serialize_message)

    def _publish_marker(self, now_ns: int) -> None:
        self._publish(self.marker_pub, bytes(self._marker.serialized(self._positions, now_ns)), now_ns)

    def diagnostics_statuses(self, now_ns: int) -> list:
        """The DiagnosticStatus tuples (name, level, message, values) of this moment."""
        return diagnostics_statuses(self.get_name(), now_ns, stats=self._stats, engine=self.engine,
                                    pose_input=self.input, ticks=self.ticks, recorder=self._recorder,
                                    needle_names=self.scene.needle_names,
                                    other_inputs=zip(self.scene.needle_names[1:], self.other_inputs),
                                    ready=self.readiness.state, source=self.config.input_description) + \
            [targets_status(self.get_name(), self.scene.targets.names, self._target_figures)] + \
            ([] if self.predictions is None else [self.predictions.status(self.get_name())])

    def publish_diagnostics(self) -> None:
        self._nodes_subscribers = self.nodes_pub.get_subscription_count()
        now_ns = self._now_ns()
        self._publish(self.diagnostics_pub,
                      cv.diagnostic_array_msg(now_ns, self.diagnostics_statuses(now_ns)), now_ns)
        self._stats.new_window(self.engine, self._now_ns(), self.input.bad_total)

    def close(self) -> None:
        """Stop the timers and the engine thread, close the recording (its summary written).
        Idempotent."""
        if self._closed:
            return
        self._closed = True
        for timer in (getattr(self, '_tick_timer', None), getattr(self, '_diagnostics_timer', None)):
            if timer is not None:
                timer.cancel()
        if getattr(self, '_ticker', None) is not None:
            self._ticker.stop()
        if self.action_server is not None:
            self.action_server.close()
        if self.predictions is not None:
            self.predictions.close()
            self.get_logger().info(f'predictions: {self.predictions.answered} answered, '
                                   f'{self.predictions.refused} with no points')
        if self.engine is not None:
            self.engine.stop()
            from tissue_sim_ros.engine.solver.inertia_estimate import inertia_line
            inertia = self.engine.driver.inertia
            simulation = self.engine.driver.scene.simulation
            self.get_logger().info(inertia_line(simulation.mass_scaling, inertia.error, inertia.rms_n,
                                                simulation.integrator, simulation.selective_added_fraction))
        if self._recorder is not None:
            path = self._recorder.path
            self._recorder.close()
            self.get_logger().info(f'recording closed: {path}')

    def destroy_node(self):
        self.close()
        return super().destroy_node()


def main(argv=None, resolve_auto=None) -> int:
    """Run the node until SIGINT or SIGTERM; 0 on a clean stop, 2 on a refused parameter.
    ``resolve_auto``: how ``model: auto`` and ``solver.mass_scaling: auto`` become concrete keys
    (``tissue_sim_ros.cli.node_script`` passes the analysis layer's; without it such a scene is
    refused, naming the key)."""
    import functools

    from tissue_sim_ros.ros.node_main import run
    return run(functools.partial(TissueSimNode, resolve_auto=resolve_auto), help_text, argv)


if __name__ == '__main__':
    sys.exit(main())
