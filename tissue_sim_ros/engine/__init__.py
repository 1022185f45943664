"""The numerics (numpy + numba): no ROS, no file format beyond meshio.

Sub-packages, bottom up:

- :mod:`~tissue_sim_ros.engine.mesh`: tetrahedral meshes, generators, files, region selectors;
- :mod:`~tissue_sim_ros.engine.model`: materials and the tensor-mass force kernels;
- :mod:`~tissue_sim_ros.engine.compiled`: the compile cache, warm-up and the compiled substeps;
- :mod:`~tissue_sim_ros.engine.solver`: explicit and implicit time integration;
- :mod:`~tissue_sim_ros.engine.needle`: the needle against the tissue;
- :mod:`~tissue_sim_ros.engine.scene`: a scene's keys -> a ready-to-run :class:`Scene`.

Modules here, above them all:

- :mod:`~tissue_sim_ros.engine.warm_up`: the needle's kernels compiled once per process;
- :mod:`~tissue_sim_ros.engine.driver`: the one driver every caller advances (health policy);
- :mod:`~tissue_sim_ros.engine.prediction`: a candidate path simulated from a copy of the state;
- :mod:`~tissue_sim_ros.engine.ladder`, :mod:`~tissue_sim_ros.engine.ladder_probe`: cheaper
  settings when the node cannot keep real time, and their errors measured on the scene.

Importing any engine module runs this first, which applies the package's numba threading and
vector-width policy (:mod:`tissue_sim_ros.system.numba_threads`) before numba's first import.
Every module of the package that imports numba lives here. Should numba have been imported
already, its configuration is read again from the environment so that the policy still holds
for the threads and kernels not yet started.
"""
import sys

from tissue_sim_ros.system import numba_threads  # noqa: F401  (must precede the first numba import)

if 'numba' in sys.modules:
    from numba.core import config as _numba_config
    _numba_config.reload_config()

__all__ = ['compiled', 'driver', 'ladder', 'ladder_probe', 'mesh', 'model', 'needle', 'prediction',
           'scene', 'solver', 'warm_up']
