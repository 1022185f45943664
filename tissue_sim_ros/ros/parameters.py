"""The node's parameters: every name with its default, range and meaning, and the checks that
ranges cannot express. No rclpy here (declaring them is :mod:`.parameter_declaration`), so tests,
the help text and the parameter file are built without a ROS graph.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from tissue_sim_ros.engine.needle.pose import DEFAULT_MAX_JUMP_M, DEFAULT_MAX_JUMP_RAD, QUATERNION_NORM_TOLERANCE
from tissue_sim_ros.ros.loop.pose_input import PoseInputLimits
from tissue_sim_ros.errors import ConfigError, InputError

__all__ = ['AUTO_THREADS_ELEMENTS', 'NODE_NAME', 'PARAMETERS', 'NodeConfig', 'make_config', 'load_scene',
           'parameters_yaml', 'help_text']

NODE_NAME = 'tissue_sim'
#: engine.threads = 0 uses one thread below this many tetrahedra, all cores above
AUTO_THREADS_ELEMENTS = 50_000
_LIMITS = PoseInputLimits()  # the input defaults live with the input

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
    _Param('engine.threads', 0, 'numba threads of the engine; 0 = auto: 1 below '
           f'{AUTO_THREADS_ELEMENTS} tetrahedra (on the default scene 2 threads are 1.4x faster '
           'for 2x the CPU), all cores above', 0, 256),
    _Param('engine.budget_fraction', 0.8, 'share of each tick period the engine thread may work; '
           'what it cannot do within it becomes lag (the tick never waits for it)', 0.05, 1.0),
    _Param('engine.max_lag_s', 0.25, 'the most simulated time the engine may be behind the '
           'received poses; beyond it the excess is dropped (the needle then reaches its pose in '
           'less simulated time), counted as dropped_time_s', 0.0, 10.0),
    _Param('engine.ladder', True, 'degrade when the engine cannot keep real time within its '
           'budget (non-linearity threshold up, then mass scaling up with fewer substeps) and '
           'recover when there is room; each change logged with its predicted error'),
    _Param('executor', 'events', "rclpy executor: 'events' (the C++ EventsExecutor, the least "
           "overhead per callback) or 'single_threaded'", choices=('events', 'single_threaded')),
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
    _Param('input.expected_frame_id', '', 'needle/pose header.frame_id taken as is; empty = frame_id. '
           'A pose in another frame is transformed into frame_id by TF (refused when TF cannot relate '
           'them: bad_input.tf_unavailable)'),
    _Param('input.source', 'topic', "where the needle's pose comes from: 'topic' (needle/pose) or 'tf' "
           '(the TF frame input.tf_frame relative to frame_id, at the rate TF updates it)',
           choices=('topic', 'tf')),
    _Param('input.tf_frame', '', "with input.source tf: the TF frame that carries the needle (e.g. the "
           "robot's tool0); the needle base is input.tf_offset_* from it"),
    _Param('input.tf_offset_position_m', [0.0, 0.0, 0.0], 'the needle base origin in input.tf_frame '
           '[x, y, z] (e.g. [0, 0, 0.15]: 150 mm along the tool axis)'),
    _Param('input.tf_offset_orientation_xyzw', [0.0, 0.0, 0.0, 1.0], 'the needle base orientation in '
           'input.tf_frame [qx, qy, qz, qw] (the needle axis is the base frame\'s +z)'),
    _Param('input.tf_timeout_s', 0.1, 'a transform at most this much older than the time asked for is '
           'used as it is; older: the pose is refused (bad_input.tf_unavailable)', 0.0, 10.0),
    _Param('tf.publish', True, 'broadcast the tissue frame (from its registration), the needle base and '
           'tip frames and each target\'s frame on /tf and /tf_static'),
    _Param('registration.parent_frame_id', '', "the robot's frame the tissue is registered in (e.g. "
           'base_link); empty = no registration published (frame_id is a root, or another node places it)'),
    _Param('registration.tissue_position_m', [0.0, 0.0, 0.0], 'the tissue frame (frame_id) origin in '
           'registration.parent_frame_id [x, y, z]; ~/set_tissue_pose changes it at run time'),
    _Param('registration.tissue_orientation_xyzw', [0.0, 0.0, 0.0, 1.0], 'the tissue frame orientation '
           'in registration.parent_frame_id [qx, qy, qz, qw]'),
    _Param('registration.needle_at_first_pose', False, 'the needle starts where the first pose received '
           'puts it, however far from the scene\'s initial pose (as ~/register_needle with that pose)'),
    _Param('input.reliability', 'reliable', 'QoS reliability of the needle/pose subscription '
           '(best_effort also accepts best-effort publishers)', choices=('reliable', 'best_effort')),
    _Param('input.max_jump_m', DEFAULT_MAX_JUMP_M, 'a pose farther than this from the previous '
           'accepted one (or from the needle) is refused, unless the stream was stale (a gap): then '
           'it starts a new stream the needle joins at input.resync_speed_m_s', 1e-6, 1.0),
    _Param('input.max_jump_rad', DEFAULT_MAX_JUMP_RAD, 'a pose rotated more than this from the '
           'previous accepted one is refused (as above)', 1e-6, math.pi),
    _Param('input.resync_speed_m_s', _LIMITS.resync_speed_m_s, 'after a gap, the needle joins the '
           'new stream of poses at most this fast', 1e-5, 1.0),
    _Param('input.resync_speed_rad_s', _LIMITS.resync_speed_rad_s, 'after a gap, the needle turns '
           'toward the new stream at most this fast', 1e-4, 10.0),
    _Param('input.stale_after_s', 0.5, 'no new pose for this long: the last one is held and '
           'diagnostics say stale', 1e-3, 3600.0),
    _Param('input.max_future_s', 0.5, 'a pose stamped further ahead of the node clock is refused '
           '(clock mismatch)', 0.0, 3600.0),
    _Param('input.max_rate_hz', 250.0, 'poses stamped closer than 1/rate to the previous one are '
           'coalesced (flood)', 1.0, 100000.0),
    _Param('input.unit_quaternion_tolerance', QUATERNION_NORM_TOLERANCE, 'a quaternion whose norm is off 1 by more is '
           'refused; closer, it is normalised', 1e-9, 0.5),
    _Param('recording.directory', '', 'directory for the MCAP log of the run (one file per run, '
           'named by the start time); empty = no recording'),
    _Param('recording.chunk_interval_s', 1.0, 'the most a hard kill loses of the log (chunks '
           'close when their oldest message is half of it old)', 0.01, 60.0),
    _Param('recording.compression', 'zstd', 'MCAP chunk compression', choices=('zstd', 'lz4', 'none')),
    _Param('recording.nodes_rate_hz', 5.0, 'rate at which tissue/nodes (the deformed cloud, most '
           'of a log) is recorded, from every k-th tick, k = round(publish_rate_hz / rate); it is '
           'still published every tick. 0 = not recorded', 0.0, 1000.0),
    _Param('recording.prefix', 'tissue_sim', 'log file name prefix (<prefix>_<UTC start>.mcap)'),
    _Param('prediction.workers', 0, 'worker processes answering plan/candidate (at a lower '
           'priority than the live engine); 0 = auto: one per 4 cores beyond the engine\'s, at '
           'least 1; -1 = predictions off (no subscription)', -1, 256),
    _Param('prediction.threads', 0, 'numba threads of each prediction worker; 0 = auto: the '
           "cores beyond the engine's shared among the workers", 0, 256),
    _Param('prediction.prestart', True, 'start the workers with the node (their first answer at '
           'full speed); false: at the first request'),
    _Param('prediction.max_error', 0.02, 'predictions run on the cheapest degradation-ladder rung '
           "whose measured axial-force error (NRMSE against the scene as configured) is at most "
           'this (the default scene: mass scaling x16, 0.013, 12x real time on one core); 0 = on the '
           'live scene as it is (a prediction then equals the live run)', 0.0, 1.0),
    _Param('prediction.max_duration_s', 60.0, 'longest candidate path accepted [s]', 0.01, 3600.0),
    _Param('on_divergence', 'reset', 'when the simulation diverges: reset it to rest, or hold the '
           'last good wrench until ~/reset', choices=('reset', 'hold')),
)


@dataclass(frozen=True)
class NodeConfig:
    publish_rate_hz: float
    engine_threads: int
    budget_fraction: float
    max_lag_s: float
    ladder: bool
    executor: str
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
    recording_nodes_rate_hz: float
    recording_prefix: str
    on_divergence: str
    input_source: str
    tf_frame: str
    tf_offset: tuple              # (position (3,), orientation (4,)) of the needle base in tf_frame
    tf_timeout_s: float
    tf_publish: bool
    registration_parent: str
    tissue_pose: tuple            # (position (3,), orientation (4,)) of frame_id in registration_parent
    needle_at_first_pose: bool
    prediction_workers: int
    prediction_threads: int
    prediction_prestart: bool
    prediction_max_error: float
    prediction_max_duration_s: float
    values: dict  # every parameter by name, as read

    @property
    def period_s(self) -> float:
        return 1.0 / self.publish_rate_hz

    def threads_for(self, n_elements: int) -> int:
        """The engine's numba threads for a mesh of ``n_elements`` (engine.threads, 0 = auto)."""
        if self.engine_threads:
            return self.engine_threads
        import os
        return 1 if n_elements < AUTO_THREADS_ELEMENTS else len(os.sched_getaffinity(0))

    @property
    def input_description(self) -> str:
        """Where the first needle's poses come from, in words (diagnostics)."""
        return 'needle/pose' if self.input_source == 'topic' else f'tf: {self.tf_frame} in {self.frame_id}'

    @property
    def wrench_frame(self) -> str:
        """'needle' or 'world': the frame argument of Scene.reaction_wrench."""
        return 'needle' if self.wrench_frame_id == self.needle_frame_id else 'world'


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
    for name in ('marker_rate_hz', 'recording.nodes_rate_hz'):
        if v[name] > v['publish_rate_hz']:
            refuse(name, f'at most publish_rate_hz ({v["publish_rate_hz"]})')
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
    tf_offset = _pose_parameter(v, 'input.tf_offset_position_m', 'input.tf_offset_orientation_xyzw', refuse)
    tissue_pose = _pose_parameter(v, 'registration.tissue_position_m',
                                  'registration.tissue_orientation_xyzw', refuse)
    if v['input.source'] == 'tf':
        own = {frame_id, v['needle_frame_id'], f"{v['needle_frame_id']}_tip"}
        if not v['input.tf_frame'] or v['input.tf_frame'] in own:
            refuse('input.tf_frame',
                   f'a TF frame the robot publishes (input.source is tf), not one of {sorted(own)}')
    parent = v['registration.parent_frame_id']
    if parent and (parent == frame_id or parent != parent.strip() or parent.startswith('/')):
        refuse('registration.parent_frame_id', f'a frame name other than frame_id ({frame_id!r})')
    if not v['recording.prefix'] or '/' in v['recording.prefix']:
        refuse('recording.prefix', 'a non-empty file name prefix without /')
    limits = PoseInputLimits(
        expected_frame_id=v['input.expected_frame_id'] or frame_id,
        max_jump_m=v['input.max_jump_m'], max_jump_rad=v['input.max_jump_rad'],
        stale_after_s=v['input.stale_after_s'], max_future_s=v['input.max_future_s'],
        max_rate_hz=v['input.max_rate_hz'],
        unit_quaternion_tolerance=v['input.unit_quaternion_tolerance'],
        resync_speed_m_s=v['input.resync_speed_m_s'], resync_speed_rad_s=v['input.resync_speed_rad_s'])
    return NodeConfig(
        publish_rate_hz=v['publish_rate_hz'], engine_threads=v['engine.threads'],
        budget_fraction=v['engine.budget_fraction'], max_lag_s=v['engine.max_lag_s'],
        ladder=v['engine.ladder'], executor=v['executor'],
        marker_rate_hz=v['marker_rate_hz'],
        marker_max_triangles=v['marker.max_triangles'], diagnostics_rate_hz=v['diagnostics_rate_hz'],
        scene_file=v['scene_file'], frame_id=frame_id, needle_frame_id=v['needle_frame_id'],
        wrench_frame_id=v['wrench.frame_id'], input_limits=limits,
        input_reliability=v['input.reliability'], recording_directory=directory,
        recording_chunk_interval_s=v['recording.chunk_interval_s'],
        recording_compression=v['recording.compression'],
        recording_nodes_rate_hz=v['recording.nodes_rate_hz'], recording_prefix=v['recording.prefix'],
        on_divergence=v['on_divergence'], input_source=v['input.source'], tf_frame=v['input.tf_frame'],
        tf_offset=tf_offset, tf_timeout_s=v['input.tf_timeout_s'], tf_publish=v['tf.publish'],
        registration_parent=parent, tissue_pose=tissue_pose,
        needle_at_first_pose=v['registration.needle_at_first_pose'],
        prediction_workers=v['prediction.workers'],
        prediction_threads=v['prediction.threads'], prediction_prestart=v['prediction.prestart'],
        prediction_max_error=v['prediction.max_error'],
        prediction_max_duration_s=v['prediction.max_duration_s'], values=dict(values))


