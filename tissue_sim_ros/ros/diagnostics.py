"""The node's rolling statistics and its /diagnostics content (no rclpy: plain values).

Three statuses: ``<node>: engine`` (state, tick timing, real-time factor, lag, budget use,
the degradation ladder, the engine's cost and the kernel's share of it, divergences, the
needle's phase), ``<node>: input`` (poses received, accepted, each bad-input kind counted,
latency) and, when recording, ``<node>: recording``. Rates and maxima are over the window since
the previous diagnostics message; percentiles over the last ten seconds of ticks. A value that
does not exist yet (a latency before the first pose, a rate before a window has passed) reads
``none yet``: tools parsing diagnostics never meet NaN.
"""
from __future__ import annotations

import math
import threading
import time

import numpy as np

from tissue_sim_ros.units import NS_PER_S

__all__ = ['NONE_YET', 'Ring', 'NodeStats', 'diagnostics_statuses']

#: the value of a figure that does not exist yet
NONE_YET = 'none yet'
#: how long the input status warns of a delivery stall [s]
STALL_WARNING_S = 10.0


class Ring:
    """Last ``n`` values (preallocated), for percentiles in diagnostics and the bench."""

    def __init__(self, n: int, dtype=np.float64):
        self.values = np.zeros(max(1, int(n)), dtype=dtype)
        self.count = 0

    def add(self, x: float) -> None:
        self.values[self.count % self.values.size] = x
        self.count += 1

    def array(self) -> np.ndarray:
        return self.values[:min(self.count, self.values.size)]

    def percentile(self, q: float) -> float | None:
        """The ``q``-th percentile of what the ring holds; None while it holds nothing."""
        a = self.array()
        return float(np.percentile(a, q)) if a.size else None


class NodeStats:
    """The publishing side's rings (``rings``, ten seconds of ticks) and the window since the
    last diagnostics message."""

    def __init__(self, publish_rate_hz: float):
        self.period_s = 1.0 / publish_rate_hz
        window = int(math.ceil(publish_rate_hz * 10))
        self.rings = {name: Ring(window) for name in
                      ('tick_interval_s', 'publish_work_s', 'latency_s', 'input_s')}
        self.missed_ticks = 0
        self.missed_for_input = 0     # missed ticks the node's own input handling caused
        self.tick_errors = 0          # ticks skipped for an exception (logged once)
        self._input_s = 0.0           # time in pose callbacks since the last tick
        self._input_lock = threading.Lock()   # the callbacks' thread adds, the tick's takes
        self._last_tick_wall: float | None = None
        self.window: dict = {}

    def input_done(self, seconds: float) -> None:
        """A pose callback took ``seconds`` (from the executor's thread)."""
        with self._input_lock:
            self._input_s += seconds

    def new_window(self, engine, clock_ns: int | None, bad_total: int) -> None:
        self.window = {'missed0': self.missed_ticks, 'wall0': time.perf_counter(),
                       'clock0': clock_ns, 'stepped0': engine.stepped_s,
                       'busy0': engine.pacing.busy_s, 'cpu0': engine.busy_cpu_s, 'advances0': engine.advances,
                       'kernel0': engine.driver.scene.simulation.kernel_s,
                       'dropped0': engine.driver.dropped_s, 'bad0': bad_total}

    def tick_started(self, wall: float) -> None:
        """A tick's callback began at ``wall`` (perf_counter s): its interval, missed ticks
        (a gap of more than 1.5 periods), and among them those input handling caused (it took
        more than half a period of the gap)."""
        last, self._last_tick_wall = self._last_tick_wall, wall
        with self._input_lock:
            input_s, self._input_s = self._input_s, 0.0
        self.rings['input_s'].add(input_s)
        if last is not None:
            interval = wall - last
            self.rings['tick_interval_s'].add(interval)
            if interval > 1.5 * self.period_s:
                missed = int(round(interval / self.period_s)) - 1
                self.missed_ticks += missed
                if input_s > 0.5 * self.period_s:
                    self.missed_for_input += missed

    def tick_done(self, work_s: float) -> None:
        self.rings['publish_work_s'].add(work_s)


