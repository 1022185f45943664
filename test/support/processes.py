"""Processes seen through /proc: running or not, and the spinners this process started."""

import os
import time
from pathlib import Path

from tissue_sim_ros.bench.background_load import SPIN


def _alive(pid):
    """True while the process runs (a zombie or a reaped process is not running)."""
    try:
        state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0]
    except OSError:
        return False
    return state not in ('Z', 'X')


def _my_spinners():
    """Pids of running spinner processes this test process started."""
    found = []
    for proc in Path('/proc').iterdir():
        try:
            argv = (proc / 'cmdline').read_bytes().split(b'\0')
        except OSError:
            continue
        if len(argv) > 3 and argv[2] == SPIN.encode() and argv[3] == str(os.getpid()).encode():
            if _alive(int(proc.name)):
                found.append(int(proc.name))
    return found


def group_gone(pgid: int, timeout_s: float) -> bool:
    """Whether every process of the group has ended within ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.05)
    return False


def wait_for(condition, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, f'{what}: not within {timeout_s} s'
        time.sleep(0.05)
