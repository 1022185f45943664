"""Console script ``tissue_sim_node``: the ROS 2 node (needle pose in, wrench and mesh out).

::

    tissue_sim_node --ros-args --params-file config/tissue_sim.yaml
    tissue_sim_node --help            # the parameters, their defaults, ranges and meaning

Node ``tissue_sim``. Topics (relative names; remap with ``--ros-args -r``), all reliable:

==================== ================================ ===================================
``needle/pose``      geometry_msgs/msg/PoseStamped    in: pose of the needle base frame in
                                                      ``frame_id`` (needle axis = its +z)
``needle/wrench``    geometry_msgs/msg/WrenchStamped  out, every tick: the wrench the tissue
                                                      exerts on the needle [N, N m], about
                                                      the needle base origin, expressed in
                                                      ``wrench.frame_id``
``tissue/nodes``     sensor_msgs/msg/PointCloud2      out, every tick: every vertex, fields
                                                      x y z (deformed) ux uy uz (displacement)
``tissue/surface``   shape_msgs/msg/Mesh              out, transient local: rest vertices (same
                                                      order as the cloud) and the surface
                                                      triangles; at start and after every
                                                      topology change
``tissue/marker``    visualization_msgs/msg/Marker    out, ``marker_rate_hz`` (from a tick): surface,
                                                      TRIANGLE_LIST, decimated for RViz
``/diagnostics``     diagnostic_msgs/DiagnosticArray  out, ``diagnostics_rate_hz``
==================== ================================ ===================================

Services: ``~/reset`` (std_srvs/srv/Trigger) puts the tissue at rest and the needle at its
initial pose; ``~/pause`` (std_srvs/srv/SetBool) freezes (true) or resumes (false) the
simulation; while paused the node keeps publishing the frozen state.

Timing: a timer on the node clock (``use_sim_time`` is honoured; with it and nothing on
``/clock`` no tick fires) calls :meth:`TissueSimNode.tick` ``engine.slices_per_tick`` times per
tick of 1/``publish_rate_hz``. Each slice advances the engine to the newest received pose's stamp
(never past now, and never more than one period behind it: with no pose for longer the needle is
held at the newest), the needle on the pose interpolated between received poses (see
:mod:`tissue_sim_ros.ros.pose_input`). After a tick's last slice the wrench and the cloud go out,
stamped with the tick time; they show the engine at most one period (with poses streaming, one
pose interval) behind that time, as a tick that advanced to its own time with the pose held after
the newest did. Each advance is by the node-clock time since the previous one (at most
``MAX_TICK_ADVANCE`` tick periods, and one period after a tick that overran; the excess dropped
and counted in diagnostics as ``dropped_time_s``), in as many substeps of the engine's fixed dt
as bring the engine time to the running total (so the rounding to whole substeps never
accumulates). The needle therefore moves in the engine at the speed of its poses, whatever the
timer jitter. With poses streaming, most of a tick's engine work is done before the tick time
comes, so the wrench follows the tick time by the work of its last slice only (the latency from
a pose to its wrench). A slice that does not publish starts no substep that would run into the
next slice's time (``SLICE_MARGIN_S``; on the wall clock, so not with ``use_sim_time``): the
publishing slice runs what it left, and the ticks stay on time when the machine slows a slice. A tick whose slices take longer than the period in all is a deadline
overrun; a gap of more than 1.5 periods between ticks is a missed tick; both are counted in
diagnostics.

Bad input never stops the node and never reaches a topic as NaN: see ``BAD_INPUT_KINDS`` in
:mod:`~tissue_sim_ros.ros.pose_input` (each kind logged once, counted in diagnostics). A pose the
engine refuses (``engine_refused``) leaves the needle where it is for that tick. A diverging
simulation (``SimulationDiverged``, or a non-finite wrench) is logged at ERROR and, by
``on_divergence``, reset to rest (``reset``) or frozen until ``~/reset`` (``hold``: the last
finite wrench is republished, the cloud is not).

Recording: with ``recording.directory`` set, every message in (the wire bytes as received) and
out (serialized once, the same bytes published and recorded) goes to one MCAP file per run,
named by the start time (:class:`tissue_sim_ros.io.mcap_log.McapRecorder`), with a metadata
record holding the scene, the parameters and the package version. The file is closed with its
summary on a normal exit, SIGINT and SIGTERM; after SIGKILL at most the last chunk
(``recording.chunk_interval_s``) is lost.
"""
from __future__ import annotations

import datetime as _dt
import gc
import math
import signal
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseStamped, WrenchStamped
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.serialization import deserialize_message, serialize_message
from rclpy.signals import SignalHandlerOptions
from sensor_msgs.msg import PointCloud2
from service_msgs.msg import ServiceEventInfo
from shape_msgs.msg import Mesh
from std_srvs.srv import SetBool, Trigger
from visualization_msgs.msg import Marker

from tissue_sim_ros import SimulationDiverged
from tissue_sim_ros.ros import conversions as cv
from tissue_sim_ros.ros.pose_input import PoseInput, PoseInputLimits

__all__ = ['NODE_NAME', 'PARAMETERS', 'ConfigError', 'NodeConfig', 'TissueSimNode', 'main']

NODE_NAME = 'tissue_sim'
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_NS = 1_000_000_000
#: An advance of the engine is by the node-clock time since the previous one, at most this many
#: tick periods (a slice late by more drops the excess instead of asking the engine for ever
#: more). After a tick that overran its period, the next advance is one period at most: catching
#: up the node's own overrun would make every following tick longer still (measured on the
#: default scene with one numba thread and one advance per tick, about 20 ms of engine per 20 ms
#: tick: 29 Hz with the catch-up, 43 Hz without it).
MAX_TICK_ADVANCE = 2.0
#: A slice that does not publish stops starting substeps this long before the next slice is due
#: (the executor's hop to the next call). Without a deadline a slice slowed by the machine ran
#: into the publishing slice's time and that tick went out 2-4 ms late.
SLICE_MARGIN_S = 0.5e-3