def diagnostics_statuses(name: str, now_ns: int, *, stats: NodeStats, engine, pose_input,
                         ticks: int, recorder=None, needle_names=('needle',), other_inputs=(),
                         ready: str = 'ready', source: str = 'needle/pose') -> list:
    """The DiagnosticStatus tuples (name, level, message, values) of this moment. With several
    needles (``needle_names``; ``other_inputs``: (name, PoseInput) of all but the first) each
    needle's input has a status ``input <name>`` (the others' bad poses counted since start).
    ``ready``: the node's readiness (:mod:`~tissue_sim_ros.ros.readiness`); ``source``: where the
    first needle's poses come from."""
    first = f' {needle_names[0]}' if len(needle_names) > 1 else ''
    engine_status = _engine_status(name, now_ns, stats, engine, ticks)
    engine_status[3]['ready'] = ready
    input_status = _input_status(name, now_ns, stats, pose_input, first)
    input_status[3]['source'] = source
    return [engine_status, input_status] + \
        [_input_status(name, now_ns, stats, other, f' {needle}', 0) for needle, other in other_inputs] + \
        ([] if recorder is None else [_recording_status(name, recorder)])


def _engine_status(name, now_ns, stats, engine, ticks) -> tuple:
    w, driver, pacing = stats.window, engine.driver, engine.pacing
    scene = driver.scene
    wall = max(time.perf_counter() - w['wall0'], 1e-9)
    # engine time per node-clock time (with use_sim_time, per simulated /clock time)
    clock = wall if w['clock0'] is None else (now_ns - w['clock0']) / NS_PER_S
    rtf = (engine.stepped_s - w['stepped0']) / clock if clock > 0 else NONE_YET
    busy = pacing.busy_s - w['busy0']
    busy_cpu = engine.busy_cpu_s - w['cpu0']
    kernel = scene.simulation.kernel_s - w['kernel0']
    intervals = stats.rings['tick_interval_s'].array()
    deviation = np.abs(intervals - stats.period_s) if intervals.size else np.zeros(1)
    dropped = driver.dropped_s - w['dropped0']
    ladder = engine.ladder
    if driver.held or engine.failure is not None:
        level = 'ERROR'
        state = 'diverged, held until ~/reset' if driver.held else f'engine thread stopped: {engine.failure!r}'
    elif dropped > 0 or driver.lag_s > 0.5 * pacing.max_lag_s or stats.missed_ticks > w['missed0']:
        level, state = 'WARN', (f'behind: lag {driver.lag_s * 1e3:.0f} ms, {dropped:.3g} s dropped, '
                                f'{stats.missed_ticks - w["missed0"]} missed ticks in the last {wall:.3g} s')
    elif ladder is not None and ladder.level > 0:
        level, state = 'WARN', f'degraded: ladder level {ladder.level} ({ladder.rung.name})'
    else:
        level, state = 'OK', 'paused' if engine.paused else 'running'
    values = {
        'state': 'held' if driver.held else 'paused' if engine.paused else 'running',
        'engine_thread': 'running' if engine.failure is None else f'stopped: {engine.failure!r}',
        'simulated_time_s': float(scene.time),
        'ticks': ticks,
        'tick_period_s': stats.period_s,
        'tick_period_deviation_ms_p99': float(np.percentile(deviation, 99)) * 1e3,
        'publish_work_ms_p99': _ms(stats.rings['publish_work_s'].percentile(99)),
        'missed_ticks': stats.missed_ticks,
        'missed_ticks_for_input': stats.missed_for_input,
        'tick_errors': stats.tick_errors,
        'real_time_factor': rtf,
        'lag_s': driver.lag_s,
        'max_lag_s': pacing.max_lag_s,
        'dropped_time_s': driver.dropped_s,
        'skipped_time_s': pacing.skipped_s,
        'budget_use': NONE_YET if pacing.demand is None else pacing.demand,
        'budget_ms_per_tick': pacing.budget_s * 1e3,
        'budget_windows_spent_behind': pacing.windows_spent,
        'engine_busy_fraction': busy / wall,
        'advances_per_s': (engine.advances - w['advances0']) / wall,
        'advances_total': engine.advances,
        'waits_for_poses': engine.coalesced,
        'kernel_share_of_engine': kernel / busy_cpu if busy_cpu > 0 else NONE_YET,
        'engine_busy_s_total': pacing.busy_s,
        'engine_cpu_s_total': engine.busy_cpu_s,
        'kernel_s_total': scene.simulation.kernel_s,
        'engine_threads': engine.threads,
        'engine_dt_s': float(scene.dt),
        'mass_scaling': float(scene.simulation.mass_scaling),
        'inertia_error_estimate': ('none: quasi-static, no inertia' if scene.simulation.integrator == 'quasi_static'
                                   else 'not estimated yet' if driver.inertia.error is None
                                   else driver.inertia.error),
        'nonlinearity_threshold': float(scene.model.nonlinearity_threshold),
        'divergences': driver.divergences,
        'stability': 'held after divergence' if driver.held else 'stable',
        'phase': str(scene.phase),
        'tip_depth_m': float(scene.tip_depth),
        'tip_x_m': float(scene.needle.tip[0]),
        'tip_y_m': float(scene.needle.tip[1]),
        'tip_z_m': float(scene.needle.tip[2]),
        'tip_deflection_m': float(scene.tip_deflection),
        'topology_version': int(scene.topology_version),
        'punctures': len(scene.puncture_events),
    }
    if ladder is not None:
        error = ladder.predicted_error()
        values.update({'ladder_level': ladder.level, 'ladder_rung': ladder.rung.name,
                       'ladder_changes': engine.ladder_changes,
                       # 'not measured': the probe failed (its warning says why); the ladder steps anyway
                       'ladder_predicted_error': error if error is not None else
                       'not measured yet' if ladder.predicted_errors is None else 'not measured'})
    return f'{name}: engine', level, state, values


