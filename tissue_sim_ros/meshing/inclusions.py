"""Inclusions (a tumour, a vessel) as tagged element regions, by the generalised winding number.

The winding number of a closed, outward surface at a point is the solid angle its triangles
subtend there over 4 pi (Van Oosterom and Strackee 1983 for each triangle's): 1 inside, 0
outside, whatever the element sizes (Jacobson et al. 2013). The mesher embeds every inclusion's
surface in the tetrahedra (they are meshed together with the organ's), so an element's centroid
lies on one side of each: its tag is the last inclusion that holds it, else the organ's.
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.errors import MeshError

__all__ = ['ORGAN_TAG', 'check_inside', 'element_tags', 'winding_numbers']

#: the organ's own elements; inclusion k (0-based, in the order given) is tagged ORGAN_TAG + 1 + k
ORGAN_TAG = 1


def winding_numbers(vertices, triangles, points, chunk_entries=4_000_000) -> np.ndarray:
    """(p,) the generalised winding number of the surface at each point (module docstring)."""
    points = np.atleast_2d(np.asarray(points, dtype=float))
    corners = np.asarray(vertices, dtype=float)[np.asarray(triangles, dtype=np.int64)]     # (k, 3, 3)
    out = np.zeros(len(points))
    step = max(1, chunk_entries // max(1, len(corners)))
    for start in range(0, len(points), step):
        rel = corners[None, :, :, :] - points[start:start + step, None, None, :]           # (p, k, 3, 3)
        a, b, c = rel[:, :, 0], rel[:, :, 1], rel[:, :, 2]
        la, lb, lc = (np.linalg.norm(x, axis=2) for x in (a, b, c))
        numerator = np.einsum('pki,pki->pk', a, np.cross(b, c))
        denominator = (la * lb * lc + np.einsum('pki,pki->pk', a, b) * lc + np.einsum('pki,pki->pk', b, c) * la
                       + np.einsum('pki,pki->pk', c, a) * lb)
        out[start:start + step] = np.arctan2(numerator, denominator).sum(axis=1) / (2.0 * np.pi)
    return out


def element_tags(points, tetrahedra, inclusions) -> np.ndarray:
    """(m,) each element's tag: ORGAN_TAG, or ORGAN_TAG + 1 + k for inclusion k (a Surface)
    that holds its centroid (later ones win)."""
    centroids = points[tetrahedra].mean(axis=1)
    tags = np.full(len(tetrahedra), ORGAN_TAG, dtype=np.int32)
    for k, surface in enumerate(inclusions):
        lo, hi = surface.vertices.min(axis=0), surface.vertices.max(axis=0)
        near = np.flatnonzero(np.all((centroids >= lo) & (centroids <= hi), axis=1))
        inside = winding_numbers(surface.vertices, surface.triangles, centroids[near]) > 0.5
        tags[near[inside]] = ORGAN_TAG + 1 + k
    return tags


def check_inside(organ, inclusion, name) -> None:
    """Refuse an inclusion that leaves the organ (its vertices' winding numbers in the organ's
    surface), naming it: the mesher would add the part outside to the tissue."""
    outside = winding_numbers(organ.vertices, organ.triangles, inclusion.vertices) < 0.5
    if outside.any():
        point = inclusion.vertices[np.argmax(outside)]
        raise MeshError(f'--inclusion {name}: {int(outside.sum())} of its {len(outside)} vertices lie outside the '
                        f'organ surface (the first at {np.round(point * 1e3, 2).tolist()} mm); an inclusion must '
                        'lie inside it')
