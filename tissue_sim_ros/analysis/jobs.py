"""Running an analysis's independent simulations over the machine's cores, with progress.

One runner for compare, calibrate and chart: ``run_jobs(function, jobs)`` calls
``function(job)`` for each job and returns the results in the jobs' order, in a process pool of
``workers`` processes (default: the cores this process may use), each with one numba thread (the
simulations are the parallelism; threads inside each would fight over the same cores), or in
this process when ``workers`` is 1, or on a Dask distributed cluster when ``scheduler`` gives its
address ('tcp://host:8786', or a ``distributed.Client``). A progress bar (tqdm, on stderr) counts
the jobs done; ``on_result(index, result)`` sees each result as it arrives (the caller saves it:
that is what makes a run resumable). ``function`` and the jobs must pickle (a module-level
function and plain data). A job that raises ends its batch at once: the simulations still
running are dropped (``process_pools.stop_pool``), not waited for.

A study that runs many small batches (a calibration: one per parameter vector or Jacobian)
keeps one :class:`WorkerPool` open across them: starting a spawned worker (Python, numpy, numba
and its cached kernels) costs seconds, more than a small batch's simulations.
"""
from __future__ import annotations

import json
import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed

from tissue_sim_ros.system.process_pools import sigint_blocked, start_worker, stop_pool

__all__ = ['default_workers', 'run_jobs', 'run_logged', 'WorkerPool']


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _start_worker(parent_pid: int):
    """Worker start-up, before numba is imported there: one numba thread per simulation
    process; Ctrl-C left to the parent, and an end with it (``process_pools.start_worker``)."""
    start_worker(parent_pid)
    os.environ['NUMBA_NUM_THREADS'] = '1'


def _progress(total: int, label: str, quiet: bool):
    from tqdm import tqdm
    return tqdm(total=total, desc=label, unit='run', file=sys.stderr, disable=quiet or total == 0,
                dynamic_ncols=True)


class WorkerPool:
    """A process pool of ``workers`` spawned processes (one numba thread each) kept open across
    :func:`run_jobs` calls (``pool=``); a context manager. With one worker it holds no process."""

    def __init__(self, workers: int | None = None):
        self.workers = default_workers() if workers is None else int(workers)
        self.executor = None

    def __enter__(self):
        if self.workers > 1:      # spawned, not forked: libgomp (numba's OpenMP layer) is not fork-safe
            self.executor = ProcessPoolExecutor(max_workers=self.workers, initializer=_start_worker,
                                                initargs=(os.getpid(),),
                                                mp_context=multiprocessing.get_context('spawn'))
        return self

    def __exit__(self, exc_type, *exc):
        if self.executor is not None:
            if exc_type is None:
                self.executor.shutdown(cancel_futures=True)
            else:          # a failure or an interruption: the running simulations are dropped
                stop_pool(self.executor)
            self.executor = None
        return False


def run_jobs(function, jobs, *, workers: int | None = None, scheduler=None, label: str = 'simulations',
             on_result=None, quiet: bool = False, postfix=None, pool: WorkerPool | None = None) -> list:
    """``[function(job) for job in jobs]`` in parallel (see the module docstring). ``postfix()``:
    text the progress bar shows after each result (e.g. the best objective so far); ``pool``: an
    open WorkerPool to run them in (``workers`` is then its size)."""
    jobs = list(jobs)
    results = [None] * len(jobs)
    workers = default_workers() if workers is None else int(workers)
    with _progress(len(jobs), label, quiet) as bar:
        def done(index, result):
            results[index] = result
            if on_result is not None:
                on_result(index, result)
            bar.update(1)
            if postfix is not None:
                bar.set_postfix_str(postfix(), refresh=False)

        if scheduler is not None:
            _run_dask(function, jobs, scheduler, done)
        elif pool is not None and pool.executor is not None and len(jobs) > 1:
            with sigint_blocked():                    # a first submit starts the workers
                futures = {pool.executor.submit(function, job): index for index, job in enumerate(jobs)}
            for future in as_completed(futures):
                done(futures[future], future.result())
        elif workers <= 1 or len(jobs) <= 1:
            for index, job in enumerate(jobs):
                done(index, function(job))
        else:
            with WorkerPool(min(workers, len(jobs))) as own:
                with sigint_blocked():
                    futures = {own.executor.submit(function, job): index for index, job in enumerate(jobs)}
                for future in as_completed(futures):
                    done(futures[future], future.result())
    return results


def run_logged(function, jobs, log, **options) -> list:
    """run_jobs over the jobs that ``log`` (a JSON-lines file) has no result for, appending each
    result as it arrives; returns every job's result in order. Each job is a dict with a 'key'
    (a string naming it, its settings included) and ``function`` returns a dict carrying that key.
    A line cut by an interrupted run is skipped (its job runs again) and ended, so the next line
    starts on its own: this is what makes a study resumable."""
    from pathlib import Path
    log = Path(log)
    done = {}
    if log.exists():
        text = log.read_text()
        for line in text.splitlines():
            try:
                row = json.loads(line)
            except json.JSONDecodeError:
                continue
            if isinstance(row, dict):
                done[row.get('key')] = row
        if text and not text.endswith('\n'):
            with log.open('a') as f:
                f.write('\n')

    def save(index, row):
        with log.open('a') as f:
            f.write(json.dumps(row) + '\n')
        done[row['key']] = row

    run_jobs(function, [job for job in jobs if job['key'] not in done], on_result=save, **options)
    return [done[job['key']] for job in jobs]


def _run_dask(function, jobs, scheduler, done) -> None:
    """The jobs on a Dask distributed cluster (``scheduler``: an address or a Client)."""
    try:
        from distributed import Client, as_completed as dask_completed
    except ImportError as exc:
        raise RuntimeError('--scheduler needs dask.distributed (pip install "distributed"); '
                           f'it is not installed: {exc}') from None
    client = scheduler if isinstance(scheduler, Client) else Client(scheduler)
    try:
        futures = client.map(function, jobs, pure=False)
        index_of = {future.key: index for index, future in enumerate(futures)}
        for future in dask_completed(futures):
            done(index_of[future.key], future.result())
    finally:
        if client is not scheduler:
            client.close()
