"""Stopping a process pool now, whatever its workers are running.

``concurrent.futures`` joins a ProcessPoolExecutor's manager thread at interpreter exit (and
``shutdown(wait=True)`` waits), and that thread waits for the items the workers are running: a
node whose prediction workers are still in their start-up run would take tens of seconds to end
on SIGINT on a busy machine, and an analysis whose batch failed would wait for every simulation
still running. The node's predictions and the analyses' runner stop their pools here.
"""
from __future__ import annotations

import contextlib

__all__ = ['stop_pool']


def stop_pool(pool) -> None:
    """Queued work cancelled and the workers terminated: running items are dropped. Python
    3.14's ProcessPoolExecutor.terminate_workers; before it, the worker processes the pool holds
    (taken before the shutdown, which lets go of them)."""
    terminate = getattr(pool, 'terminate_workers', None)
    if terminate is not None:
        terminate()
        return
    processes = list((getattr(pool, '_processes', None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        with contextlib.suppress(OSError, ValueError):     # already gone, or already closed
            process.terminate()
