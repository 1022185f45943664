"""Numba threading policy, applied before numba is first imported.

On a busy 2-core machine numba's OpenMP workers spin-wait between parallel regions and can
slow every kernel call by 10x or more when another process (the ROS executor, a recorder)
wants the core. We pick the OpenMP layer (race-free per-thread buffers, tested) with a
*passive* wait policy: idle workers sleep instead of spinning. Both are defaults only; a user
who exports NUMBA_THREADING_LAYER or OMP_WAIT_POLICY keeps their choice.
"""
import os

os.environ.setdefault('NUMBA_THREADING_LAYER', 'omp')
os.environ.setdefault('OMP_WAIT_POLICY', 'passive')
