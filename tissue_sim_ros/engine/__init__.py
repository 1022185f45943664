"""The numerics (numpy + numba): mesh, material, force kernels, solver, needle, scene.

Importing any engine module runs this first, which applies the package's numba threading and
vector-width policy (:mod:`tissue_sim_ros._threading`) before numba's first import. Every module
of the package that imports numba lives here. Should numba have been imported already (a script
or module that imports it before the engine), its configuration is read again from the
environment so that the policy still holds for the threads and kernels not yet started.
"""
import sys

from tissue_sim_ros import _threading  # noqa: F401  (must precede the first numba import)

if 'numba' in sys.modules:
    from numba.core import config as _numba_config
    _numba_config.reload_config()
