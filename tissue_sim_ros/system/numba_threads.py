"""Numba threading and vector-width policy, applied before numba is first imported.

We use numba's OpenMP layer (libgomp). Its idle workers spin between parallel regions; on a
busy 2-core machine a fully spinning pool (OMP_WAIT_POLICY=active) steals the core the other
thread needs, while a sleeping pool (passive) pays ~0.1 ms to wake at every parallel region, a
6x slowdown of a 1e3-tetrahedron step. A bounded spin, GOMP_SPINCOUNT=10000 (microseconds, then
sleep), covers the gap between the back-to-back kernels of one step and sleeps otherwise.
Figures: docs/performance.md.

On AVX-512 machines LLVM prefers 256-bit vectors by default (the 'prefer-256-bit' tuning of
Skylake-X and later, against the clock drop of older parts); the element pass's lane loops are
long straight-line arithmetic, and 512-bit vectors run the full model's about 8 % faster (the
linear model's no slower). So on such a host numba gets the host's own features with
'-prefer-256-bit' appended.

These are defaults only: a user who exports NUMBA_THREADING_LAYER, OMP_WAIT_POLICY,
GOMP_SPINCOUNT or NUMBA_CPU_FEATURES keeps their choice (OMP_WAIT_POLICY=passive is the better
pick on a machine that is always oversubscribed).

numba's cache of compiled kernels goes to a per-user directory, $XDG_CACHE_HOME/tissue_sim_ros/numba
(default ~/.cache/tissue_sim_ros/numba), one known place instead of __pycache__ beside the installed
sources, which may be read-only on a ROS install. Under it, one directory per version of the engine's
sources (user_cache.sources_key): numba checks only the stamp of the file that defines a kernel, so
a kernel whose helpers live in another file (kernels.py's element pass and simd_lanes.py) would load
its old machine code after a change to that file alone. A user's own NUMBA_CACHE_DIR keeps its
meaning, and that check only.
The variable is process-wide: other numba code in the same process caches there too (under its own
source directory's name, as numba always does).
"""
import os

os.environ.setdefault('NUMBA_THREADING_LAYER', 'omp')
if 'OMP_WAIT_POLICY' not in os.environ:
    os.environ.setdefault('GOMP_SPINCOUNT', '10000')

if 'NUMBA_CPU_FEATURES' not in os.environ and 'NUMBA_CPU_NAME' not in os.environ:
    import llvmlite.binding

    _features = llvmlite.binding.get_host_cpu_features()
    if _features.get('avx512f'):
        os.environ['NUMBA_CPU_FEATURES'] = _features.flatten() + ',-prefer-256-bit'


from tissue_sim_ros.system.user_cache import sources_key, user_cache_dir  # noqa: E402 (stdlib only, no numba)

if 'NUMBA_CACHE_DIR' not in os.environ and user_cache_dir('numba') is not None:
    os.environ['NUMBA_CACHE_DIR'] = os.path.join(
        user_cache_dir('numba'), sources_key(os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), 'engine')))
