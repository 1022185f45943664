"""The node's rolling statistics and its /diagnostics content (no rclpy: plain values).

Three statuses: ``<node>: engine`` (state, timing, real-time factor, overruns, missed ticks,
divergences, the needle's phase), ``<node>: input`` (poses received, accepted, each bad-input kind
counted, latency) and, when recording, ``<node>: recording``. Rates and maxima are over the window
since the previous diagnostics message; percentiles over the last ten seconds of ticks.
"""
from __future__ import annotations

import math
import time

import numpy as np

from tissue_sim_ros.units import NS_PER_S

__all__ = ['Ring', 'NodeStats', 'diagnostics_statuses']


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

    def percentile(self, q: float) -> float:
        a = self.array()
        return float(np.percentile(a, q)) if a.size else float('nan')


class NodeStats:
    """Per-tick and per-advance rings (``rings``, ten seconds of them) and the window since the
    last diagnostics message."""

    def __init__(self, publish_rate_hz: float, slices: int):
        window = int(math.ceil(publish_rate_hz * 10))
        self.rings = {name: Ring(window) for name in
                      ('tick_work_s', 'step_s', 'tick_interval_s', 'latency_s', 'substeps', 'input_s')}
        # per engine advance: the node-clock time it went to, the time it advanced, its substeps
        self.rings['slice_ns'] = Ring(window * slices, np.int64)  # ns: beyond float64
        self.rings['advance_s'] = Ring(window * slices)
        self.rings['advance_steps'] = Ring(window * slices, np.int64)
        self.rings['advances_at_tick'] = Ring(window, np.int64)  # advances made before each tick
        self.window: dict = {}
        self.new_window(0.0, None, 0)

    def new_window(self, simulated_s: float, clock_ns: int | None, bad_total: int) -> None:
        self.window = {'ticks': 0, 'step_s': 0.0, 'step_max_s': 0.0, 'overruns': 0,
                       'wall0': time.perf_counter(), 'sim0': simulated_s, 'clock0': clock_ns,
                       'bad0': bad_total}

    # -- the current tick's accumulators ---------------------------------------------------------

    tick_step_s = 0.0   # engine time of this tick's slices
    tick_substeps = 0
    tick_work_s = 0.0   # slices' whole work before the publishing one
    input_s = 0.0       # time on received poses since the last tick
    last_substeps = 0   # substeps of the last running tick

    def advanced(self, to_ns: int, advance_s: float, substeps: int, step_s: float) -> None:
        """One engine advance of a slice: to node time ``to_ns`` by ``advance_s``."""
        self.rings['slice_ns'].add(to_ns)
        self.rings['advance_s'].add(advance_s)
        self.rings['advance_steps'].add(substeps)
        self.tick_step_s += step_s
        self.tick_substeps += substeps

    def tick_started(self, interval: float | None) -> None:
        self.rings['input_s'].add(self.input_s)
        self.input_s = 0.0
        if interval is not None:
            self.rings['tick_interval_s'].add(interval)

    def tick(self, work_s: float, overran: bool, running: bool) -> None:
        """A tick published after ``work_s`` of its slices' work; ``running``: neither paused
        nor held (the engine's figures count only then)."""
        step_s = self.tick_step_s
        if running:
            self.last_substeps = self.tick_substeps
            self.rings['step_s'].add(step_s)
            self.rings['substeps'].add(self.tick_substeps)
        self.tick_step_s, self.tick_substeps, self.tick_work_s = 0.0, 0, 0.0
        self.rings['tick_work_s'].add(work_s)
        self.rings['advances_at_tick'].add(self.rings['advance_s'].count)
        w = self.window
        w['ticks'] += 1
        w['step_s'] += step_s
        w['step_max_s'] = max(w['step_max_s'], step_s)
        w['overruns'] += int(overran)


