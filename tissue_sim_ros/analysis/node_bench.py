"""``tissue-sim node-bench``: the node's timing, measured from outside, on a scene.

The node runs as its own process (the ``tissue_sim_node`` console script, recording on, private
ROS domain, localhost discovery). This process drives it with scripted insertions and
retractions (``tissue-sim drive``'s trajectory) at ``rate_hz``, poses stamped with their send
time, and listens to the wrench. Afterwards the node's MCAP log gives the receipt time of each
pose (its log time) and, for each wrench, its tick time (header stamp) and publish time (log
time), all on the node's clock (the system clock: the node runs without sim time here).

Figures:

- wrench rate: messages received here over the measured window / its length;
- tick period: differences of the wrench stamps (the node's tick times): p50, and p99 and max of
  the absolute deviation from 1/publish_rate_hz;
- latency from a pose's receipt to the first wrench computed with it: the first wrench whose tick
  time is at or after the receipt (the tick takes the poses received before it), its publish time
  minus the receipt, p50/p99; and end to end, pose sent here to that wrench received here;
- CPU: the node process's user + system time over the window (/proc), in % of one core;
- overruns: ticks whose work took longer than a period, and missed ticks, from the node's last
  diagnostics; its mean step time, substeps, compute load.

The numbers are figures of this machine at the time of the run (other load shows in them); the
issue's goals are printed beside them, not enforced.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

__all__ = ['run', 'measure']

GOALS = {'rate_rel': 0.005, 'period_dev_p99_ms': 4.0, 'latency_p99_ms': 25.0}


def _cpu_seconds(pid: int) -> float | None:
    try:
        fields = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf('SC_CLK_TCK')  # utime + stime


def _node_command(params: list[str]) -> list[str]:
    script = Path(sys.executable).parent / 'tissue_sim_node'
    cmd = [str(script)] if script.exists() else [sys.executable, '-m', 'tissue_sim_ros.ros.node']
    cmd.append('--ros-args')
    for p in params:
        cmd += ['-p', p]
    return cmd


def measure(duration_s: float = 20.0, rate_hz: float = 100.0, scene_file: str | None = None,
            log_dir: str | Path | None = None, speed_mm_s: float = 5.0, depth_mm: float = 15.0,
            domain_id: int | None = None, publish_rate_hz: float = 50.0,
            slices_per_tick: int | None = None) -> dict:
    """Run the node and the scripted driver for ``duration_s``; the figures as a dict."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from shape_msgs.msg import Mesh

    from tissue_sim_ros.io import mcap_log as ml
    from tissue_sim_ros.ros.conversions import ns_to_stamp, stamp_to_ns
    from tissue_sim_ros.ros.drive import insertion_trajectory, scene_start

    own_dir = log_dir is None
    log_dir = Path(tempfile.mkdtemp(prefix='node_bench_')) if own_dir else Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    domain_id = domain_id if domain_id is not None else 150 + os.getpid() % 80
    env = dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    params = [f'recording.directory:={log_dir}', f'publish_rate_hz:={float(publish_rate_hz)}']
    if scene_file:
        params.append(f'scene_file:={scene_file}')
    if slices_per_tick is not None:
        params.append(f'engine.slices_per_tick:={int(slices_per_tick)}')
    start = scene_start(scene_file)
    times, positions = insertion_trajectory(start, speed_mm_s * 1e-3, depth_mm * 1e-3, 0.5,
                                            rate_hz)
    earlier_logs = set(log_dir.glob('*.mcap'))
    node_log = open(log_dir / 'node.log', 'w')  # noqa: SIM115
    t_launch = time.monotonic()
    proc = subprocess.Popen(_node_command(params), env=env, stdout=node_log,
                            stderr=subprocess.STDOUT)

    previous_range = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain_id)
    client = rclpy.create_node('node_bench', context=ctx)
    wrench_rx: list[tuple[int, int]] = []  # (receive ns on the system clock, stamp ns)
    diagnostics: list = []
    surfaces: list = []
    reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    client.create_subscription(
        WrenchStamped, 'needle/wrench',
        lambda m: wrench_rx.append((time.time_ns(), stamp_to_ns(m.header.stamp))), reliable)
    client.create_subscription(DiagnosticArray, '/diagnostics', diagnostics.append, reliable)
    client.create_subscription(Mesh, 'tissue/surface', surfaces.append, QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    pub = client.create_publisher(PoseStamped, 'needle/pose', reliable)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(client)
    stop = threading.Event()

    def spin():
        while not stop.is_set():
            executor.spin_once(timeout_sec=0.05)
    spinner = threading.Thread(target=spin, daemon=True)
    spinner.start()
    sent: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while not (surfaces and pub.get_subscription_count()):
            if proc.poll() is not None:
                raise RuntimeError(f'the node exited ({proc.returncode}); see {log_dir / "node.log"}')
            if time.monotonic() > deadline:
                raise RuntimeError('the node did not come up within 120 s')
            time.sleep(0.02)
        startup_s = time.monotonic() - t_launch
        time.sleep(1.0)  # let the first ticks (caches, page faults) pass
        msg = PoseStamped()
        msg.header.frame_id = start.frame_id
        (msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z,
         msg.pose.orientation.w) = (float(c) for c in start.orientation)
        cpu0, wall0_ns = _cpu_seconds(proc.pid), time.time_ns()
        t0 = time.monotonic()
        k = 0
        while time.monotonic() - t0 < duration_s:
            cycle, i = divmod(k, len(times))
            delay = t0 + cycle * (times[-1] + 1.0 / rate_hz) + times[i] - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            stamp = time.time_ns()
            msg.header.stamp = ns_to_stamp(stamp)
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = \
                (float(c) for c in positions[i])
            pub.publish(msg)
            sent.append(stamp)
            k += 1
        cpu1, wall1_ns = _cpu_seconds(proc.pid), time.time_ns()
        time.sleep(0.3)
        n_diag = len(diagnostics)
        wait_until = time.monotonic() + 3
        while len(diagnostics) == n_diag and time.monotonic() < wait_until:
            time.sleep(0.02)
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(timeout=30)
        time.sleep(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
        stop.set()
        spinner.join(timeout=5)
        client.destroy_node()
        rclpy.shutdown(context=ctx)
        node_log.close()
        if previous_range is None:
            os.environ.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
        else:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = previous_range

    new_logs = sorted(set(log_dir.glob('*.mcap')) - earlier_logs)
    if len(new_logs) != 1:
        raise RuntimeError(f'expected one new MCAP log in {log_dir}, found {new_logs}')
    path = new_logs[0]
    period_ns = 1e9 / publish_rate_hz
    pose_receipt, pose_stamp, wrench_tick, wrench_publish = [], [], [], []
    for m in ml.read_log(path, topics=['/needle/pose', '/needle/wrench']):
        if m.topic == '/needle/pose':
            pose_receipt.append(m.log_time_ns)
            pose_stamp.append(stamp_to_ns(m.message.header.stamp))
        else:
            wrench_tick.append(stamp_to_ns(m.message.header.stamp))
            wrench_publish.append(m.log_time_ns)
    pose_receipt = np.array(pose_receipt, dtype=np.int64)
    pose_stamp = np.array(pose_stamp, dtype=np.int64)
    wrench_tick = np.array(wrench_tick, dtype=np.int64)
    wrench_publish = np.array(wrench_publish, dtype=np.int64)

    rx = np.array(wrench_rx, dtype=np.int64)
    in_window = (rx[:, 0] >= wall0_ns) & (rx[:, 0] <= wall1_ns)
    rx_w = rx[in_window]
    rate = (len(rx_w) - 1) / ((rx_w[-1, 0] - rx_w[0, 0]) / 1e9)
    ticks_w = wrench_tick[(wrench_tick >= wall0_ns) & (wrench_tick <= wall1_ns)]
    periods = np.diff(ticks_w) / 1e6
    deviation = np.abs(periods - period_ns / 1e6)
    rx_periods = np.diff(rx_w[:, 0]) / 1e6

    in_w = (pose_receipt >= wall0_ns) & (pose_receipt <= wall1_ns)
    receipts = pose_receipt[in_w]
    idx = np.searchsorted(wrench_tick, receipts, side='left')  # first tick at or after receipt
    ok = idx < len(wrench_tick)
    latency = (wrench_publish[idx[ok]] - receipts[ok]) / 1e6
    # end to end: sent here -> that wrench received here (matched by its tick stamp)
    rx_by_stamp = dict(zip(rx[:, 1].tolist(), rx[:, 0].tolist()))
    e2e = []
    for stamp, j in zip(pose_stamp[in_w][ok], idx[ok]):
        got = rx_by_stamp.get(int(wrench_tick[j]))
        if got is not None:
            e2e.append((got - stamp) / 1e6)
    e2e = np.array(e2e)

    def values(msg, name_part):
        for st in msg.status:
            if name_part in st.name:
                return {kv.key: kv.value for kv in st.values}
        return {}
    engine = values(diagnostics[-1], 'engine') if diagnostics else {}
    inputs = values(diagnostics[-1], 'input') if diagnostics else {}
    cpu = None
    if cpu0 is not None and cpu1 is not None:
        cpu = 100.0 * (cpu1 - cpu0) / ((wall1_ns - wall0_ns) / 1e9)
    result = {
        'scene': scene_file or 'default (config/liver_sample.yaml)',
        'slices_per_tick': slices_per_tick or 'default',
        'duration_s': (wall1_ns - wall0_ns) / 1e9,
        'pose_rate_hz': rate_hz,
        'poses_sent': len(sent),
        'poses_logged': int(len(pose_receipt)),
        'startup_s': startup_s,
        'node_exit_code': rc,
        'wrench_rate_hz': rate,
        'wrench_rate_error_pct': 100.0 * (rate - publish_rate_hz) / publish_rate_hz,
        'tick_period_ms_p50': float(np.percentile(periods, 50)),
        'tick_period_dev_ms_p99': float(np.percentile(deviation, 99)),
        'tick_period_dev_ms_max': float(deviation.max()),
        'receive_period_dev_ms_p99': float(np.percentile(np.abs(rx_periods - period_ns / 1e6), 99)),
        'latency_ms_p50': float(np.percentile(latency, 50)),
        'latency_ms_p99': float(np.percentile(latency, 99)),
        'latency_ms_max': float(latency.max()),
        'end_to_end_ms_p50': float(np.percentile(e2e, 50)) if e2e.size else float('nan'),
        'end_to_end_ms_p99': float(np.percentile(e2e, 99)) if e2e.size else float('nan'),
        'node_cpu_pct_of_one_core': cpu,
        'deadline_overruns': int(engine.get('deadline_overruns', -1)),
        'missed_ticks': int(engine.get('missed_ticks', -1)),
        'ticks': int(engine.get('ticks', -1)),
        'step_time_ms_mean_last_window': float(engine.get('step_time_ms_mean', 'nan')),
        'substeps_per_tick': int(engine.get('substeps_last', -1)),
        'node_latency_ms_p99_own': float(inputs.get('latency_ms_p99', 'nan')),
        'mcap': str(path),
    }
    if own_dir:
        shutil.rmtree(log_dir, ignore_errors=True)
        result['mcap'] = '(deleted)'
    return result


def report(r: dict) -> str:
    g = GOALS
    lines = [
        f'node bench: {r["scene"]}, engine slices per tick {r["slices_per_tick"]}, '
        f'{r["duration_s"]:.1f} s measured, poses at {r["pose_rate_hz"]:g} Hz '
        f'({r["poses_sent"]} sent, {r["poses_logged"]} logged by the node), node up in {r["startup_s"]:.1f} s',
        f'  wrench rate          {r["wrench_rate_hz"]:8.3f} Hz   ({r["wrench_rate_error_pct"]:+.2f} %; goal within '
        f'{100 * g["rate_rel"]:.1f} %)',
        f'  tick period          p50 {r["tick_period_ms_p50"]:.3f} ms, |deviation| p99 '
        f'{r["tick_period_dev_ms_p99"]:.2f} ms, max {r["tick_period_dev_ms_max"]:.2f} ms   (goal p99 <= '
        f'{g["period_dev_p99_ms"]:g} ms; at the receiver p99 {r["receive_period_dev_ms_p99"]:.2f} ms)',
        f'  latency receipt->wrench  p50 {r["latency_ms_p50"]:.2f} ms, p99 {r["latency_ms_p99"]:.2f} ms, max '
        f'{r["latency_ms_max"]:.2f} ms   (goal p99 <= {g["latency_p99_ms"]:g} ms)',
        f'  end to end sent->received p50 {r["end_to_end_ms_p50"]:.2f} ms, p99 {r["end_to_end_ms_p99"]:.2f} ms',
        f'  node CPU             {r["node_cpu_pct_of_one_core"]:.0f} % of one core',
        f'  overruns             {r["deadline_overruns"]} deadline overruns, {r["missed_ticks"]} missed ticks of '
        f'{r["ticks"]} ticks; step {r["step_time_ms_mean_last_window"]:.2f} ms mean, '
        f'{r["substeps_per_tick"]} substeps per tick',
    ]
    return '\n'.join(lines)


def run(duration_s: float = 20.0, rate_hz: float = 100.0, scene_file: str | None = None,
        out: str | None = None, slices_per_tick: int | None = None) -> dict:
    """Measure and print; with ``out``, keep the MCAP log there and write node_bench.json."""
    result = measure(duration_s=duration_s, rate_hz=rate_hz, scene_file=scene_file, log_dir=out,
                     slices_per_tick=slices_per_tick)
    print(report(result))
    if out:
        (Path(out) / 'node_bench.json').write_text(json.dumps(result, indent=2))
        print(f'wrote {Path(out) / "node_bench.json"} and {result["mcap"]}')
    return result
