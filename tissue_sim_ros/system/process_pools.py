"""Worker processes that end with their parent and leave Ctrl-C to it, and stopping a pool now.

A terminal's Ctrl-C sends SIGINT to the whole process group: a worker that took it printed a
KeyboardInterrupt traceback, or died and broke its pool, which then scored its work as failed
and went on. Workers are therefore started with SIGINT blocked (:func:`sigint_blocked` around
the pool's start: the signal mask is inherited across fork and exec, so no Ctrl-C reaches a
worker even while Python starts in it) and ignore it from their first line
(:func:`start_worker`); their parent alone decides, and ends them. A worker also ends within a
second of its parent's end, however that came (a SIGKILL included), instead of running on.

``concurrent.futures`` joins a ProcessPoolExecutor's manager thread at interpreter exit (and
``shutdown(wait=True)`` waits), and that thread waits for the items the workers are running: a
node whose prediction workers are still in their start-up run would take tens of seconds to end
on SIGINT on a busy machine, and an analysis whose batch failed would wait for every simulation
still running. The node's predictions and the analyses' runner stop their pools here.
"""
from __future__ import annotations

import contextlib
import os
import signal
import threading
import time

__all__ = ['sigint_blocked', 'start_worker', 'stop_pool']


@contextlib.contextmanager
def sigint_blocked():
    """SIGINT blocked in this thread for the duration: processes started meanwhile start with
    it blocked. A Ctrl-C that comes meanwhile is delivered when it ends."""
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def start_worker(parent_pid: int) -> None:
    """A pool worker's first line: SIGINT ignored (the parent ends the worker), and a watch that
    ends the worker within a second of its parent."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})

    def watch_parent():
        while os.getppid() == parent_pid:
            time.sleep(1.0)
        os._exit(0)
    threading.Thread(target=watch_parent, name='tissue_sim-parent-watch', daemon=True).start()


def stop_pool(pool) -> None:
    """Queued work cancelled and the workers terminated: running items are dropped. Python
    3.14's ProcessPoolExecutor.terminate_workers; before it, the worker processes the pool holds
    (taken before the shutdown, which lets go of them)."""
    terminate = getattr(pool, 'terminate_workers', None)
    if terminate is not None:
        terminate()
        return
    processes = list((getattr(pool, '_processes', None) or {}).values())
    manager = getattr(pool, '_executor_manager_thread', None)
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError):     # already gone, or already closed
            process.terminate()
    # the pool's manager thread notices the terminated workers and closes its wake-up pipe: at
    # the interpreter's exit concurrent.futures writes to the pipe of a manager still running,
    # which raced that closing ('Exception ignored ... Bad file descriptor' on a Ctrl-C)
    if manager is not None:
        manager.join(timeout=5.0)
