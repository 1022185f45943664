"""The main job: the node on the default scene, one scripted insertion, the MCAP log read back.

Starts ``tissue_sim_node`` (recording on, private ROS domain, localhost discovery), runs
``tissue-sim drive`` at ``speed_mm_s`` to ``depth_mm`` below the surface and back, stops the node
with SIGINT, then reads the log with the project's reader and prints messages per topic, the
wrench rate, the peak axial force and where the capsule gave way, and plots force against depth.
"""
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np


def _script(name):
    path = Path(sys.executable).parent / name
    return str(path) if path.exists() else name


def _wrench_and_travel(log):
    """(time s, travel m, axial force N) per wrench: the pose log gives the needle's travel along
    its axis from the first pose (interpolated at the wrench stamps); the wrench is in the needle
    frame (axial = -F_z) or the world frame (axial = -F . axis)."""
    from tissue_sim_ros.io.mcap_log import read_log
    from tissue_sim_ros.engine.needle import rotation_matrix
    poses, wrenches = [], []
    for m in read_log(log, topics=['/needle/pose', '/needle/wrench']):
        stamp = m.message.header.stamp.sec + 1e-9 * m.message.header.stamp.nanosec
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


def run(out='out', speed_mm_s=5.0, depth_mm=15.0):
    from tissue_sim_ros.io.mcap_log import summarize_log
    out = Path(out).resolve()
    logs = out / 'logs'
    logs.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, ROS_DOMAIN_ID=str(100 + os.getpid() % 100),
               ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST', PYTHONUNBUFFERED='1')
    before = set(logs.glob('*.mcap'))
    print(f'starting tissue_sim_node (recording to {logs}) ...', flush=True)
    node = subprocess.Popen([_script('tissue_sim_node'), '--ros-args', '-p', f'recording.directory:={logs}'],
                            env=env, stdout=open(out / 'node.log', 'w'), stderr=subprocess.STDOUT)
    try:
        drive = subprocess.run([_script('tissue-sim'), 'drive', '--speed-mm-s', str(speed_mm_s),
                                '--depth-mm', str(depth_mm), '--hold-s', '0.5'],
                               env=env, timeout=300)
        time.sleep(0.3)                         # the last wrenches
    finally:
        node.send_signal(signal.SIGINT)
        try:
            node.wait(timeout=30)
        except subprocess.TimeoutExpired:
            node.kill()
    if drive.returncode != 0:
        raise SystemExit(f'tissue-sim drive failed (exit {drive.returncode}); node output in {out / "node.log"}')
    new = sorted(set(logs.glob('*.mcap')) - before)
    if not new:
        raise SystemExit(f'the node wrote no log; its output is in {out / "node.log"}')
    log = new[-1]
    summary = summarize_log(log)
    print(f'\nlog {log} (node exit {node.returncode}):')
    for topic, entry in sorted(summary['topics'].items()):
        print(f'  {topic:<20} {entry["type"]:<36} {entry["count"]:>6} messages')
    t, travel, axial = _wrench_and_travel(log)
    rate = (len(t) - 1) / (t[-1] - t[0])
    inserting = np.arange(len(t)) <= int(np.argmax(travel))
    drops = np.diff(axial)
    k = int(np.argmin(np.where(inserting[1:], drops, np.inf)))
    print(f'wrench rate {rate:.2f} Hz over {t[-1] - t[0]:.1f} s; peak axial force {axial.max():.3f} N '
          f'at travel {travel[int(np.argmax(axial))] * 1e3:.2f} mm')
    print(f'largest force drop while inserting (the capsule giving way): {axial[k]:.3f} -> {axial[k + 1]:.3f} N '
          f'at travel {travel[k] * 1e3:.2f} mm')
    _plot(travel, axial, inserting, out / 'node_insertion.png', speed_mm_s)
    print(f'wrote {out / "node_insertion.png"}')
    return {'log': log, 'rate_hz': rate, 'peak_axial_n': float(axial.max()), 'puncture_travel_m': float(travel[k])}


def _plot(travel, axial, inserting, path, speed_mm_s):
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    from tissue_sim_ros.analysis.insertion import DATA_DIR, okamura_main_trace
    fig, ax = plt.subplots(figsize=(7, 4.2))
    if DATA_DIR.exists():
        d, f = okamura_main_trace()
        ax.plot(d * 1e3, f, '.', ms=3, color='0.55', label='bovine liver, ex vivo (Okamura et al. 2004, 3 mm/s)')
    ax.plot(travel[inserting] * 1e3, axial[inserting], color='C0', label='node, insertion (from the MCAP log)')
    ax.plot(travel[~inserting] * 1e3, axial[~inserting], color='C3', label='node, retraction')
    ax.set_xlabel('needle travel from start [mm]')
    ax.set_ylabel('axial force on the needle [N]')
    ax.set_title(f'tissue_sim_node, insertion at {speed_mm_s:g} mm/s')
    ax.grid(alpha=0.3)
    ax.legend(loc='upper left', fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
