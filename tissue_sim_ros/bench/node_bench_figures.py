"""The figures ``tissue-sim node-bench`` computes from what it recorded of a run.

:mod:`~tissue_sim_ros.bench.node_bench` runs the node and drives it; this module turns the
record into numbers: the node's CPU and its threads' (/proc, read at both ends of the window),
the tick periods and the pose-to-wrench latencies from the node's MCAP log (the latency through
the engine's trace: the first wrench computed with each pose), and the counters of the node's
last diagnostics. Plain arrays and dicts in, figures out; no rclpy.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tissue_sim_ros.ros.loop.trace import TRACE_TOPIC
from tissue_sim_ros.ros.parameters import NODE_NAME
from tissue_sim_ros.units import NS_PER_S

__all__ = ['THREAD_GROUPS', 'Window', 'cpu_seconds', 'thread_cpu_seconds', 'thread_groups_pct', 'log_timings',
           'rate_and_periods', 'first_ticks_with', 'latencies', 'status_values', 'engine_dt_s',
           'diagnostic_figures', 'kernel_share']

_NS_PER_MS = NS_PER_S // 1000
_TRACE_TOPIC = f'/{NODE_NAME}/{TRACE_TOPIC.removeprefix("~/")}'   # the node's ~/engine_trace, resolved


def _stat_cpu_seconds(stat_path: str) -> float:
    """User + system CPU seconds from a /proc stat file (the process's or one thread's)."""
    fields = Path(stat_path).read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def cpu_seconds(pid: int) -> float | None:
    """The process's CPU seconds so far (None once it is gone)."""
    try:
        return _stat_cpu_seconds(f'/proc/{pid}/stat')
    except OSError:
        return None


#: the node's threads by their OS names (os_thread_name); the main thread is the executor's
THREAD_GROUPS = (('engine', 'ts-engine'), ('tick', 'ts-tick'), ('recording', 'mcap-writer'), ('dds', 'dds.'))


def thread_cpu_seconds(pid: int) -> dict[int, tuple[str, float]]:
    """Each live thread of ``pid``: tid -> (OS name, user + system CPU seconds)."""
    threads = {}
    try:
        tids = [int(t) for t in os.listdir(f'/proc/{pid}/task')]
    except OSError:
        return threads
    for tid in tids:
        try:
            threads[tid] = (Path(f'/proc/{pid}/task/{tid}/comm').read_text().strip(),
                            _stat_cpu_seconds(f'/proc/{pid}/task/{tid}/stat'))
        except OSError:                   # the thread ended meanwhile
            continue
    return threads


def thread_groups_pct(pid: int, before: dict, after: dict, seconds: float) -> dict[str, float]:
    """CPU of each group of threads over a window, % of one core: 'engine', 'tick', 'executor'
    (the main thread), 'recording', 'dds' and 'other' (numba's, the predictions' intake...); a
    thread started in the window counts from 0, one that ended in it is not seen."""
    groups = {'engine': 0.0, 'tick': 0.0, 'executor': 0.0, 'recording': 0.0, 'dds': 0.0, 'other': 0.0}
    for tid, (name, cpu) in after.items():
        used = cpu - before.get(tid, (name, 0.0))[1]
        group = 'executor' if tid == pid else next(
            (group for group, prefix in THREAD_GROUPS if name.startswith(prefix)), 'other')
        groups[group] += 100.0 * used / seconds
    return groups


@dataclass
class Window:
    """The measured window: its ends on the system clock, the node's CPU seconds at each, the
    stamps of the poses sent in it."""

    wall0_ns: int
    wall1_ns: int
    cpu0: float | None
    cpu1: float | None
    sent: list[int] = field(default_factory=list)
    thread_pct: dict = field(default_factory=dict)   # thread_groups_pct over the window

    @property
    def seconds(self) -> float:
        return (self.wall1_ns - self.wall0_ns) / NS_PER_S

    def cpu_pct(self) -> float | None:
        if self.cpu0 is None or self.cpu1 is None:
            return None
        return 100.0 * (self.cpu1 - self.cpu0) / self.seconds