# --------------------------------------------------------------------------------------------
# parameters


@dataclass(frozen=True)
class _Param:
    name: str
    default: Any
    description: str
    low: float | int | None = None
    high: float | int | None = None
    choices: tuple = ()


#: Every parameter: name (unit in the name), default, meaning, inclusive range or choices.
PARAMETERS = (
    _Param('publish_rate_hz', 50.0, 'tick rate: the engine advances 1/rate per tick and the wrench '
           'and the node cloud are published once per tick', 1.0, 1000.0),
    _Param('engine.slices_per_tick', 4, 'the engine is advanced this many times per tick, each '
           "time to the newest pose's stamp (at most one period behind now); the wrench and the "
           'cloud go out after the last. More slices leave less engine work between a tick time '
           'and its wrench (the latency); 1 = one advance per tick', 1, 100),
    _Param('marker_rate_hz', 5.0, 'rate of the RViz surface marker (0 = no marker); sent from '
           'every k-th tick, k = round(publish_rate_hz / marker_rate_hz), after the wrench',
           0.0, 100.0),
    _Param('marker.max_triangles', 2000, 'the marker keeps every k-th surface triangle so that at '
           'most this many remain (a preview: each point is a Python object)', 1, 1_000_000),
    _Param('diagnostics_rate_hz', 1.0, 'rate of /diagnostics', 0.01, 10.0),
    _Param('scene_file', '', 'scene YAML; empty = the packaged config/liver_sample.yaml'),
    _Param('frame_id', '', 'frame of the mesh, the cloud, the marker and of needle/pose; empty = '
           "the scene's mesh frame"),
    _Param('needle_frame_id', 'needle', 'name of the needle base frame (its +z is the needle axis)'),
    _Param('wrench.frame_id', 'needle', 'frame the wrench is expressed in: needle_frame_id or '
           'frame_id (either way about the needle base origin)'),
    _Param('input.expected_frame_id', '', 'needle/pose header.frame_id accepted; empty = frame_id '
           '(there is no tf here: other frames are refused)'),
    _Param('input.reliability', 'reliable', 'QoS reliability of the needle/pose subscription '
           '(best_effort also accepts best-effort publishers)', choices=('reliable', 'best_effort')),
    _Param('input.max_jump_m', 0.005, 'a pose farther than this from the previous accepted one (or '
           'from the needle) is refused', 1e-6, 1.0),
    _Param('input.max_jump_rad', 0.5, 'a pose rotated more than this from the previous accepted one '
           'is refused', 1e-6, math.pi),
    _Param('input.stale_after_s', 0.5, 'no new pose for this long: the last one is held and '
           'diagnostics say stale', 1e-3, 3600.0),
    _Param('input.max_future_s', 0.5, 'a pose stamped further ahead of the node clock is refused '
           '(clock mismatch)', 0.0, 3600.0),
    _Param('input.max_rate_hz', 250.0, 'poses stamped closer than 1/rate to the previous one are '
           'coalesced (flood)', 1.0, 100000.0),
    _Param('input.unit_quaternion_tolerance', 0.01, 'a quaternion whose norm is off 1 by more is '
           'refused; closer, it is normalised', 1e-9, 0.5),
    _Param('recording.directory', '', 'directory for the MCAP log of the run (one file per run, '
           'named by the start time); empty = no recording'),
    _Param('recording.chunk_interval_s', 1.0, 'an MCAP chunk is closed at least this often: the '
           'most a hard kill loses', 0.01, 60.0),
    _Param('recording.compression', 'zstd', 'MCAP chunk compression', choices=('zstd', 'lz4', 'none')),
    _Param('recording.prefix', 'tissue_sim', 'log file name prefix (<prefix>_<UTC start>.mcap)'),
    _Param('on_divergence', 'reset', 'when the simulation diverges: reset it to rest, or hold the '
           'last good wrench until ~/reset', choices=('reset', 'hold')),
)


class ConfigError(ValueError):
    """A parameter the node refuses at start; the message names it and its value."""


@dataclass(frozen=True)
class NodeConfig:
    publish_rate_hz: float
    slices_per_tick: int
    marker_rate_hz: float
    marker_max_triangles: int
    diagnostics_rate_hz: float
    scene_file: str
    frame_id: str
    needle_frame_id: str
    wrench_frame_id: str
    input_limits: PoseInputLimits
    input_reliability: str
    recording_directory: str
    recording_chunk_interval_s: float
    recording_compression: str
    recording_prefix: str
    on_divergence: str
    values: dict  # every parameter by name, as read

    @property
    def period_s(self) -> float:
        return 1.0 / self.publish_rate_hz

    @property
    def wrench_frame(self) -> str:
        """'needle' or 'world': the frame argument of Scene.reaction_wrench."""
        return 'needle' if self.wrench_frame_id == self.needle_frame_id else 'world'


def _descriptor(p: _Param) -> ParameterDescriptor:
    text = p.description
    if p.choices:
        text += f' (one of: {", ".join(p.choices)})'
    d = ParameterDescriptor(description=text, read_only=True)
    if p.low is not None:
        if isinstance(p.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(p.low),
                                                         to_value=float(p.high), step=0.0)]
        else:
            d.integer_range = [IntegerRange(from_value=int(p.low), to_value=int(p.high), step=0)]
    if p.choices:
        d.additional_constraints = f'one of: {", ".join(p.choices)}'
    return d


def _type_word(value) -> str:
    if isinstance(value, bool):
        return 'a boolean'
    if isinstance(value, int):
        return 'an integer'
    if isinstance(value, float):
        return 'a floating-point number'
    if isinstance(value, str):
        return 'a string'
    return type(value).__name__


