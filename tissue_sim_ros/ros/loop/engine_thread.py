"""The node's engine on its own thread: poses in, the latest state out, never waited for.

The ROS side (:mod:`~tissue_sim_ros.ros.node`) only hands received poses over (:meth:`submit`),
calls :meth:`tick` every period and publishes :meth:`latest`, whatever the engine's progress:
the tick never waits for the physics. The engine thread (no rclpy) wakes on a pose, a request,
a tick that finds it behind, or a period without any of them; woken by a pose with time to
spare before the tick, it sleeps while more may come and their advance still ends before the
tick (:meth:`EnginePacing.wait_for_poses_s`: one cycle for a batch of a fast stream's poses, not
one each); then it decodes at most ``MAX_POSES_PER_CYCLE`` of the newest poses, advances the
:class:`~tissue_sim_ros.engine.driver.SimulationDriver` as :mod:`~tissue_sim_ros.ros.loop.pacing`
says (toward the newest pose's stamp, within each tick's budget of wall time), keeps its lag
within the bound (dropping the excess), steps the degradation ladder, and leaves the state in a
triple buffer for the publisher: the publisher reads one buffer while the engine fills another,
with no copy and no wait under the lock but a swap of indices. The element pass and the node
update release the GIL (numba ``nogil``), so the publishing thread runs while the engine works.

Services reach the engine as requests run on its thread between advances (:meth:`call`), so the
engine's state is only ever touched by one thread. Every advance, reset, ladder change and drop
is written to the trace (:mod:`~tissue_sim_ros.ros.loop.trace`) the node records for replay.

Several needles: ``other_inputs`` are the other needles' PoseInputs (their poses come through
:meth:`submit` with the needle's index); each advance moves every needle to its interpolated
pose (a needle with nothing buffered is held), toward the newest stamp of any of them. The trace
holds the first needle's poses.

With ``use_sim_time`` the node is lock-step instead: :meth:`tick` waits until the engine has
simulated up to the tick (no wall-clock budget), so each wrench shows the state at its stamp.
"""
from __future__ import annotations

import queue
import threading
import time
from collections import deque

import numpy as np

from tissue_sim_ros.system.thread_names import name_os_thread
from tissue_sim_ros.ros.loop.pacing import EnginePacing, LadderControl
from tissue_sim_ros.ros.loop.trace import DROP, LEVEL, RESET, advance_row, event_row, place_row
from tissue_sim_ros.ros.loop.pose_receiver import PoseReceiver
from tissue_sim_ros.units import NS_PER_S

__all__ = ['EngineLoop', 'Snapshot', 'MAX_POSES_PER_CYCLE']

#: Received poses decoded per engine cycle at most, the newest; older ones waiting count as
#: backlog (they are recorded all the same). A 1 kHz stream brings about 10 per cycle.
MAX_POSES_PER_CYCLE = 64


class Snapshot:
    """The engine state a tick publishes (one of three buffers; see :class:`EngineLoop`)."""

    def __init__(self, n_nodes: int, n_needles: int = 1, shape_sizes=(2,)):
        self.index = 0                       # advances done when it was taken
        self.forces = np.zeros((n_needles, 3))   # each needle's wrench; force, torque: the first's
        self.torques = np.zeros((n_needles, 3))
        self.force, self.torque = self.forces[0], self.torques[0]
        self.displacement = np.zeros((n_nodes, 3))
        self.time_s = 0.0
        self.phase = 'approach'
        self.tip_depth_m = 0.0
        self.punctures = 0
        self.topology_version = 0
        self.held = False
        self.tip = np.zeros(3)               # the needle tip [m] and axis, for the targets' figures
        self.axis = np.zeros(3)
        self.positions = np.zeros((n_needles, 3))      # each needle's base pose (TF out)
        self.orientations = np.zeros((n_needles, 4))
        # each needle's centreline and its frames (NeedleTissue.write_shape), for needle/shape
        self.shape_positions = [np.zeros((k, 3)) for k in shape_sizes]
        self.shape_quaternions = [np.tile([0.0, 0.0, 0.0, 1.0], (k, 1)) for k in shape_sizes]


