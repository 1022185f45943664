"""What a candidate needle path would do, simulated from a copy of the current state.

A planner asks before it commits the robot: from the tissue and needle as they are now
(deformation, velocity, contact, punctured layers, cut elements: the whole scene), follow these
poses of the needle base and report the wrench, the tip's depth and how far each target moves.

The copy is the scene pickled and unpickled (:func:`scene_snapshot`, :func:`scene_from_snapshot`):
every array and every piece of needle state goes with it, so a prediction continues exactly as
the live scene would under the same poses (bit for bit: test_prediction), and the live scene is
never touched. The snapshot is bytes, so it travels to a worker process as is.

A path moves the scene's first needle; in a scene with several, the others hold still and their
wrenches are columns too. A path (:class:`CandidatePath`) is times from its first pose [s] and base poses; its first pose is
where the needle is now (within the jump limit: a planner's idea of "now" may be a tick old), and
the needle then moves linearly (slerp for the orientation) from each pose to the next, as the
live node moves between received poses. :func:`check_path` refuses, naming the pose and value:
no poses, a non-finite value, a quaternion that is not unit, stamps that do not increase, a pose
farther than the jump limit from the one before (or the first from the needle), or a path longer
than the duration limit.

The answer (:class:`Prediction`) has one row per requested pose: ``time_from_start_s`` and the
columns of :func:`prediction_columns`; row 0 is the current state.
"""
from __future__ import annotations

import math
import pickle
import struct
import time
from dataclasses import dataclass, field

import numpy as np

from tissue_sim_ros.engine.needle.pose import pose_jump, validate_pose
from tissue_sim_ros.errors import PoseError

__all__ = ['WRENCH_COLUMNS', 'DEFAULT_MAX_DURATION_S', 'CandidatePath', 'Prediction',
           'prediction_columns', 'check_path', 'scene_snapshot', 'scene_from_snapshot', 'predict',
           'predict_snapshot', 'write_snapshot', 'read_snapshot']

#: The columns every prediction has: force [N] and torque [N m] about the needle base, in the
#: wrench's frame; the tip's depth below the entry point [m]; where the tip is [m] (world frame)
#: and its distance from the base frame's axis [m] (a flexible needle's bend; 0 for a rigid one).
WRENCH_COLUMNS = ('force_x_n', 'force_y_n', 'force_z_n', 'torque_x_nm', 'torque_y_nm',
                  'torque_z_nm', 'tip_depth_m', 'tip_x_m', 'tip_y_m', 'tip_z_m', 'tip_deflection_m')
#: Longest path accepted by default [s of simulated time].
DEFAULT_MAX_DURATION_S = 60.0


def prediction_columns(target_names, other_needles=()) -> list[str]:
    """The prediction's columns: :data:`WRENCH_COLUMNS` (of the needle the path moves), each
    target's displacement from its rest position [m], then, in a scene with several needles,
    each other needle's wrench (``needle/<name>/force_x_n``...; they hold still)."""
    return list(WRENCH_COLUMNS) + [f'target/{name}/displacement_m' for name in target_names] + \
        [f'needle/{name}/{column}' for name in other_needles for column in WRENCH_COLUMNS[:6]]


@dataclass
class CandidatePath:
    """Times [s] from the first pose (increasing, the first 0), base positions (k, 3) [m] and
    unit quaternions (k, 4) (x, y, z, w)."""

    times: np.ndarray
    positions: np.ndarray
    orientations: np.ndarray

    def __len__(self):
        return int(self.times.size)

    @property
    def duration_s(self) -> float:
        return float(self.times[-1]) if self.times.size else 0.0


