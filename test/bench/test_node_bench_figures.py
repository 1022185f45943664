"""node-bench's figures (bench/node_bench_figures.py) from timings whose answers are known by
construction: rates and periods, latencies, diagnostics, per-thread CPU."""

import numpy as np
import pytest

from tissue_sim_ros.bench import node_bench_figures
import math

MS = 1_000_000  # ns


def test_rate_and_period_figures_of_a_known_tick_train():
    """Ticks every 20 ms over 1 s, one of them 5 ms late; each wrench received 1 ms after its
    tick: 50 Hz at the receiver, periods 25 and 15 ms around the late one, so |deviation| p99
    and max are 5 ms and the median period 20 ms."""
    ticks = np.arange(0, 1200, 20, dtype=np.int64) * MS
    ticks[25] += 5 * MS
    rx = np.stack([ticks + MS, ticks], axis=1)
    window = node_bench_figures.Window(0, 1000 * MS, 0.0, 0.5)
    f = node_bench_figures.rate_and_periods(rx, ticks, window, 50.0)
    assert f['wrench_rate_hz'] == pytest.approx(50.0)  # 50 arrivals in 0.98 s
    assert f['wrench_rate_error_pct'] == pytest.approx(0.0, abs=1e-9)
    assert f['tick_period_ms_p50'] == pytest.approx(20.0)
    assert f['tick_period_dev_ms_p99'] == pytest.approx(5.0)
    assert f['tick_period_dev_ms_max'] == pytest.approx(5.0)
    assert f['receive_period_dev_ms_p99'] == pytest.approx(5.0)
    assert window.cpu_pct() == pytest.approx(50.0)  # 0.5 CPU s in 1 s


def _trace_log(ticks, shown, advances, receipts, stamps, publish_delay=3 * MS):
    """A node log with its engine trace: wrenches ticked at ``ticks`` showing states ``shown``,
    published ``publish_delay`` later; ``advances``: (state index, node-clock time it went to)."""
    return {'wrench_tick': ticks, 'wrench_publish': ticks + publish_delay,
            'trace_tick': ticks, 'trace_shown': np.asarray(shown, dtype=np.int64),
            'advance_index': np.array([a for a, _ in advances], dtype=np.int64),
            'advance_clock': np.array([c for _, c in advances], dtype=np.int64),
            'pose_receipt': np.asarray(receipts, dtype=np.int64), 'pose_stamp': np.asarray(stamps, dtype=np.int64)}


def test_latency_is_receipt_to_the_publish_of_the_first_wrench_computed_with_the_pose():
    """Ticks at 0, 20, 40, 60 ms published 3 ms later and received here 2 ms after that. Poses
    received at 10, 40 and 41 ms (stamped 1 ms before); the engine goes to 9.5 ms at once
    (state 1, within the 1 ms step of the first pose), but reaches the second and third poses
    only in state 3, which the tick at 60 ms is the first to show (the tick at 40 ms still
    shows state 1): latencies 13, 23 and 22 ms, end to end 16, 26 and 25 ms. Taking the next
    tick after each receipt would have said 13, 3 and 22."""
    ticks = np.array([0, 20, 40, 60], dtype=np.int64) * MS
    log = _trace_log(ticks, shown=[0, 1, 1, 3], advances=[(1, 9_500_000), (2, 30 * MS), (3, 41 * MS)],
                     receipts=np.array([10, 40, 41]) * MS, stamps=np.array([9, 39, 40]) * MS)
    rx = np.stack([ticks + 5 * MS, ticks], axis=1)
    f = node_bench_figures.latencies(log, rx, node_bench_figures.Window(0, 100 * MS, None, None), dt_s=0.001)
    assert f['latency_ms_p50'] == pytest.approx(22.0)
    assert f['latency_ms_max'] == pytest.approx(23.0)
    assert f['latency_ms_p99'] == pytest.approx(np.percentile([13, 23, 22], 99))
    assert f['end_to_end_ms_p50'] == pytest.approx(25.0)
    assert f['end_to_end_ms_p99'] == pytest.approx(np.percentile([16, 26, 25], 99))
    assert f['poses_not_in_a_wrench'] == 0
    # with no tolerance (a step of 0) a pose stamped 10 ms is reached only by state 2, which the
    # tick at 40 ms is the first to show; one stamped 44 ms by no advance in the log
    late = _trace_log(ticks, shown=[0, 1, 2, 2], advances=[(1, 9_500_000), (2, 30 * MS)],
                      receipts=[10 * MS, 45 * MS], stamps=[10 * MS, 44 * MS])
    f = node_bench_figures.latencies(late, rx, node_bench_figures.Window(0, 100 * MS, None, None), dt_s=0.0)
    assert f['latency_ms_max'] == pytest.approx(33.0)       # 10 ms -> the tick at 40 ms, out at 43
    assert f['poses_not_in_a_wrench'] == 1                  # 44 ms: no advance went there