class _TripleBuffer:
    """The engine writes ``back``, :meth:`publish` makes it the newest; :meth:`latest` gives the
    publisher the newest, which the engine does not touch until the publisher asks again."""

    def __init__(self, n_nodes: int, n_needles: int = 1, shape_sizes=(2,)):
        self.slots = [Snapshot(n_nodes, n_needles, shape_sizes) for _ in range(3)]
        self._back, self._ready, self._front = 0, 1, 2
        self._fresh = False
        self._lock = threading.Lock()

    @property
    def back(self) -> Snapshot:
        return self.slots[self._back]

    def publish(self) -> None:
        with self._lock:
            self._back, self._ready = self._ready, self._back
            self._fresh = True

    def latest(self) -> Snapshot:
        with self._lock:
            if self._fresh:
                self._front, self._ready = self._ready, self._front
                self._fresh = False
            return self.slots[self._front]


class _Wake:
    """The engine thread's wake-up call: :meth:`set` from any thread, :meth:`wait` on the
    engine's (it returns at a set since the last wait, or after ``timeout_s``). A
    ``queue.SimpleQueue``, whose put and get are C: a ``threading.Event``'s Python-level
    condition costs the running node about 60 us of thread time a wait and 10-15 us a set (run
    cold, between element passes), at 150 waits and 150 sets a second."""

    def __init__(self):
        self._queue = queue.SimpleQueue()

    def set(self) -> None:
        self._queue.put(True)

    def wait(self, timeout_s: float) -> None:
        try:
            self._queue.get(timeout=timeout_s)
        except queue.Empty:
            return
        self.clear()

    def clear(self) -> None:
        """Forget the sets so far (one wake for all of them)."""
        for _ in range(self._queue.qsize()):
            self._queue.get_nowait()


