"""tissue_sim_ros: real-time tensor-mass soft-tissue simulation for needle insertion.

The public engine API lives at the top level (``import tissue_sim_ros as ts``); its names are
loaded on first use (PEP 562 module ``__getattr__``), so that importing a part that needs no
numerics (``tissue_sim_ros.io`` writing or reading a log, ``__version__``) does not load numba
and the kernels. The ROS 2 node is in :mod:`tissue_sim_ros.ros` and is imported only when used,
so the engine runs without ROS. The threading policy that must precede numba's first import is
applied by :mod:`tissue_sim_ros.engine`.
"""
from importlib import import_module

#: public name -> the engine module that defines it
_ENGINE_NAMES = {
    'Material': 'model.material', 'MaterialError': 'model.material', 'MeanRatioLaw': 'model.material',
    'Viscosity': 'model.material',
    'MeshError': 'mesh.tetmesh', 'TetMesh': 'mesh.tetmesh', 'make_mesh': 'mesh.tetmesh',
    'mean_ratio': 'mesh.tetmesh',
    'box_mesh': 'mesh.generators', 'graded_box_mesh': 'mesh.generators',
    'load_mesh': 'mesh.files', 'save_mesh': 'mesh.files',
    'TensorMassModel': 'model.tensor_mass',
    'Simulation': 'solver.explicit', 'SimulationDiverged': 'solver.explicit',
}

__all__ = [*_ENGINE_NAMES, '__version__']


def _package_version() -> str:
    from importlib.metadata import PackageNotFoundError, version
    try:
        return version('tissue_sim_ros')
    except PackageNotFoundError:  # running from a source tree that was not installed
        return '0+unknown'


def __getattr__(name: str):
    """Load an engine name (or the version) on first use and keep it as a module attribute."""
    if name == '__version__':
        value = _package_version()
    elif name in _ENGINE_NAMES:
        value = getattr(import_module(f'tissue_sim_ros.engine.{_ENGINE_NAMES[name]}'), name)
    else:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
