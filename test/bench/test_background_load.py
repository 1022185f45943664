"""Busy processes and a listening client beside the node (bench/background_load.py): the listener
hears every message a stand-in node sends, the spinners use CPU, and all of them stop whatever
happens, even when their parent is gone."""

import contextlib
import os
import subprocess
import sys
import time
import types
from pathlib import Path

import pytest

from support.processes import _alive, _my_spinners
from tissue_sim_ros.bench.background_load import BackgroundLoad, SPIN


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