def log_timings(path: Path) -> dict:
    """From the node's log: each pose's receipt (log time) and stamp, each wrench's tick (stamp)
    and publish time (log time), and from the engine's trace each advance (its state index, the
    node-clock time it went to) and each tick's published state; ns on the node's clock."""
    from tissue_sim_ros.io import mcap as ml
    from tissue_sim_ros.ros.loop import trace as engine_trace
    from tissue_sim_ros.ros.messages.conversions import stamp_to_ns
    columns = {name: [] for name in ('pose_receipt', 'pose_stamp', 'wrench_tick', 'wrench_publish',
                                     'advance_index', 'advance_clock', 'trace_tick', 'trace_shown')}
    for m in ml.read_log(path, topics=['/needle/pose', '/needle/wrench', _TRACE_TOPIC]):
        if m.topic == '/needle/pose':
            columns['pose_receipt'].append(m.log_time_ns)
            columns['pose_stamp'].append(stamp_to_ns(m.message.header.stamp))
        elif m.topic == '/needle/wrench':
            columns['wrench_tick'].append(stamp_to_ns(m.message.header.stamp))
            columns['wrench_publish'].append(m.log_time_ns)
        else:
            trace = engine_trace.decode(m.message.data)
            columns['trace_tick'].append(trace.stamp_ns)
            columns['trace_shown'].append(trace.published_index)
            advances = trace.rows[:, 0] == engine_trace.ADVANCE
            columns['advance_index'].extend(trace.rows[advances, 1].astype(np.int64).tolist())
            columns['advance_clock'].extend(trace.clock_ns()[advances].tolist())
    return {name: np.array(values, dtype=np.int64) for name, values in columns.items()}


def rate_and_periods(wrench_rx: np.ndarray, ticks: np.ndarray, window: Window,
                      publish_rate_hz: float) -> dict:
    """Wrench rate at this receiver and tick period figures over the window."""
    period_ms = 1e3 / publish_rate_hz
    rx = wrench_rx[(wrench_rx[:, 0] >= window.wall0_ns) & (wrench_rx[:, 0] <= window.wall1_ns)]
    if len(rx) < 2:
        raise RuntimeError(f'{len(rx)} wrenches arrived in the {window.seconds:.1f} s window; '
                           'expected a steady stream (is the node running?)')
    rate = (len(rx) - 1) / ((rx[-1, 0] - rx[0, 0]) / NS_PER_S)
    ticks_w = ticks[(ticks >= window.wall0_ns) & (ticks <= window.wall1_ns)]
    periods = np.diff(ticks_w) / _NS_PER_MS
    deviation = np.abs(periods - period_ms)
    rx_periods = np.diff(rx[:, 0]) / _NS_PER_MS
    return {
        'wrench_rate_hz': rate,
        'wrench_rate_error_pct': 100.0 * (rate - publish_rate_hz) / publish_rate_hz,
        'tick_period_ms_p50': float(np.percentile(periods, 50)),
        'tick_period_dev_ms_p99': float(np.percentile(deviation, 99)),
        'tick_period_dev_ms_max': float(deviation.max()),
        'receive_period_dev_ms_p99': float(np.percentile(np.abs(rx_periods - period_ms), 99)),
    }


def first_ticks_with(log: dict, stamps: np.ndarray, dt_s: float) -> np.ndarray:
    """For each pose stamp, the tick stamp of the first wrench computed with it (-1: none in the
    log): the first advance that went to within ``dt_s`` of the stamp, then the first tick that
    published that state or a later one (engine trace; both sequences taken as running maxima)."""
    clocks = np.maximum.accumulate(log['advance_clock'])
    shown = np.maximum.accumulate(log['trace_shown'])
    advance = np.searchsorted(clocks, stamps - round(dt_s * NS_PER_S), side='left')
    ticks = np.full(stamps.shape, -1, dtype=np.int64)
    reached = advance < clocks.size
    tick = np.searchsorted(shown, log['advance_index'][advance[reached]], side='left')
    published = tick < shown.size
    ticks[np.flatnonzero(reached)[published]] = log['trace_tick'][tick[published]]
    return ticks


def latencies(log: dict, wrench_rx: np.ndarray, window: Window, dt_s: float) -> dict:
    """Pose receipt -> the publish of the first wrench computed with it (:func:`first_ticks_with`,
    ``dt_s`` the engine's step), and end to end: pose sent here -> that wrench received here
    (matched by its tick stamp). Poses no published state reached are left out (counted)."""
    in_window = (log['pose_receipt'] >= window.wall0_ns) & (log['pose_receipt'] <= window.wall1_ns)
    receipts, stamps = log['pose_receipt'][in_window], log['pose_stamp'][in_window]
    ticks = first_ticks_with(log, stamps, dt_s)
    publish_of = dict(zip(log['wrench_tick'].tolist(), log['wrench_publish'].tolist()))
    received_of = dict(zip(wrench_rx[:, 1].tolist(), wrench_rx[:, 0].tolist()))
    latency, e2e = [], []
    for receipt, stamp, tick in zip(receipts.tolist(), stamps.tolist(), ticks.tolist()):
        if tick in publish_of:
            latency.append((publish_of[tick] - receipt) / _NS_PER_MS)
        if tick in received_of:
            e2e.append((received_of[tick] - stamp) / _NS_PER_MS)
    if not latency:
        raise RuntimeError(f'none of the {receipts.size} poses of the window reached a published wrench '
                           '(no engine trace in the log?)')
    latency, e2e = np.array(latency), np.array(e2e)
    nan = float('nan')
    return {
        'poses_not_in_a_wrench': int(receipts.size - latency.size),
        'latency_ms_p50': float(np.percentile(latency, 50)),
        'latency_ms_p99': float(np.percentile(latency, 99)),
        'latency_ms_max': float(latency.max()),
        'end_to_end_ms_p50': float(np.percentile(e2e, 50)) if e2e.size else nan,
        'end_to_end_ms_p99': float(np.percentile(e2e, 99)) if e2e.size else nan,
    }