def declare_parameters(node: Node) -> dict:
    """Declare every parameter (descriptions, ranges, read-only); their values by name.

    Raises ConfigError naming the parameter and its value when rclpy refuses an override
    (wrong type, out of range).
    """
    values = {}
    for p in PARAMETERS:
        try:
            values[p.name] = node.declare_parameter(p.name, p.default, _descriptor(p)).value
        except InvalidParameterTypeException as exc:
            raise ConfigError(
                f'parameter {p.name}: {exc}; expected {_type_word(p.default)} like '
                f'{p.default!r}' + (' (write 50.0, not 50)' if isinstance(p.default, float) else '')
            ) from None
        except InvalidParameterValueException as exc:
            low, high = p.low, p.high
            raise ConfigError(f'parameter {p.name}: {exc}; expected {low} <= value <= {high}') \
                from None
        except ParameterException as exc:
            raise ConfigError(f'parameter {p.name}: {exc}') from None
    return values


def make_config(values: dict, scene_frame_id: str | None = None) -> NodeConfig:
    """Check what ranges cannot express; NodeConfig, or ConfigError naming the parameter."""
    v = dict(values)

    def refuse(name, expected):
        raise ConfigError(f'parameter {name}: {v[name]!r}; expected {expected}')

    for p in PARAMETERS:
        if p.choices and v[p.name] not in p.choices:
            refuse(p.name, f'one of {list(p.choices)}')
        if isinstance(p.default, float) and not math.isfinite(v[p.name]):
            refuse(p.name, f'a finite number in [{p.low}, {p.high}]')
    frame_id = v['frame_id'] or (scene_frame_id or 'world')
    for name, value in (('frame_id', frame_id), ('needle_frame_id', v['needle_frame_id'])):
        if not value or value != value.strip() or value.startswith('/'):
            v[name] = value
            refuse(name, 'a non-empty frame name without spaces or a leading /')
    if v['needle_frame_id'] == frame_id:
        refuse('needle_frame_id', f'a frame other than frame_id ({frame_id!r})')
    if v['wrench.frame_id'] not in (v['needle_frame_id'], frame_id):
        refuse('wrench.frame_id', f'{v["needle_frame_id"]!r} (needle_frame_id) or {frame_id!r} '
               '(frame_id)')
    if v['marker_rate_hz'] > v['publish_rate_hz']:
        refuse('marker_rate_hz', f'at most publish_rate_hz ({v["publish_rate_hz"]})')
    if v['scene_file'] and not Path(v['scene_file']).is_file():
        refuse('scene_file', 'an existing scene YAML file (or empty for the packaged default)')
    directory = v['recording.directory']
    if directory:
        try:
            Path(directory).mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            refuse('recording.directory', f'a directory that can be created ({exc.strerror})')
        if not Path(directory).is_dir():
            refuse('recording.directory', 'a directory')
        probe = Path(directory) / f'.tissue_sim_write_test_{time.monotonic_ns()}'
        try:
            probe.write_bytes(b'')
            probe.unlink()
        except OSError as exc:
            refuse('recording.directory', f'a writable directory ({exc.strerror})')
    if not v['recording.prefix'] or '/' in v['recording.prefix']:
        refuse('recording.prefix', 'a non-empty file name prefix without /')
    limits = PoseInputLimits(
        expected_frame_id=v['input.expected_frame_id'] or frame_id,
        max_jump_m=v['input.max_jump_m'], max_jump_rad=v['input.max_jump_rad'],
        stale_after_s=v['input.stale_after_s'], max_future_s=v['input.max_future_s'],
        max_rate_hz=v['input.max_rate_hz'],
        unit_quaternion_tolerance=v['input.unit_quaternion_tolerance'])
    return NodeConfig(
        publish_rate_hz=v['publish_rate_hz'], slices_per_tick=v['engine.slices_per_tick'],
        marker_rate_hz=v['marker_rate_hz'],
        marker_max_triangles=v['marker.max_triangles'], diagnostics_rate_hz=v['diagnostics_rate_hz'],
        scene_file=v['scene_file'], frame_id=frame_id, needle_frame_id=v['needle_frame_id'],
        wrench_frame_id=v['wrench.frame_id'], input_limits=limits,
        input_reliability=v['input.reliability'], recording_directory=directory,
        recording_chunk_interval_s=v['recording.chunk_interval_s'],
        recording_compression=v['recording.compression'], recording_prefix=v['recording.prefix'],
        on_divergence=v['on_divergence'], values=dict(values))


def parameters_yaml(values: dict, node_name: str = NODE_NAME) -> str:
    """The parameters as a ROS parameter file (nested YAML under ``<node>: ros__parameters:``)."""
    nested: dict = {}
    for name, value in values.items():
        parts = name.split('.')
        d = nested
        for part in parts[:-1]:
            d = d.setdefault(part, {})
        d[parts[-1]] = value
    return yaml.safe_dump({node_name: {'ros__parameters': nested}}, sort_keys=False)


def help_text() -> str:
    lines = [__doc__.split('\n\n')[0].strip(), '', 'Parameters (--ros-args -p name:=value or '
             '--params-file FILE; see config/tissue_sim.yaml):']
    for p in PARAMETERS:
        rng = f' [{p.low} .. {p.high}]' if p.low is not None else ''
        rng += f' {{{", ".join(p.choices)}}}' if p.choices else ''
        lines.append(f'  {p.name} = {p.default!r}{rng}\n      {p.description}')
    return '\n'.join(lines)


# --------------------------------------------------------------------------------------------
# QoS

def _qos(depth: int, transient_local: bool = False,
         reliability: ReliabilityPolicy = ReliabilityPolicy.RELIABLE) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST, depth=depth, reliability=reliability,
        durability=DurabilityPolicy.TRANSIENT_LOCAL if transient_local else DurabilityPolicy.VOLATILE)


WRENCH_QOS = _qos(10)
NODES_QOS = _qos(2)
SURFACE_QOS = _qos(1, transient_local=True)
MARKER_QOS = _qos(1)
DIAGNOSTICS_QOS = _qos(10)


