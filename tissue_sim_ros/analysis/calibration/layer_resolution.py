"""How many of the mesh's elements a proposed layer is thick along the needle's path.

A layer a few elements thick shares its tip's load with its neighbours: the axial force then
reads a blend of their moduli, and no calibration on that mesh tells them apart. Measured on the
three-layer bench phantom (docs/performance.md), a 6 mm middle layer: the calibration's
Jacobian columns for the middle and core moduli have cosine 0.96 with elements of 4.1 mm mean
edge along the path (1.5 across the layer; 0.91 at 3.8 mm, 1.6 across), 0.76 at 2.2 mm (2.8
across) and 0.74 at 1.8 mm (3.4 across). So
``propose`` reports each layer's thickness in elements (its thickness over the mean edge length
of the elements nearest the needle's path) and warns under ``MIN_ELEMENTS_ACROSS``.

Thickness: from the layer's boundary (the surface for the outer one) to the next layer's, the
last one to the deepest travel of the data. The elements along the path: the ``PATH_SHARE`` of
the mesh's elements whose centroids lie nearest the needle's line (at least ``PATH_MIN``).
"""
from __future__ import annotations

import numpy as np

__all__ = ['MIN_ELEMENTS_ACROSS', 'PATH_MIN', 'PATH_SHARE', 'elements_across', 'path_edge_length',
           'resolution_warnings']

#: a layer thinner than this many elements along the path is warned about
MIN_ELEMENTS_ACROSS = 3.0
#: the elements along the path: this share of the mesh's, nearest the needle's line, and at least PATH_MIN
PATH_SHARE, PATH_MIN = 0.05, 10

_EDGES = ((0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3))


def path_edge_length(rest_positions, tetrahedra, start, axis) -> float:
    """The mean edge length [m] of the elements whose centroids lie nearest the line through
    ``start`` along ``axis`` (module docstring)."""
    points = np.asarray(rest_positions, dtype=float)[np.asarray(tetrahedra)]
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    offset = points.mean(axis=1) - np.asarray(start, dtype=float)
    distance = np.linalg.norm(offset - np.outer(offset @ axis, axis), axis=1)
    count = min(len(points), max(PATH_MIN, int(PATH_SHARE * len(points))))
    nearest = np.argsort(distance)[:count]
    edges = [np.linalg.norm(points[nearest, a] - points[nearest, b], axis=1) for a, b in _EDGES]
    return float(np.mean(edges))


def elements_across(boundary_depths_m, deepest_m: float, edge_m: float) -> list[dict]:
    """Per layer: ``thickness_m`` (its boundary depth below the surface, 0 for the outer layer,
    to the next one's; the last to ``deepest_m``) and ``elements_across`` (over ``edge_m``)."""
    tops = [0.0] + [float(d) for d in boundary_depths_m]
    bottoms = tops[1:] + [max(float(deepest_m), tops[-1])]
    return [{'thickness_m': bottom - top, 'elements_across': (bottom - top) / edge_m if edge_m > 0 else float('inf')}
            for top, bottom in zip(tops, bottoms)]


def resolution_warnings(rows: list[dict], edge_m: float) -> list[str]:
    """A warning per layer under MIN_ELEMENTS_ACROSS (with one layer: none, there is nothing to blend)."""
    return [f"layer {k} is {row['thickness_m'] * 1e3:.1f} mm thick, {row['elements_across']:.1f} elements of "
            f"{edge_m * 1e3:.2f} mm along the needle: its modulus and its neighbours' act alike on the force "
            f"(fewer than {MIN_ELEMENTS_ACROSS:g}); refine the mesh along the path before calibrating them apart"
            for k, row in enumerate(rows) if len(rows) > 1 and row['elements_across'] < MIN_ELEMENTS_ACROSS - 1e-9]