def check_path(stamps_s, positions, orientations, *, max_jump_m: float,
               max_duration_s: float = DEFAULT_MAX_DURATION_S, start_pose=None,
               length_m: float = 0.0, field_name: str = 'path') -> CandidatePath:
    """A :class:`CandidatePath` from stamps [s] (any origin) and poses, or PoseError naming
    the pose and its value. ``start_pose``: (position, orientation) of the needle now, which the
    first pose must be within ``max_jump_m`` of; ``length_m``: the needle's length, so the tip's
    move counts toward a jump as it does in the engine."""
    stamps = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
    k = stamps.size
    if k == 0:
        raise PoseError(f'{field_name}.poses', [], 'no poses; a path needs at least one')
    try:
        positions = np.asarray(positions, dtype=np.float64).reshape(k, 3)
        orientations = np.asarray(orientations, dtype=np.float64).reshape(k, 4)
    except ValueError:
        raise PoseError(f'{field_name}.poses', (np.shape(positions), np.shape(orientations)),
                               f'expected {k} positions (x, y, z) and {k} quaternions, one per stamp') from None
    unit = np.empty_like(orientations)
    for i in range(k):
        if not math.isfinite(stamps[i]):
            raise PoseError(f'{field_name}.poses[{i}].header.stamp', float(stamps[i]), 'expected a finite time')
        if i and not stamps[i] > stamps[i - 1]:
            raise PoseError(f'{field_name}.poses[{i}].header.stamp', float(stamps[i]),
                                   f'not after poses[{i - 1}] ({stamps[i - 1]:.9g} s): stamps must increase')
        positions[i], unit[i] = validate_pose(positions[i], orientations[i], f'{field_name}.poses[{i}].pose')
    duration = float(stamps[-1] - stamps[0])
    if duration > max_duration_s:
        raise PoseError(f'{field_name}.poses[{k - 1}].header.stamp', float(stamps[-1]),
                               f'the path lasts {duration:.6g} s, more than the limit {max_duration_s:g} s')
    previous = start_pose
    for i in range(k):
        if previous is not None:
            jump = pose_jump(previous[0], previous[1], positions[i], unit[i], length_m)
            if jump.exceeds(max_jump_m):
                came_from = f'poses[{i - 1}]' if i else "the needle's current pose"
                raise PoseError(f'{field_name}.poses[{i}].pose.position', positions[i].tolist(),
                                       f'{jump.distance_m * 1e3:.4g} mm from {came_from}, more than the '
                                       f'jump limit {max_jump_m * 1e3:.4g} mm')
        previous = positions[i], unit[i]
    return CandidatePath(stamps - stamps[0], positions, unit)


@dataclass
class Prediction:
    """One row per requested pose: ``time_from_start_s`` (k,) and ``values`` (k, columns)."""

    columns: list
    time_from_start_s: np.ndarray
    values: np.ndarray
    phase: list = field(default_factory=list)
    wall_s: float = 0.0
    substeps: int = 0

    @property
    def simulated_s(self) -> float:
        return float(self.time_from_start_s[-1]) if self.time_from_start_s.size else 0.0

    @property
    def real_time_factor(self) -> float:
        return self.simulated_s / self.wall_s if self.wall_s > 0 else math.inf

    def column(self, name) -> np.ndarray:
        return self.values[:, self.columns.index(name)]


def scene_snapshot(scene) -> bytes:
    """The whole scene as bytes: state, needle and topology (a pickle; 12 MB and about 10 ms for
    the default scene)."""
    return pickle.dumps(scene, protocol=pickle.HIGHEST_PROTOCOL)


def scene_from_snapshot(snapshot: bytes):
    """A scene of its own from :func:`scene_snapshot`'s bytes."""
    return pickle.loads(snapshot)


_LENGTH = struct.Struct('<Q')


def write_snapshot(scene, path) -> int:
    """Write the scene to the file ``path`` for a worker process (:func:`read_snapshot`); returns
    its size in bytes. The arrays go out of band (pickle protocol 5): the pickle of the object
    graph is small, and the arrays' bytes are written straight from their memory by the file's
    write, which does not hold the interpreter lock, so a thread that publishes runs meanwhile."""
    buffers = []
    graph = pickle.dumps(scene, protocol=5, buffer_callback=buffers.append)
    size = 0
    with open(path, 'wb') as f:
        for part in [graph] + [b.raw() for b in buffers]:
            size += f.write(_LENGTH.pack(len(part))) + f.write(part)
    return size


