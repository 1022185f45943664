"""Predictions for a planner: ``plan/candidate`` in, ``plan/prediction`` out.

A planner publishes a candidate path of the needle base (``nav_msgs/Path`` in ``frame_id`` or a
frame TF relates to it, each pose's stamp its time, the first pose where the needle is now); the
action ``~/predict_path`` asks the same with feedback (:mod:`~.prediction_action`: a goal's request
streams its rows through a :class:`Progress` file and can be cancelled). The node answers on
``plan/prediction`` with a ``trajectory_msgs/JointTrajectory``: ``header.stamp`` copied from the
request's (how a planner pairs answers with questions), ``header.frame_id`` the wrench's frame,
``joint_names`` the columns (engine.prediction.prediction_columns: force, torque, tip depth, each
target's displacement), one point per requested pose with its values in ``positions`` and
``time_from_start`` from the request's stamps (the wrench's frame and sign as on ``needle/wrench``). A refused path, or one the engine cannot follow
(a divergence, a pose it refuses on the way), is answered with no points; the reason goes to the
log (once per kind) and to the ``predictions`` diagnostics status.

Off the live loop: the engine thread only writes a copy of the scene to a file in shared memory
(engine.prediction.write_snapshot: 12 MB and a few ms on the default scene, its arrays written
without the interpreter lock so the tick runs meanwhile; once per engine advance however many
requests share it, deleted when no request needs it) and hands its name to a pool of worker
processes, which run at a lower priority (nice +{niceness}) so the live engine keeps its core
(their numba threads: the cores less the engine's, shared). Answers go out in the order the
requests came, from the pool's thread, never from the tick. Requests arrive as bytes and are
decoded and checked on a thread of their own, so a burst costs the executor (which runs the tick)
no more than queueing them. A file, not the pool's pipe: sending the 12 MB through the pipe would
hold the interpreter lock long enough to stall the tick in a burst. ``prediction.max_error`` > 0
runs predictions on the cheapest degradation-ladder rung whose measured error
(engine.ladder_probe) is within it.
"""
from __future__ import annotations

import contextlib
import multiprocessing
import os
import queue
import shutil
import tempfile
import threading
import time
from collections import Counter, deque
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Duration
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from tissue_sim_ros.engine.needle.pose import pose_jump
from tissue_sim_ros.errors import PoseError
from tissue_sim_ros.engine.prediction import (check_path, predict_snapshot, prediction_columns,
                                              write_snapshot)
from tissue_sim_ros.errors import InputError, SimulationDiverged
from tissue_sim_ros.system.thread_names import name_os_thread
from tissue_sim_ros.system.process_pools import sigint_blocked, start_worker, stop_pool
from tissue_sim_ros.ros.diagnostics import NONE_YET
from tissue_sim_ros.ros.messages.conversions import header, stamp_to_ns
from tissue_sim_ros.units import NS_PER_S

__all__ = ['CANCELLED', 'WORKER_NICENESS', 'PredictionService', 'Progress', 'path_arrays', 'path_msg',
           'prediction_msg',
           'auto_workers']

#: How much lower the workers' scheduling priority is than the node's (os.nice).
WORKER_NICENESS = 10
__doc__ = __doc__.format(niceness=WORKER_NICENESS)


