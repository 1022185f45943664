"""``tissue-sim replay LOG.mcap --out DIR``: a recorded run through the engine again, offline.

A log the node recorded holds what its engine did (the engine trace: every advance with its pose
and the substeps it ran, resets, ladder levels, drops, and which state each tick published) and
the scene and parameters it ran with (metadata). Replayed with that scene, the trace reproduces
the recorded wrenches message for message, with the same header stamps, to rounding (the same
kernels on the same arrays: in practice bit for bit). With ``--scene`` or ``--set`` the same
motion (the needle poses the engine went to, at the node-clock times it went to them) drives
another scene or model instead, sampled at the recorded ticks. A log with no engine trace (another
robot's log) is driven by its pose messages the same way.

Everything runs as fast as the engine can (no real-time pacing). Outputs in ``--out DIR``:

- ``replay.mcap``: ``/needle/wrench`` and ``/needle/shape`` (every tick, the recorded stamps),
  ``/tissue/nodes`` (at the node's ``recording.nodes_rate_hz``) and ``/diagnostics`` (a summary at
  1 Hz), the node's topic names and types, so the two logs overlay in a viewer;
- ``replay.csv``: per tick, the stamp, the recorded and the replayed wrench, and the replayed tip
  (``tip_x_m tip_y_m tip_z_m tip_deflection_m``: where the apex is and its distance from the base
  axis, a flexible needle's bend);
- ``replay.png``: recorded and replayed axial force against time;
- ``replay.json`` / ``replay.md``: the figures (schema: ``mode`` 'exact' or 'motion', ``ticks``,
  ``max_abs_difference_n``, ``rms_difference_n``, ``final_tip_deflection_m``, ``simulated_s``, ``wall_s``,
  ``real_time_factor``, ``scene``, ``log``, ``outputs``).
"""
from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from tissue_sim_ros.units import NS_PER_S
from tissue_sim_ros.errors import ReplayError

__all__ = ['NodeRun', 'ReplayResult', 'read_node_run', 'replay', 'main']

_WRENCH = 'geometry_msgs/msg/WrenchStamped'
_TRACE = 'std_msgs/msg/Float64MultiArray'
_POSE = 'geometry_msgs/msg/PoseStamped'


def _flatten(d: dict, prefix: str = '') -> dict:
    out = {}
    for key, value in d.items():
        name = f'{prefix}{key}'
        out.update(_flatten(value, name + '.') if isinstance(value, dict) else {name: value})
    return out


@dataclass
class NodeRun:
    """What a node's log says about its run."""

    path: Path
    scene_spec: dict | None
    scene_base_dir: Path
    parameters: dict            # flat, by parameter name
    threads: int | None
    topics: dict                # topic -> type
    wrench_topic: str
    trace_topic: str | None
    pose_topic: str | None

    @property
    def wrench_frame(self) -> str:
        p = self.parameters
        return 'needle' if p.get('wrench.frame_id', 'needle') == p.get('needle_frame_id', 'needle') else 'world'


def read_node_run(path) -> NodeRun:
    """The run of a node log (ReplayError for a log that has no wrench)."""
    from tissue_sim_ros.io.mcap.reader import read_metadata, summarize_log
    path = Path(path)
    topics = {name: entry['type'] for name, entry in summarize_log(path)['topics'].items()}
    meta = read_metadata(path)
    spec_text = meta.get('scene_spec') or meta.get('scene') or ''
    spec = yaml.safe_load(spec_text) if spec_text.strip() else None
    scene_file = meta.get('scene_file', '')
    base = Path(scene_file).parent if scene_file and Path(scene_file).exists() else Path('.')
    params_text = meta.get('parameters', '')
    params = {}
    if params_text.strip():
        (node_params,) = yaml.safe_load(params_text).values()
        params = _flatten(node_params.get('ros__parameters', {}))
    wrenches = [t for t, kind in topics.items() if kind == _WRENCH]
    if not wrenches:
        raise ReplayError(f'{path}: no {_WRENCH} topic to replay against (topics: '
                          f'{", ".join(f"{t} ({k})" for t, k in topics.items()) or "none"})')
    wrench = next((t for t in wrenches if t.endswith('needle/wrench')), wrenches[0])
    trace = next((t for t, kind in topics.items() if kind == _TRACE and t.endswith('engine_trace')), None)
    pose = next((t for t, kind in topics.items() if kind == _POSE and t.endswith('needle/pose')), None)
    threads = meta.get('engine_threads') or None
    return NodeRun(path, spec, base, params, int(threads) if threads else None, topics, wrench,
                   trace, pose)


