"""Meshes and counts computed by brute force: a unit corner, a regular tetrahedron, face counts
with plain Python sets, area vectors, rotations, and a box's top and bottom nodes."""

from collections import Counter

import numpy as np

UNIT_CORNER = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
# Regular tetrahedron with edge 2 sqrt(2), positively oriented (checked in engine/mesh/test_tetmesh.py).
REGULAR = np.array([[1.0, 1.0, 1.0], [-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, -1.0]])
ONE_TET = np.array([[0, 1, 2, 3]])

#: the box of the box_mesh tests (engine/mesh/conftest.py)
SIZE = (0.03, 0.05, 0.02)
DIVISIONS = (3, 4, 2)
ORIGIN = (0.2, -0.1, 0.05)


def _bottom(mesh):
    return np.flatnonzero(np.isclose(mesh.rest_positions[:, 2], 0.0))


def _top(mesh):
    return np.flatnonzero(np.isclose(mesh.rest_positions[:, 2], mesh.rest_positions[:, 2].max()))


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def face_counts(tetrahedra) -> Counter:
    """How many elements hold each face (as a frozenset of nodes), by brute force."""
    counts = Counter()
    for a, b, c, d in tetrahedra.tolist():
        for face in ((b, c, d), (a, c, d), (a, b, d), (a, b, c)):
            counts[frozenset(face)] += 1
    return counts


def oriented_set(triangles) -> set:
    """Triangles as tuples rotated to start at their smallest node (keeps the orientation)."""
    out = set()
    for t in triangles.tolist():
        k = t.index(min(t))
        out.add(tuple(t[k:] + t[:k]))
    return out


def triangle_area_vectors(positions, triangles) -> np.ndarray:
    p = positions[triangles]
    return 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def cell_widths(coordinates) -> np.ndarray:
    return np.diff(np.unique(coordinates))
