"""Grading: a background sizing field that asks for edge length h near a focus or a planned
needle path and lets it grow to the organ's H away from it.

The target edge length at distance d from the fine zone's core (a point, or a polyline path) is

    s(d) = min(H, h + g max(d - R, 0))

with R the fine zone's radius and g = :data:`GRADIENT` the growth of the edge length per unit
distance: at 0.25 neighbouring elements differ by about 25 % in size (a graded box's growth of
1.3 between neighbouring cells, :mod:`~tissue_sim_ros.engine.mesh.generators`). The field lives
on a box of Kuhn-split hexahedra over the surface's bounding box, fine enough to resolve the
zone (spacing at most R / 2 and h, at most :data:`MAX_DIVISIONS` along an axis); fTetWild
interpolates it linearly in each background tetrahedron (:mod:`.tetwild`).
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.engine.mesh.generators import box_axes, grid_mesh
from tissue_sim_ros.errors import MeshError

__all__ = ['GRADIENT', 'MAX_DIVISIONS', 'distance_to_path', 'read_path', 'sizing_field', 'target_size']

GRADIENT = 0.25
MAX_DIVISIONS = 60


def read_path(path, factor) -> np.ndarray:
    """(k, 3) points of a planned path from a CSV of x, y, z rows (a header line allowed), in
    the surface file's units, times ``factor`` (to metres)."""
    try:
        rows = np.genfromtxt(path, delimiter=',', dtype=float, comments='#')
    except (OSError, ValueError) as exc:
        raise MeshError(f'--along {path}: cannot read it ({exc}); expected CSV rows x, y, z') from exc
    rows = np.atleast_2d(rows)
    rows = rows[~np.isnan(rows).all(axis=1)]
    if rows.ndim != 2 or rows.shape[1] != 3 or len(rows) < 2 or not np.isfinite(rows).all():
        raise MeshError(f'--along {path}: expected at least two CSV rows of three numbers x, y, z, got shape '
                        f'{rows.shape}')
    return rows * factor


def distance_to_path(points, path) -> np.ndarray:
    """(p,) the distance from each point to a polyline (k, 3) (a single point for k = 1)."""
    points = np.atleast_2d(points)
    path = np.atleast_2d(path)
    if len(path) == 1:
        return np.linalg.norm(points - path[0], axis=1)
    best = np.full(len(points), np.inf)
    for a, b in zip(path[:-1], path[1:]):
        ab = b - a
        t = np.clip((points - a) @ ab / max(float(ab @ ab), 1e-300), 0.0, 1.0)
        best = np.minimum(best, np.linalg.norm(points - (a + t[:, None] * ab), axis=1))
    return best


def target_size(distance, fine, coarse, radius):
    """s(d) of the module docstring."""
    return np.minimum(coarse, fine + GRADIENT * np.maximum(np.asarray(distance) - radius, 0.0))


def sizing_field(lower, upper, core, fine, coarse, radius):
    """(points, tetrahedra, target edge length at each point) of the background mesh over the
    box ``lower``-``upper`` (padded by a coarse edge), graded toward ``core`` (a point (3,) or a
    polyline (k, 3))."""
    if not 0 < fine <= coarse:
        raise MeshError(f'--fine-mm = {fine * 1e3:g}: expected a size > 0 and at most --cell-mm ({coarse * 1e3:g})')
    lower = np.asarray(lower, dtype=float) - coarse
    upper = np.asarray(upper, dtype=float) + coarse
    spacing = max(min(radius / 2.0 if radius > 0 else fine, fine * 2.0), float(np.max(upper - lower)) / MAX_DIVISIONS)
    divisions = np.maximum(1, np.ceil((upper - lower) / spacing)).astype(np.int64)
    background = grid_mesh(box_axes(upper - lower, divisions, lower))
    points = np.asarray(background.rest_positions)
    values = target_size(distance_to_path(points, np.atleast_2d(core)), fine, coarse, radius)
    return points, np.asarray(background.tetrahedra, dtype=np.int32), values
