"""``tissue-sim node-bench``: the node's timing, measured from outside, on a scene.

The node runs as its own process (the ``tissue_sim_node`` console script, recording on, private
ROS domain, localhost discovery). This process drives it with scripted insertions and
retractions (``tissue-sim drive``'s trajectory) at ``rate_hz``, poses stamped with their send
time, and listens to the wrench. Afterwards the node's MCAP log gives the receipt time of each
pose (its log time) and, for each wrench, its tick time (header stamp) and publish time (log
time), all on the node's clock (the system clock: the node runs without sim time here).

Figures (computed from the record by :mod:`~tissue_sim_ros.bench.node_bench_figures`):

- wrench rate: messages received here over the measured window / its length;
- tick period: differences of the wrench stamps (the node's tick times): p50, and p99 and max of
  the absolute deviation from 1/publish_rate_hz;
- latency from a pose's receipt to the first wrench computed with it, p50/p99: from the engine's
  trace in the log, the first advance that brought the needle to the pose's stamp (to within one
  substep: the engine steps whole substeps and carries the rest), then the first tick that
  published that advance's state or a later one, its publish time minus the receipt; and end to
  end, pose sent here to that wrench received here. Read from the trace, not as the first tick
  after the receipt: not every pose makes it into that tick's state, and that reading would be
  low. The node's own figure, diagnostics ``latency_ms_p99``, is reported beside it.
- CPU: the node process's user + system time over the window (/proc), in % of one core, and
  per thread (``thread_cpu_pct``): the engine thread, the tick's thread, the executor (the main
  thread: the pose callbacks, diagnostics, services), the recorder's writer, the DDS threads and
  the rest, by the names the node gives its threads at the OS level
  (:mod:`tissue_sim_ros.system.thread_names`);
- overruns: ticks whose work took longer than a period, and missed ticks, from the node's last
  diagnostics; its mean step time, substeps, compute load.

The numbers are figures of this machine at the time of the run (other load shows in them: the
report gives the load average before the run); the goals (``GOALS``) are printed beside them,
not enforced. ``load`` > 0 runs that many busy processes and one listening ROS client (wrench and
point cloud) beside the node during the window (:mod:`tissue_sim_ros.bench.background_load`),
so that a figure under load can be reproduced; ``listen`` runs that client alone (the node builds
and sends its cloud only for a subscriber, so without one its CPU is the wrench-only case).
``predictions`` > 0 sends that many candidate paths on ``plan/candidate`` at once, 1 s into the
window (:mod:`tissue_sim_ros.bench.prediction_burst`): the live figures then show what a burst
of planner requests costs the loop, and the report adds how fast they were answered.
"""
from __future__ import annotations

import json
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from tissue_sim_ros.bench.node_bench_figures import (Window, cpu_seconds, diagnostic_figures, engine_dt_s,
                                                        kernel_share, latencies, log_timings, rate_and_periods, status_values,
                                                        thread_cpu_seconds, thread_groups_pct)

__all__ = ['run', 'measure']

GOALS = {'rate_rel': 0.005, 'period_dev_p99_ms': 4.0, 'latency_p99_ms': 25.0}


def _node_params(log_dir: Path, publish_rate_hz: float, scene_file: str | None,
                 threads: int | None, executor: str | None) -> list[str]:
    params = [f'recording.directory:={log_dir}', f'publish_rate_hz:={float(publish_rate_hz)}']
    if scene_file:
        params.append(f'scene_file:={scene_file}')
    if threads is not None:
        params.append(f'engine.threads:={int(threads)}')
    if executor is not None:
        params.append(f'executor:={executor}')
    return params