@dataclass
class ReplayResult:
    mode: str                        # 'exact' (the trace through the node's scene) or 'motion'
    stamps_ns: np.ndarray            # (k,) the recorded ticks
    wrench: np.ndarray               # (k, 6) replayed
    recorded: np.ndarray             # (k, 6)
    clouds: dict = field(default_factory=dict)   # tick index -> displacement (n, 3)
    simulated_s: float = 0.0
    wall_s: float = 0.0
    refused: int = 0
    tips: np.ndarray = None          # (k, 4) replayed tip x, y, z [m] and its deflection [m]
    shapes: tuple = None             # (k, p, 3) and (k, p, 4): the needle's shape each tick


def _recorded(run: NodeRun):
    """(wrench stamps, wrenches (k, 6), traces, poses [(stamp, position, orientation)])."""
    from tissue_sim_ros.io.mcap.reader import read_log
    from tissue_sim_ros.ros.loop.trace import decode
    stamps, values, traces, poses = [], [], [], []
    wanted = [t for t in (run.wrench_topic, run.trace_topic, run.pose_topic) if t]
    for m in read_log(run.path, topics=wanted):
        msg = m.message
        if m.topic == run.wrench_topic:
            f, t = msg.wrench.force, msg.wrench.torque
            stamps.append(msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec)
            values.append((f.x, f.y, f.z, t.x, t.y, t.z))
        elif m.topic == run.trace_topic:
            traces.append(decode(msg.data))
        else:
            p, o = msg.pose.position, msg.pose.orientation
            poses.append((msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec,
                          (p.x, p.y, p.z), (o.x, o.y, o.z, o.w)))
    return np.array(stamps, dtype=np.int64), np.array(values, dtype=float).reshape(-1, 6), traces, poses


def _node_scene(run: NodeRun, scene_file=None, sets=()):
    """The scene to replay with: the log's own (its keys as the engine used them), or the one
    given, with the ``--set`` overrides; laid out for the node's engine threads."""
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.engine.scene.keys import apply_overrides
    from tissue_sim_ros.ros.parameters import AUTO_THREADS_ELEMENTS
    if scene_file is not None:
        scene = load_scene(scene_file, sets=sets)
    else:
        if run.scene_spec is None:
            raise ReplayError(f'{run.path}: the log holds no scene (metadata "scene"); give --scene')
        scene = Scene(apply_overrides(run.scene_spec, sets), base_dir=run.scene_base_dir)
    if len(scene.needles) > 1:
        raise ReplayError(f'{run.path}: the scene has {len(scene.needles)} needles ({", ".join(scene.needle_names)}); '
                          "the engine trace holds the first needle's poses only, so a run with several "
                          'needles cannot be replayed (the log itself reads as any other)')
    threads = run.threads or int(run.parameters.get('engine.threads') or 0) or \
        (1 if scene.mesh.n_elements < AUTO_THREADS_ELEMENTS else None)
    if threads:
        scene.model.set_threads(threads)
    return scene


def _replay_trace(run, scene, stamps, traces, every_cloud):
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.ros.loop.trace import TraceReplayer
    driver = SimulationDriver(scene, wrench_frame=run.wrench_frame,
                              on_divergence=run.parameters.get('on_divergence', 'reset'))
    replayer = TraceReplayer(driver, DegradationLadder(scene), keep_displacement=every_cloud > 0)
    by_stamp = {t.stamp_ns: t for t in traces}
    wrench, clouds = np.zeros((len(stamps), 6)), {}
    tips, shapes = _tip_arrays(scene, len(stamps))
    missing = [int(s) for s in stamps if int(s) not in by_stamp]
    if missing:
        raise ReplayError(f'{run.path}: {len(missing)} wrench(es) without an engine trace (first '
                          f'stamp {missing[0]}); replay with --scene to drive by the motion instead')
    for k, stamp in enumerate(stamps):
        force, torque, displacement = replayer.apply(by_stamp[int(stamp)])
        wrench[k, :3], wrench[k, 3:] = force, torque
        _take_tip(scene, k, tips, shapes)
        if every_cloud and k % every_cloud == 0:
            clouds[k] = displacement
    return wrench, clouds, driver, tips, shapes