def read_snapshot(path):
    """The scene :func:`write_snapshot` wrote to ``path`` (a scene of its own)."""
    with open(path, 'rb') as f:
        data = memoryview(f.read())
    parts, offset = [], 0
    while offset < len(data):
        (length,) = _LENGTH.unpack_from(data, offset)
        offset += _LENGTH.size
        parts.append(data[offset:offset + length])
        offset += length
    return pickle.loads(parts[0], buffers=[bytearray(p) for p in parts[1:]])


def predict(scene, path: CandidatePath, *, wrench_frame: str = 'world', copy: bool = True,
            on_row=None) -> Prediction:
    """Follow ``path`` from the scene's current state and return the :class:`Prediction`.

    ``copy`` (default): the scene is copied first and left as it was; False runs on ``scene``
    itself (a worker's own copy). ``on_row(k, row)``: called with each row as soon as it is
    computed (a caller streaming partial results); an exception it raises stops the prediction
    and reaches the caller (how a caller cancels). Time asked of the scene but not yet stepped is kept up
    to one
    step (the fraction the live scene carries into its next call, so the prediction steps on the
    live schedule) and dropped beyond it (the lag of an engine that ran late: the path starts
    from the state as it is). Raises SimulationDiverged
    or PoseError (a pose the engine refuses on the way)."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    wall0 = time.perf_counter()
    if copy:
        scene = scene_from_snapshot(scene_snapshot(scene))
    scene.drop_behind(scene.dt)
    driver = SimulationDriver(scene, wrench_frame=wrench_frame, on_divergence='raise')
    driver.take_state()               # the wrench of the state as it is (no step, no pose set)
    names = scene.targets.names
    columns = prediction_columns(names, scene.needle_names[1:])
    values = np.empty((len(path), len(columns)))
    phases = []
    rest = scene.targets.rest
    w, t = len(WRENCH_COLUMNS), len(WRENCH_COLUMNS) + len(names)

    def sample(k, drv):
        values[k, 0:3], values[k, 3:6] = drv.force, drv.torque
        values[k, 6] = scene.tip_depth
        values[k, 7:10], values[k, 10] = scene.needle.tip, scene.tip_deflection
        if names:
            values[k, w:t] = np.linalg.norm(scene.target_positions() - rest, axis=1)
        values[k, t:] = np.hstack([drv.forces[1:], drv.torques[1:]]).ravel()
        phases.append(str(scene.phase))
        if on_row is not None:
            on_row(k, values[k])

    sample(0, driver)
    substeps = 0
    if len(path) > 1:
        samples = driver.follow(path.times[1:], path.positions[1:], path.orientations[1:],
                                progress=lambda k, drv: sample(k + 1, drv))
        substeps = samples.substeps
    return Prediction(columns, path.times.copy(), values, phases, time.perf_counter() - wall0, substeps)


def predict_snapshot(snapshot, path: CandidatePath, wrench_frame: str = 'world', *,
                     threads: int = 1, threshold: float | None = None,
                     mass_scaling: float | None = None, on_row=None) -> Prediction:
    """:func:`predict` on a scene from a snapshot: :func:`scene_snapshot`'s bytes, or the file
    :func:`write_snapshot` wrote (a path): a worker process's entry. The element pass runs on
    ``threads`` numba threads;
    ``threshold`` and ``mass_scaling`` (None: as the snapshot has them) are a degradation-ladder
    rung's settings (engine.ladder), for a prediction cheaper than the live scene; ``on_row``: as
    :func:`predict`'s."""
    import numba
    scene = scene_from_snapshot(snapshot) if isinstance(snapshot, bytes) else read_snapshot(snapshot)
    numba.set_num_threads(min(int(threads), numba.config.NUMBA_NUM_THREADS))
    scene.model.set_threads(numba.get_num_threads())
    if threshold is not None:
        scene.model.set_nonlinearity_threshold(threshold)
    if mass_scaling is not None and mass_scaling != scene.simulation.mass_scaling:
        scene.simulation.rescale_masses(mass_scaling)
    return predict(scene, path, wrench_frame=wrench_frame, copy=False, on_row=on_row)
