"""tissue_sim_ros: real-time tensor-mass soft-tissue simulation for needle insertion.

The public engine API lives at the top level (``import tissue_sim_ros as ts``); the ROS 2 node
is in :mod:`tissue_sim_ros.ros` and is imported only when used, so the engine runs without ROS.
"""
from tissue_sim_ros import _threading  # noqa: F401  (must precede the first numba import)

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version('tissue_sim_ros')
except PackageNotFoundError:  # running from a source tree that was not installed
    __version__ = '0+unknown'