class _BenchClient:
    """This process's side of the graph: publishes the poses, records each wrench's arrival
    (system clock ns, stamp ns), keeps the diagnostics and the surface (the sign the node is
    up), spun on a thread until close()."""

    def __init__(self, context):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped, WrenchStamped
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from shape_msgs.msg import Mesh

        from tissue_sim_ros.ros.messages.conversions import stamp_to_ns
        self.node = rclpy.create_node('node_bench', context=context)
        self.wrench_rx: list[tuple[int, int]] = []
        self.diagnostics: list = []
        self.surfaces: list = []
        reliable = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        self.node.create_subscription(
            WrenchStamped, 'needle/wrench',
            lambda m: self.wrench_rx.append((time.time_ns(), stamp_to_ns(m.header.stamp))), reliable)
        self.node.create_subscription(DiagnosticArray, '/diagnostics', self.diagnostics.append,
                                      reliable)
        self.node.create_subscription(Mesh, 'tissue/surface', self.surfaces.append, QoSProfile(
            depth=1, reliability=ReliabilityPolicy.RELIABLE,
            durability=DurabilityPolicy.TRANSIENT_LOCAL))
        self.pose_pub = self.node.create_publisher(PoseStamped, 'needle/pose', reliable)
        self.executor = SingleThreadedExecutor(context=context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._spinner = threading.Thread(target=self._spin, daemon=True)
        self._spinner.start()

    def _spin(self) -> None:
        while not self._stop.is_set():
            self.executor.spin_once(timeout_sec=0.05)

    def node_is_up(self) -> bool:
        return bool(self.surfaces) and self.pose_pub.get_subscription_count() > 0

    def predictions_starting(self) -> bool:
        """Whether the node's prediction workers are still starting (loading the machine), or no
        diagnostics came yet to tell."""
        if not self.diagnostics:
            return True
        return status_values(self.diagnostics[-1], 'predictions').get('workers_state') == 'starting'

    def ladder_measuring(self) -> bool:
        """Whether the node's degradation ladder is still measuring its rungs' errors (its probe: a
        run of the scene at every level, in a thread beside the engine, the first start of a scene;
        the ladder does not step before), or no diagnostics came yet to tell."""
        if not self.diagnostics:
            return True
        engine = status_values(self.diagnostics[-1], 'engine')
        return engine.get('ladder_predicted_error') == 'not measured yet'

    def await_next_diagnostics(self, timeout_s: float = 3.0) -> None:
        """Wait for one more diagnostics message (the counters at the end of the window)."""
        seen, deadline = len(self.diagnostics), time.monotonic() + timeout_s
        while len(self.diagnostics) == seen and time.monotonic() < deadline:
            time.sleep(0.02)

    def close(self) -> None:
        self._stop.set()
        self._spinner.join(timeout=5)
        self.executor.shutdown()
        self.node.destroy_node()


def _drive_window(node, client: _BenchClient, message, times, positions, rate_hz: float,
                  duration_s: float) -> Window:
    """Stream the scripted poses (``message`` moved along them) for ``duration_s``, the node's
    CPU time read at both ends."""
    from tissue_sim_ros.ros.clients.drive import publish_trajectory
    threads0, cpu0, wall0_ns = thread_cpu_seconds(node.pid), cpu_seconds(node.pid), time.time_ns()
    sent = publish_trajectory(client.pose_pub, message, times, positions, time.time_ns,
                              repeat_for_s=duration_s, cycle_s=times[-1] + 1.0 / rate_hz)
    window = Window(wall0_ns, time.time_ns(), cpu0, cpu_seconds(node.pid), sent)
    window.thread_pct = thread_groups_pct(node.pid, threads0, thread_cpu_seconds(node.pid), window.seconds)
    return window


def _new_log(log_dir: Path, earlier: set) -> Path:
    new_logs = sorted(set(log_dir.glob('*.mcap')) - earlier)
    if len(new_logs) != 1:
        raise RuntimeError(f'expected one new MCAP log in {log_dir}, found {new_logs}')
    return new_logs[0]


def _run_node(log_dir: Path, params: list[str], domain_id: int | None, start, times, positions,
              rate_hz: float, duration_s: float, load: int, predictions: int = 0,
              prediction_s: float = 10.0, listen: bool = False) -> dict:
    """Start the node (and the load), wait until it is up, stream poses for the window (a burst
    of ``predictions`` 1 s into it), stop it; what was seen here, as a dict."""
    from tissue_sim_ros.bench.background_load import BackgroundLoad, machine_load
    from tissue_sim_ros.bench.prediction_burst import PredictionBurst
    from tissue_sim_ros.ros.clients.drive import pose_message
    from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context
    machine = machine_load()
    message = pose_message(start.frame_id, start.orientation)
    burst = None
    with NodeProcess(params, log_dir / 'node.log', domain_id) as node, \
            client_context(node.domain_id) as context:
        client = _BenchClient(context)
        try:
            if predictions:
                burst = PredictionBurst(client.node, predictions, path_s=prediction_s)
            startup_s = node.wait_until(client.node_is_up, 300.0)
            # the prediction workers start with the node and load their kernels (a core for
            # several seconds): the window starts after, so the node is measured, not its start
            warm_up_s = node.wait_until(lambda: not client.predictions_starting(), 300.0,
                                        'start its prediction workers') - startup_s
            # and its ladder's probe (a core for about a minute on an organ-scale scene's first
            # start, and no ladder step before it ends): likewise not the node's steady state
            probe_s = node.wait_until(lambda: not client.ladder_measuring(), 900.0,
                                      'measure its degradation ladder') - startup_s - warm_up_s
            with BackgroundLoad(load, node.env, listen=listen) as background:
                time.sleep(1.0)  # let the first ticks (caches, page faults) pass
                if burst is not None:
                    p = message.pose.position
                    burst.start(1.0, lambda: ([p.x, p.y, p.z], start.orientation, start.frame_id))
                window = _drive_window(node, client, message, times, positions, rate_hz, duration_s)
                time.sleep(0.3)
                client.await_next_diagnostics()
            exit_code = node.stop()
            time.sleep(0.2)
        finally:
            client.close()
    return {'window': window, 'startup_s': startup_s, 'warm_up_s': warm_up_s, 'probe_s': probe_s,
            'exit_code': exit_code,
            'predictions': burst.figures() if burst is not None else {},
            'wrench_rx': np.array(client.wrench_rx, dtype=np.int64),
            'diagnostics': client.diagnostics, 'load': background.describe(),
            'listener': background.listener, 'machine': machine}


def measure(duration_s: float = 20.0, rate_hz: float = 100.0, scene_file: str | None = None,
            log_dir: str | Path | None = None, speed_mm_s: float = 5.0, depth_mm: float = 15.0,
            domain_id: int | None = None, publish_rate_hz: float = 50.0,
            threads: int | None = None, executor: str | None = None, load: int = 0,
            predictions: int = 0, prediction_s: float = 10.0, params=(), listen: bool = False) -> dict:
    """Run the node and the scripted driver for ``duration_s`` (with ``load`` busy processes and
    a listening client beside them when ``load`` > 0, the client alone with ``listen``, a burst of
    ``predictions`` candidate paths of ``prediction_s`` seconds; ``params``: more node parameters,
    ``name:=value``); the figures as a dict."""
    from tissue_sim_ros.ros.clients.drive import insertion_trajectory, scene_start
    start = scene_start(scene_file)
    times, positions = insertion_trajectory(start, speed_mm_s * 1e-3, depth_mm * 1e-3, 0.5,
                                            rate_hz)
    own_dir = log_dir is None
    log_dir = Path(tempfile.mkdtemp(prefix='node_bench_')) if own_dir else Path(log_dir)
    log_dir.mkdir(parents=True, exist_ok=True)
    earlier_logs = set(log_dir.glob('*.mcap'))
    run = _run_node(log_dir, _node_params(log_dir, publish_rate_hz, scene_file, threads, executor) + list(params),
                    domain_id, start, times, positions, rate_hz, duration_s, load, predictions, prediction_s,
                    listen)
    path = _new_log(log_dir, earlier_logs)
    log, window = log_timings(path), run['window']
    result = {
        'scene': scene_file or 'default (config/liver_sample.yaml)',
        'engine_threads_asked': threads if threads is not None else 'default',
        'executor': executor or 'default',
        'parameters': list(params),
        'load': run['load'],
        'listener': run['listener'],
        'machine_before': run['machine'],
        'duration_s': window.seconds,
        'pose_rate_hz': rate_hz,
        'poses_sent': len(window.sent),
        'poses_logged': int(len(log['pose_receipt'])),
        'startup_s': run['startup_s'],
        'prediction_warm_up_s': run['warm_up_s'],
        'ladder_probe_wait_s': run['probe_s'],
        'node_exit_code': run['exit_code'],
        **rate_and_periods(run['wrench_rx'], log['wrench_tick'], window, publish_rate_hz),
        **latencies(log, run['wrench_rx'], window, engine_dt_s(run['diagnostics'])),
        'node_cpu_pct_of_one_core': window.cpu_pct(),
        'thread_cpu_pct': window.thread_pct,
        **diagnostic_figures(run['diagnostics'], window.wall0_ns),
        'mcap': str(path),
        **run['predictions'],
    }
    result['kernel_share_of_node_cpu'] = kernel_share(result, window)
    if own_dir:
        shutil.rmtree(log_dir, ignore_errors=True)
        result['mcap'] = '(deleted)'
    return result


def report(r: dict) -> str:
    g = GOALS
    lines = [
        f'node bench: {r["scene"]}, engine threads {r["engine_threads"]}, executor {r["executor"]}, '
        f'{r["duration_s"]:.1f} s measured, poses at {r["pose_rate_hz"]:g} Hz '
        f'({r["poses_sent"]} sent, {r["poses_logged"]} logged by the node), node up in {r["startup_s"]:.1f} s'
        + (f', its prediction workers warm {r["prediction_warm_up_s"]:.1f} s later (the window starts after)'
           if r.get('prediction_workers', -1) > 0 else '')
        + (f', its ladder measured {r["ladder_probe_wait_s"]:.1f} s later'
           if r.get('ladder_probe_wait_s', 0) > 0.5 else ''),
        f'  load beside the node {r["load"]}; before the run: {r["machine_before"]}'
        + (f'; parameters {" ".join(r["parameters"])}' if r.get('parameters') else ''),
        f'  wrench rate          {r["wrench_rate_hz"]:8.3f} Hz   ({r["wrench_rate_error_pct"]:+.2f} %; goal within '
        f'{100 * g["rate_rel"]:.1f} %)',
        f'  tick period          p50 {r["tick_period_ms_p50"]:.3f} ms, |deviation| p99 '
        f'{r["tick_period_dev_ms_p99"]:.2f} ms, max {r["tick_period_dev_ms_max"]:.2f} ms   (goal p99 <= '
        f'{g["period_dev_p99_ms"]:g} ms; at the receiver p99 {r["receive_period_dev_ms_p99"]:.2f} ms)',
        f'  latency receipt->wrench  p50 {r["latency_ms_p50"]:.2f} ms, p99 {r["latency_ms_p99"]:.2f} ms, max '
        f'{r["latency_ms_max"]:.2f} ms   (goal p99 <= {g["latency_p99_ms"]:g} ms; the node\'s own p99 '
        f'{r.get("node_latency_ms_p99_own", float("nan")):.2f} ms)'
        + (f'; {r["poses_not_in_a_wrench"]} poses in no wrench yet' if r.get('poses_not_in_a_wrench') else ''),
        f'  end to end sent->received p50 {r["end_to_end_ms_p50"]:.2f} ms, p99 {r["end_to_end_ms_p99"]:.2f} ms',
        f'  node CPU             {r["node_cpu_pct_of_one_core"]:.0f} % of one core; the force kernel '
        f'{100 * r["kernel_share_of_node_cpu"]:.0f} % of it ({100 * r["kernel_share_of_engine"]:.0f} % of the '
        f'engine thread\'s work)',
        '  threads              ' + ', '.join(f'{name} {pct:.1f} %' for name, pct in r.get('thread_cpu_pct', {}).items())
        + ' of one core',
        f'  engine               {r.get("advances_per_s", float("nan")):.0f} advances a second, budget use '
        f'{r["budget_use"]:.2f}, lag {1e3 * r["lag_s"]:.1f} ms, '
        f'{r["dropped_time_s"]:.3g} s dropped, ladder level {r["ladder_level"]} ({r["ladder_changes"]} changes); '
        f'{r["missed_ticks"]} missed ticks of {r["ticks"]}',
    ]
    if r.get('predictions_sent'):
        lines.append(
            f'  predictions          {r["predictions_sent"]} candidates of {r["prediction_path_s"]:g} s sent at '
            f'once: {r["predictions_answered"]} answered within the window ({r["predictions_with_points"]} with '
            f'points), first after {r["prediction_first_answer_s"]:.2f} s, last after '
            f'{r["prediction_last_answer_s"]:.2f} s; {r["prediction_workers"]} worker(s), each '
            f'{r["prediction_real_time_factor"]:.2f}x real time (median)')
    listener = r.get('listener') or {}
    if listener:
        lines.append('  listening client     ' + ', '.join(
            f'{name} {v["count"]} messages at {v["rate_hz"]:.2f} Hz (sent at {v.get("sent_rate_hz", 0.0):.2f})'
            for name, v in listener.items()))
    return '\n'.join(lines)


def run(duration_s: float = 20.0, rate_hz: float = 100.0, scene_file: str | None = None,
        out: str | None = None, threads: int | None = None, executor: str | None = None,
        load: int = 0, predictions: int = 0, prediction_s: float = 10.0, params=(),
        listen: bool = False) -> dict:
    """Measure and print; with ``out``, keep the MCAP log there and write node_bench.json."""
    result = measure(duration_s=duration_s, rate_hz=rate_hz, scene_file=scene_file, log_dir=out,
                     threads=threads, executor=executor, load=load, predictions=predictions,
                     prediction_s=prediction_s, params=params, listen=listen)
    print(report(result))
    if out:
        (Path(out) / 'node_bench.json').write_text(json.dumps(result, indent=2))
        print(f'wrote {Path(out) / "node_bench.json"} and {result["mcap"]}')
    return result