class _Ring:
    """Last ``n`` values (preallocated), for percentiles in diagnostics and the bench."""

    def __init__(self, n: int, dtype=np.float64):
        self.values = np.zeros(max(1, int(n)), dtype=dtype)
        self.count = 0

    def add(self, x: float) -> None:
        self.values[self.count % self.values.size] = x
        self.count += 1

    def array(self) -> np.ndarray:
        return self.values[:min(self.count, self.values.size)]

    def percentile(self, q: float) -> float:
        a = self.array()
        return float(np.percentile(a, q)) if a.size else float('nan')


# --------------------------------------------------------------------------------------------
# the node


class TissueSimNode(Node):
    """The ``tissue_sim`` node. ``scene``: an engine scene to use instead of loading
    ``scene_file`` (tests inject one); other keyword arguments go to ``rclpy.node.Node``.

    Raises ConfigError (a parameter refused, or the scene file not loaded) from the constructor.
    """

    def __init__(self, *, scene=None, node_name: str = NODE_NAME, **node_kwargs):
        super().__init__(node_name, **node_kwargs)
        self._recorder = None
        self._closed = False
        try:
            self._set_up(scene)
        except BaseException:
            # a half-built node left to the garbage collector takes its logger's /rosout
            # registration with it whenever it is collected, even from a later node of that name
            self.destroy_node()
            raise

    def _set_up(self, scene) -> None:
        values = declare_parameters(self)
        if scene is None:
            scene = self._load_scene(values['scene_file'])
        self.scene = scene
        self.config = make_config(values, getattr(scene, 'mesh_frame_id', None))
        cfg = self.config
        from tissue_sim_ros.engine.needle import NeedleInputError
        self._needle_input_error = NeedleInputError

        self.input = PoseInput(cfg.input_limits, reference_pose=scene.needle_pose)
        self._period_s = cfg.period_s
        self._period_ns = int(round(cfg.period_s * _NS))
        self._slices = cfg.slices_per_tick
        self._slice_s = cfg.period_s / cfg.slices_per_tick
        self._schedule0_ns: int | None = None  # scheduled time of the timer's first call
        self._published_tick = -1  # index of the last tick published, on that schedule
        self._tick_step_s = 0.0  # engine time, substeps and work of the current tick's slices
        self._tick_substeps = 0
        self._tick_work_s = 0.0
        self._logged_kinds: set[str] = set()
        self.paused = False
        self.held = False  # diverged with on_divergence = hold
        self.divergences = 0
        self.simulated_s = 0.0  # simulated time advanced since start (resets do not rewind it)
        # the engine time each tick advances to: the engine steps in multiples of its dt, so
        # each advance() asks for what brings it to this target, and the rounding never adds up
        self._sim_target_s = float(scene.time)
        self._engine_clock_ns: int | None = None  # node clock the engine was last advanced to
        self.dropped_time_s = 0.0  # time not simulated because a tick came too late
        self._overran = False  # the previous tick's work took longer than a period
        self.ticks = 0
        self.deadline_overruns = 0
        self.missed_ticks = 0
        self._last_wrench = (np.zeros(3), np.zeros(3))
        self._last_substeps = 0
        self._topology_version = None
        self._triangles = None
        self._deformed = np.empty((0, 3))
        self._pending_receipts: list[int] = []
        self._last_tick_wall: float | None = None
        window = int(math.ceil(cfg.publish_rate_hz * 10))
        self.stats = {name: _Ring(window) for name in
                      ('tick_work_s', 'step_s', 'tick_interval_s', 'latency_s', 'substeps')}
        # per engine advance: the node-clock time it went to and the time it advanced
        self.stats['slice_ns'] = _Ring(window * self._slices, np.int64)  # ns: beyond float64
        self.stats['advance_s'] = _Ring(window * self._slices)
        self.stats['advance_steps'] = _Ring(window * self._slices, np.int64)  # substeps each ran
        self.stats['advances_at_tick'] = _Ring(window, np.int64)  # advances made before each tick
        self._window = {'ticks': 0, 'step_s': 0.0, 'step_max_s': 0.0, 'overruns': 0,
                        'wall0': time.perf_counter(), 'sim0': 0.0, 'clock0': None,
                        'bad0': self.input.bad_total}

        # publishers and subscription (names resolved: that is what the recording shows)
        self.wrench_pub = self.create_publisher(WrenchStamped, 'needle/wrench', WRENCH_QOS)
        self.nodes_pub = self.create_publisher(PointCloud2, 'tissue/nodes', NODES_QOS)
        self.surface_pub = self.create_publisher(Mesh, 'tissue/surface', SURFACE_QOS)
        self.marker_pub = (self.create_publisher(Marker, 'tissue/marker', MARKER_QOS)
                           if cfg.marker_rate_hz > 0 else None)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics',
                                                     DIAGNOSTICS_QOS)
        reliability = (ReliabilityPolicy.RELIABLE if cfg.input_reliability == 'reliable'
                       else ReliabilityPolicy.BEST_EFFORT)
        self.pose_qos = _qos(100, reliability=reliability)  # absorbs a 1 kHz flood during a tick
        self.pose_sub = self.create_subscription(PoseStamped, 'needle/pose', self._on_pose,
                                                 self.pose_qos, raw=True)
        self.reset_srv = self.create_service(Trigger, '~/reset', self._on_reset)
        self.pause_srv = self.create_service(SetBool, '~/pause', self._on_pause)
        self._service_calls = 0

        if cfg.recording_directory:
            self._start_recording()
        self._publish_surface(self._now_ns())
        self._tick_timer = self.create_timer(self._slice_s, self.tick)
        self._sim_time = bool(self.get_parameter('use_sim_time').value)
        # the marker (milliseconds of Python objects) goes out from a tick, after its wrench and
        # cloud: a timer of its own could fire just before a tick and delay it
        self._marker_every = (max(1, round(cfg.publish_rate_hz / cfg.marker_rate_hz))
                              if self.marker_pub is not None else 0)
        self._diagnostics_timer = self.create_timer(1.0 / cfg.diagnostics_rate_hz,
                                                    self.publish_diagnostics)
        self.get_logger().info(
            f'ticking at {cfg.publish_rate_hz:g} Hz ({self._slices} engine slices per tick) on '
            f'{self._scene_label()}; wrench in '
            f'{cfg.wrench_frame_id!r}, mesh in {cfg.frame_id!r}'
            + (f'; recording to {self._recorder.path}' if self._recorder else '; not recording'))

    # -- set-up -----------------------------------------------------------------------------

    def _load_scene(self, scene_file: str):
        from tissue_sim_ros.engine.scene import Scene, default_scene_path
        path = scene_file or default_scene_path()
        try:
            return Scene.from_file(path)
        except FileNotFoundError as exc:
            raise ConfigError(f'parameter scene_file: {scene_file!r}: {exc}') from None
        except (ValueError, KeyError, TypeError, OSError, yaml.YAMLError) as exc:
            raise ConfigError(f'parameter scene_file: {str(path)!r} was refused: {exc}') from None

    def _scene_label(self) -> str:
        return self.config.scene_file or 'the default scene'

    def _start_recording(self) -> None:
        from tissue_sim_ros.io.mcap_log import McapRecorder
        cfg = self.config
        metadata = {
            'scene': str(getattr(self.scene, 'text', '')),
            'scene_file': cfg.scene_file or '(packaged default)',
            'parameters': parameters_yaml(cfg.values, self.get_name()),
            'node': self.get_fully_qualified_name(),
            'started_at': _dt.datetime.now(_dt.timezone.utc).isoformat(),
            'ros_distro': 'jazzy',
        }
        self._recorder = McapRecorder.create(
            cfg.recording_directory, prefix=cfg.recording_prefix, metadata=metadata,
            chunk_interval_s=cfg.recording_chunk_interval_s,
            compression=cfg.recording_compression)
        rec = self._recorder
        for pub, type_name, qos in (
                (self.wrench_pub, 'geometry_msgs/msg/WrenchStamped', WRENCH_QOS),
                (self.nodes_pub, 'sensor_msgs/msg/PointCloud2', NODES_QOS),
                (self.surface_pub, 'shape_msgs/msg/Mesh', SURFACE_QOS),
                (self.marker_pub, 'visualization_msgs/msg/Marker', MARKER_QOS),
                (self.diagnostics_pub, 'diagnostic_msgs/msg/DiagnosticArray', DIAGNOSTICS_QOS)):
            if pub is not None:
                rec.add_topic(pub.topic_name, type_name, cv.qos_to_dict(qos))
        rec.add_topic(self.pose_sub.topic_name, 'geometry_msgs/msg/PoseStamped',
                      cv.qos_to_dict(self.pose_qos))
        for srv, type_name in ((self.reset_srv, 'std_srvs/srv/Trigger_Event'),
                               (self.pause_srv, 'std_srvs/srv/SetBool_Event')):
            rec.add_topic(self._event_topic(srv), type_name, cv.qos_to_dict(_qos(10)))

    def _event_topic(self, service) -> str:
        return self.resolve_service_name(service.srv_name) + '/_service_event'

    def _record_call(self, service, srv_type, request, response) -> None:
        """Record a service call as rosbag2 records service introspection (contents): a
        REQUEST_RECEIVED event with the request and a RESPONSE_SENT event with the response, on
        ``<service>/_service_event``."""
        if self._recorder is None:
            return
        self._service_calls += 1
        now_ns = self._now_ns()
        for event_type, requests, responses in ((ServiceEventInfo.REQUEST_RECEIVED, [request], []),
                                                (ServiceEventInfo.RESPONSE_SENT, [], [response])):
            event = srv_type.Event()
            event.info.event_type = event_type
            event.info.stamp = cv.ns_to_stamp(now_ns)
            event.info.sequence_number = self._service_calls
            event.request = requests
            event.response = responses
            self._recorder.write(self._event_topic(service), serialize_message(event), now_ns)

    @property
    def recording_path(self) -> Path | None:
        return None if self._recorder is None else self._recorder.path

    def _now_ns(self) -> int:
        return self.get_clock().now().nanoseconds

    def _publish(self, publisher, msg, now_ns: int | None = None) -> None:
        """Publish; when recording, serialize once and publish and record the same bytes."""
        if self._recorder is None:
            publisher.publish(msg)
            return
        data = serialize_message(msg)
        publisher.publish(data)
        self._recorder.write(publisher.topic_name, data,
                             self._now_ns() if now_ns is None else now_ns)

    def _log_once(self, kind: str, text: str, level: str = 'warning') -> None:
        if kind in self._logged_kinds:
            return
        self._logged_kinds.add(kind)
        getattr(self.get_logger(), level)(f'{text} (logged once for {kind}; counted in diagnostics)')

    # -- input ------------------------------------------------------------------------------

    def _on_pose(self, data: bytes) -> None:
        receipt_ns = self._now_ns()
        if self._recorder is not None:
            self._recorder.write(self.pose_sub.topic_name, data, receipt_ns)
        msg = deserialize_message(data, PoseStamped)
        position, orientation, frame_id, stamp_ns = cv.pose_from_msg(msg)
        kind, detail = self.input.offer(position, orientation, frame_id, stamp_ns, receipt_ns)
        if kind is not None:
            self._log_once(kind, f'needle/pose: {kind}: {detail}')
        if kind in (None, 'flood', 'unstamped'):
            self._pending_receipts.append(receipt_ns)

    def _drain_poses(self, limit: int = 1000) -> None:
        """Take every pose waiting in the subscription now (at most ``limit``).

        The executor takes one message per subscription per wait: when ticks overrun, the timer is
        ready at every wait and poses would be taken at the tick rate only, the backlog growing
        until the queue drops them. Taking them here (the same rclpy call the executor makes)
        keeps the input current whatever the tick costs.
        """
        handle = getattr(self.pose_sub, 'handle', None)
        if handle is None or not hasattr(handle, 'take_message'):
            return
        for _ in range(limit):
            with handle:
                taken = handle.take_message(PoseStamped, True)
            if taken is None:
                return
            self._on_pose(taken[0])

    # -- the tick ---------------------------------------------------------------------------

    def tick(self) -> None:
        """One slice of a tick: advance the engine as far as the received poses reach (the
        newest stamp, at most one period behind now), then after the tick's last slice publish
        the wrench and the cloud stamped with the tick time.

        Advancing to now would hold the needle at the newest pose until the next arrives: with
        100 Hz poses and 5 ms slices a stop-go whose inertial force spikes punctured the capsule
        0.7 mm early, and a needle standing still at the sampled step read 5 % low at 5 mm/s."""
        wall0 = time.perf_counter()
        self._drain_poses()  # before the slice time: a pose taken now is older than it
        now_ns = self._now_ns()
        publish, until_next_ns = self._last_slice_of_tick(now_ns)
        if publish:
            if self._last_tick_wall is not None:
                interval = wall0 - self._last_tick_wall
                self.stats['tick_interval_s'].add(interval)
                if interval > 1.5 * self._period_s:
                    self.missed_ticks += int(round(interval / self._period_s)) - 1
            self._last_tick_wall = wall0
        if self.paused or self.held:
            self._engine_clock_ns = now_ns  # that time is not caught up later
        else:
            newest = self.input.newest()
            to_ns = now_ns if newest is None else \
                min(now_ns, max(int(newest[0]), now_ns - self._period_ns))
            # a slice that does not publish ends before the next slice is due, by the last
            # substep's wall time; the publishing slice runs what it left (SLICE_MARGIN_S)
            deadline = None if publish or self._sim_time else \
                wall0 + until_next_ns / _NS - SLICE_MARGIN_S
            if self._engine_clock_ns is None or to_ns > self._engine_clock_ns:
                self._advance_engine(to_ns, deadline)
                self._engine_clock_ns = to_ns
            elif self.scene.time + self.scene.dt <= self.scene.target_time:  # what a deadline left
                self._advance_engine(self._engine_clock_ns, deadline)
        if publish:
            self._publish_tick(now_ns, wall0)
        else:
            self._tick_work_s += time.perf_counter() - wall0

    def _last_slice_of_tick(self, now_ns: int) -> tuple[bool, int]:
        """(Whether this timer call ends a tick, ns until the timer's next call). A call ends a
        tick when it is the last slice of a tick on the timer's own schedule, or the first call
        after a tick whose last slice the executor skipped (late)."""
        period_ns = self._tick_timer.timer_period_ns
        until_next = self._tick_timer.time_until_next_call()
        until_next = until_next if until_next is not None else period_ns
        # the scheduled time of this call: the timer's next call less one period (rcl keeps the
        # phase of its schedule when calls are missed)
        scheduled = now_ns + until_next - period_ns
        if self._schedule0_ns is None:
            self._schedule0_ns = scheduled
        index = int(round((scheduled - self._schedule0_ns) / period_ns))
        tick, position = divmod(index, self._slices)
        if position == self._slices - 1:
            self._published_tick = tick
            return True, until_next
        if tick > self._published_tick + 1:  # the previous tick's last slice never ran
            self._published_tick = tick - 1
            return True, until_next
        return False, until_next

    def _advance_engine(self, to_ns: int, deadline: float | None = None) -> None:
        """Advance the engine by the node-clock time since it was last advanced, to the pose at
        ``to_ns``; no substep starts that would end past ``deadline`` (perf_counter s), the rest
        is left to the next slice."""
        scene = self.scene
        target = self.input.pose_at(to_ns)
        if target is None:
            target = scene.needle_pose
        step0 = time.perf_counter()
        # the engine follows the node clock: each advance is by the node-clock time since the
        # previous one (at most MAX_TICK_ADVANCE tick periods, and one tick period after a tick
        # that overran, the rest dropped and counted), so the needle moves at the speed of its
        # poses
        advance_s = self._slice_s
        if self._engine_clock_ns is not None:
            advance_s = max(0.0, (to_ns - self._engine_clock_ns) / _NS)
            limit = self._period_s if self._overran else MAX_TICK_ADVANCE * self._period_s
            if advance_s > limit:
                self.dropped_time_s += advance_s - limit
                advance_s = limit
        self._sim_target_s += advance_s
        self.stats['slice_ns'].add(to_ns)
        self.stats['advance_s'].add(advance_s)
        duration = max(0.0, self._sim_target_s - float(scene.target_time))
        substeps = 0
        try:
            try:
                substeps = scene.advance(duration, target[0], target[1], deadline)
            except self._needle_input_error as exc:
                self.input.count('engine_refused')
                self._log_once('engine_refused',
                               f'the engine refused the needle pose, holding the needle: {exc}')
                hold = scene.needle_pose
                substeps = scene.advance(duration, hold[0], hold[1])
            force, torque = scene.reaction_wrench(self.config.wrench_frame)
            force = np.asarray(force, dtype=np.float64)
            torque = np.asarray(torque, dtype=np.float64)
            if not (np.isfinite(force).all() and np.isfinite(torque).all()):
                raise SimulationDiverged(
                    f'non-finite reaction wrench {force.tolist()} {torque.tolist()}',
                    self.ticks, float(scene.time), float(scene.dt), float('nan'))
            largest = float(np.abs(scene.displacement).max())
            if not largest < _FLOAT32_MAX:   # the cloud goes out as float32: never inf on a topic
                raise SimulationDiverged(
                    f'displacement {largest:.3g} m does not fit the float32 cloud',
                    self.ticks, float(scene.time), float(scene.dt), float('nan'))
            self._last_wrench = (force, torque)
            self.simulated_s += advance_s
        except SimulationDiverged as exc:
            self._diverged(exc)
        except self._needle_input_error as exc:  # even holding was refused: skip the slice
            self._log_once('engine_refused_hold', f'the engine refused to hold the needle: {exc}',
                           'error')
        self._tick_step_s += time.perf_counter() - step0
        self._tick_substeps += int(substeps)
        self.stats['advance_steps'].add(int(substeps))

    def _publish_tick(self, now_ns: int, wall0: float) -> None:
        """The tick's outputs (wrench, cloud, surface after a topology change, marker) and its
        statistics; ``wall0``: when its last slice started."""
        scene = self.scene
        step_s = self._tick_step_s
        if not (self.paused or self.held):
            self._last_substeps = self._tick_substeps
            self.stats['step_s'].add(step_s)
            self.stats['substeps'].add(self._tick_substeps)
        force, torque = self._last_wrench
        self._publish(self.wrench_pub,
                      cv.wrench_msg(force, torque, self.config.wrench_frame_id, now_ns))
        publish_ns = self._now_ns()
        if not self.held:
            self._update_deformed()
            self._publish(self.nodes_pub, cv.point_cloud_msg(
                self._deformed, scene.displacement, self.config.frame_id, now_ns), publish_ns)
            if scene.topology_version != self._topology_version:
                self._publish_surface(publish_ns)
        for receipt in self._pending_receipts:
            self.stats['latency_s'].add((publish_ns - receipt) / _NS)
        self._pending_receipts.clear()
        if self._marker_every and self.ticks % self._marker_every == 0:
            self._publish_marker(now_ns)
        work = self._tick_work_s + (time.perf_counter() - wall0)
        self._tick_step_s, self._tick_substeps, self._tick_work_s = 0.0, 0, 0.0
        self.stats['tick_work_s'].add(work)
        self.stats['advances_at_tick'].add(self.stats['advance_s'].count)
        self._overran = work > self._period_s
        self.ticks += 1
        w = self._window
        w['ticks'] += 1
        w['step_s'] += step_s
        w['step_max_s'] = max(w['step_max_s'], step_s)
        if work > self._period_s:
            self.deadline_overruns += 1
            w['overruns'] += 1

    def _update_deformed(self) -> None:
        rest = self.scene.rest_positions
        if self._deformed.shape != rest.shape:
            self._deformed = np.empty_like(rest)
        np.add(rest, self.scene.displacement, out=self._deformed)

    def _diverged(self, exc: Exception) -> None:
        self.divergences += 1
        if self.config.on_divergence == 'reset':
            self.get_logger().error(
                f'simulation diverged: {exc}; on_divergence = reset: tissue back at rest, needle '
                f'at its initial pose (divergence {self.divergences})', throttle_duration_sec=1.0)
            self._reset_scene()
        else:
            self.held = True
            self.get_logger().error(
                f'simulation diverged: {exc}; on_divergence = hold: the last finite wrench is '
                'republished until ~/reset', throttle_duration_sec=1.0)

    def _reset_scene(self) -> None:
        self.scene.reset()
        self._sim_target_s = float(self.scene.time)
        self.held = False
        self.input.reset(self.scene.needle_pose)
        force, torque = (np.asarray(a, dtype=np.float64)
                         for a in self.scene.reaction_wrench(self.config.wrench_frame))
        if not (np.isfinite(force).all() and np.isfinite(torque).all()):
            force, torque = np.zeros(3), np.zeros(3)  # never publish NaN, even from a reset
        self._last_wrench = (force, torque)

    # -- surface, marker ----------------------------------------------------------------------

    def _publish_surface(self, now_ns: int) -> None:
        scene = self.scene
        self._topology_version = scene.topology_version
        self._triangles = np.asarray(scene.surface_triangles())
        self._publish(self.surface_pub, cv.surface_mesh_msg(scene.rest_positions, self._triangles),
                      now_ns)

    def _publish_marker(self, now_ns: int) -> None:
        if self.held or self._triangles is None:
            return
        self._publish(self.marker_pub, cv.surface_marker_msg(
            self._deformed, self._triangles, self.config.frame_id, now_ns,
            max_triangles=self.config.marker_max_triangles), now_ns)

    # -- services ---------------------------------------------------------------------------

    def _on_reset(self, request, response):
        self._reset_scene()
        self.get_logger().info('~/reset: tissue at rest, needle at its initial pose')
        if self.scene.topology_version != self._topology_version:
            self._publish_surface(self._now_ns())
        response.success = True
        response.message = (f'reset: simulated time {self.scene.time:g} s, needle at '
                            f'{np.round(self.scene.needle_pose[0], 6).tolist()} m; poses farther '
                            f'than input.max_jump_m from it are refused')
        self._record_call(self.reset_srv, Trigger, request, response)
        return response

    def _on_pause(self, request, response):
        was = self.paused
        self.paused = bool(request.data)
        response.success = True
        response.message = (f'{"paused" if self.paused else "running"} at simulated time '
                            f'{self.scene.time:.6g} s' + ('' if was != self.paused else ' (unchanged)'))
        self.get_logger().info(f'~/pause: {response.message}')
        self._record_call(self.pause_srv, SetBool, request, response)
        return response

    # -- diagnostics --------------------------------------------------------------------------

    def diagnostics_statuses(self, now_ns: int) -> list:
        """The DiagnosticStatus tuples (name, level, message, values) of this moment."""
        w = self._window
        wall = time.perf_counter()
        elapsed = max(wall - w['wall0'], 1e-9)
        sim_now = float(self.scene.time)
        # engine time per node-clock time (with use_sim_time, per simulated /clock time)
        clock_elapsed = elapsed if w['clock0'] is None else (now_ns - w['clock0']) / _NS
        rtf = (self.simulated_s - w['sim0']) / clock_elapsed if clock_elapsed > 0 else float('nan')
        ticks = max(w['ticks'], 1)
        step_mean = w['step_s'] / ticks
        intervals = self.stats['tick_interval_s'].array()
        deviation = np.abs(intervals - self._period_s) if intervals.size else np.zeros(1)
        if self.held:
            level, state = 'ERROR', 'diverged, held until ~/reset'
        elif w['overruns'] or (w['ticks'] and not self.paused and not rtf >= 0.95):
            level, state = 'WARN', f'{w["overruns"]} deadline overruns in the last {elapsed:.3g} s'
        else:
            level, state = 'OK', 'paused' if self.paused else 'running'
        engine = {
            'state': 'held' if self.held else 'paused' if self.paused else 'running',
            'simulated_time_s': sim_now,
            'ticks': self.ticks,
            'tick_period_s': self._period_s,
            'step_time_ms_mean': step_mean * 1e3,
            'step_time_ms_max': w['step_max_s'] * 1e3,
            'tick_work_ms_p99': self.stats['tick_work_s'].percentile(99) * 1e3,
            'tick_period_deviation_ms_p99': float(np.percentile(deviation, 99)) * 1e3,
            'substeps_last': self._last_substeps,
            'engine_dt_s': float(self.scene.dt),
            'engine_time_behind_s': self._sim_target_s - sim_now,
            'real_time_factor': rtf,
            'compute_load': step_mean / self._period_s,
            'deadline_overruns': self.deadline_overruns,
            'missed_ticks': self.missed_ticks,
            'dropped_time_s': self.dropped_time_s,
            'divergences': self.divergences,
            'stability': 'held after divergence' if self.held else 'stable',
            'phase': str(self.scene.phase),
            'tip_depth_m': float(self.scene.tip_depth),
            'topology_version': int(self.scene.topology_version),
            'punctures': len(self.scene.puncture_events),
        }
        age = self.input.age_s(now_ns)
        stale = self.input.stale(now_ns)
        bad_new = self.input.bad_total - w['bad0']
        inp = {'poses_received': self.input.received, 'poses_accepted': self.input.accepted,
               'last_pose_age_s': 'none yet' if age is None else age, 'stale': stale,
               'latency_ms_p50': self.stats['latency_s'].percentile(50) * 1e3,
               'latency_ms_p99': self.stats['latency_s'].percentile(99) * 1e3}
        inp.update({f'bad_input.{k}': v for k, v in self.input.counts.items()})
        if bad_new:
            in_level, in_msg = 'WARN', f'{bad_new} bad poses in the last {elapsed:.3g} s'
        elif stale:
            in_level, in_msg = 'WARN', f'no pose for {age:.3g} s: holding the last one'
        elif age is None:
            in_level, in_msg = 'OK', 'no pose yet: the needle holds its initial pose'
        else:
            in_level, in_msg = 'OK', 'receiving'
        statuses = [(f'{self.get_name()}: engine', level, state, engine),
                    (f'{self.get_name()}: input', in_level, in_msg, inp)]
        if self._recorder is not None:
            st = self._recorder.stats()
            statuses.append((f'{self.get_name()}: recording', 'WARN' if st.messages_dropped else 'OK',
                             str(self._recorder.path),
                             {'messages_written': st.messages_written,
                              'messages_dropped': st.messages_dropped,
                              'messages_unsaved': st.messages_unsaved,
                              'chunks_closed': st.chunks_closed,
                              'bytes_written': st.bytes_written}))
        return statuses

    def publish_diagnostics(self) -> None:
        now_ns = self._now_ns()
        self._publish(self.diagnostics_pub,
                      cv.diagnostic_array_msg(now_ns, self.diagnostics_statuses(now_ns)), now_ns)
        self._window = {'ticks': 0, 'step_s': 0.0, 'step_max_s': 0.0, 'overruns': 0,
                        'wall0': time.perf_counter(), 'sim0': self.simulated_s,
                        'clock0': self._now_ns(),
                        'bad0': self.input.bad_total}

    # -- shutdown ---------------------------------------------------------------------------

    def close(self) -> None:
        """Stop the timers and close the recording (its summary written). Idempotent."""
        if self._closed:
            return
        self._closed = True
        for timer in (getattr(self, '_tick_timer', None),
                      getattr(self, '_diagnostics_timer', None)):
            if timer is not None:
                timer.cancel()
        if self._recorder is not None:
            path = self._recorder.path
            self._recorder.close()
            self.get_logger().info(f'recording closed: {path}')

    def destroy_node(self):
        self.close()
        return super().destroy_node()