def _ms(seconds: float | None):
    return NONE_YET if seconds is None else seconds * 1e3


def _input_status(name, now_ns, stats, pose_input, needle='', bad0=None) -> tuple:
    age = pose_input.age_s(now_ns)
    stale = pose_input.stale(now_ns)
    bad_new = pose_input.bad_total - (stats.window['bad0'] if bad0 is None else bad0)
    wall = max(time.perf_counter() - stats.window['wall0'], 1e-9)
    values = {'poses_received': pose_input.received, 'poses_accepted': pose_input.accepted,
              'last_pose_age_s': NONE_YET if age is None else age, 'stale': stale,
              'latency_ms_p50': _ms(stats.rings['latency_s'].percentile(50)),
              'latency_ms_p99': _ms(stats.rings['latency_s'].percentile(99)),
              'input_work_ms_per_tick_max': float(stats.rings['input_s'].array().max(initial=0.0)) * 1e3,
              'delivery_stalls': pose_input.delivery_stalls,
              'delivery_stall_max_s': pose_input.delivery_stall_max_s if pose_input.delivery_stalls else NONE_YET}
    values.update({f'bad_input.{k}': v for k, v in pose_input.counts.items()})
    stalled = pose_input.last_stall_ns
    if stalled is not None and now_ns - stalled < STALL_WARNING_S * NS_PER_S:
        level, message = 'WARN', (f'a delivery stall {(now_ns - stalled) / NS_PER_S:.3g} s ago: poses arrived up '
                                  f'to {pose_input.delivery_stall_max_s:.3g} s after their stamps in a late burst '
                                  '(held up on the way; an empty payload on the topic does this to a reliable '
                                  'subscription: input.reliability best_effort is not held up)')
    elif bad_new:
        level, message = 'WARN', f'{bad_new} bad poses in the last {wall:.3g} s'
    elif stale:
        level, message = 'WARN', f'no pose for {age:.3g} s: holding the last one'
    elif age is None:
        level, message = 'OK', 'no pose yet: the needle holds its initial pose'
    else:
        level, message = 'OK', 'receiving'
    return f'{name}: input{needle}', level, message, values


def _recording_status(name, recorder) -> tuple:
    st = recorder.stats()
    return (f'{name}: recording', 'WARN' if st.messages_dropped else 'OK', str(recorder.path),
            {'messages_written': st.messages_written, 'messages_dropped': st.messages_dropped,
             'messages_unsaved': st.messages_unsaved, 'chunks_closed': st.chunks_closed,
             'bytes_written': st.bytes_written})
