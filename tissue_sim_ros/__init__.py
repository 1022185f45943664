"""tissue_sim_ros: real-time tensor-mass soft-tissue simulation for needle insertion.

The public engine API lives at the top level (``import tissue_sim_ros as ts``); the ROS 2 node
is in :mod:`tissue_sim_ros.ros` and is imported only when used, so the engine runs without ROS.
"""
from tissue_sim_ros import _threading  # noqa: F401  (must precede the first numba import)

from importlib.metadata import PackageNotFoundError, version as _version

from tissue_sim_ros.engine.material import Material, MaterialError, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.mesh import (MeshError, TetMesh, box_mesh, graded_box_mesh, load_mesh,
                                        make_mesh, mean_ratio, save_mesh)
from tissue_sim_ros.engine.model import TensorMassModel
from tissue_sim_ros.engine.solver import Simulation, SimulationDiverged

try:
    __version__ = _version('tissue_sim_ros')
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = '0+unknown'

__all__ = ['Material', 'MaterialError', 'MeanRatioLaw', 'Viscosity', 'MeshError', 'TetMesh', 'box_mesh', 'graded_box_mesh',
           'load_mesh', 'make_mesh', 'mean_ratio', 'save_mesh', 'TensorMassModel', 'Simulation',
           'SimulationDiverged', '__version__']
