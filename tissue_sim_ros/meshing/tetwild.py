"""fTetWild (Hu et al. 2020, "Fast Tetrahedral Meshing in the Wild") through the pytetwild wheel.

fTetWild fills the inside of a triangle soup with tetrahedra whose boundary lies within an
envelope ``epsilon`` (relative to the bounding-box diagonal) of the input, whatever the input's
defects, then optimises the elements' AMIPS energy toward the ideal edge length. Its ideal edge
length is the ``--cell-mm`` of ``tissue-sim mesh``; a background sizing field (a tetrahedral
mesh with a target edge length at each node, interpolated linearly) grades it.

pytetwild's package import also loads PyVista for an optional accessor; the compiled extension
needs only numpy, so it is loaded here on its own (:func:`_extension`) and PyVista is not a
dependency. fTetWild writes a file of its own (``_tracked_surface.stl``) into the working
directory whatever its options; the call runs in a temporary one (:func:`_scratch_directory`).
pytetwild is MPL-2.0 (fTetWild's licence): a file-level copyleft that an Apache-2.0
package may depend on unchanged.
"""
from __future__ import annotations

import contextlib
import importlib.machinery
import importlib.util
import os
import tempfile

import numpy as np

from tissue_sim_ros.errors import MeshError

__all__ = ['INSTALL_HINT', 'tetrahedralize']

INSTALL_HINT = ('the mesher is not installed: pip install pytetwild (the version pinned in the '
                "package's requirements.txt; ./run_tests.sh and scripts/bootstrap.sh install it)")
_MODULE = 'PyfTetWildWrapper'
_loaded = None


def _extension():
    """pytetwild's compiled module, loaded without the package's __init__ (module docstring)."""
    global _loaded
    if _loaded is None:
        spec = importlib.util.find_spec('pytetwild')
        if spec is None or not spec.submodule_search_locations:
            raise MeshError(INSTALL_HINT)
        folder = spec.submodule_search_locations[0]
        found = [f for f in os.listdir(folder) if f.startswith(_MODULE) and f.endswith(('.so', '.pyd'))]
        if not found:
            raise MeshError(f'{INSTALL_HINT} (pytetwild at {folder} has no compiled {_MODULE})')
        loader = importlib.machinery.ExtensionFileLoader(_MODULE, os.path.join(folder, found[0]))
        module = importlib.util.module_from_spec(importlib.util.spec_from_loader(_MODULE, loader))
        loader.exec_module(module)
        _loaded = module
    return _loaded


@contextlib.contextmanager
def _scratch_directory():
    """The working directory a temporary one for the block (the process's: meshing is a command's
    foreground work, not a node's)."""
    previous = os.getcwd()
    with tempfile.TemporaryDirectory(prefix='tetwild_') as scratch:
        os.chdir(scratch)
        try:
            yield
        finally:
            os.chdir(previous)


def tetrahedralize(vertices, triangles, edge_length, *, epsilon=1e-3, sizing=None, threads=0,
                   iterations=80, stop_energy=10.0, coarsen=False):
    """(points (n, 3), tetrahedra (m, 4), positively oriented) of the volume the triangles bound.

    ``edge_length``: the ideal edge length (the input's units); ``epsilon``: the envelope,
    relative to the bounding-box diagonal; ``sizing``: None or (points, tetrahedra, target edge
    length at each point) of a background mesh, which fTetWild applies in its optimisation
    stage; ``threads``: 0 for all cores; ``iterations`` and ``stop_energy``: the optimisation's
    bounds (fTetWild's defaults); ``coarsen``: fTetWild's coarsening pass, fewer elements (a
    quarter fewer on the organ example) with somewhat lower quality.
    """
    if sizing is None:
        background = (np.empty((0, 3)), np.empty((0, 4), dtype=np.int32), np.empty(0))
    else:
        background = (np.array(sizing[0], dtype=np.float64, order='C'),     # writeable copies: the
                      np.array(sizing[1], dtype=np.int32, order='C'),       # binding refuses read-only ones
                      np.array(sizing[2], dtype=np.float64, order='C').ravel())
    with _scratch_directory():
        points, tetrahedra = _extension().tetrahedralize_mesh(
            np.array(vertices, dtype=np.float64, order='C'), np.array(triangles, dtype=np.uint32, order='C'),
            True, False, 0.05, float(edge_length), float(epsilon), float(stop_energy), bool(coarsen), int(threads),
            int(iterations), 6, True, False, False, *background)
    points = np.asarray(points, dtype=np.float64)
    tetrahedra = np.asarray(tetrahedra, dtype=np.int64)
    if len(tetrahedra) == 0:
        raise MeshError('the mesher made no tetrahedra: the surface encloses no volume at this edge length')
    corners = points[tetrahedra]
    signed = np.einsum('ij,ij->i', np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                       corners[:, 3] - corners[:, 0])
    flip = signed < 0.0                      # fTetWild's ordering is the opposite of the engine's
    tetrahedra[flip] = tetrahedra[flip][:, [0, 2, 1, 3]]
    return points, tetrahedra