def _tip_arrays(scene, k):
    """Room for k ticks' tips (k, 4) and shapes ((k, p, 3), (k, p, 4))."""
    size = scene.needle.shape_size
    return np.zeros((k, 4)), (np.zeros((k, size, 3)), np.zeros((k, size, 4)))


def _take_tip(scene, k, tips, shapes):
    tips[k, :3], tips[k, 3] = scene.needle.tip, scene.tip_deflection
    scene.needle.write_shape(shapes[0][k], shapes[1][k])


def _motion(traces, poses):
    """(clock ns, positions, orientations) the needle went to: the trace's advances, or the
    recorded poses when there is no trace; the tick stamps at which the node was reset; and the
    needle's placements (registrations) by tick stamp: {stamp: (position, orientation)}."""
    from tissue_sim_ros.ros.loop.trace import ADVANCE, PLACE, RESET
    if traces:
        rows = [(c, r) for t in traces for c, r in zip(t.clock_ns(), t.rows)
                if r[0] == ADVANCE and not math.isnan(r[3])]
        resets = [t.stamp_ns for t in traces if np.any(t.rows[:, 0] == RESET)]
        places = {t.stamp_ns: (r[3:6].copy(),
                               r[6:10].copy()) for t in traces for r in t.rows if r[0] == PLACE}
        return (np.array([c for c, _ in rows], dtype=np.int64), np.array([r[3:6] for _, r in rows]),
                np.array([r[6:10] for _, r in rows]), resets, places)
    good = [p for p in poses if np.all(np.isfinite(p[1])) and np.all(np.isfinite(p[2]))]
    return (np.array([p[0] for p in good], dtype=np.int64), np.array([p[1] for p in good]),
            np.array([p[2] for p in good]), [], {})


def _replay_motion(run, scene, stamps, traces, poses, every_cloud):
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.engine.needle.pose import slerp
    clock, positions, orientations, resets, places = _motion(traces, poses)
    if len(clock) == 0:
        raise ReplayError(f'{run.path}: no needle motion in the log (no engine trace, no pose on '
                          f'{run.pose_topic or "needle/pose"})')
    driver = SimulationDriver(scene, wrench_frame=run.wrench_frame, on_divergence='reset')
    order = np.argsort(clock, kind='stable')
    clock, positions, orientations = clock[order], positions[order], orientations[order]
    base = int(clock[0])
    wrench, clouds, refused, previous = np.zeros((len(stamps), 6)), {}, 0, None
    tips, shapes = _tip_arrays(scene, len(stamps))
    resets = set(resets)
    for k, stamp in enumerate(stamps):
        if int(stamp) in resets:
            driver.reset()
        if int(stamp) in places:
            driver.place_needle(*places[int(stamp)])
        t = float(stamp - base)
        i = int(np.clip(np.searchsorted(clock - base, t, side='right') - 1, 0, len(clock) - 1))
        j = min(i + 1, len(clock) - 1)
        span = float(clock[j] - clock[i])
        s = 0.0 if span <= 0 else min(max((t - float(clock[i] - base)) / span, 0.0), 1.0)
        position = positions[i] + s * (positions[j] - positions[i])
        orientation = slerp(orientations[i], orientations[j], s)
        duration = 0.02 if previous is None else (int(stamp) - previous) / NS_PER_S
        previous = int(stamp)
        outcome = driver.advance(max(duration, 0.0), position, orientation)
        refused += outcome.refused is not None
        wrench[k, :3], wrench[k, 3:] = driver.force, driver.torque
        _take_tip(scene, k, tips, shapes)
        if every_cloud and k % every_cloud == 0:
            clouds[k] = scene.displacement.copy()
    return wrench, clouds, driver, refused, tips, shapes


