"""Running an analysis's independent simulations over the machine's cores, with progress.

One runner for compare, calibrate and chart: ``run_jobs(function, jobs)`` calls
``function(job)`` for each job and returns the results in the jobs' order, in a process pool of
``workers`` processes (default: the cores this process may use), each with one numba thread (the
simulations are the parallelism; threads inside each would fight over the same cores), or in
this process when ``workers`` is 1, or on a Dask distributed cluster when ``scheduler`` gives its
address ('tcp://host:8786', or a ``distributed.Client``). A progress bar (tqdm, on stderr) counts
the jobs done; ``on_result(index, result)`` sees each result as it arrives (the caller saves it:
that is what makes a run resumable). ``function`` and the jobs must pickle (a module-level
function and plain data).
"""
from __future__ import annotations

import multiprocessing
import os
import sys
from concurrent.futures import ProcessPoolExecutor, as_completed

__all__ = ['default_workers', 'run_jobs']


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):
        return max(1, os.cpu_count() or 1)


def _one_thread():
    """Worker start-up, before numba is imported there: one numba thread per simulation
    process."""
    os.environ['NUMBA_NUM_THREADS'] = '1'


def _progress(total: int, label: str, quiet: bool):
    from tqdm import tqdm
    return tqdm(total=total, desc=label, unit='run', file=sys.stderr, disable=quiet or total == 0,
                dynamic_ncols=True)


def run_jobs(function, jobs, *, workers: int | None = None, scheduler=None, label: str = 'simulations',
             on_result=None, quiet: bool = False, postfix=None) -> list:
    """``[function(job) for job in jobs]`` in parallel (see the module docstring). ``postfix()``:
    text the progress bar shows after each result (e.g. the best objective so far)."""
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
        elif workers <= 1 or len(jobs) <= 1:
            for index, job in enumerate(jobs):
                done(index, function(job))
        else:
            # spawned, not forked: libgomp (numba's OpenMP layer) is not safe across a fork
            context = multiprocessing.get_context('spawn')
            with ProcessPoolExecutor(max_workers=min(workers, len(jobs)), mp_context=context,
                                     initializer=_one_thread) as pool:
                futures = {pool.submit(function, job): index for index, job in enumerate(jobs)}
                for future in as_completed(futures):
                    done(futures[future], future.result())
    return results


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
