"""Busy processes and a listening ROS client beside the node: ``tissue-sim node-bench --load N``.

A node's rate on a quiet machine says little about a lab PC that also runs a controller, RViz and
a logger. ``BackgroundLoad(n, env)`` starts ``n`` processes that only spin the CPU and one ROS
client (:mod:`tissue_sim_ros.ros.clients.listener`) subscribed to the wrench and the point cloud, so the
rate under load is a figure anyone can reproduce. ``listen`` runs the client without busy
processes too (``node-bench --listen``: the node's cost with a subscriber to its cloud, which it
builds only then). Leaving the block stops them all, whatever happened; a spinner also ends by
itself when its parent is gone (checked every few ms).
"""
from __future__ import annotations

import json
import os
import select
import signal
import subprocess
import sys

__all__ = ['BackgroundLoad', 'SPIN', 'machine_load']

#: a busy process (``python -c SPIN PARENT_PID``): pure Python loops, no I/O, while its parent is
#: the process named (it ends at once if that one is gone before it starts)
SPIN = ('import os, sys\n'
        'while os.getppid() == int(sys.argv[1]):\n'
        '    for _ in range(200000):\n'
        '        pass\n')


class BackgroundLoad:
    """``n_busy`` CPU spinners plus, when ``n_busy`` > 0 or ``listen``, one listener on the
    node's graph (``env`` holds its ROS domain). ``listener`` afterwards: what it received per
    topic."""

    def __init__(self, n_busy: int, env: dict, ready_timeout_s: float = 60.0, listen: bool = False):
        if int(n_busy) != n_busy or n_busy < 0:
            raise ValueError(f'load: {n_busy!r}; expected a whole number of busy processes >= 0')
        self.n_busy = int(n_busy)
        self.listen = bool(listen) or self.n_busy > 0
        self.env = env
        self.ready_timeout_s = ready_timeout_s
        self.spinners: list[subprocess.Popen] = []
        self.listener_process: subprocess.Popen | None = None
        self.listener: dict = {}

    def describe(self) -> str:
        if not self.listen:
            return 'none (no busy process, no extra listener)'
        busy = f'{self.n_busy} busy process{"es" if self.n_busy > 1 else ""}' if self.n_busy else 'no busy process'
        return f'{busy} + 1 listening client (needle/wrench, tissue/nodes)'

    def start(self) -> BackgroundLoad:
        """Start the listener, wait until it hears both topics, then the spinners; on any
        failure, stop what was started."""
        if not self.listen:
            return self
        try:
            self.listener_process = subprocess.Popen(
                [sys.executable, '-m', 'tissue_sim_ros.ros.clients.listener'], env=self.env,
                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
            if _read_json(self.listener_process.stdout, self.ready_timeout_s) != {'ready': True}:
                raise RuntimeError('the listening client did not hear the node within '
                                   f'{self.ready_timeout_s:g} s')
            for _ in range(self.n_busy):
                self.spinners.append(subprocess.Popen([sys.executable, '-c', SPIN, str(os.getpid())],
                                                     env=self.env))
        except BaseException:
            self.stop()
            raise
        return self

    def stop(self) -> None:
        """Kill the spinners, ask the listener for its counts (SIGINT) and end it."""
        for spinner in self.spinners:
            spinner.kill()
        for spinner in self.spinners:
            spinner.wait()
        self.spinners = []
        process, self.listener_process = self.listener_process, None
        if process is None:
            return
        if process.poll() is None:
            process.send_signal(signal.SIGINT)  # the listener prints its counts and exits
            self.listener = _read_json(process.stdout, 10.0)
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
        process.stdout.close()

    def __enter__(self) -> BackgroundLoad:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _read_json(stream, timeout_s: float) -> dict:
    """The next output line of a child as JSON; {} at its end, on garbage or after ``timeout_s``."""
    ready, _, _ = select.select([stream], [], [], timeout_s)
    line = stream.readline() if ready else ''
    try:
        return json.loads(line) if line.strip() else {}
    except json.JSONDecodeError:
        return {}


def machine_load() -> str:
    """The 1-minute load average and the core count, for the report (other load shows in it)."""
    return f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'