def replay(log, scene_file=None, sets=()) -> tuple[ReplayResult, NodeRun, object]:
    """Replay ``log``: exact with its own scene and trace, else by its motion. Returns the
    result, the run and the scene."""
    from tissue_sim_ros.ros.recording import every_kth_tick
    run = read_node_run(log)
    stamps, recorded, traces, poses = _recorded(run)
    scene = _node_scene(run, scene_file, sets)
    rate = float(run.parameters.get('publish_rate_hz', 50.0))
    every_cloud = every_kth_tick(rate, float(run.parameters.get('recording.nodes_rate_hz', 5.0)))
    wall0 = time.perf_counter()
    exact = traces and scene_file is None and not sets
    if exact:
        wrench, clouds, driver, tips, shapes = _replay_trace(run, scene, stamps, traces, every_cloud)
        refused = driver.refusals
    else:
        wrench, clouds, driver, refused, tips, shapes = _replay_motion(run, scene, stamps, traces, poses,
                                                                       every_cloud)
    result = ReplayResult('exact' if exact else 'motion', stamps, wrench, recorded, clouds,
                          driver.simulated_s, time.perf_counter() - wall0, refused, tips, shapes)
    return result, run, scene


def _write_mcap(path: Path, run: NodeRun, result: ReplayResult, scene) -> None:
    """The replayed wrench, clouds and a summary diagnostic, with the node's topics and types."""
    from rclpy.serialization import serialize_message

    from tissue_sim_ros.io.mcap.writer import McapRecorder
    from tissue_sim_ros.ros.messages import conversions as cv
    from tissue_sim_ros.ros.messages.cdr_bytes import CloudBytes, NeedleShapeBytes, WrenchBytes
    from tissue_sim_ros.ros.messages.topics import DIAGNOSTICS_QOS, NODES_QOS, WRENCH_QOS
    p = run.parameters
    frame_id = p.get('frame_id') or scene.mesh_frame_id
    wrench_frame_id = p.get('wrench.frame_id', 'needle')
    base = run.wrench_topic[:-len('needle/wrench')] if run.wrench_topic.endswith('needle/wrench') else '/'
    topics = {'wrench': run.wrench_topic, 'shape': f'{base}needle/shape', 'nodes': f'{base}tissue/nodes',
              'diagnostics': '/diagnostics'}
    with McapRecorder(path, overwrite=True, metadata={'replay_of': str(run.path), 'mode': result.mode,
                                                     'scene_spec': yaml.safe_dump(scene.spec, sort_keys=False)}) as rec:
        rec.add_topic(topics['wrench'], _WRENCH, cv.qos_to_dict(WRENCH_QOS))
        rec.add_topic(topics['shape'], 'nav_msgs/msg/Path', cv.qos_to_dict(WRENCH_QOS))
        rec.add_topic(topics['nodes'], 'sensor_msgs/msg/PointCloud2', cv.qos_to_dict(NODES_QOS))
        rec.add_topic(topics['diagnostics'], 'diagnostic_msgs/msg/DiagnosticArray', cv.qos_to_dict(DIAGNOSTICS_QOS))
        cloud = CloudBytes(len(scene.rest_positions), frame_id, serialize_message)
        wrench = WrenchBytes(wrench_frame_id, serialize_message)
        shape = NeedleShapeBytes(result.shapes[0].shape[1], frame_id, serialize_message)
        last_diag = None
        for k, stamp in enumerate(result.stamps_ns):
            stamp = int(stamp)
            rec.write(topics['wrench'], wrench.serialized(result.wrench[k, :3], result.wrench[k, 3:], stamp), stamp)
            rec.write(topics['shape'], shape.serialized(result.shapes[0][k], result.shapes[1][k], stamp), stamp)
            if k in result.clouds:
                displacement = result.clouds[k]
                rec.write(topics['nodes'], cloud.serialized(scene.rest_positions + displacement, displacement, stamp),
                          stamp)
            if last_diag is None or stamp - last_diag >= NS_PER_S:
                last_diag = stamp
                difference = float(np.abs(result.wrench[k] - result.recorded[k]).max())
                rec.write(topics['diagnostics'], serialize_message(cv.diagnostic_array_msg(stamp, [(
                    'tissue_sim_replay', 'OK', result.mode,
                    {'tick': k, 'max_abs_difference_n': difference})])), stamp)


