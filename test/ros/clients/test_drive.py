"""tissue-sim drive (ros/clients/drive.py): its scripted motion against the scene file's own
numbers, and a drive against the node as a process stopped with SIGTERM."""

import os
import signal
import subprocess
import threading
import time

import numpy as np
import pytest
import yaml

from support.paths import ROOT
from tissue_sim_ros.io import mcap as ml
from tissue_sim_ros.ros.clients.drive import insertion_trajectory, scene_start


@pytest.fixture(scope='module')
def start():
    return scene_start()


def test_start_is_the_scenes_initial_pose_and_gap(start):
    scene = yaml.safe_load((ROOT / 'config' / 'liver_sample.yaml').read_text())
    needle = scene['needle']
    top = scene['mesh']['origin_m'][2] + scene['mesh']['size_m'][2]
    np.testing.assert_allclose(start.initial_position, needle['initial_position_m'])
    np.testing.assert_allclose(start.orientation, needle['initial_orientation_xyzw'])
    np.testing.assert_allclose(start.axis, [0, 0, -1], atol=1e-15)  # pointing down
    # pointing down from above the block: the tip is (base z - length) - top above its top face
    assert start.gap_m == pytest.approx(needle['initial_position_m'][2] - needle['length_m'] - top)
    assert start.frame_id == 'world'


def test_trajectory_goes_down_to_the_depth_and_back_at_the_speed(start):
    speed, depth, hold, rate = 0.005, 0.02, 0.5, 100.0
    t, p = insertion_trajectory(start, speed, depth, hold, rate)
    z0 = start.initial_position[2]
    bottom = z0 - (start.gap_m + depth)
    assert p[:, 2].min() == pytest.approx(bottom)
    np.testing.assert_allclose(p[0], start.initial_position)
    np.testing.assert_allclose(p[-1], start.initial_position)
    np.testing.assert_allclose(p[:, :2], 0.0)
    v = np.abs(np.diff(p[:, 2])) / np.diff(t)
    assert v.max() == pytest.approx(speed, rel=1e-9)
    total = 2 * (start.gap_m + depth) / speed + hold
    assert t[-1] == pytest.approx(total)
    assert np.all(np.diff(t) <= 1 / rate + 1e-12)
    at_bottom = t[np.isclose(p[:, 2], bottom, atol=1e-12)]
    assert at_bottom[-1] - at_bottom[0] == pytest.approx(hold, abs=1 / rate)


def test_start_height_moves_the_start_pose_first(start):
    t, p = insertion_trajectory(start, 0.01, 0.003, 0.0, 100.0, start_gap_m=0.002)
    z0 = start.initial_position[2]
    start_z = z0 - (start.gap_m - 0.002)  # tip 2 mm above the surface
    assert p[:, 2].min() == pytest.approx(start_z - 0.005)
    assert p[-1, 2] == pytest.approx(start_z)  # back to the start pose, not the initial one


@pytest.mark.parametrize('kw, name', [
    ({'speed_m_s': 0.0}, 'speed_m_s'), ({'depth_m': -1.0}, 'depth_m'),
    ({'hold_s': float('nan')}, 'hold_s'), ({'rate_hz': -5.0}, 'rate_hz'),
    ({'start_gap_m': -0.001}, 'start_gap_m')])
def test_impossible_drives_are_refused_by_name(start, kw, name):
    args = {'speed_m_s': 0.005, 'depth_m': 0.01, 'hold_s': 0.0, 'rate_hz': 100.0, **kw}
    with pytest.raises(ValueError, match=name):
        insertion_trajectory(start, **args)


class _RecordingPublisher:
    """Stands in for a rclpy publisher: keeps what each publish() saw and when."""

    def __init__(self):
        self.positions, self.stamps, self.at = [], [], []

    def publish(self, msg):
        import time
        self.at.append(time.monotonic())
        p = msg.pose.position
        self.positions.append((p.x, p.y, p.z))
        self.stamps.append(msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec)


def test_publish_trajectory_sends_each_pose_on_its_schedule():
    pytest.importorskip('geometry_msgs')
    import time
    from tissue_sim_ros.ros.clients.drive import pose_message, publish_trajectory
    times = np.array([0.0, 0.02, 0.04, 0.05])
    positions = np.arange(12, dtype=float).reshape(4, 3) * 1e-3
    clock = iter(range(7_000_000_000, 8_000_000_000, 1_000))
    pub = _RecordingPublisher()
    t0 = time.monotonic()
    sent = publish_trajectory(pub, pose_message('world', [0.0, 1.0, 0.0, 0.0]), times, positions,
                              lambda: next(clock))
    assert sent == [7_000_000_000, 7_000_001_000, 7_000_002_000, 7_000_003_000] == pub.stamps
    np.testing.assert_array_equal(pub.positions, positions)
    assert all(at - t0 >= t - 1e-3 for at, t in zip(pub.at, times))  # never early