def _pose_parameter(v: dict, position_name: str, orientation_name: str, refuse) -> tuple:
    """(position (3,), unit quaternion (4,)) from a pair of array parameters; a wrong length, a
    non-finite value or a quaternion off unit by more than the input's tolerance is refused."""
    import numpy as np
    position = np.asarray(v[position_name], dtype=np.float64)
    orientation = np.asarray(v[orientation_name], dtype=np.float64)
    if position.shape != (3,) or not np.isfinite(position).all():
        refuse(position_name, 'three finite numbers [x, y, z] in metres')
    norm = float(np.linalg.norm(orientation)) if orientation.shape == (4,) else 0.0
    if orientation.shape != (4,) or not np.isfinite(orientation).all() or \
            abs(norm - 1.0) > v['input.unit_quaternion_tolerance']:
        refuse(orientation_name, f'a unit quaternion [qx, qy, qz, qw] (norm {norm:.6g})')
    return position, orientation / norm


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


def help_text(summary: str = '') -> str:
    """``tissue_sim_node --help``: the summary line, then every parameter with its range."""
    lines = [summary, '', 'Parameters (--ros-args -p name:=value or '
             '--params-file FILE; see config/tissue_sim.yaml):']
    for p in PARAMETERS:
        rng = f' [{p.low} .. {p.high}]' if p.low is not None else ''
        rng += f' {{{", ".join(p.choices)}}}' if p.choices else ''
        lines.append(f'  {p.name} = {p.default!r}{rng}\n      {p.description}')
    return '\n'.join(lines)


def load_scene(scene_file: str, resolve_auto=None):
    """The scene of ``scene_file`` (empty: the packaged default), or ConfigError naming it;
    ``resolve_auto``: as ``Scene.from_file``'s (the console script passes the analysis layer's,
    for ``model: auto`` and ``solver.mass_scaling: auto``)."""
    from tissue_sim_ros.engine.scene.scene import Scene, default_scene_path
    path = scene_file or default_scene_path()
    try:
        return Scene.from_file(path, resolve_auto=resolve_auto)
    except FileNotFoundError as exc:
        raise ConfigError(f'parameter scene_file: {scene_file!r}: {exc}') from None
    except (InputError, OSError) as exc:
        raise ConfigError(f'parameter scene_file: {str(path)!r} was refused: {exc}') from None