class EngineLoop:
    """The engine thread (see the module docstring).

    ``now_ns()``: the node clock; ``decode(bytes) -> (position, orientation, frame, stamp_ns)``;
    ``log_once(kind, text, level)`` and ``log(level, text)``: the node's logger, from this thread.
    ``ladder``: a DegradationLadder (None: no ladder). ``slow_down(substeps) -> s``: tests make
    the engine slower by sleeping that long after an advance (as a larger scene would take).
    """

    def __init__(self, driver, pose_input, *, period_s: float, now_ns, decode, log_once, log,
                 budget_fraction: float = 0.8, max_lag_s: float = 0.25, ladder=None,
                 threads: int = 1, sim_time: bool = False, slow_down=None, other_inputs=()):
        self.driver, self.input = driver, pose_input
        self.other_inputs = list(other_inputs)
        self.pacing = EnginePacing(period_s, budget_fraction, max_lag_s, sim_time)
        self.ladder = ladder
        self.control = LadderControl(0 if ladder is None else ladder.bottom,
                                     lambda level: ladder.rungs[level].cost_ratio, ladder is not None)
        self.threads, self.sim_time, self.slow_down = int(threads), bool(sim_time), slow_down
        self._now_ns, self._decode, self._log_once, self._log = now_ns, decode, log_once, log
        self.receiver = PoseReceiver(limit=MAX_POSES_PER_CYCLE)
        self.other_receivers = [PoseReceiver(limit=MAX_POSES_PER_CYCLE) for _ in self.other_inputs]
        self._snapshots = _TripleBuffer(driver.scene.rest_positions.shape[0], 1 + len(self.other_inputs),
                                        [needle.shape_size for needle in driver.scene.needles])
        self._trace: list = []
        self._receipts: deque = deque()          # (receipt ns, advance index) of accepted poses
        self._requests: deque = deque()
        self._wake, self._stop = _Wake(), threading.Event()
        self._cond = threading.Condition()
        self._tick_seq = self._window_seq = self._served_seq = 0
        self._tick_wall: float | None = None       # perf_counter time of the last tick
        self.coalesced = 0                          # waits for more poses before an advance
        self.paused = False
        self.advances = 0
        self.stepped_s = 0.0                      # simulated seconds actually stepped
        self.busy_cpu_s = 0.0                     # the engine thread's CPU time in advances
        self.ladder_changes = 0
        self.failure: BaseException | None = None
        #: place the needle at the first pose received (registration.needle_at_first_pose), once
        self.place_at_first_pose = False
        self._publish_state()
        self._thread = threading.Thread(target=self._run, name='tissue_sim-engine', daemon=True)

    # -- the ROS side ---------------------------------------------------------------------------

    def start(self) -> None:
        self.control.started_s = time.perf_counter()
        self._thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        self._stop.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        with self._cond:
            self._cond.notify_all()

    def submit(self, receipt_ns: int, data: bytes, needle: int = 0) -> None:
        """A received pose (bytes as received) of needle ``needle`` (its index), for the engine's
        next cycle."""
        (self.receiver if needle == 0 else self.other_receivers[needle - 1]).add(receipt_ns, data)
        self._wake.set()

    def tick(self, wait: bool = False, timeout_s: float = 10.0) -> None:
        """A tick: a new budget window, which the engine opens at its next cycle; with ``wait``
        (sim time), return once the engine has simulated up to now. The engine is woken for it
        only when it is behind (a deadline left substeps for this window) or with ``wait``: else
        its next pose wakes it, or its wait's timeout (a period) when none comes: a cycle of its
        own for the tick, 50 a second, would have nothing to do."""
        self._tick_wall = time.perf_counter()
        with self._cond:
            self._tick_seq += 1
            seq = self._tick_seq
        if wait or self.driver.behind:
            self._wake.set()
        if wait and self._thread.is_alive():
            with self._cond:
                self._cond.wait_for(lambda: self._served_seq >= seq or self._stop.is_set(), timeout_s)

    def latest(self) -> Snapshot:
        """The newest state (read it before the next call: the engine may then reuse it)."""
        return self._snapshots.latest()

    def take_trace(self) -> list:
        """The trace rows since the previous call."""
        with self._cond:
            rows, self._trace = self._trace, []
        return rows

    def take_receipts(self, index: int) -> list[int]:
        """Receipt times [ns] of the accepted poses the state of advance ``index`` includes."""
        taken = []
        while self._receipts and self._receipts[0][1] <= index:
            taken.append(self._receipts.popleft()[0])
        return taken

    def post(self, job) -> None:
        """Run ``job()`` on the engine thread between advances without waiting for it (at once
        when the thread does not run). ``job`` must not raise: it would stop the engine."""
        if not self._thread.is_alive():
            job()
            return
        self._requests.append(job)
        self._wake.set()

    def call(self, job, timeout_s: float = 5.0):
        """Run ``job()`` on the engine thread between advances and return its result (at once
        when the thread does not run)."""
        if not self._thread.is_alive():
            return job()
        done, box = threading.Event(), {}

        def run():
            try:
                box['result'] = job()
            except BaseException as exc:  # noqa: BLE001 - handed back to the caller
                box['error'] = exc
            finally:
                done.set()
        self._requests.append(run)
        self._wake.set()
        if not done.wait(timeout_s):
            raise TimeoutError(f'the engine thread did not answer within {timeout_s:g} s')
        if 'error' in box:
            raise box['error']
        return box['result']

    def place(self, pose=None) -> tuple:
        """Start the first needle at ``pose`` (position, orientation in the tissue frame; None: the
        input's newest checked pose, PoseInput.seen) from now on, on the engine thread, traced; the
        pose used. PoseError when there is none, or the engine refuses it (in or touching the tissue)."""
        def job():
            from tissue_sim_ros.ros.registration import needle_start_rule
            position, orientation = pose if pose is not None else needle_start_rule(self.input.seen,
                                                                                    'the tissue frame')
            self._place(position, orientation)
            return position, orientation
        return self.call(job)

    def _place(self, position, orientation) -> None:
        self.driver.place_needle(position, orientation)
        self.input.reset(self.driver.scene.needle_pose)
        self.advances += 1
        self._record(place_row(self.advances, position, orientation))
        self._publish_state()

    def reset(self) -> None:
        """Tissue at rest, needle at its initial pose (on the engine thread, traced)."""
        def job():
            self.driver.reset()
            self._reset_inputs()
            now_ns = self._now_ns()
            if now_ns > 0:     # the time owed from before the reset is not simulated on the tissue at rest
                self.pacing.hold(now_ns)
            self.advances += 1                   # a new state (the trace's index)
            self._record(event_row(RESET, self.advances))
            self._publish_state()
        self.call(job)

    # -- the engine thread ----------------------------------------------------------------------

    def _run(self) -> None:
        import numba
        name_os_thread()
        numba.set_num_threads(self.threads)
        try:
            while not self._stop.is_set():
                self._wake.wait(self.pacing.period_s)
                self._wait_for_more_poses()
                self._cycle()
        except BaseException as exc:  # noqa: BLE001 - a bug: said at ERROR, the node publishes on
            self.failure = exc
            self._log('error', f'the engine thread stopped: {type(exc).__name__}: {exc}; the last '
                               'state is published from now on')
        finally:
            with self._cond:
                self._served_seq = self._tick_seq
                self._cond.notify_all()

    def _wait_for_more_poses(self) -> None:
        """Woken by a pose with time to spare before the tick: sleep while more poses may come
        and the advance of them all still ends before the tick (EnginePacing.wait_for_poses_s),
        so a fast pose stream costs a cycle per batch, not per pose. A sleep, not a wait on the
        wake: the poses that come meanwhile do not wake the engine (a request or a stop waits
        at most the sleep, under a period); their wakes are forgotten, the cycle takes them. A
        tick during the wait ends it (a sleep that overran the tick must not start another)."""
        pacing, seq = self.pacing, self._tick_seq
        while True:
            if (self._tick_seq != seq or self._tick_wall is None or pacing.engine_clock_ns is None
                    or self._requests or self.paused
                    or self.driver.held or self.driver.behind or self._stop.is_set()
                    or not (self.receiver.queue or any(r.queue for r in self.other_receivers))):
                return
            to_tick = self._tick_wall + pacing.period_s - time.perf_counter()
            wait = pacing.wait_for_poses_s(to_tick, (self._now_ns() - pacing.engine_clock_ns) / NS_PER_S)
            if wait <= 0.0:
                return
            self.coalesced += 1
            time.sleep(wait)
            self._wake.clear()

    def _cycle(self) -> None:
        while self._requests:
            self._requests.popleft()()
        seq = self._tick_seq
        if seq > self._window_seq:
            self._window_seq = seq
            self.pacing.new_window(self.driver.behind)
        now_ns = self._now_ns()
        if self.sim_time and now_ns == 0:         # no /clock yet: nothing has happened
            return
        for receipt in self.receiver.decode_into(self.input, self._decode, self._log_once):
            self._receipts.append((receipt, self.advances + 1))
        for receiver, other in zip(self.other_receivers, self.other_inputs):
            receiver.decode_into(other, self._decode, self._log_once)
        if self.place_at_first_pose and self.input.oldest() is not None:
            self._place_at_first_pose()
        if self.paused or self.driver.held or self._tick_seq == 0:
            # before the first tick the node is still starting (its set-up holds the GIL for
            # tenths of a second): time not simulated then is not owed, and no lag is warned of
            self.pacing.hold(now_ns)
        else:
            stamps = [newest[0] for newest in (i.newest() for i in [self.input] + self.other_inputs)
                      if newest is not None]
            to_ns = self.pacing.target_ns(now_ns, max(stamps) if stamps else None)
            advance_s = self.pacing.advance_s(to_ns)
            if advance_s > 0.0 or self.driver.behind:
                self._advance(advance_s)
            self._step_ladder()
        if not self.driver.behind:
            with self._cond:
                self._served_seq = seq
                self._cond.notify_all()

    def _place_at_first_pose(self) -> None:
        """The needle starts at the first pose received (its input took it from anywhere)."""
        from tissue_sim_ros.errors import PoseError
        self.place_at_first_pose = False
        _, position, orientation = self.input.oldest()
        try:
            self._place(position, orientation)
            self._log('info', f'the needle starts at the first pose received: {position.round(6).tolist()} m '
                              '(registration.needle_at_first_pose)')
        except PoseError as exc:
            self.input.reset(self.driver.scene.needle_pose)
            self._log('error', f'registration.needle_at_first_pose: the first pose was refused: {exc}')

    def _advance(self, advance_s: float) -> None:
        driver, pacing = self.driver, self.pacing
        target = self.input.pose_at(pacing.engine_clock_ns) or (None, None)
        others = [other.pose_at(pacing.engine_clock_ns) for other in self.other_inputs] or None
        wall0, cpu0 = time.perf_counter(), time.thread_time()
        outcome = driver.advance(advance_s, target[0], target[1],
                                 deadline=pacing.deadline(wall0), others=others)
        if self.slow_down is not None:
            time.sleep(self.slow_down(outcome.substeps))
        simulated = outcome.substeps * driver.dt
        self.busy_cpu_s += time.thread_time() - cpu0
        pacing.spent(time.perf_counter() - wall0, simulated)
        self.stepped_s += simulated
        self.advances += 1
        self._record(advance_row(self.advances, advance_s, target[0], target[1], outcome.substeps,
                                 pacing.engine_clock_ns))
        if outcome.refused is not None:
            self.input.count('engine_refused')
            self._log_once('engine_refused', 'the engine refused the needle pose, holding the '
                           f'needle: {outcome.refused}', 'warning')
        if outcome.diverged is not None:
            self._diverged(outcome.diverged)
        if not self.sim_time and driver.drop_lag(pacing.max_lag_s) > 0.0:
            self._record(event_row(DROP, self.advances, pacing.max_lag_s))
            # before any pose the needle rests where the scene put it: the time dropped is the
            # resting tissue's, and no pose is behind (a loaded machine's start is not a fault)
            if any(i.newest() is not None for i in [self.input] + self.other_inputs):
                self._log_once('lag', f'the engine is more than engine.max_lag_s = {pacing.max_lag_s:g} s '
                               'behind the poses: the excess is dropped (the needle then moves faster '
                               'in simulated time)', 'warning')
        self._publish_state()

    def _diverged(self, exc) -> None:
        then = ('hold: the last finite wrench is republished until ~/reset' if self.driver.held else
                f'reset: tissue back at rest, needle at its initial pose (divergence '
                f'{self.driver.divergences})')
        self._log('error', f'simulation diverged: {exc}; on_divergence = {then}')
        if not self.driver.held:
            self._reset_inputs()

    def _reset_inputs(self) -> None:
        """Each needle's input forgets its poses; jumps are measured from where the needle is."""
        for needle, pose_input in zip(self.driver.scene.needles, [self.input] + self.other_inputs):
            pose_input.reset((needle.position.copy(), needle.orientation.copy()))

    def _step_ladder(self) -> None:
        control, pacing = self.control, self.pacing
        if not control.enabled or self.ladder.predicted_errors is None:
            return         # (nor while the ladder's probe runs: it loads the machine)
        now = time.perf_counter()
        level = control.decide(now, pacing.demand, self.driver.lag_s, pacing.max_lag_s,
                               pacing.cost_per_sim_s)
        if level is None:
            return
        demand, before, was = pacing.demand, pacing.cost_per_sim_s, self.ladder.level
        self.ladder.set_level(level)
        control.changed(now, level, before)
        pacing.reset_cost()
        self.ladder_changes += 1
        self._record(event_row(LEVEL, self.advances, level))
        why = (f'cannot keep real time (budget use {demand:.2f}, lag {self.driver.lag_s * 1e3:.0f} ms)'
               if level > was else f'has room again (budget use {demand:.2f})')
        error = self.ladder.predicted_error()
        self._log_once(f'ladder {was}->{level}',
                       f'the engine {why}: ladder level {was} -> {level}: {self.ladder.rung.name}; '
                       'predicted axial-force error ' + ('not measured yet' if error is None else
                                                          f'{100 * error:.1f} % (NRMSE)') +
                       ' against the scene as configured', 'warning' if level > was else 'info')

    def _record(self, row: tuple) -> None:
        with self._cond:
            self._trace.append(row)

    def _publish_state(self) -> None:
        driver, scene = self.driver, self.driver.scene
        snap = self._snapshots.back
        snap.index = self.advances
        snap.forces[:] = driver.forces
        snap.torques[:] = driver.torques
        np.copyto(snap.displacement, scene.displacement)
        snap.time_s = float(scene.time)
        snap.phase = str(scene.phase)
        snap.tip_depth_m = float(scene.tip_depth)
        snap.punctures = len(scene.puncture_events)
        snap.topology_version = int(scene.topology_version)
        snap.held = bool(driver.held)
        snap.tip[:] = scene.needle.tip
        snap.axis[:] = scene.needle.axis
        for k, needle in enumerate(scene.needles):
            snap.positions[k] = needle.position
            snap.orientations[k] = needle.orientation
        for needle, positions, quaternions in zip(scene.needles, snap.shape_positions, snap.shape_quaternions):
            needle.write_shape(positions, quaternions)
        self._snapshots.publish()

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

