"""The needle's flat end bonded to the tissue surface (phase ``contact``) until the membrane ruptures.

When the tip crosses the deformed surface, the needle's flat end is sampled by points on rings
(centre, 6 at r/2, 12 at r) and each is bonded to the surface point under it. A sample bonds its
whole triangle, so on a mesh coarser than the needle radius the punch is as wide as the
triangles under it (elements larger than the needle are handled, the force is overestimated).
Where the surface triangles are smaller than the radius, the surface nodes under the end are
bonded instead (with at least 3 of them), and the force converges to the rigid bonded flat punch
as the mesh is refined: 2 a E delta / (1 - nu^2) (Sneddon) times (1 - nu) ln(3 - 4 nu) / (1 - 2 nu)
for no slip (Mossakovskii), within 2 % at 0.5 mm cells.

The bond is a hard constraint solved exactly each step: the mass-weighted smallest correction
that puts every sample point on its target (a rigid-body point of the needle end),
Delta u = M^-1 W^T lambda with (W M^-1 W^T) lambda = -(W x - T); the force on the tissue is
W^T lambda / dt^2. The pseudo-inverse of W M^-1 W^T is computed once per contact, so samples that
share one coarse triangle are fine. The caller (:class:`~.interaction.NeedleTissue`) lets the contact
go when the needle, not advancing, would pull the tissue, and decides puncture with
:meth:`ContactPatch.ruptured`.
"""
from __future__ import annotations

import math

import numpy as np

from tissue_sim_ros.engine.needle.kernels import first_surface_hit, patch_apply, patch_solve, put_rigid_points

__all__ = ['bond_offsets', 'disc_offsets', 'end_samples', 'ContactPatch']


def disc_offsets(radius):
    """The flat end's sample points in the needle frame: centre, 6 at r/2, 12 at r (z = 0)."""
    points = [(0.0, 0.0)]
    for ring, count in ((0.5, 6), (1.0, 12)):
        for k in range(count):
            angle = 2 * math.pi * k / count
            points.append((ring * radius * math.cos(angle), ring * radius * math.sin(angle)))
    return np.array([(x, y, 0.0) for x, y in points])


def bond_offsets(offsets, rest, displacement, nodes, weights, tip, rotation, tolerance):
    """The offsets (needle frame, from the tip) at which a sharp tip's samples bond to their
    material points (``nodes``, ``weights`` (s, k)): each sample's own, except where the material
    point already lies behind the sample along the axis by more than ``tolerance``: bonded
    there, where it is.

    Contact starts when the apex crosses the surface. Along the surface's normal every sample
    has then crossed it by at most a step's travel, and pulling the points onto the samples is
    that step's indentation. On a surface oblique to the needle, a bevel's heel may have crossed
    it earlier, by up to its length times the tilt: pulled onto the samples in one step, those
    points load the tissue with an impulse (20 N at first contact for the 18 gauge bevel at 25
    degrees on the organ example, past the capsule's rupture force). Bonded where they are, the
    force starts from 0 and grows with the advance."""
    points = np.einsum('sk,skr->sr', weights, rest[nodes] + displacement[nodes])
    axial = (points - tip) @ rotation[:, 2]
    out = np.array(offsets, dtype=float, copy=True)
    behind = axial < out[:, 2] - tolerance
    out[behind, 2] = axial[behind]
    return out


def end_samples(rest, displacement, surface_triangles, surface_nodes, tip, rotation, axis, diameter, offsets):
    """The material points the flat end bonds to once the tip has crossed the surface.

    Returns (sample offsets (s, 3) in the needle frame from the tip, their nodes (s, 3), their
    weights (s, 3)), or None when no sample finds the surface. ``offsets``: :func:`disc_offsets`.
    Each point is bonded where it is, at its axial place relative to the end: the samples of a
    coarse triangle then ask for the triangle's own plane, whatever its angle to the needle, and
    the bond starts without an impulse. Pulled onto the end instead, as when the surface is
    normal to the axis (they are then off it by at most a step's travel), the points of a surface
    oblique to the needle ask a triangle to bend: its least-squares multipliers reach 110 N from
    a 1.5 um inconsistency (the flat end on the organ example's dome).
    """
    reach = diameter
    radius = 0.5 * reach
    samples, nodes, weights, areas = [], [], [], []
    for offset in offsets:
        origin = tip + rotation @ offset - reach * axis
        k, ts, w0, w1, w2 = first_surface_hit(rest, displacement, surface_triangles, origin,
                                              axis, 0.0, 2.0 * reach)
        if k < 0:
            continue
        samples.append(offset + np.array([0.0, 0.0, ts - reach]))        # < 0: behind the end
        nodes.append(surface_triangles[k])
        weights.append((w0, w1, w2))
        corners = rest[surface_triangles[k]] + displacement[surface_triangles[k]]
        areas.append(0.5 * np.linalg.norm(np.cross(corners[1] - corners[0], corners[2] - corners[0])))
    if not samples:
        return None
    # A mesh finer than the needle radius resolves the footprint: bond the surface nodes
    # under the end instead. A sample bonds its whole triangle, so the rings make a punch of
    # radius up to a + h (linear, 1 mm deep: 2.4x the flat punch with 1 mm cells, still 1.5x
    # with 0.5 mm ones) while the nodes under it converge to it (1.14, 1.01, 0.99 at 1, 0.7,
    # 0.5 mm).
    element_size = math.sqrt(2.0 * float(np.mean(areas)))       # leg of a right isosceles triangle
    if element_size <= radius:
        relative = (rest[surface_nodes] + displacement[surface_nodes] - tip) @ rotation
        under = np.flatnonzero((np.hypot(relative[:, 0], relative[:, 1]) <= radius * (1.0 + 1e-9))
                               & (np.abs(relative[:, 2]) <= reach))
        if len(under) >= 3:
            samples = [relative[j].copy() for j in under]
            nodes = [np.full(3, surface_nodes[j]) for j in under]
            weights = [(1.0, 0.0, 0.0)] * len(under)
    return np.array(samples), np.array(nodes), np.array(weights)


