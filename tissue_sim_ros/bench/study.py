"""Benchmark of replay and compare, printed, not asserted::

    tissue-sim bench study [--replay-s 60] [--trials 30] [--samples 5000]

- replay: the node runs the default scene for ``--replay-s`` seconds under node-bench's
  scripted insertions (recording on); ``tissue-sim replay`` then runs the log again: its
  real-time factor, the largest difference from the recorded wrenches, and the memory it took;
- compare: ``--trials`` synthetic load-cell files of ``--samples`` samples each (three speeds,
  1, 2 and 3 mm/s, to 25 mm, a 2 s pause, back; 5 mN noise, jittery sampling), made from the
  default scene's own insertions, compared with the default scene: the wall time, the
  simulations it ran, and the memory.

Memory is the peak resident set of this process and, separately, of its largest child (the
node, the simulation workers), from getrusage.

``tissue-sim bench dask [--out DIR] [--workers 2]`` (:func:`dask_main`): ``compare`` on a Dask
cluster against this process and a process pool. The study: the two-layer phantom (:func:`~tissue_sim_ros.analysis.synthetic_study.phantom_scene`,
the 'bench' mesh, 4320 tetrahedra), two repeats at each of 1, 2 and 3 mm/s (three simulations of
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
import resource
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ['bench_replay', 'bench_compare', 'dask_main', 'main']


def _peak_mb() -> tuple[float, float]:
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024.0
    return own, children


def bench_replay(duration_s: float, directory: Path) -> dict:
    from tissue_sim_ros.analysis import replay
    from tissue_sim_ros.bench import node_bench
    print(f'recording {duration_s:g} s of the node on the default scene ...', flush=True)
    bench = node_bench.measure(duration_s=duration_s, log_dir=directory / 'node')
    wall0 = time.perf_counter()
    summary = replay.main(bench['mcap'], directory / 'replay')
    own, children = _peak_mb()
    return {'log_s': duration_s, 'ticks': summary['ticks'], 'replay_wall_s': time.perf_counter() - wall0,
            'real_time_factor': summary['real_time_factor'], 'max_abs_difference_n': summary['max_abs_difference_n'],
            'peak_rss_mb': own, 'peak_child_rss_mb': children}


def _synthetic_study(directory: Path, trials: int, samples: int) -> Path:
    """``trials`` CSV files at three speeds from the default scene's insertions (see the module
    docstring); the data description's path."""
    from tissue_sim_ros.analysis.insertion import run_insertion
    from tissue_sim_ros.engine.scene.scene import Scene
    rng = np.random.default_rng(7)
    directory.mkdir(parents=True, exist_ok=True)
    speeds = (0.001, 0.002, 0.003)
    for k, speed in enumerate(speeds):
        run = run_insertion(Scene.from_file(), speed, 0.025 + 0.009, hold_s=2.0, tick=0.01)
        repeats = [r for r in range(trials) if r % len(speeds) == k]
        for repeat in repeats:
            times = np.cumsum(rng.uniform(0.9, 1.1, samples)) * run.time[-1] / samples
            force = np.interp(times, run.time, run.axial_force) + rng.normal(0.0, 0.005, samples)
            travel = np.interp(times, run.time, run.travel)
            name = f'sample_{speed * 1e3:.1f}'.replace('.', '_') + f'_{repeat + 1}.csv'
            np.savetxt(directory / name, np.column_stack([np.round(times * 1e6), force * 1e3, travel * 1e3]),
                       delimiter=',', header='time,fz,pz', comments='', fmt=['%d', '%.4f', '%.5f'])
    spec = directory / 'study.yaml'
    spec.write_text("files: ['sample_*.csv']\ntime: {column: time, unit: us}\n"
                    'force: {column: fz, unit: mN}\nposition: {column: pz, unit: mm}\n'
                    "file_name: {pattern: 'sample_(?P<speed>[0-9_]+)_(?P<repeat>[0-9]+)', speed_unit: mm/s}\n")
    return spec


def bench_compare(trials: int, samples: int, directory: Path) -> dict:
    from tissue_sim_ros.analysis.compare import compare
    print(f'writing {trials} synthetic trials of {samples} samples ...', flush=True)
    spec = _synthetic_study(directory / 'data', trials, samples)
    wall0 = time.perf_counter()
    report = compare.main(data_spec=spec, out=directory / 'compare')
    own, children = _peak_mb()
    return {'trials': trials, 'samples': samples, 'wall_s': time.perf_counter() - wall0,
            'simulations': report['summary']['simulations'], 'nrmse_mean': report['summary']['nrmse_mean'],
            'noise_floor_nrmse': report['summary']['noise_floor_nrmse'],
            'peak_rss_mb': own, 'peak_child_rss_mb': children}


def main(*, replay_s=60.0, trials=30, samples=5000, skip=None) -> dict:
    """``tissue-sim bench study``: run both parts (or one), print their figures."""
    results = {}
    with tempfile.TemporaryDirectory(prefix='study_bench_') as tmp:
        if skip != 'compare':
            results['compare'] = c = bench_compare(trials, samples, Path(tmp))
            print(f"compare: {c['trials']} trials x {c['samples']} samples, {c['simulations']} simulations, "
                  f"{c['wall_s']:.1f} s wall; model NRMSE {c['nrmse_mean']:.4f}, noise floor "
                  f"{c['noise_floor_nrmse']:.4f}; peak memory {c['peak_rss_mb']:.0f} MB here, "
                  f"{c['peak_child_rss_mb']:.0f} MB in the largest worker")
        if skip != 'replay':
            results['replay'] = r = bench_replay(replay_s, Path(tmp))
            print(f"replay: a {r['log_s']:g} s node log, {r['ticks']} ticks in {r['replay_wall_s']:.1f} s "
                  f"(real-time factor {r['real_time_factor']:.1f}), largest difference "
                  f"{r['max_abs_difference_n']:.3g} N; peak memory {r['peak_rss_mb']:.0f} MB")
    return results


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
        except OSError:              # the scheduler not listening yet: asked again below
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


def dask_main(*, out='out/bench_dask', workers=2) -> dict:
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
    sys.exit('this benchmark runs as: tissue-sim bench study or dask (tissue-sim bench --help)')
