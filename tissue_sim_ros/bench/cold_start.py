"""Cold-start benchmark: wall time from a fresh install (an empty numba cache) to the first step.

    tissue-sim bench cold-start [--scene FILE] [--modes parallel one-process warm]

Each mode runs a new Python process that loads a scene (default: the packaged one) and takes one
step, timed from the process's start as a user sees it:

* parallel: an empty cache, compiling as the package does on a first start (a second process
  compiles the needle, solver and linear kernels beside the scene's model, engine.compiled.cache);
* one-process: an empty cache, everything compiled in the one process (the second process off);
* warm: the cache the parallel run filled, as every later start.

It prints the seconds per mode and the compile lines the process printed (the kernels compiled
in it and their durations). Figures: docs/performance.md.

The kernels are not compiled ahead of time (numba.pycc): pycc is pending deprecation, exports
module-level functions with one explicit signature each (the element pass is a closure per model),
needs a C compiler where the package is built, and builds generic x86-64 code by default (without
AVX2/FMA, or the host features system.numba_threads gives numba), so shipped kernels would run
slower than the ones a first start compiles once for its host.
"""
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tissue_sim_ros.system.child_env import importing_from
from tissue_sim_ros.system.paths import SOURCE_ROOT

_CHILD = '''
import sys
from tissue_sim_ros.engine.scene.scene import Scene
scene = Scene.from_file(sys.argv[1] or None)
position, orientation = scene.needle_pose
scene.advance(scene.dt, position, orientation)
'''
MODES = ('parallel', 'one-process', 'warm')


def time_first_step(cache_dir, scene_file=None, parallel=True):
    """Seconds from starting a Python process to the scene's first step, with numba's cache in
    ``cache_dir``; and the compile lines the process printed on stderr."""
    env = importing_from(SOURCE_ROOT)
    env['NUMBA_CACHE_DIR'] = str(cache_dir)
    env['TISSUE_SIM_ROS_COMPILE_PROCESSES'] = '1' if parallel else '0'
    start = time.perf_counter()
    result = subprocess.run([sys.executable, '-c', _CHILD, str(scene_file or '')], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - start
    if result.returncode != 0:
        raise RuntimeError(f'the scene process failed (status {result.returncode}): '
                           f'{result.stderr.strip().splitlines()[-1:]}')
    lines = [line for line in result.stderr.splitlines() if line.startswith('tissue_sim_ros:')]
    return elapsed, lines


def run(scene_file=None, modes=MODES, out=sys.stdout):
    """Time the given modes (see the module docstring); returns {mode: seconds}."""
    figures = {}
    with tempfile.TemporaryDirectory(prefix='tissue_sim_cold_start_') as scratch:
        parallel_cache = Path(scratch) / 'parallel'
        for mode in modes:
            if mode == 'warm' and not parallel_cache.exists():
                time_first_step(parallel_cache, scene_file)          # fill it first
            cache = Path(scratch) / 'one-process' if mode == 'one-process' else parallel_cache
            seconds, lines = time_first_step(cache, scene_file, parallel=mode != 'one-process')
            figures[mode] = seconds
            print(f'{mode:12s} {seconds:6.1f} s to the first step', file=out, flush=True)
            for line in lines:
                if 'compiled ' in line or 'second compile process' in line:
                    print(f'    {line}', file=out)
    return figures


def main(*, scene=None, modes=MODES):
    """``tissue-sim bench cold-start``: run each mode, print the figures."""
    return run(scene, list(modes))


if __name__ == '__main__':
    import sys
    sys.exit('this benchmark runs as: tissue-sim bench cold-start (tissue-sim bench --help)')