def status_values(message, name_part) -> dict:
    for status in (message.status if message is not None else ()):
        if name_part in status.name:
            return {kv.key: kv.value for kv in status.values}
    return {}


def _number(values: dict, key: str) -> float:
    """A diagnostics value as a number: NaN where the node did not report it, or reported that
    it does not exist yet ('none yet')."""
    try:
        return float(values[key])
    except (KeyError, ValueError):
        return float('nan')


def engine_dt_s(diagnostics: list) -> float:
    """The engine's time step [s] from the node's last diagnostics (0 when it did not say)."""
    engine = status_values(diagnostics[-1] if diagnostics else None, 'engine')
    dt = _number(engine, 'engine_dt_s')
    return dt if dt > 0.0 else 0.0


def _in_window(engine: dict, engine0: dict, key: str, kind=int):
    """A cumulative counter of the engine's status over the window: the last value minus the one
    the last message before the window had (the node counts from its start, and a large scene's
    start, with nothing to keep up with yet, drops time and misses ticks of its own); the last
    value where no message came before the window, -1 (NaN) where the node did not report it."""
    if key not in engine:
        return kind(-1) if kind is int else float('nan')
    last = kind(_number(engine, key))
    return last - kind(_number(engine0, key)) if key in engine0 else last


def diagnostic_figures(diagnostics: list, window_start_ns: int | None = None) -> dict:
    """Figures from the node's diagnostics (engine and input status): its counters over the window
    (missed ticks, ticks, dropped time, ladder changes, kernel seconds, advances a second: the last
    message's minus the last one's before the window starts), and the last message's state (budget
    use, lag, ladder level). -1 or NaN where the node did not report a figure."""
    from tissue_sim_ros.ros.messages.conversions import stamp_to_ns
    last = diagnostics[-1] if diagnostics else None
    engine, inputs = status_values(last, 'engine'), status_values(last, 'input')
    predictions = status_values(last, 'predictions')
    before = [m for m in diagnostics if window_start_ns is not None
              and stamp_to_ns(m.header.stamp) <= window_start_ns]
    engine0 = status_values(before[-1] if before else None, 'engine')
    kernel = _number(engine, 'kernel_s_total') - _number(engine0, 'kernel_s_total')
    span_s = (stamp_to_ns(last.header.stamp) - stamp_to_ns(before[-1].header.stamp)) / 1e9 if before else 0.0
    advances = ((_number(engine, 'advances_total') - _number(engine0, 'advances_total')) / span_s
                if span_s > 0 else _number(engine, 'advances_per_s'))
    return {
        'missed_ticks': _in_window(engine, engine0, 'missed_ticks'),
        'ticks': _in_window(engine, engine0, 'ticks'),
        'budget_use': _number(engine, 'budget_use'),
        'lag_s': _number(engine, 'lag_s'),
        'dropped_time_s': _in_window(engine, engine0, 'dropped_time_s', float),
        'ladder_level': int(engine.get('ladder_level', -1)),
        'ladder_changes': _in_window(engine, engine0, 'ladder_changes'),
        'engine_threads': int(engine.get('engine_threads', -1)),
        'kernel_share_of_engine': _number(engine, 'kernel_share_of_engine'),
        'advances_per_s': advances,
        'kernel_s_in_window': kernel,
        'node_latency_ms_p99_own': _number(inputs, 'latency_ms_p99'),
        'prediction_real_time_factor': _number(predictions, 'real_time_factor_median'),
        'prediction_workers': int(predictions.get('workers', -1)),
        'prediction_workers_state': predictions.get('workers_state', ''),
    }


def kernel_share(r: dict, window: Window) -> float:
    """The force kernel's CPU over the node's: the engine thread's CPU seconds in the kernel
    over the window, times the engine's threads (each busy in the kernel's parallel loops: an
    estimate above one thread), over the node process's CPU seconds."""
    if window.cpu0 is None or window.cpu1 is None or window.cpu1 <= window.cpu0:
        return float('nan')
    return r['kernel_s_in_window'] * max(r['engine_threads'], 1) / (window.cpu1 - window.cpu0)