def _summary(result: ReplayResult, run: NodeRun, scene_label: str, outputs: dict) -> dict:
    difference = result.wrench - result.recorded
    return {
        'mode': result.mode, 'log': str(run.path), 'scene': scene_label, 'ticks': len(result.stamps_ns),
        'max_abs_difference_n': float(np.abs(difference).max()) if difference.size else 0.0,
        'rms_difference_n': float(np.sqrt(np.mean(difference[:, :3] ** 2))) if difference.size else 0.0,
        'refused_poses': int(result.refused),
        'final_tip_deflection_m': float(result.tips[-1, 3]) if len(result.tips) else 0.0,
        'simulated_s': result.simulated_s, 'wall_s': result.wall_s,
        'real_time_factor': result.simulated_s / result.wall_s if result.wall_s > 0 else math.inf,
        'outputs': outputs,
    }


def _write_tables(out: Path, result: ReplayResult, summary: dict, axis_label: str) -> None:
    with open(out / 'replay.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        names = ('force_x_n', 'force_y_n', 'force_z_n', 'torque_x_nm', 'torque_y_nm', 'torque_z_nm')
        tip = ('tip_x_m', 'tip_y_m', 'tip_z_m', 'tip_deflection_m')
        writer.writerow(['stamp_ns', *(f'recorded_{n}' for n in names), *(f'replayed_{n}' for n in names),
                         *(f'replayed_{n}' for n in tip)])
        for k, stamp in enumerate(result.stamps_ns):
            writer.writerow([int(stamp), *(f'{v:.9g}' for v in result.recorded[k]),
                             *(f'{v:.9g}' for v in result.wrench[k]), *(f'{v:.9g}' for v in result.tips[k])])
    (out / 'replay.json').write_text(json.dumps(summary, indent=2))
    how = ("the engine trace through the log's own scene" if summary['mode'] == 'exact'
           else f"the recorded motion through {summary['scene']}")
    (out / 'replay.md').write_text(
        f"# Replay of {summary['log']}\n\n"
        f"- mode: {summary['mode']} ({how})\n"
        f"- ticks: {summary['ticks']}; largest difference from the recorded wrench: "
        f"{summary['max_abs_difference_n']:.3g} N (force RMS {summary['rms_difference_n']:.3g} N)\n"
        f"- the tip's deflection from the base axis at the end: {summary['final_tip_deflection_m'] * 1e3:.3f} mm\n"
        f"- simulated {summary['simulated_s']:.2f} s in {summary['wall_s']:.2f} s: real-time factor "
        f"{summary['real_time_factor']:.2f}\n")
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    t = (result.stamps_ns - result.stamps_ns[0]) / NS_PER_S if len(result.stamps_ns) else np.zeros(0)
    column = 2
    fig, ax = plt.subplots(figsize=(8, 4))
    ax.plot(t, result.recorded[:, column], color='0.3', lw=2.5, label='recorded')
    ax.plot(t, result.wrench[:, column], color='tab:red', lw=1.0, label=f'replayed ({summary["mode"]})')
    ax.set_xlabel('time since the first tick [s]')
    ax.set_ylabel(axis_label)
    ax.legend()
    ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / 'replay.png', dpi=120)
    plt.close(fig)


def main(log, out, scene_file=None, sets=(), stream=None) -> dict:
    """The ``tissue-sim replay`` command: replay, write the outputs, print the figures."""
    import sys
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    result, run, scene = replay(log, scene_file, sets)
    outputs = {name: str(out / name) for name in ('replay.mcap', 'replay.csv', 'replay.png',
                                                  'replay.json', 'replay.md')}
    _write_mcap(out / 'replay.mcap', run, result, scene)
    summary = _summary(result, run, scene_file or '(the log\'s scene)', outputs)
    frame = 'needle' if run.wrench_frame == 'needle' else 'world'
    _write_tables(out, result, summary, f'force z [N] ({frame} frame)')
    print(f'replayed {summary["ticks"]} ticks of {run.path} ({summary["mode"]}): largest difference '
          f'from the recorded wrench {summary["max_abs_difference_n"]:.3g} N; simulated '
          f'{summary["simulated_s"]:.2f} s in {summary["wall_s"]:.2f} s (real-time factor '
          f'{summary["real_time_factor"]:.1f}); wrote {", ".join(outputs.values())}', file=stream)
    return summary
