"""node-bench's parts: the figures from timings whose answers are known by construction, the node
launched as a process (a refusal reaches the user with the node's reason), and the background load
(busy processes and a listening client that hears every message, all stopped whatever happens)."""
import contextlib
import os
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.bench import node_bench
from tissue_sim_ros.bench import node_bench_figures
from tissue_sim_ros.bench.background_load import SPIN, BackgroundLoad

MS = 1_000_000  # ns


def _alive(pid):
    """True while the process runs (a zombie or a reaped process is not running)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state not in ('Z', 'X')


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


def test_diagnostic_figures_read_the_last_message_and_the_kernel_over_the_window():
    diagnostic_msgs = pytest.importorskip('diagnostic_msgs.msg')
    from builtin_interfaces.msg import Time

    def array(sec, missed, kernel_s, advances=0):
        status = diagnostic_msgs.DiagnosticStatus(name='tissue_sim: engine', values=[
            diagnostic_msgs.KeyValue(key='missed_ticks', value=str(missed)),
            diagnostic_msgs.KeyValue(key='advances_total', value=str(advances)),
            diagnostic_msgs.KeyValue(key='advances_per_s', value='99'),
            diagnostic_msgs.KeyValue(key='ticks', value='1000'),
            diagnostic_msgs.KeyValue(key='kernel_s_total', value=str(kernel_s)),
            diagnostic_msgs.KeyValue(key='budget_use', value='0.5')])
        inputs = diagnostic_msgs.DiagnosticStatus(name='tissue_sim: input', values=[
            diagnostic_msgs.KeyValue(key='latency_ms_p99', value='12.5')])
        msg = diagnostic_msgs.DiagnosticArray(status=[status, inputs])
        msg.header.stamp = Time(sec=sec)
        return msg
    f = node_bench_figures.diagnostic_figures([array(10, 7, 1.0, 40), array(11, 7, 1.5, 100),
                                               array(20, 3, 4.0, 640)], window_start_ns=11 * 1_000_000_000)
    assert (f['missed_ticks'], f['ticks'], f['budget_use']) == (3, 1000, 0.5)
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


def test_a_node_that_refuses_its_parameters_is_one_error_naming_the_reason(tmp_path):
    pytest.importorskip('rclpy')
    from tissue_sim_ros.ros.clients.node_process import NodeProcess
    from tissue_sim_ros.errors import NodeProcessError
    with NodeProcess(['publish_rate_hz:=-5.0'], tmp_path / 'node.log') as node:
        assert node.env['ROS_AUTOMATIC_DISCOVERY_RANGE'] == 'LOCALHOST'
        assert node.env['ROS_DOMAIN_ID'] == str(node.domain_id) != os.environ.get('ROS_DOMAIN_ID')
        with pytest.raises(NodeProcessError) as refused:
            node.wait_until(lambda: False, timeout_s=120)
    message = str(refused.value)
    assert 'exited with status 2' in message and 'publish_rate_hz' in message
    assert str(tmp_path / 'node.log') in message and '\n' not in message


def test_a_spinner_ends_when_its_parent_is_gone():
    """Even if the bench is killed before it can stop them, its busy processes do not linger."""
    parent = subprocess.run(
        [sys.executable, '-c', 'import os, subprocess, sys\n'
         f'p = subprocess.Popen([sys.executable, "-c", {SPIN!r}, str(os.getpid())],\n'
         '                     stdout=subprocess.DEVNULL)\nprint(p.pid)'],
        capture_output=True, text=True, timeout=60)
    pid = int(parent.stdout)
    deadline = time.monotonic() + 10
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(pid)


def _cpu_seconds(pid):
    fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')


def test_background_load_spins_listens_and_stops_whatever_happens():
    """A stand-in node publishes 25 wrenches and 10 clouds at up to 50 Hz: the listener hears
    every one, at the rate they were sent; the two spinners use CPU; an error inside the block still stops them all."""
    with _stand_in_node() as stand_in:
        wrench, cloud = stand_in.wrench, stand_in.cloud
        load = BackgroundLoad(2, stand_in.env)
        with pytest.raises(KeyboardInterrupt):
            with load:
                pids = [s.pid for s in load.spinners] + [load.listener_process.pid]
                deadline = time.monotonic() + 10   # a loaded machine may show them late in /proc
                while sorted(_my_spinners()) != sorted(pids[:2]) and time.monotonic() < deadline:
                    time.sleep(0.05)
                assert sorted(_my_spinners()) == sorted(pids[:2])
                cpu0 = [_cpu_seconds(pid) for pid in pids[:2]]
                deadline = time.monotonic() + 30
                while not (wrench.get_subscription_count() and cloud.get_subscription_count()):
                    assert time.monotonic() < deadline
                    time.sleep(0.02)
                sent_at = []
                for k in range(25):
                    wrench.publish(stand_in.Wrench())
                    sent_at.append(time.monotonic())
                    if k % 5 < 2:
                        cloud.publish(stand_in.Cloud())
                    time.sleep(0.02)
                time.sleep(0.5)
                assert all(_cpu_seconds(pid) - c > 0.05 for pid, c in zip(pids, cpu0))
                raise KeyboardInterrupt  # e.g. the user stops the bench
    assert not any(_alive(pid) for pid in pids) and _my_spinners() == []
    assert load.listener['wrench']['count'] == 25 and load.listener['cloud']['count'] == 10
    sent_rate = 24 / (sent_at[-1] - sent_at[0])  # about 50 Hz; less on a loaded machine
    # the rate they were sent at, from their source stamps, whatever the listener's scheduling;
    # the receipt rate bunches when its middleware thread is starved (92 Hz seen for 48 Hz sent)
    assert load.listener['wrench']['sent_rate_hz'] == pytest.approx(sent_rate, rel=0.1)
    assert sent_rate / 3 < load.listener['wrench']['rate_hz'] < 3 * sent_rate
    assert '2 busy processes + 1 listening client' in load.describe()


def test_listen_alone_starts_the_listener_without_busy_processes():
    """--listen: the listening client hears the stand-in's wrench and cloud; no spinner runs."""
    assert BackgroundLoad(0, {}).describe().startswith('none')
    with _stand_in_node() as stand_in:
        with BackgroundLoad(0, stand_in.env, listen=True) as load:
            assert load.spinners == [] and load.listener_process is not None and _my_spinners() == []
            deadline = time.monotonic() + 30
            while not (stand_in.wrench.get_subscription_count() and stand_in.cloud.get_subscription_count()):
                assert time.monotonic() < deadline
                time.sleep(0.02)
            for _ in range(5):
                stand_in.wrench.publish(stand_in.Wrench())
                stand_in.cloud.publish(stand_in.Cloud())
                time.sleep(0.02)
            time.sleep(0.5)
    assert load.listener['wrench']['count'] == 5 and load.listener['cloud']['count'] == 5
    assert load.describe() == 'no busy process + 1 listening client (needle/wrench, tissue/nodes)'