# --------------------------------------------------------------------------------------------
# entry point


def main(argv=None) -> int:
    """Run the node until SIGINT or SIGTERM; 0 on a clean stop, 2 on a refused parameter."""
    args = list(sys.argv if argv is None else argv)
    user_args = args[1:args.index('--ros-args')] if '--ros-args' in args else args[1:]
    if '-h' in user_args or '--help' in user_args:
        print(help_text())
        return 0
    stop = threading.Event()

    def on_signal(signum, frame):  # noqa: ARG001
        stop.set()

    rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
    previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGINT, signal.SIGTERM)}
    node = None
    try:
        try:
            node = TissueSimNode()
        except ConfigError as exc:
            print(f'tissue_sim_node: {exc}', file=sys.stderr)
            return 2
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        # the start-up's objects (numba, rclpy, the scene) move out of the collector's reach: a
        # full collection walked them all, a 40-60 ms stall of the tick every few seconds
        gc.collect()
        gc.freeze()
        try:
            while not stop.is_set() and rclpy.ok():
                executor.spin_once(timeout_sec=0.1)
        except ExternalShutdownException:   # rclpy shut down from outside: close cleanly below
            return 0
        return 0
    finally:
        if node is not None:
            node.close()  # the recording first: it must not depend on rclpy shutting down well
            node.destroy_node()
        rclpy.try_shutdown()
        for sig, handler in previous.items():
            signal.signal(sig, handler)


if __name__ == '__main__':
    sys.exit(main())
