"""The main job: the node on the default scene, one scripted insertion, the MCAP log read back.

Starts ``tissue_sim_node`` (recording on, private ROS domain, localhost discovery), runs
``tissue-sim drive`` at ``speed_mm_s`` to ``depth_mm`` below the surface and back, stops the node
with SIGINT, then reads the log with the project's reader and prints messages per topic, the
wrench rate, the peak axial force and where the capsule gave way. Writes into ``out``:
``demo.csv`` (per wrench: time, tip travel, axial force), ``demo.png`` (force against travel),
``demo_vs_bovine_liver.png``, ``demo.md`` and ``demo.json`` (the figures), ``logs/*.mcap`` and the
node's output ``node.log``.
"""
import csv
import json
import subprocess
import time
from pathlib import Path

import numpy as np

from tissue_sim_ros.units import NS_PER_S


def _wrench_and_travel(log):
    """(time s, travel m, axial force N) per wrench: the pose log gives the needle's travel along
    its axis from the first pose (interpolated at the wrench stamps); the wrench is in the needle
    frame (axial = -F_z) or the world frame (axial = -F . axis)."""
    from tissue_sim_ros.io.mcap import read_log
    from tissue_sim_ros.engine.needle.interaction import rotation_matrix
    poses, wrenches = [], []
    for m in read_log(log, topics=['/needle/pose', '/needle/wrench']):
        stamp = m.message.header.stamp.sec + m.message.header.stamp.nanosec / NS_PER_S
        if m.topic.endswith('pose'):
            p, o = m.message.pose.position, m.message.pose.orientation
            poses.append((stamp, p.x, p.y, p.z, o.x, o.y, o.z, o.w))
        else:
            f = m.message.wrench.force
            wrenches.append((stamp, f.x, f.y, f.z, m.message.header.frame_id))
    poses = np.array(poses)
    axis = rotation_matrix(poses[0, 4:8])[:, 2]
    travel_at_pose = (poses[:, 1:4] - poses[0, 1:4]) @ axis
    t = np.array([w[0] for w in wrenches])
    force = np.array([w[1:4] for w in wrenches])
    axial = np.where([w[4] == 'needle' for w in wrenches], -force[:, 2], -(force @ axis))
    return t, np.interp(t, poses[:, 0], travel_at_pose), axial


def _drive_node(out, logs, speed_mm_s, depth_mm):
    """Start the node recording into ``logs``, wait for it, run ``tissue-sim drive`` against it,
    stop it with SIGINT; the drive's exit status and the node's."""
    from tissue_sim_ros.ros.clients.node_process import NodeProcess, console_script
    print(f'starting tissue_sim_node (recording to {logs}) ...', flush=True)
    with NodeProcess([f'recording.directory:={logs}'], out / 'node.log') as node:
        node.wait_until_ready()              # its latched ~/ready: it ticks, its subscriptions are up
        drive = subprocess.run(console_script('tissue-sim', 'tissue_sim_ros.cli') +
                               ['drive', '--speed-mm-s', str(speed_mm_s), '--depth-mm', str(depth_mm),
                                '--hold-s', '0.5'], env=node.env, timeout=300)
        time.sleep(0.3)                         # the last wrenches
    return drive.returncode, node.returncode


def run(out='out', speed_mm_s=5.0, depth_mm=15.0):
    """Node, scripted insertion, log read back: print the figures, plot, return them."""
    from tissue_sim_ros.analysis.compare.compare import compare_with_reference
    from tissue_sim_ros.analysis.force_plot import plot_force_against_travel
    from tissue_sim_ros.io.mcap import summarize_log
    out = Path(out).resolve()
    logs = out / 'logs'
    logs.mkdir(parents=True, exist_ok=True)
    before = set(logs.glob('*.mcap'))
    drive_status, node_status = _drive_node(out, logs, speed_mm_s, depth_mm)
    if drive_status != 0:
        raise SystemExit(f'tissue-sim drive failed (exit {drive_status}); node output in {out / "node.log"}')
    new = sorted(set(logs.glob('*.mcap')) - before)
    if not new:
        raise SystemExit(f'the node wrote no log; its output is in {out / "node.log"}')
    log = new[-1]
    summary = summarize_log(log)
    print(f'\nlog {log} (node exit {node_status}):')
    for topic, entry in sorted(summary['topics'].items()):
        print(f'  {topic:<20} {entry["type"]:<36} {entry["count"]:>6} messages')
    t, travel, axial = _wrench_and_travel(log)
    rate = (len(t) - 1) / (t[-1] - t[0])
    inserting = np.arange(len(t)) <= int(np.argmax(travel))
    drops = np.diff(axial)
    k = int(np.argmin(np.where(inserting[1:], drops, np.inf)))
    print(f'wrench rate {rate:.2f} Hz over {t[-1] - t[0]:.1f} s; peak axial force {axial.max():.3f} N '
          f'at travel {travel[int(np.argmax(axial))] * 1e3:.2f} mm')
    print(f'largest force drop while inserting (the capsule giving way): {axial[k]:.3f} -> '
          f'{axial[k + 1]:.3f} N at travel {travel[k] * 1e3:.2f} mm')
    plot_force_against_travel(out / 'demo.png', travel, axial, ~inserting,
                              title=f'tissue_sim_node, insertion at {speed_mm_s:g} mm/s',
                              labels=('node, insertion (from the MCAP log)', 'node, retraction'))
    comparison = compare_with_reference(t, travel, axial, plot=out / 'demo_vs_bovine_liver.png',
                                        label='node (from the MCAP log)')
    nrmse = comparison.errors.get('nrmse')
    print(f'against the bovine-liver insertion (Okamura et al. 2004, 3 mm/s), by depth since contact: '
          f'NRMSE {float("nan") if nrmse is None else nrmse:.3f} over the insertion')
    figures = {'log': str(log), 'node_exit': node_status,
               'messages': {topic: entry['count'] for topic, entry in summary['topics'].items()},
               'rate_hz': rate, 'peak_axial_n': float(axial.max()), 'puncture_travel_m': float(travel[k]),
               'puncture_force_n': [float(axial[k]), float(axial[k + 1])], 'bovine_liver_nrmse': nrmse}
    _write_figures(out, t, travel, axial, figures, speed_mm_s)
    print(f'wrote {out / "demo.png"}, demo_vs_bovine_liver.png, demo.csv, demo.md and demo.json')
    return figures


def _write_figures(out: Path, t, travel, axial, figures: dict, speed_mm_s: float) -> None:
    """demo.csv (per wrench), demo.json (the figures) and demo.md (the same for a person)."""
    with open(out / 'demo.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['time_s', 'travel_m', 'axial_force_n'])
        writer.writerows([f'{a:.6f}', f'{b:.7f}', f'{c:.6g}'] for a, b, c in zip(t, travel, axial))
    (out / 'demo.json').write_text(json.dumps(figures, indent=1))
    lines = [f'# The main job: the node, an insertion at {speed_mm_s:g} mm/s, its log read back', '',
             f"Wrench rate {figures['rate_hz']:.2f} Hz; peak axial force "
             f"{figures['peak_axial_n']:.3f} N; the "
             f"capsule gave way at travel {figures['puncture_travel_m'] * 1e3:.2f} mm "
             f"({figures['puncture_force_n'][0]:.3f} -> {figures['puncture_force_n'][1]:.3f} N).", '',
             '| topic | messages |', '|---|---|']
    lines += [f'| {topic} | {count} |' for topic, count in sorted(figures['messages'].items())]
    lines += ['', '![force against travel](demo.png)', '']
    (out / 'demo.md').write_text('\n'.join(lines))

