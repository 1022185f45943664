"""``tissue-sim drive`` waits for the node itself: a monitor subscribed to ``needle/pose`` before
the node starts does not start the drive, and the needle moves (ros.clients.drive)."""
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml

pytest.importorskip('rclpy')
from tissue_sim_ros.ros.clients.node_process import NodeProcess, client_context, private_ros_env  # noqa: E402

BIN = Path(sys.executable).parent


def test_drive_with_a_monitor_subscribed_first_moves_the_needle(tmp_path):
    import rclpy
    import rclpy.executors
    from geometry_msgs.msg import PoseStamped, WrenchStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy
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