def test_publish_trajectory_repeats_the_schedule_for_a_duration():
    pytest.importorskip('geometry_msgs')
    import time
    from tissue_sim_ros.ros.clients.drive import pose_message, publish_trajectory
    times = np.array([0.0, 0.01, 0.02])
    positions = np.array([[0.0, 0.0, 0.1], [0.0, 0.0, 0.2], [0.0, 0.0, 0.3]])
    pub = _RecordingPublisher()
    msg = pose_message('world', [0.0, 0.0, 0.0, 1.0])
    t0 = time.monotonic()
    sent = publish_trajectory(pub, msg, times, positions, time.time_ns, repeat_for_s=0.2,
                              cycle_s=0.05)
    # cycles start every 50 ms: 4 whole cycles of 3 poses in 0.2 s, maybe the 5th cycle's first
    assert len(sent) in (12, 13)
    np.testing.assert_array_equal(pub.positions, positions[np.arange(len(sent)) % 3])
    scheduled = [(k // 3) * 0.05 + times[k % 3] for k in range(len(sent))]
    assert all(at - t0 >= s - 1e-3 for at, s in zip(pub.at, scheduled))
    assert msg.pose.orientation.w == 1.0 and msg.header.frame_id == 'world'


# tissue-sim drive against the node, stopped with SIGTERM
def test_drive_then_sigterm_leaves_a_complete_log(tmp_path, scene_file):
    pytest.importorskip('rclpy')
    from support.node_process import (BIN, Client, _DOMAINS, check_log_against_received, ros_env, start_node,
                                      stop_node, wait_for_the_log)
    domain = next(_DOMAINS)
    proc = start_node(tmp_path, domain, scene_file, f'recording.directory:={tmp_path / "logs"}',
                      'recording.nodes_rate_hz:=50.0')
    client = Client(domain)
    try:
        client.wait_ready(proc)
        drive = subprocess.run(
            [str(BIN / 'tissue-sim'), 'drive', '--speed-mm-s', '20', '--depth-mm', '4',
             '--hold-s', '0', '--rate-hz', '100', '--scene-file', scene_file],
            env=ros_env(domain), capture_output=True, text=True, timeout=60)
        assert drive.returncode == 0, drive.stderr
        sent = len(insertion_trajectory(scene_start(scene_file), 0.02, 0.004, 0.0, 100.0)[0])   # by the drive
        client.wait_until(client.next_diagnostics, lambda d: int(d['tissue_sim: input'][2]['poses_received']) >= sent,
                          what="every pose of the drive judged")
        rc = stop_node(proc, signal.SIGTERM)
        wait_for_the_log(client, tmp_path / 'logs')
        received = {k: client.get(k) for k in client.received}
    finally:
        if proc.poll() is None:
            proc.kill()
        client.close()
    assert rc == 0, proc.log_path.read_text()[-3000:]
    times, positions = insertion_trajectory(scene_start(scene_file), 0.02, 0.004, 0.0, 100.0)
    travel_mm = np.linalg.norm(positions - positions[0], axis=1).max() * 1e3
    assert f'down {travel_mm:.1f} mm at 20 mm/s to 4 mm below the surface' in drive.stdout
    (path,) = sorted((tmp_path / 'logs').glob('*.mcap'))
    counts = check_log_against_received(path, received, len(times))  # every pose the drive sent
    from rosbags.highlevel import AnyReader
    with AnyReader([path]) as reader:
        conn = [c for c in reader.connections if c.topic == '/needle/pose']
        poses = [reader.deserialize(raw, c.msgtype) for c, _, raw in
                 reader.messages(connections=conn)]
    z = np.array([p.pose.position.z for p in poses])
    np.testing.assert_allclose(z, positions[:, 2], atol=1e-12)
    assert ml.summarize_log(path)['statistics']['message_count'] == sum(counts.values())


def test_drive_with_a_monitor_subscribed_first_moves_the_needle(tmp_path):
    """drive waits for the node itself: a monitor subscribed to needle/pose before the node
    starts does not start the drive, and the needle moves."""
    import rclpy
    import rclpy.executors
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from support.node_process import BIN
    from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context, private_ros_env
    domain = 200 + os.getpid() % 30
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump({'mesh': {'fine_size_m': 0.004, 'divisions': [5, 5, 4]},
                                     'regions': [{'name': 'tissue', 'young_modulus_pa': 20000.0,
                                                  'membrane': {'criterion': 'force', 'rupture_force_n': 5.0}}]}))
    forces, poses = [], []
    with client_context(domain) as context:
        monitor = rclpy.create_node('monitor', context=context)
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        monitor.create_subscription(PoseStamped, 'needle/pose', poses.append, reliable)
        monitor.create_subscription(WrenchStamped, 'needle/wrench', lambda m: forces.append(m.wrench.force.z),
                                    reliable)
        executor = rclpy.executors.SingleThreadedExecutor(context=context)
        executor.add_node(monitor)
        stop = threading.Event()

        def spin():
            while not stop.is_set():
                executor.spin_once(timeout_sec=0.05)
        spinner = threading.Thread(target=spin, daemon=True)
        spinner.start()
        try:
            drive = subprocess.Popen([str(BIN / 'tissue-sim'), 'drive', '--speed-mm-s', '20', '--depth-mm', '3',
                                      '--hold-s', '0', '--scene', str(scene), '--wait-for-node-s', '120'],
                                     env=private_ros_env(domain), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
            deadline = time.monotonic() + 120        # it loads the scene first (compiles on a first start)
            while not monitor.get_publishers_info_by_topic('needle/pose'):      # the drive is up, waiting
                assert drive.poll() is None, drive.communicate()[1]
                assert time.monotonic() < deadline, 'the drive did not come up'
                time.sleep(0.05)
            time.sleep(1.0)            # a second with only the monitor subscribed: the drive must wait
            assert not poses, 'the drive published before the node was there'
            with NodeProcess([f'scene_file:={scene}'], tmp_path / 'node.log', domain) as node:
                out, err = drive.communicate(timeout=180)
                node.stop()
        finally:
            stop.set()
            spinner.join(timeout=5)
            if drive.poll() is None:
                drive.kill()
    assert drive.returncode == 0, err
    assert len(poses) > 10
    # the node followed the poses into the tissue: it pushed back (a refused pose would hold it)
    assert max(np.abs(forces), default=0.0) > 0.01
