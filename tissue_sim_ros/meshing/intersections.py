"""Where a triangle surface crosses itself: pairs of triangles, sharing no vertex, one of whose
edges passes through the other (the non-coplanar crossings; Moeller and Trumbore 1997's
segment-triangle test on every edge of both).

Candidates are the pairs whose centroids lie closer than the two largest circumradii (a
k-d tree's pair query), so the work grows with the surface, not its square. Pairs that share a
vertex are not tested (neighbours always touch there), nor coplanar overlaps: a surface that
folds back through a shared vertex or lies on itself is missed, one that passes through itself
is found.
"""
from __future__ import annotations

import numpy as np

__all__ = ['self_intersections']


def _segments_cross(p, q, a, b, c):
    """(k,) whether segment p-q crosses triangle a-b-c (open ends, all (k, 3))."""
    direction = q - p
    e1, e2 = b - a, c - a
    h = np.cross(direction, e2)
    det = np.einsum('ij,ij->i', e1, h)
    scale = np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(direction, axis=1)
    usable = np.abs(det) > 1e-12 * scale
    inv = np.where(usable, 1.0 / np.where(usable, det, 1.0), 0.0)
    s = p - a
    u = np.einsum('ij,ij->i', s, h) * inv
    qv = np.cross(s, e1)
    v = np.einsum('ij,ij->i', direction, qv) * inv
    t = np.einsum('ij,ij->i', e2, qv) * inv
    eps = 1e-9
    return usable & (u >= -eps) & (v >= -eps) & (u + v <= 1 + eps) & (t > eps) & (t < 1 - eps)


def self_intersections(vertices, triangles, chunk=200_000) -> np.ndarray:
    """(p, 2) index pairs of triangles that cross each other (module docstring); (0, 2): none."""
    from scipy.spatial import cKDTree
    vertices = np.asarray(vertices, dtype=float)
    triangles = np.asarray(triangles, dtype=np.int64)
    corners = vertices[triangles]
    centroids = corners.mean(axis=1)
    radius = np.linalg.norm(corners - centroids[:, None], axis=2).max()
    pairs = cKDTree(centroids).query_pairs(2.0 * radius, output_type='ndarray')
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    shared = (triangles[pairs[:, 0], :, None] == triangles[pairs[:, 1], None, :]).any(axis=(1, 2))
    pairs = pairs[~shared]
    found = []
    for start in range(0, len(pairs), chunk):
        part = pairs[start:start + chunk]
        first, second = corners[part[:, 0]], corners[part[:, 1]]
        crossing = np.zeros(len(part), dtype=bool)
        for one, other in ((first, second), (second, first)):
            for i, j in ((0, 1), (1, 2), (2, 0)):
                crossing |= _segments_cross(one[:, i], one[:, j], other[:, 0], other[:, 1], other[:, 2])
        found.append(part[crossing])
    return np.concatenate(found) if found else np.zeros((0, 2), dtype=np.int64)
