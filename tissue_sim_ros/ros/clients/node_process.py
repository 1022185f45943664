"""``tissue_sim_node`` as a child process on a private ROS graph, for runs that drive it from outside.

``tissue-sim demo`` and ``tissue-sim node-bench`` both start the node, wait until it is up, drive
it and stop it. The child gets its own ``ROS_DOMAIN_ID`` and localhost-only discovery, so that a
run sees no other run and no lab robot; it is stopped with SIGINT (the node then closes its MCAP
log completely) and killed if it has not stopped within the timeout. A client in this process
joins the same private graph through :func:`client_context`.
"""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import Callable

from tissue_sim_ros.errors import NodeProcessError

__all__ = ['NodeProcess', 'console_script', 'private_domain_id',
           'private_ros_env', 'client_context']

_LOCALHOST = 'LOCALHOST'


def private_domain_id() -> int:
    """A ROS domain for this process's runs (100-199, from the process id), apart from domain 0."""
    return 100 + os.getpid() % 100


def private_ros_env(domain_id: int) -> dict:
    """The environment for a child on the private graph: its domain, localhost discovery, and
    unbuffered Python output (its log is read while it runs)."""
    return dict(os.environ, ROS_DOMAIN_ID=str(domain_id),
                ROS_AUTOMATIC_DISCOVERY_RANGE=_LOCALHOST, PYTHONUNBUFFERED='1')


def console_script(name: str, module: str) -> list[str]:
    """The command for one of the package's console scripts: the script beside this Python (a
    venv or a colcon install), else ``python -m module``."""
    script = Path(sys.executable).parent / name
    return [str(script)] if script.exists() else [sys.executable, '-m', module]


class NodeProcess:
    """``tissue_sim_node --ros-args -p PARAM ...`` on a private domain, its output in ``log_path``.

    Use as a context manager (or call start() and stop()): leaving the block stops the node,
    whatever happened inside it.
    """

    def __init__(self, params: list[str], log_path: str | Path, domain_id: int | None = None):
        self.params = list(params)
        self.log_path = Path(log_path)
        self.domain_id = private_domain_id() if domain_id is None else int(domain_id)
        self.env = private_ros_env(self.domain_id)
        self.process: subprocess.Popen | None = None
        self.started_at = 0.0

    @property
    def command(self) -> list[str]:
        cmd = console_script('tissue_sim_node', 'tissue_sim_ros.cli.node_script') + ['--ros-args']
        for param in self.params:
            cmd += ['-p', param]
        return cmd

    @property
    def pid(self) -> int:
        return self.process.pid

    @property
    def returncode(self) -> int | None:
        return None if self.process is None else self.process.poll()

    def start(self) -> NodeProcess:
        with open(self.log_path, 'w') as log:  # the child keeps its own descriptor
            self.started_at = time.monotonic()
            self.process = subprocess.Popen(self.command, env=self.env, stdout=log,
                                            stderr=subprocess.STDOUT)
        return self

    def last_log_line(self) -> str:
        """The node's last non-empty output line (its refusal, when it exits at start)."""
        try:
            lines = [line for line in self.log_path.read_text(errors='replace').splitlines()
                     if line.strip()]
        except OSError:
            return ''
        return lines[-1].strip() if lines else ''

    def wait_until(self, ready: Callable[[], bool], timeout_s: float = 300.0,
                   what: str = 'come up') -> float:
        """Poll ``ready()`` until true; the seconds since start. NodeProcessError, naming the
        node's log, when the node exits first or ``timeout_s`` passes (a cold numba cache
        compiles for minutes, hence the long default)."""
        deadline = time.monotonic() + timeout_s
        while not ready():
            if self.returncode is not None:
                raise NodeProcessError(
                    f'tissue_sim_node exited with status {self.returncode} before it could {what} '
                    f'({self.last_log_line() or "no output"}); its output: {self.log_path}')
            if time.monotonic() > deadline:
                raise NodeProcessError(f'tissue_sim_node did not {what} within {timeout_s:g} s; '
                                       f'its output: {self.log_path}')
            time.sleep(0.02)
        return time.monotonic() - self.started_at

    def wait_for_subscriber(self, topic: str = 'needle/pose', timeout_s: float = 300.0) -> float:
        """Wait until something on the private graph subscribes to ``topic`` (the node, once up)."""
        with client_context(self.domain_id) as context:
            import rclpy
            probe = rclpy.create_node('tissue_sim_probe', context=context)
            try:
                name = topic if topic.startswith('/') else '/' + topic
                return self.wait_until(lambda: probe.count_subscribers(name) > 0, timeout_s,
                                       f'subscribe to {topic}')
            finally:
                probe.destroy_node()

    def wait_until_ready(self, name: str = '/tissue_sim', timeout_s: float = 300.0) -> float:
        """Wait until the node ``name`` says it ticks: its latched ``<name>/ready`` is true (the
        node's readiness, :mod:`~tissue_sim_ros.ros.readiness`); the seconds since start."""
        with client_context(self.domain_id) as context:
            import rclpy
            from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
            from std_msgs.msg import Bool
            probe = rclpy.create_node('tissue_sim_probe', context=context)
            ready = []
            probe.create_subscription(Bool, f'{name}/ready', lambda msg: ready.append(msg.data), QoSProfile(
                depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL))
            executor = rclpy.executors.SingleThreadedExecutor(context=context)
            executor.add_node(probe)

            def spun_ready():
                executor.spin_once(timeout_sec=0.05)
                return bool(ready) and ready[-1]
            try:
                return self.wait_until(spun_ready, timeout_s, f'say {name}/ready')
            finally:
                executor.remove_node(probe)
                probe.destroy_node()

    def stop(self, timeout_s: float = 30.0) -> int | None:
        """SIGINT, then wait up to ``timeout_s`` (the node closes its log), else kill; the exit
        status."""
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGINT)
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        return self.process.returncode

    def __enter__(self) -> NodeProcess:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


@contextmanager
def client_context(domain_id: int):
    """An rclpy context in this process on the private graph (``domain_id``, localhost
    discovery), shut down on leaving; the discovery variable is restored afterwards."""
    import rclpy
    previous = os.environ.get('ROS_AUTOMATIC_DISCOVERY_RANGE')
    os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = _LOCALHOST  # read when the context starts
    context = rclpy.Context()
    try:
        rclpy.init(context=context, domain_id=domain_id)
        yield context
    finally:
        rclpy.try_shutdown(context=context)
        if previous is None:
            os.environ.pop('ROS_AUTOMATIC_DISCOVERY_RANGE', None)
        else:
            os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = previous
