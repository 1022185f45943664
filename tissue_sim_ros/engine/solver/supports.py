"""Supports where anatomy has them: held nodes, elastic foundations, gravity, and the check that
they stop rigid motion.

Elastic foundation (Winkler). A surface patch resting on neighbouring organs is held by a
pressure proportional to its displacement: p = -(k_n (n . u) n + k_t (u - (n . u) n)) per unit
area, k_n and k_t the normal and tangential stiffness per area [N/m^3]. Lumped on the nodes (each
triangle's area shared equally by its three nodes, with its own normal), node i takes the force
-K_i u_i with the symmetric K_i = sum over its patch triangles of A/3 (k_n n n^T + k_t (I - n
n^T)). The solvers add it in their force evaluation (:func:`add_support_forces`; the explicit
node update adds the same sum in its own loop). Linear in u: the foundation stands for tissue
that deforms little under a needle (SOFA's RestShapeSpringsForceField, FEBio's spring-attached
surfaces work the same way).

Rigid motion. The supports restrain the six rigid-body modes r_j (three translations, three
rotations about the centroid) if the 6 x 6 matrix R^T K_s R is positive definite, K_s the
foundations' stiffness and a large stiffness at every held node (:func:`unrestrained_modes`):
fewer than three non-collinear held nodes and no foundation fail it, and so does a flat patch on
normal springs alone (it can slide).
"""
from __future__ import annotations

import numpy as np

__all__ = ['SIX', 'add_support_forces', 'foundation', 'support_energy', 'unrestrained_modes']

#: the order of a node's symmetric 3 x 3 stiffness as 6 numbers: xx, yy, zz, xy, xz, yz
SIX = ((0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2))


def foundation(rest_positions, surface_triangles, selected, normal, tangential):
    """(nodes (r,), stiffness (r, 6)) of one foundation: the surface triangles whose three nodes
    are ``selected`` (an (n,) mask), k_n = ``normal``, k_t = ``tangential`` [N/m^3]."""
    triangles = np.asarray(surface_triangles)[np.all(np.asarray(selected)[surface_triangles], axis=1)]
    corners = np.asarray(rest_positions)[triangles]
    cross = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    doubled = np.linalg.norm(cross, axis=1)
    n = cross / np.where(doubled > 0, doubled, 1.0)[:, None]
    share = doubled / 6.0                                                  # A / 3 of each triangle
    outer = n[:, :, None] * n[:, None, :]
    k = share[:, None, None] * (normal * outer + tangential * (np.eye(3) - outer))
    six = np.stack([k[:, a, b] for a, b in SIX], axis=1)
    nodes, inverse = np.unique(triangles.ravel(), return_inverse=True)
    stiffness = np.zeros((len(nodes), 6))
    np.add.at(stiffness, inverse.reshape(-1), np.repeat(six, 3, axis=0))
    return nodes, stiffness


def _full(stiffness):
    """(r, 3, 3) of (r, 6)."""
    k = np.empty((len(stiffness), 3, 3))
    for c, (a, b) in enumerate(SIX):
        k[:, a, b] = k[:, b, a] = stiffness[:, c]
    return k


def add_support_forces(rows, stiffness, displacement, out):
    """out[i] -= K_i u_i for every supported node (``rows`` (n,): its row in ``stiffness``, -1
    for none)."""
    nodes = np.flatnonzero(rows >= 0)
    if len(nodes):
        out[nodes] -= np.einsum('rab,rb->ra', _full(stiffness[rows[nodes]]), displacement[nodes])


def support_energy(rows, stiffness, displacement) -> float:
    """The foundations' stored energy sum u_i K_i u_i / 2 [J]."""
    nodes = np.flatnonzero(rows >= 0)
    if not len(nodes):
        return 0.0
    u = displacement[nodes]
    return 0.5 * float(np.einsum('ra,rab,rb->', u, _full(stiffness[rows[nodes]]), u))


def unrestrained_modes(rest_positions, held, rows, stiffness) -> list[str]:
    """The rigid-body motions the supports do not stop (module docstring), named ('translation
    along x', 'rotation about z', ...); [] when they stop them all. ``held``: (n,) mask of the
    fixed nodes; ``rows``/``stiffness`` the foundations' per-node stiffness."""
    x = np.asarray(rest_positions, dtype=float)
    centre = x.mean(axis=0)
    size = max(float(np.ptp(x, axis=0).max()), 1e-300)
    r = (x - centre) / size
    modes = np.zeros((len(x), 3, 6))
    modes[:, :, :3] = np.eye(3)
    for axis in range(3):
        modes[:, :, 3 + axis] = np.cross(np.eye(3)[axis], r)
    k = np.zeros((len(x), 3, 3))
    supported = np.flatnonzero(rows >= 0)
    k[supported] = _full(stiffness[rows[supported]])
    scale = max(float(np.abs(stiffness).max()) if len(stiffness) else 0.0, 1.0)
    k[np.asarray(held, dtype=bool)] += scale * np.eye(3)
    matrix = np.einsum('nai,nab,nbj->ij', modes, k, modes)
    values, vectors = np.linalg.eigh(matrix)
    loose = values <= 1e-9 * max(float(values.max()), 1e-300)
    names = ['translation along x', 'translation along y', 'translation along z',
             'rotation about x', 'rotation about y', 'rotation about z']
    return [names[int(np.argmax(np.abs(vectors[:, j])))] for j in np.flatnonzero(loose)]
