"""Benchmark of ``compare`` on a Dask cluster against this process and a process pool.

``tissue-sim bench dask [--out DIR] [--workers 2]``

The study: the two-layer phantom (:func:`~tissue_sim_ros.analysis.synthetic_study.phantom_scene`,
the 'bench' mesh, 4356 tetrahedra), two repeats at each of 1, 2 and 3 mm/s (three simulations of
31-55 s each). ``compare`` of its truth scene runs three ways, each into its own directory (no
simulation reused): in this process (``--jobs 1``), on a process pool of ``--workers``
processes, and against a local ``dask scheduler`` with ``--workers`` ``dask worker`` processes of
one thread each, started here as a user would start them and stopped at the end; the Dask run
twice, the second on the same workers (warm). Printed: each run's wall time and NRMSE (they must
agree) and each simulation's own seconds (the engine's run, the scene built and the kernels
loaded before it): fresh workers that compiled the kernels would take the compile's minutes
more than warm ones.
"""
from __future__ import annotations

import os
import socket
import subprocess
import sys
import time
from pathlib import Path

__all__ = ['main']


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(('127.0.0.1', 0))
        return sock.getsockname()[1]


def _start_cluster(workers: int, log_dir: Path):
    """A ``dask scheduler`` and ``workers`` one-thread ``dask worker`` processes; (address, processes)."""
    port = _free_port()
    address = f'tcp://127.0.0.1:{port}'
    dask = [sys.executable, '-m', 'distributed.cli.dask_scheduler']
    processes = [subprocess.Popen(dask + ['--port', str(port), '--no-dashboard'], stdout=subprocess.DEVNULL,
                                  stderr=open(log_dir / 'scheduler.log', 'w'))]
    for k in range(workers):
        processes.append(subprocess.Popen([sys.executable, '-m', 'distributed.cli.dask_worker', address,
                                           '--nthreads', '1', '--nworkers', '1', '--no-dashboard'],
                                          stdout=subprocess.DEVNULL, stderr=open(log_dir / f'worker{k}.log', 'w')))
    from distributed import Client
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            with Client(address, timeout=5) as client:
                if len(client.scheduler_info()['workers']) == workers:
                    return address, processes
        except OSError:
            pass
        time.sleep(1)
    _stop(processes)
    raise RuntimeError(f'the local Dask cluster at {address} did not start within 120 s (logs in {log_dir})')


def _stop(processes) -> None:
    for process in reversed(processes):
        process.terminate()
    for process in processes:
        try:
            process.wait(timeout=30)
        except subprocess.TimeoutExpired:
            process.kill()


def main(*, out='out/bench_dask', workers=2) -> dict:
    """``tissue-sim bench dask``: run the benchmark, print its figures."""
    import yaml

    from tissue_sim_ros.analysis.compare import compare
    from tissue_sim_ros.analysis.synthetic_study import phantom_scene, write_layered_study
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scene = out / 'truth.yaml'
    scene.write_text(yaml.safe_dump(phantom_scene(2, 'bench')))
    spec = write_layered_study(out / 'data', [], [1.0, 2.0, 3.0], scene_file=scene, repeats=2, workers=workers)
    runs = {}

    def run(name, **options):
        target = out / name
        if target.exists():
            import shutil
            shutil.rmtree(target)
        t0 = time.perf_counter()
        report = compare.main(data_spec=spec, scene_file=scene, out=target, stream=open(os.devnull, 'w'), **options)
        runs[name] = {'wall_s': time.perf_counter() - t0, 'nrmse': report['summary']['nrmse_mean'],
                      'simulation_wall_s': [r['wall_s'] for r in _results(target)]}
        print(f"{name:>22}: {runs[name]['wall_s']:6.1f} s, NRMSE {runs[name]['nrmse']:.5f}, simulations "
              + ', '.join(f'{w:.1f}' for w in runs[name]['simulation_wall_s']) + ' s')
    run('in this process', workers=1)
    run('process pool', workers=workers)
    address, processes = _start_cluster(workers, out)
    try:
        run('dask (fresh workers)', scheduler=address)
        run('dask (warm workers)', scheduler=address)
    finally:
        _stop(processes)
    return runs


def _results(directory: Path) -> list[dict]:
    import numpy as np
    return [{'wall_s': float(np.load(path)['wall_s'])} for path in sorted((directory / 'simulations').glob('*.npz'))]


if __name__ == '__main__':
    sys.exit('this benchmark runs as: tissue-sim bench dask (tissue-sim bench --help)')