def test_diagnostic_figures_read_the_counters_and_the_kernel_over_the_window():
    diagnostic_msgs = pytest.importorskip('diagnostic_msgs.msg')
    from builtin_interfaces.msg import Time

    def array(sec, missed, kernel_s, advances=0, dropped_s=0.0, changes=0):
        status = diagnostic_msgs.DiagnosticStatus(name='tissue_sim: engine', values=[
            diagnostic_msgs.KeyValue(key='missed_ticks', value=str(missed)),
            diagnostic_msgs.KeyValue(key='advances_total', value=str(advances)),
            diagnostic_msgs.KeyValue(key='advances_per_s', value='99'),
            diagnostic_msgs.KeyValue(key='ticks', value=str(50 * sec)),
            diagnostic_msgs.KeyValue(key='dropped_time_s', value=str(dropped_s)),
            diagnostic_msgs.KeyValue(key='ladder_changes', value=str(changes)),
            diagnostic_msgs.KeyValue(key='kernel_s_total', value=str(kernel_s)),
            diagnostic_msgs.KeyValue(key='budget_use', value='0.5')])
        inputs = diagnostic_msgs.DiagnosticStatus(name='tissue_sim: input', values=[
            diagnostic_msgs.KeyValue(key='latency_ms_p99', value='12.5')])
        msg = diagnostic_msgs.DiagnosticArray(status=[status, inputs])
        msg.header.stamp = Time(sec=sec)
        return msg
    # the node counts from its start: a start that dropped 40 s and missed 7 ticks before the
    # window is not the window's
    messages = [array(10, 7, 1.0, 40, 30.0, 1), array(11, 7, 1.5, 100, 40.0, 1),
                array(20, 10, 4.0, 640, 40.25, 3)]
    f = node_bench_figures.diagnostic_figures(messages, window_start_ns=11 * 1_000_000_000)
    assert (f['missed_ticks'], f['ticks'], f['budget_use']) == (3, 450, 0.5)
    assert (f['dropped_time_s'], f['ladder_changes']) == (pytest.approx(0.25), 2)
    whole = node_bench_figures.diagnostic_figures([array(20, 10, 4.0, 640, 40.25, 3)], window_start_ns=0)
    # no message before the window: the node's counts since its start
    assert (whole['missed_ticks'], whole['ticks'], whole['dropped_time_s']) == (10, 1000, 40.25)
    assert f['kernel_s_in_window'] == pytest.approx(2.5)   # from the last message before the window
    assert f['advances_per_s'] == pytest.approx(60.0)      # (640 - 100) advances in 9 s, not the last second's
    assert f['node_latency_ms_p99_own'] == 12.5
    assert f['ladder_level'] == -1  # not reported: said so, not invented
    assert node_bench_figures.diagnostic_figures([])['missed_ticks'] == -1


def test_thread_groups_by_os_name_with_the_main_thread_as_the_executor():
    """CPU seconds of each thread at both ends of a 2 s window: the main thread (tid = pid) is
    the executor, names pick the engine, tick, recorder and DDS threads, a thread born in the window
    counts from 0, and the groups add up to the threads' total."""
    before = {100: ('tissue_sim_node', 1.0), 101: ('ts-engine', 5.0), 102: ('mcap-writer:ti', 0.5),
              103: ('dds.shm.4711', 0.2), 104: ('tissue_sim_node', 0.0), 106: ('ts-tick', 0.3)}
    after = {100: ('tissue_sim_node', 1.1), 101: ('ts-engine', 5.8), 102: ('mcap-writer:ti', 0.52),
             103: ('dds.shm.4711', 0.22), 104: ('tissue_sim_node', 0.01), 105: ('dds.ev.0', 0.03),
             106: ('ts-tick', 0.34)}
    groups = node_bench_figures.thread_groups_pct(100, before, after, 2.0)
    assert groups == pytest.approx({'engine': 40.0, 'tick': 2.0, 'executor': 5.0, 'recording': 1.0, 'dds': 2.5,
                                    'other': 0.5})
    used = sum(c for _, c in after.values()) - sum(c for _, c in before.values())
    assert sum(groups.values()) == pytest.approx(100.0 * used / 2.0)


def test_node_bench_reads_a_figure_that_does_not_exist_as_nan():
    """node-bench's figures from the node's diagnostics: 'none yet' is a missing number, not an
    error (it read every value as a float)."""
    from types import SimpleNamespace

    from tissue_sim_ros.bench.node_bench_figures import diagnostic_figures
    from tissue_sim_ros.ros.messages.conversions import diagnostic_array_msg
    msg = diagnostic_array_msg(0, [('tissue_sim: engine', 'OK', '', {'budget_use': 'none yet', 'lag_s': 0.001,
                                                                     'ticks': 10}),
                                   ('tissue_sim: predictions', 'OK', '', {'real_time_factor_median': 'none yet'})])
    figures = diagnostic_figures([SimpleNamespace(header=msg.header, status=msg.status)])
    assert math.isnan(figures['budget_use']) and math.isnan(figures['prediction_real_time_factor'])
    assert figures['lag_s'] == 0.001 and figures['ticks'] == 10