def diagnostics_statuses(name: str, now_ns: int, *, stats: NodeStats, schedule, driver, pose_input,
                         paused: bool, ticks: int, recorder=None) -> list:
    """The DiagnosticStatus tuples (name, level, message, values) of this moment."""
    w = stats.window
    scene = driver.scene
    elapsed = max(time.perf_counter() - w['wall0'], 1e-9)
    sim_now = float(scene.time)
    # engine time per node-clock time (with use_sim_time, per simulated /clock time)
    clock_elapsed = elapsed if w['clock0'] is None else (now_ns - w['clock0']) / NS_PER_S
    rtf = (driver.simulated_s - w['sim0']) / clock_elapsed if clock_elapsed > 0 else float('nan')
    ticks_in_window = max(w['ticks'], 1)
    step_mean = w['step_s'] / ticks_in_window
    period = schedule.period_s
    intervals = stats.rings['tick_interval_s'].array()
    deviation = np.abs(intervals - period) if intervals.size else np.zeros(1)
    if driver.held:
        level, state = 'ERROR', 'diverged, held until ~/reset'
    elif w['overruns'] or (w['ticks'] and not paused and not rtf >= 0.95):
        level, state = 'WARN', f'{w["overruns"]} deadline overruns in the last {elapsed:.3g} s'
    else:
        level, state = 'OK', 'paused' if paused else 'running'
    engine = {
        'state': 'held' if driver.held else 'paused' if paused else 'running',
        'simulated_time_s': sim_now,
        'ticks': ticks,
        'tick_period_s': period,
        'step_time_ms_mean': step_mean * 1e3,
        'step_time_ms_max': w['step_max_s'] * 1e3,
        'tick_work_ms_p99': stats.rings['tick_work_s'].percentile(99) * 1e3,
        'tick_period_deviation_ms_p99': float(np.percentile(deviation, 99)) * 1e3,
        'substeps_last': stats.last_substeps,
        'engine_dt_s': float(scene.dt),
        'engine_time_behind_s': driver.target_time - sim_now,
        'real_time_factor': rtf,
        'compute_load': step_mean / period,
        'deadline_overruns': schedule.deadline_overruns,
        'missed_ticks': schedule.missed_ticks,
        'missed_ticks_for_input': schedule.missed_for_input,
        'dropped_time_s': schedule.dropped_time_s,
        'divergences': driver.divergences,
        'stability': 'held after divergence' if driver.held else 'stable',
        'phase': str(scene.phase),
        'tip_depth_m': float(scene.tip_depth),
        'topology_version': int(scene.topology_version),
        'punctures': len(scene.puncture_events),
    }
    statuses = [(f'{name}: engine', level, state, engine),
                _input_status(name, now_ns, stats, pose_input, elapsed)]
    if recorder is not None:
        st = recorder.stats()
        statuses.append((f'{name}: recording', 'WARN' if st.messages_dropped else 'OK',
                         str(recorder.path),
                         {'messages_written': st.messages_written,
                          'messages_dropped': st.messages_dropped,
                          'messages_unsaved': st.messages_unsaved,
                          'chunks_closed': st.chunks_closed,
                          'bytes_written': st.bytes_written}))
    return statuses


def _input_status(name, now_ns, stats, pose_input, elapsed) -> tuple:
    age = pose_input.age_s(now_ns)
    stale = pose_input.stale(now_ns)
    bad_new = pose_input.bad_total - stats.window['bad0']
    values = {'poses_received': pose_input.received, 'poses_accepted': pose_input.accepted,
              'last_pose_age_s': 'none yet' if age is None else age, 'stale': stale,
              'latency_ms_p50': stats.rings['latency_s'].percentile(50) * 1e3,
              'latency_ms_p99': stats.rings['latency_s'].percentile(99) * 1e3,
              'input_work_ms_per_tick_max': float(stats.rings['input_s'].array().max(initial=0.0)) * 1e3}
    values.update({f'bad_input.{k}': v for k, v in pose_input.counts.items()})
    if bad_new:
        level, message = 'WARN', f'{bad_new} bad poses in the last {elapsed:.3g} s'
    elif stale:
        level, message = 'WARN', f'no pose for {age:.3g} s: holding the last one'
    elif age is None:
        level, message = 'OK', 'no pose yet: the needle holds its initial pose'
    else:
        level, message = 'OK', 'receiving'
    return f'{name}: input', level, message, values