class ContactPatch:
    """A bonded contact: sample material points (weights over ``nodes``) held to targets fixed in
    the needle frame (offsets from the tip), with its work arrays (no allocation per step)."""

    def __init__(self, nodes, weights, offsets, inverse_mass, region):
        self.nodes = nodes.astype(np.int64)
        self.weights = weights
        self.offsets = offsets                                  # (s, 3) in the needle frame
        self.region = region
        self._factor(inverse_mass)
        n = len(offsets)
        self.targets = np.zeros((n, 3))
        self.residual = np.zeros((n, 3))
        self.multipliers = np.zeros((n, 3))
        self.sample_forces = np.zeros((n, 3))
        self.sample_scale = np.zeros(n)          # sum_j w_sj (1 + dt gamma_j), set by set_masses
        self.scale_generation = -1
        self.total = np.zeros(3)
        self.work = 0.0

    @classmethod
    def from_samples(cls, offsets, sample_nodes, sample_weights, inverse_mass, region):
        """The patch of samples given by their own (s, k) nodes and weights: the nodes are merged
        so that samples sharing a node share its column of W."""
        unique, inverse = np.unique(sample_nodes, return_inverse=True)
        weights = np.zeros((len(offsets), len(unique)))
        np.add.at(weights, (np.repeat(np.arange(len(offsets)), sample_nodes.shape[1]), inverse.ravel()),
                  sample_weights.ravel())
        return cls(unique, weights, offsets, inverse_mass, region)

    def _factor(self, inverse_mass):
        """The pseudo-inverse of W M^-1 W^T per axis, for the current masses."""
        w_scaled = self.weights[None, :, :] * inverse_mass[self.nodes].T[:, None, :]    # (3, s, j)
        system = np.einsum('rsj,tj->rst', w_scaled, self.weights)
        self.pseudo_inverse = np.stack([np.linalg.pinv(system[r], rcond=1e-10, hermitian=True)
                                        for r in range(3)])

    def set_masses(self, inverse_mass, force_scale, generation):
        """New masses or time step (a topology change, the node's degradation ladder): the
        constraint system refactored, the force scale of each sample updated."""
        if self.scale_generation >= 0:          # the constructor factored the first masses
            self._factor(inverse_mass)
        self.sample_scale[:] = self.weights @ force_scale[self.nodes]
        self.scale_generation = generation

    def solve(self, rest, displacement, tip, rotation, dt):
        """Targets at the needle end, the multipliers and each sample's force on the tissue;
        returns the total force (3,) on the tissue (the patch's array, updated in place)."""
        put_rigid_points(tip, rotation, self.offsets, len(self.offsets), self.targets, 0)
        patch_solve(rest, displacement, self.nodes, self.weights, self.pseudo_inverse, self.targets,
                    self.residual, self.multipliers, self.sample_scale, 1.0 / (dt * dt), self.sample_forces,
                    self.total)
        return self.total

    def apply(self, displacement, velocity, inverse_mass, force_scale, dt, applied_forces):
        """Move the bonded nodes onto the targets (after :meth:`solve`), recording their forces."""
        patch_apply(displacement, velocity, inverse_mass, force_scale, self.nodes, self.weights,
                    self.multipliers, dt, applied_forces)

    def ruptured(self, membrane, axial_force, diameter, speed=0.0):
        """Whether the membrane gives way: the axial force reaches its rupture force at the
        needle's axial ``speed`` ('force', Membrane.rupture_force), or the work done since contact
        reaches the toughness times the needle's cross-section area ('energy')."""
        if membrane.criterion == 'force':
            return axial_force >= membrane.rupture_force(speed)
        return self.work >= membrane.rupture_work_j(diameter)

    def entry_point(self):
        """(nodes, weights) of the first shaft point after puncture: the centre sample's four
        heaviest nodes, weights renormalised."""
        centre = int(np.argmin(np.linalg.norm(self.offsets[:, :2], axis=1)))
        row = self.weights[centre]
        take = np.argsort(row)[::-1][:4]
        return self.nodes[take], row[take] / row[take].sum()
