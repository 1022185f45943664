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
"""
from __future__ import annotations

import resource
import tempfile
import time
from pathlib import Path

import numpy as np

__all__ = ['bench_replay', 'bench_compare', 'main']


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


if __name__ == '__main__':
    import sys
    sys.exit('this benchmark runs as: tissue-sim bench study (tissue-sim bench --help)')
