"""Stopping a process pool now (system/process_pools.py). Truth: what concurrent.futures does
without it (the exit waits for the running item), measured in the same run."""

import os
import signal
import subprocess
import sys
import time

import pytest

SCRIPT = '''import multiprocessing, os, sys, time
from concurrent.futures import ProcessPoolExecutor
from tissue_sim_ros.system.process_pools import stop_pool
if __name__ == "__main__":
    pool = ProcessPoolExecutor(1, multiprocessing.get_context("spawn"))
    assert pool.submit(os.getpid).result(timeout=60) > 0      # the worker is up
    running = pool.submit(time.sleep, 60.0)
    time.sleep(0.5)
    print(*[p.pid for p in pool._processes.values()], flush=True)
    if sys.argv[1] == "stop":
        stop_pool(pool)
    else:
        pool.shutdown(wait=False, cancel_futures=True)
'''


def _alive(pid):
    try:
        with open(f'/proc/{pid}/stat') as stat:
            return stat.read().rsplit(')', 1)[1].split()[0] != 'Z'
    except OSError:
        return False


def test_stopping_the_pool_drops_a_running_item_instead_of_holding_the_exit(tmp_path):
    """A process whose pool is stopped while a worker runs a long item (a prediction, or the
    start-up run of workers still loading on a loaded machine) exits at once, and its worker is
    gone; with a plain shutdown, the exit waits for the item (60 s here)."""
    script = tmp_path / 'pool_exit.py'
    script.write_text(SCRIPT)
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, str(script), 'stop'], capture_output=True, text=True, timeout=50)
    took = time.monotonic() - t0
    assert done.returncode == 0, done.stderr
    assert took < 30.0, f'exit held {took:.1f} s'
    (worker,) = [int(pid) for pid in done.stdout.split()]
    time.sleep(0.5)
    assert not _alive(worker)
    with pytest.raises(subprocess.TimeoutExpired) as held:
        subprocess.run([sys.executable, str(script), 'shutdown only'], capture_output=True, timeout=took + 5.0)
    # the timeout killed that script, not its worker, which would wait for work for ever
    for pid in (held.value.stdout or b'').split():
        os.kill(int(pid), signal.SIGKILL)