@contextlib.contextmanager
def _stand_in_node():
    """A stand-in for the node on a private domain: ``env`` (its ROS environment for children),
    ``wrench`` and ``cloud`` (its publishers, keeping all they send: a starved listener
    acknowledges late) and the message types ``Wrench``, ``Cloud``."""
    rclpy = pytest.importorskip('rclpy')
    from geometry_msgs.msg import WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2
    from tissue_sim_ros.ros.clients.node_process import client_context, private_domain_id, private_ros_env
    domain = private_domain_id()
    reliable = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
    with client_context(domain) as context:
        node = rclpy.create_node('tissue_sim', context=context)
        try:
            yield types.SimpleNamespace(
                env=private_ros_env(domain), Wrench=WrenchStamped, Cloud=PointCloud2,
                wrench=node.create_publisher(WrenchStamped, 'needle/wrench', reliable),
                cloud=node.create_publisher(PointCloud2, 'tissue/nodes', reliable))
        finally:
            node.destroy_node()


def _my_spinners():
    """Pids of running spinner processes this test process started."""
    found = []
    for proc in Path('/proc').iterdir():
        try:
            argv = (proc / 'cmdline').read_bytes().split(b'\0')
        except OSError:
            continue
        if len(argv) > 3 and argv[2] == SPIN.encode() and argv[3] == str(os.getpid()).encode():
            if _alive(int(proc.name)):
                found.append(int(proc.name))
    return found


@pytest.mark.slow
def test_measure_end_to_end_under_load(tmp_path):
    """One short node-bench run with one busy process on a coarse scene: every pose sent at 100 Hz
    is in the node's log, the bench and the listener both heard the wrench, the node stopped
    cleanly on SIGINT, and no spinner is left."""
    pytest.importorskip('rclpy')
    import yaml
    root = Path(__file__).resolve().parents[1]
    spec = yaml.safe_load((root / 'config' / 'liver_sample.yaml').read_text())
    spec['mesh'] = {'generator': 'box', 'size_m': spec['mesh']['size_m'],
                    'origin_m': spec['mesh']['origin_m'], 'divisions': [6, 6, 4]}
    scene = tmp_path / 'coarse.yaml'
    scene.write_text(yaml.safe_dump(spec, sort_keys=False))
    r = node_bench.measure(duration_s=1.0, rate_hz=100.0, scene_file=str(scene),
                           log_dir=tmp_path / 'out', load=1)
    assert r['node_exit_code'] == 0
    assert r['poses_sent'] == pytest.approx(100, abs=3) and r['poses_logged'] == r['poses_sent']
    assert r['load'].startswith('1 busy process + 1 listening client')
    assert r['listener']['wrench']['count'] > 10 and r['listener']['cloud']['count'] > 0
    assert 0 < r['wrench_rate_hz'] <= 50.0 * 1.05 and r['ticks'] > 0
    assert Path(r['mcap']).is_file() and (tmp_path / 'out' / 'node.log').is_file()
    assert _my_spinners() == []
    # the window started once the prediction workers had loaded (they take seconds, the window 1 s)
    assert r['prediction_workers'] > 0 and r['prediction_workers_state'] == 'warm'
    assert r['prediction_warm_up_s'] > 0.0
    text = node_bench.report(r)
    assert 'load beside the node 1 busy process' in text and 'listening client     wrench' in text
    assert 'prediction workers warm' in text
    # per thread: the groups add up to the process (both /proc, 10 ms ticks over a 1 s window)
    threads = r['thread_cpu_pct']
    # the executor (pose callbacks) and the tick take about 1 % of a core each: 10 ms in the 1 s
    # window, /proc's clock tick, so either may read 0 there
    assert threads['engine'] > 0.0 and {'tick', 'executor'} <= set(threads)
    assert sum(threads.values()) == pytest.approx(r['node_cpu_pct_of_one_core'], abs=6.0)