def auto_workers(workers: int, threads: int) -> tuple[int, int]:
    """(worker processes, numba threads each) for the parameters (0 = auto): the cores less the
    live engine's one, one worker per 4 of them (at least 1: a planner waits for one answer, so
    threads make it sooner; several workers answer a burst in parallel), shared among them. (A
    worker with a thread on the engine's core runs its parallel loops at the pace of the thread
    the engine preempts: 1.3x real time instead of 2.9x on 2 cores, measured.)"""
    spare = max(1, len(os.sched_getaffinity(0)) - 1)
    workers = workers or max(1, spare // 4)
    return workers, threads or max(1, spare // workers)


def _snapshot_directory() -> Path:
    """Shared memory where there is some (/dev/shm), else the temporary directory."""
    shm = Path('/dev/shm')
    return shm if shm.is_dir() and os.access(shm, os.W_OK) else Path(tempfile.gettempdir())


def path_arrays(msg, frame_id: str, to_tissue=None):
    """(stamps [s from the first pose], positions (k, 3), quaternions (k, 4)) of a nav_msgs/Path in
    ``frame_id``; a pose
    in another frame (the path's header frame, or the pose's own when it names one) is brought into
    it by ``to_tissue(position, orientation, frame, stamp_ns)`` (the node's TF input) and raises
    PoseError naming it when that cannot (or when there is no ``to_tissue``)."""
    k = len(msg.poses)
    stamps, positions, orientations = np.empty(k), np.empty((k, 3)), np.empty((k, 4))
    first_ns = stamp_to_ns(msg.poses[0].header.stamp) if k else 0
    for i, stamped in enumerate(msg.poses):
        frame = stamped.header.frame_id or msg.header.frame_id
        p, q = stamped.pose.position, stamped.pose.orientation
        stamp_ns = stamp_to_ns(stamped.header.stamp)
        stamps[i] = (stamp_ns - first_ns) / NS_PER_S      # (a float of today's epoch is 0.2 us coarse)
        positions[i] = p.x, p.y, p.z
        orientations[i] = q.x, q.y, q.z, q.w
        if frame != frame_id:
            if to_tissue is None:
                raise PoseError(f'path.poses[{i}].header.frame_id', frame,
                                f'expected {frame_id!r}, the node\'s frame')
            try:
                positions[i], orientations[i], _, _ = to_tissue(positions[i], orientations[i], frame,
                                                                stamp_ns)
            except InputError as exc:
                raise PoseError(f'path.poses[{i}].header.frame_id', frame,
                                f'not {frame_id!r}, the node\'s frame, and TF cannot relate them: {exc}'
                                ) from None
    return stamps, positions, orientations


def path_msg(stamps_ns, positions, orientations, frame_id: str) -> PathMsg:
    """A nav_msgs/Path of base poses (the inverse of :func:`path_arrays`), stamped with
    ``stamps_ns`` [ns], the path's header with the first: what a planner sends."""
    msg = PathMsg(header=header(frame_id, int(stamps_ns[0])))
    for stamp_ns, p, q in zip(stamps_ns, positions, orientations):
        pose = PoseStamped(header=header(frame_id, int(stamp_ns)))
        pose.pose.position.x, pose.pose.position.y, pose.pose.position.z = (float(c) for c in p)
        o = pose.pose.orientation
        o.x, o.y, o.z, o.w = (float(c) for c in q)
        msg.poses.append(pose)
    return msg


def prediction_msg(stamp, frame_id: str, columns, prediction=None) -> JointTrajectory:
    """The answer: the request's stamp, the columns as joint names, a point per pose (none when
    ``prediction`` is None: refused). The caller has refused a non-finite prediction
    (:meth:`PredictionService._answer`: never publish NaN)."""
    msg = JointTrajectory(header=header(frame_id, stamp), joint_names=list(columns))
    if prediction is None:
        return msg
    points = []
    for t, row in zip(prediction.time_from_start_s, prediction.values):
        sec, nanosec = divmod(int(round(float(t) * NS_PER_S)), NS_PER_S)
        points.append(JointTrajectoryPoint(positions=row.tolist(),
                                           time_from_start=Duration(sec=sec, nanosec=nanosec)))
    msg.points = points
    return msg


def _start_worker(niceness: int, parent_pid: int) -> None:
    """A worker's start: Ctrl-C left to the node and an end with it (``process_pools``), lower
    priority, the engine's modules loaded."""
    start_worker(parent_pid)
    with contextlib.suppress(OSError):        # not allowed here: the worker runs at the node's priority
        os.nice(niceness)
    from tissue_sim_ros.engine.warm_up import warm_up
    warm_up()


#: the reason a cancelled request gives
CANCELLED = 'cancelled'


class _Cancelled(Exception):
    pass


class Progress:
    """A prediction's rows as its worker computes them: a file in shared memory of float64,
    ``[rows done, cancel flag, row 0, row 1, ...]``, written by the worker (each row, then the count)
    and read by the node (feedback); the node sets the flag to cancel, the worker stops at its next
    row. ``path``: the file; ``rows`` x ``columns``: the prediction's size."""

    def __init__(self, path, rows: int, columns: int, create: bool = True):
        self.path, self.rows, self.columns = Path(path), int(rows), int(columns)
        self._data = np.memmap(self.path, dtype=np.float64, mode='w+' if create else 'r+',
                               shape=(2 + self.rows * self.columns,))

    def write(self, k: int, row) -> None:
        """Row ``k`` (the worker's side); raises when the node cancelled."""
        if self._data[1] != 0.0:
            raise _Cancelled()
        self._data[2 + k * self.columns:2 + (k + 1) * self.columns] = row
        self._data[0] = k + 1

    def done(self) -> int:
        return int(self._data[0])

    def read(self, start: int, stop: int) -> np.ndarray:
        """Rows ``start`` .. ``stop - 1`` (a copy)."""
        return np.array(self._data[2 + start * self.columns:2 + stop * self.columns]).reshape(-1,
                                                                                              self.columns)

    def cancel(self) -> None:
        self._data[1] = 1.0

    def close(self) -> None:
        self._data = None
        self.path.unlink(missing_ok=True)


def _work(snapshot, path, wrench_frame, threads, threshold, mass_scaling, progress=None):
    """A prediction in a worker: (Prediction, None) or (None, the reason it could not be made);
    ``progress``: (file, rows, columns) of a :class:`Progress` to write each row into."""
    on_row = None if progress is None else Progress(*progress, create=False).write
    try:
        return predict_snapshot(snapshot, path, wrench_frame, threads=threads, threshold=threshold,
                                mass_scaling=mass_scaling, on_row=on_row), None
    except _Cancelled:
        return None, CANCELLED
    except (SimulationDiverged, PoseError) as exc:
        return None, f'the engine could not follow the path: {exc}'


class _Request:
    """One prediction asked for: on the topic pair (``reply`` None: answered in order on
    plan/prediction) or by a goal (``reply(request)`` when done; ``progress`` its rows)."""

    __slots__ = ('stamp', 'received', 'prediction', 'reason', 'done', 'reply', 'progress', 'live', 'settings',
                 'cancelled', 'times')

    def __init__(self, stamp, reply=None, live=False):
        self.stamp, self.received = stamp, time.perf_counter()
        self.prediction, self.reason, self.done = None, None, False
        self.reply, self.progress, self.live, self.settings, self.cancelled = reply, None, live, '', False
        self.times = None                       # the path's times from its first pose [s]


class PredictionService:
    """The node's predictions (see the module docstring). ``publish(msg)`` sends an answer;
    ``log_once(kind, text, level)`` is the node's; ``decode(bytes)`` -> nav_msgs/Path for
    :meth:`receive`; ``rung()`` -> (threshold, mass scaling) or (None, None): the settings
    predictions run at (prediction.max_error)."""

    def __init__(self, engine, *, frame_id: str, wrench_frame: str, wrench_frame_id: str, target_names,
                 max_jump_m: float, other_needles=(), length_m: float, max_duration_s: float, workers: int, threads: int,
                 publish, log_once, decode=None, rung=lambda: (None, None), prestart: bool = True,
                 to_tissue=None):
        self.engine, self.frame_id, self.wrench_frame = engine, frame_id, wrench_frame
        self.wrench_frame_id = wrench_frame_id
        self.columns = prediction_columns(target_names, other_needles)
        self.max_jump_m, self.length_m, self.max_duration_s = max_jump_m, length_m, max_duration_s
        self.workers, self.threads = auto_workers(workers, threads)
        self._publish, self._log_once, self._rung = publish, log_once, rung
        self.to_tissue = to_tissue
        self._queue: deque = deque()
        self._lock = threading.Lock()
        self._pool_lock = threading.Lock()
        self._pool = None
        self._closed = False
        self._snapshot = (-1, None)              # (engine advance, file) of the newest copy
        self._users: Counter = Counter()          # file -> requests that still need it
        self._directory = Path(tempfile.mkdtemp(prefix='tissue_sim_predictions_', dir=_snapshot_directory()))
        self.requests = self.answered = self.refused = self.snapshots = 0
        self.last_reason = ''
        self.answer_s: deque = deque(maxlen=100)        # request to answer [s]
        self.real_time_factors: deque = deque(maxlen=100)
        self._decode = decode
        self._received: queue.SimpleQueue = queue.SimpleQueue()
        self._warming: list = []                 # the workers' start-up runs (futures)
        threading.Thread(target=self._intake, name='tissue_sim-prediction-intake', daemon=True).start()
        if prestart:       # the state at start, copied before the engine thread runs (no race)
            start = self._directory / 'start.snapshot'
            write_snapshot(engine.driver.scene, start)
            threading.Thread(target=self._warm, args=(start, engine.driver.needle_pose),
                             name='tissue_sim-prediction-start', daemon=True).start()

    # -- the executor's thread ---------------------------------------------------------------------

    def receive(self, data: bytes) -> None:
        """A request as received (CDR bytes): queued for the intake thread, nothing more."""
        self._received.put(data)

    def _intake(self) -> None:
        name_os_thread()
        while True:
            data = self._received.get()
            if data is None:
                return
            try:
                msg = self._decode(data)
            except Exception as exc:  # noqa: BLE001 - a payload that is no Path: counted, logged
                with self._lock:
                    self.requests += 1
                    self.refused += 1
                    self.last_reason = f'refused: the payload does not decode as a nav_msgs/Path ({exc})'
                self._log_once('prediction: malformed', self.last_reason, 'warning')
                continue
            self.on_candidate(msg)

    def on_candidate(self, msg, reply=None, live: bool = False):
        """A request: checked here (stamps, values, frames, jumps), then copied on the engine
        thread and worked on in the pool; a refusal is answered in its turn. ``reply``: a goal's
        (see _Request), with ``live``: on the live settings; returns the request."""
        request = _Request(msg.header.stamp, reply, live)
        with self._lock:
            if reply is None:
                self._queue.append(request)
            self.requests += 1
        try:
            stamps, positions, orientations = path_arrays(msg, self.frame_id, self.to_tissue)
            path = check_path(stamps, positions, orientations, max_jump_m=self.max_jump_m,
                              max_duration_s=self.max_duration_s, length_m=self.length_m)
        except PoseError as exc:
            self._finish(request, None, f'refused: {exc}')
            return request
        request.times = path.times
        if reply is not None:
            request.progress = Progress(self._directory / f'goal_{id(request)}.progress', len(path),
                                        len(self.columns))
        self.engine.post(lambda: self._submit(request, path))
        return request

    def cancel(self, request) -> None:
        """Stop a goal's request: its worker stops at its next row (or it never starts)."""
        request.cancelled = True
        if request.progress is not None and not request.done:
            request.progress.cancel()

    # -- the engine thread -------------------------------------------------------------------------

    def _submit(self, request, path) -> None:
        try:
            driver = self.engine.driver
            if driver.held:
                raise PoseError('path', '(any)', 'the simulation is held after a divergence; '
                                       'call ~/reset first')
            position, orientation = driver.needle_pose
            jump = pose_jump(position, orientation, path.positions[0], path.orientations[0], self.length_m)
            if jump.exceeds(self.max_jump_m):
                raise PoseError('path.poses[0].pose.position', path.positions[0].tolist(),
                                       f"{jump.distance_m * 1e3:.4g} mm from the needle's current pose "
                                       f'{position.tolist()}, more than the jump limit '
                                       f'{self.max_jump_m * 1e3:.4g} mm: a path starts where the needle is')
            if request.cancelled:
                raise _Cancelled()
            if self._snapshot[0] != self.engine.advances:
                self.snapshots += 1
                snapshot = self._directory / f'{self.snapshots}.snapshot'
                write_snapshot(driver.scene, snapshot)
                self._release(self._snapshot[1], replaced=True)
                self._snapshot = (self.engine.advances, snapshot)
            snapshot = self._snapshot[1]
            threshold, mass_scaling = (None, None) if request.live else self._rung()
            request.settings = self.settings_text(threshold, mass_scaling)
            progress = None if request.progress is None else (str(request.progress.path),
                                                              request.progress.rows,
                                                              request.progress.columns)
            with self._lock:
                self._users[snapshot] += 1
            with sigint_blocked():            # a first submit starts the workers
                future = self._ensure_pool().submit(_work, str(snapshot), path, self.wrench_frame,
                                                    self.threads, threshold, mass_scaling, progress)
        except _Cancelled:
            self._finish(request, None, CANCELLED)
            return
        except PoseError as exc:
            self._finish(request, None, f'refused: {exc}')
            return
        except Exception as exc:  # noqa: BLE001 - never the engine thread's end: answered, logged
            self._finish(request, None, f'not predicted: {type(exc).__name__}: {exc}')
            return
        future.add_done_callback(lambda done: self._done(request, done, snapshot))

    def _release(self, snapshot, replaced: bool = False) -> None:
        """One request less needs ``snapshot`` (``replaced``: a newer copy is now the newest);
        the file goes once nothing needs it and it is not the newest."""
        if snapshot is None:
            return
        with self._lock:
            if not replaced:
                self._users[snapshot] -= 1
            unused = self._users[snapshot] <= 0 and (replaced or snapshot != self._snapshot[1])
            if unused:
                del self._users[snapshot]
        if unused:
            snapshot.unlink(missing_ok=True)

    # -- the pool's thread -------------------------------------------------------------------------

    def _done(self, request, future, snapshot) -> None:
        try:
            prediction, reason = future.result()
        except Exception as exc:  # noqa: BLE001 - a worker that died: answered, logged
            prediction, reason = None, f'the prediction worker failed: {type(exc).__name__}: {exc}'
        self._release(snapshot)
        self._finish(request, prediction, reason)

    def _finish(self, request, prediction, reason) -> None:
        """Mark a request done and send every answer at the head of the queue that is ready (a
        goal's: at once, to its ``reply``)."""
        with self._lock:
            request.prediction, request.reason, request.done = prediction, reason, True
            if request.reply is not None:
                self._answer(request)
            while self._queue and self._queue[0].done:
                self._answer(self._queue.popleft())

    def _answer(self, request) -> None:
        prediction = request.prediction
        if prediction is not None and not np.isfinite(prediction.values).all():
            prediction, request.reason = None, 'the prediction has non-finite values'
            request.prediction = None
        if request.reply is not None:
            self.answer_s.append(time.perf_counter() - request.received)
            self.answered += prediction is not None
            self.refused += prediction is None and request.reason != CANCELLED
            if prediction is not None:
                self.real_time_factors.append(prediction.real_time_factor)
            request.reply(request)
            return
        if prediction is None:
            self.refused += 1
            self.last_reason = request.reason
            self._log_once(f'prediction: {request.reason.split(":")[0]}',
                           f'plan/candidate answered with no points: {request.reason}', 'warning')
        else:
            self.answered += 1
            self.real_time_factors.append(prediction.real_time_factor)
        self.answer_s.append(time.perf_counter() - request.received)
        if not self._closed:
            self._publish(prediction_msg(request.stamp, self.wrench_frame_id, self.columns, prediction))

    # -- the pool ----------------------------------------------------------------------------------

    def _ensure_pool(self):
        with self._pool_lock:
            if self._pool is None:
                self._pool = ProcessPoolExecutor(self.workers, multiprocessing.get_context('spawn'),
                                                 initializer=_start_worker, initargs=(WORKER_NICENESS, os.getpid()))
            return self._pool

    def _warm(self, snapshot, pose) -> None:
        """Start the workers and load the scene's kernels in each (a two-pose path from the
        state at start, ``snapshot``, the needle at ``pose``), so the first request is answered
        at full speed."""
        try:
            position, orientation = pose
            path = check_path([0.0, 0.01], [position, position], [orientation, orientation],
                              max_jump_m=self.max_jump_m)
            pool = self._ensure_pool()
            with sigint_blocked():            # the workers start here, with Ctrl-C left to the node
                self._warming = [pool.submit(_work, str(snapshot), path, self.wrench_frame, self.threads, None,
                                             None) for _ in range(self.workers)]
        except Exception as exc:  # noqa: BLE001 - the first request will start them instead
            self._log_once('prediction: start', f'the prediction workers did not start: {exc}', 'warning')

    @property
    def workers_state(self) -> str:
        """'warm' once the workers started with the node have loaded their kernels (the first
        request is then answered at full speed), 'starting' until then (they load the machine:
        node-bench waits for it), 'not started' without prediction.prestart (the first request
        starts them)."""
        warming = self._warming
        if not warming:
            return 'not started'
        return 'warm' if all(future.done() for future in warming) else 'starting'

    @staticmethod
    def settings_text(threshold, mass_scaling) -> str:
        """The words for the settings a prediction runs on."""
        return 'as the live scene' if threshold is None else \
            f'non-linearity threshold {threshold:g}, mass scaling {mass_scaling:g}'

    def status(self, name: str) -> tuple:
        """The DiagnosticStatus tuple ``<node>: predictions``."""
        with self._lock:
            queued = len(self._queue)
        answer = np.array(self.answer_s)
        rtf = np.array(self.real_time_factors)
        threshold, mass_scaling = self._rung()
        values = {'requests': self.requests, 'answered': self.answered, 'refused': self.refused,
                  'queued': queued, 'workers': self.workers, 'threads_per_worker': self.threads,
                  'snapshots': self.snapshots, 'workers_state': self.workers_state,
                  'answer_s_p50': float(np.percentile(answer, 50)) if answer.size else NONE_YET,
                  'answer_s_max': float(answer.max()) if answer.size else NONE_YET,
                  'real_time_factor_median': float(np.median(rtf)) if rtf.size else NONE_YET,
                  'settings': self.settings_text(threshold, mass_scaling),
                  'columns': ', '.join(self.columns), 'last_refusal': self.last_reason}
        level = 'WARN' if self.last_reason else 'OK'
        message = f'{self.answered} answered, {self.refused} with no points, {queued} queued'
        return f'{name}: predictions', level, message, values

    def close(self) -> None:
        """Stop answering; the workers are told to stop (running predictions are dropped)."""
        self._closed = True
        self._received.put(None)
        with self._pool_lock:
            if self._pool is not None:
                stop_pool(self._pool)
                self._pool = None
        shutil.rmtree(self._directory, ignore_errors=True)
