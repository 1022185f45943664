"""Numba threading policy, applied before numba is first imported.

We use numba's OpenMP layer (libgomp). Its idle workers spin between parallel regions; on a
busy 2-core machine a fully spinning pool (OMP_WAIT_POLICY=active) steals the core the other
thread needs, while a sleeping pool (passive) pays ~0.1 ms to wake at every parallel region, a
6x slowdown of a 1e3-tetrahedron step. A bounded spin, GOMP_SPINCOUNT=10000 (microseconds, then
sleep), covers the gap between the back-to-back kernels of one step and sleeps otherwise.
Measured with `tissue-sim bench` (tet-steps/s at 1e3 / 1e5 tetrahedra, 2 cores):
  unloaded:             passive 7.6e6 / 6.3e7, spin 1e4 4.6e7 / 8.1e7, active 4.5e7 / 8.9e7
  one busy process:     passive 2.8e7 / 4.8e7, spin 1e4 1.0e7 / 3.6e7, active 1.7e7 / 3.5e7
These are defaults only: a user who exports NUMBA_THREADING_LAYER, OMP_WAIT_POLICY or
GOMP_SPINCOUNT keeps their choice (OMP_WAIT_POLICY=passive is the better pick on a machine that is
always oversubscribed).
"""
import os

os.environ.setdefault('NUMBA_THREADING_LAYER', 'omp')
if 'OMP_WAIT_POLICY' not in os.environ:
    os.environ.setdefault('GOMP_SPINCOUNT', '10000')
