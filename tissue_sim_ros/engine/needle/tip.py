"""The needle's tip: its shape, the points sampling its surface, and its contact.

Shapes (``needle.tip`` in the scene), in the needle frame with the apex at the origin and the
needle behind it (-z), radius r:

- ``flat``: the end face z = 0, ρ <= r (a blunt needle; its contact is the bonded patch of
  :mod:`~tissue_sim_ros.engine.needle.contact`);
- ``conical``: a cone of half-angle θ, ρ = -z tan θ, back to z = -h, h = r / tan θ; outward normal
  (cos θ cos φ, cos θ sin φ, sin θ);
- ``bevel``: the cylinder cut by a plane at the bevel angle β to the axis, the sharp point at the
  cylinder's edge in the direction ψ (``bevel_orientation_deg`` from the needle frame's +x) and
  the heel h = 2 r / tan β behind it; the face's outward normal n = (-cos β cos ψ, -cos β sin ψ,
  sin β). The tissue pushes on it along -n: a lateral force toward the sharp point, the push that
  steers bevel needles.

Contact (conical and bevel). Points spread over the tip surface touch the tissue one by one as
the tip goes in (:func:`engage_samples`: a sample that crossed the deformed surface during the
step takes the material point there), so the loaded area grows with the indentation, as under a
real sharp tip (Sneddon: a cone's force grows as the square of its depth, a flat punch's
linearly). Before the puncture each point is bonded to its sample's place on the tip, as a flat
end's samples are (the caller's ContactPatch, an exact solve, rebuilt as points join; one bond
per triangle, the first to touch it): held by a Gauss-Seidel push out of the tip's solid with
friction instead, the force would chatter from substep to substep and a spike could rupture the
membrane early. A point-like first bond strains the elements under it far more than a flat end
does, and a stiffening law takes them past the critical step estimated at rest: the default
scene runs at 0.65 of it (config/liver_sample.yaml). The puncture criteria read the patch's
axial force. After the puncture the faces push the tissue they displace out of the tip's solid
sideways (the axial load is the cutting law's), frictionless and within the cutting force
(:func:`tip_contact_solve`, :class:`SharpTipContact`).
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle.kernels import cells_near, first_surface_hit, follow_rigid_samples

__all__ = ['SHAPES', 'FLAT', 'CONICAL', 'BEVEL', 'SharpTipContact', 'tip_length', 'tip_samples',
           'tip_parameters', 'engage_samples', 'take_found', 'tip_contact_solve']

SHAPES = ('flat', 'conical', 'bevel')
FLAT, CONICAL, BEVEL = 0, 1, 2
#: rings of samples over a conical or bevelled face (and the points on each: 6 per ring index)
_RINGS = 4


def tip_length(radius: float, tip) -> float:
    """How far behind the apex the tip's surface ends [m] (0 for a flat end)."""
    if tip.shape == 'conical':
        return radius / math.tan(math.radians(tip.half_angle_deg))
    if tip.shape == 'bevel':
        return 2.0 * radius / math.tan(math.radians(tip.bevel_angle_deg))
    return 0.0


def _disc(radius: float, rings: int) -> np.ndarray:
    """Points of a disc: its centre and ``rings`` rings of 6 k points at k / rings of the radius."""
    points = [(0.0, 0.0)]
    for k in range(1, rings + 1):
        for j in range(6 * k):
            angle = 2 * math.pi * (j + 0.5 * (k % 2)) / (6 * k)
            points.append((radius * k / rings * math.cos(angle), radius * k / rings * math.sin(angle)))
    return np.array(points)


def tip_samples(radius: float, tip) -> tuple[np.ndarray, np.ndarray]:
    """(offsets (s, 3) from the apex in the needle frame, outward normals (s, 3)) of points
    spread evenly over the tip's surface (by its projection on the cross-section)."""
    disc = _disc(radius, _RINGS)
    if tip.shape == 'conical':
        tan_half = math.tan(math.radians(tip.half_angle_deg))
        rho = np.hypot(disc[:, 0], disc[:, 1])
        z = -rho / tan_half
        phi = np.arctan2(disc[:, 1], disc[:, 0])
        cos_h, sin_h = math.cos(math.radians(tip.half_angle_deg)), math.sin(math.radians(tip.half_angle_deg))
        normals = np.column_stack([cos_h * np.cos(phi), cos_h * np.sin(phi), np.full_like(phi, sin_h)])
        return np.column_stack([disc, z]), normals
    if tip.shape == 'bevel':
        beta, psi = math.radians(tip.bevel_angle_deg), math.radians(tip.bevel_orientation_deg)
        toward_point = disc[:, 0] * math.cos(psi) + disc[:, 1] * math.sin(psi)
        z = (toward_point - radius) / math.tan(beta)
        normal = np.array([-math.cos(beta) * math.cos(psi), -math.cos(beta) * math.sin(psi), math.sin(beta)])
        return np.column_stack([disc, z]), np.repeat(normal[None, :], len(disc), axis=0)
    return np.column_stack([disc, np.zeros(len(disc))]), np.repeat([[0.0, 0.0, 1.0]], len(disc), axis=0)


def tip_parameters(radius: float, tip) -> np.ndarray:
    """(7,) what :func:`tip_contact_solve` reads: shape code, r, h, cos and sin of the cone's
    half-angle or of the bevel angle, and the bevel's direction cos ψ, sin ψ."""
    code = {'flat': FLAT, 'conical': CONICAL, 'bevel': BEVEL}[tip.shape]
    angle = math.radians(tip.half_angle_deg if tip.shape == 'conical' else tip.bevel_angle_deg)
    psi = math.radians(tip.bevel_orientation_deg)
    return np.array([code, radius, tip_length(radius, tip), math.cos(angle), math.sin(angle),
                     math.cos(psi), math.sin(psi)])


@njit(cache=True)
def engage_samples(rest, displacement, triangles, rest_boxes, surface_nodes, tip, rotation, axis, offsets, engaged,
                   new, back, reach, candidates, near_boxes, boxes, subset, subset_cells, sample_nodes,
                   sample_weights):
    """Samples not yet engaged that lie past the deformed surface (the surface within ``back``
    behind them along the axis, or the sample inside it since the last step) take the material
    point there: its triangle's nodes (4th node weight 0) and weights, and are marked ``new``.
    Only the triangles within ``reach`` of the apex are tried (:func:`.kernels.cells_near`
    with the triangles' rest boxes ``rest_boxes`` and the ``surface_nodes``; ``candidates``,
    ``near_boxes``: room for every triangle), and for each sample only those whose box across the
    axis holds the sample: a ray along the axis meets a triangle only where its projection does,
    so the answer is the one all near triangles give (the boxes are padded well past round-off),
    for a tenth of the ray tests. Scratch with room for every triangle: ``boxes`` (n, 4),
    ``subset`` (n, 3), ``subset_cells`` (n,). Returns how many took a point."""
    count = 0
    n_near = cells_near(rest, displacement, triangles, rest_boxes, surface_nodes, tip, reach, candidates,
                        near_boxes)
    # two directions across the axis: the axis crossed with the coordinate axis least along it
    k_min = 0
    for r in range(1, 3):
        if abs(axis[r]) < abs(axis[k_min]):
            k_min = r
    c0, c1, c2 = (1.0 if k_min == 0 else 0.0), (1.0 if k_min == 1 else 0.0), (1.0 if k_min == 2 else 0.0)
    a0, a1, a2 = axis[1] * c2 - axis[2] * c1, axis[2] * c0 - axis[0] * c2, axis[0] * c1 - axis[1] * c0
    b0, b1, b2 = axis[1] * a2 - axis[2] * a1, axis[2] * a0 - axis[0] * a2, axis[0] * a1 - axis[1] * a0
    for k in range(n_near):
        boxes[k, 0] = boxes[k, 2] = np.inf
        boxes[k, 1] = boxes[k, 3] = -np.inf
        for j in range(3):
            node = triangles[candidates[k], j]
            x = rest[node, 0] + displacement[node, 0]
            y = rest[node, 1] + displacement[node, 1]
            z = rest[node, 2] + displacement[node, 2]
            across_a, across_b = a0 * x + a1 * y + a2 * z, b0 * x + b1 * y + b2 * z
            boxes[k, 0], boxes[k, 1] = min(boxes[k, 0], across_a), max(boxes[k, 1], across_a)
            boxes[k, 2], boxes[k, 3] = min(boxes[k, 2], across_b), max(boxes[k, 3], across_b)
        pad = 1e-12 + 1e-9 * max(boxes[k, 1] - boxes[k, 0], boxes[k, 3] - boxes[k, 2])
        boxes[k, 0] -= pad
        boxes[k, 1] += pad
        boxes[k, 2] -= pad
        boxes[k, 3] += pad
    origin = np.empty(3)
    for s in range(offsets.shape[0]):
        if engaged[s]:
            continue
        for r in range(3):
            origin[r] = (tip[r] + rotation[r, 0] * offsets[s, 0] + rotation[r, 1] * offsets[s, 1]
                         + rotation[r, 2] * offsets[s, 2] - back * axis[r])
        across_a = a0 * origin[0] + a1 * origin[1] + a2 * origin[2]
        across_b = b0 * origin[0] + b1 * origin[1] + b2 * origin[2]
        m = 0
        for k in range(n_near):
            if boxes[k, 0] <= across_a <= boxes[k, 1] and boxes[k, 2] <= across_b <= boxes[k, 3]:
                cell = candidates[k]
                subset[m, 0], subset[m, 1], subset[m, 2] = triangles[cell, 0], triangles[cell, 1], triangles[cell, 2]
                subset_cells[m] = cell
                m += 1
        hit, t, w0, w1, w2 = first_surface_hit(rest, displacement, subset[:m], origin, axis, 0.0, back)
        if hit < 0:
            continue
        hit = subset_cells[hit]
        engaged[s] = True
        new[s] = True
        sample_nodes[s, 0], sample_nodes[s, 1] = triangles[hit, 0], triangles[hit, 1]
        sample_nodes[s, 2], sample_nodes[s, 3] = triangles[hit, 2], triangles[hit, 2]
        sample_weights[s, 0], sample_weights[s, 1], sample_weights[s, 2], sample_weights[s, 3] = w0, w1, w2, 0.0
        count += 1
    return count


@njit(cache=True)
def take_found(sample_elements, found_nodes, found_weights, engaged, new, sample_nodes, sample_weights):
    """Samples found in the tissue (``sample_elements`` >= 0; their material points in the compact
    ``found_*`` rows, in sample order, as follow_rigid_samples writes them) that hold no point
    take theirs and are marked ``new``."""
    j = 0
    for s in range(sample_elements.shape[0]):
        if sample_elements[s] < 0:
            continue
        if not engaged[s]:
            engaged[s] = True
            new[s] = True
            for k in range(4):
                sample_nodes[s, k] = found_nodes[j, k]
                sample_weights[s, k] = found_weights[j, k]
        j += 1


@njit(cache=True)
def _push_out(p, params, n):
    """Depth of the needle-frame point ``p`` inside the tip's solid (<= 0: outside) and the
    outward direction to push it along (written in ``n``)."""
    shape, radius, height = params[0], params[1], params[2]
    cos_a, sin_a = params[3], params[4]
    rho = math.sqrt(p[0] * p[0] + p[1] * p[1])
    rx, ry = (p[0] / rho, p[1] / rho) if rho > 1e-15 else (1.0, 0.0)
    side = radius - rho                                   # inside the cylinder behind the tip
    if shape == CONICAL:
        if p[2] > 0.0:
            return 0.0
        if p[2] >= -height:
            depth = -(rho * cos_a + p[2] * sin_a)         # distance into the cone's face
            n[0], n[1], n[2] = cos_a * rx, cos_a * ry, sin_a
            return depth
        n[0], n[1], n[2] = rx, ry, 0.0
        return side
    # bevel: below the face plane through the sharp point, and inside the cylinder
    cos_p, sin_p = params[5], params[6]
    nx, ny, nz = -cos_a * cos_p, -cos_a * sin_p, sin_a
    face = -((p[0] - radius * cos_p) * nx + (p[1] - radius * sin_p) * ny + p[2] * nz)
    if face <= 0.0 or side <= 0.0:
        return 0.0
    if face <= side:
        n[0], n[1], n[2] = nx, ny, nz
        return face
    n[0], n[1], n[2] = rx, ry, 0.0
    return side


@njit(cache=True)
def _move_point(displacement, velocity, inverse_mass, force_scale, nodes, weights, s, move, dt,
                applied_forces, sample_forces):
    """Move material point ``s`` by the vector ``move`` with the mass-weighted correction of its
    nodes; record the force that takes ((1 + dt gamma) m Delta u / dt^2 per node)."""
    for r in range(3):
        if move[r] == 0.0:
            continue
        denom = 0.0
        for k in range(4):
            denom += weights[s, k] * weights[s, k] * inverse_mass[nodes[s, k], r]
        if denom <= 0.0:
            continue
        lam = move[r] / denom
        for k in range(4):
            i, w = nodes[s, k], weights[s, k]
            if w == 0.0:
                continue
            correction = w * inverse_mass[i, r] * lam
            displacement[i, r] += correction
            velocity[i, r] += correction / dt
            if inverse_mass[i, r] > 0.0:
                f = force_scale[i] * w * lam / (dt * dt)
                applied_forces[i, r] += f
                sample_forces[s, r] += f


@njit(cache=True)
def _share_within(inverse_mass, force_scale, nodes, weights, s, direction, depth, dt, limit, sample_forces):
    """The fraction of a correction ``depth`` along ``direction`` that keeps point ``s``'s force
    along it (so far this step: ``sample_forces``) within ``limit``."""
    inverse_effective = 0.0
    scale = 0.0
    for k in range(4):
        w = weights[s, k]
        if w == 0.0:
            continue
        scale += w * force_scale[nodes[s, k]]
        for r in range(3):
            inverse_effective += w * w * inverse_mass[nodes[s, k], r] * direction[r] * direction[r]
    if inverse_effective <= 0.0:
        return 0.0
    force = scale * depth / (inverse_effective * dt * dt)
    taken = 0.0
    for r in range(3):
        taken += sample_forces[s, r] * direction[r]
    room = limit - taken
    if room <= 0.0:
        return 0.0
    return min(1.0, room / force)


@njit(cache=True)
def tip_contact_solve(rest, displacement, velocity, inverse_mass, force_scale, sample_nodes, sample_weights,
                      engaged, limit, params, tip, rotation, dt, sweeps, sample_forces, sample_points,
                      applied_forces, total):
    """Keep the engaged material points out of the tip's solid (module docstring): Gauss-Seidel
    sweeps of the mass-weighted projection, sideways (across the axis) out of the face or the
    cylinder, frictionless, each point's
    force along its push within ``limit`` [N] per step (beyond it the tissue is cut rather than
    pushed further); a point that slid back past the heel is let go (the shaft holds it).
    Writes each sample's force on the tissue and its point of action (world), adds the nodal
    forces to ``applied_forces`` (as the other constraints) and the total force on the tissue to
    ``total``."""
    p = np.empty(3)
    n_local = np.empty(3)
    n_world = np.empty(3)
    move = np.empty(3)
    for s in range(engaged.shape[0]):
        for r in range(3):
            sample_forces[s, r] = 0.0
    for _ in range(sweeps):
        for s in range(engaged.shape[0]):
            if not engaged[s]:
                continue
            for r in range(3):
                x = 0.0
                for k in range(4):
                    i = sample_nodes[s, k]
                    x += sample_weights[s, k] * (rest[i, r] + displacement[i, r])
                sample_points[s, r] = x
            for r in range(3):
                p[r] = 0.0
                for c in range(3):
                    p[r] += rotation[c, r] * (sample_points[s, c] - tip[c])
            if p[2] < -params[2]:              # slid past the heel: the shaft has it
                engaged[s] = False
                continue
            depth = _push_out(p, params, n_local)
            if depth <= 0.0:
                continue
            # sideways only: the cutting law carries the axial load at the same samples (an
            # axial share of the faces would make the axial force jump whenever points cross from
            # the face to the cylinder's side together); moving along the face normal's lateral
            # part by depth / |n_lateral| takes the point out just the same
            lateral = math.sqrt(n_local[0] * n_local[0] + n_local[1] * n_local[1])
            if lateral <= 1e-12:
                continue
            depth /= lateral
            for r in range(3):
                n_world[r] = (rotation[r, 0] * n_local[0] + rotation[r, 1] * n_local[1]) / lateral
            depth *= _share_within(inverse_mass, force_scale, sample_nodes, sample_weights, s, n_world, depth,
                                   dt, limit, sample_forces)
            if depth <= 0.0:
                continue
            for r in range(3):
                move[r] = depth * n_world[r]
                sample_points[s, r] += move[r]
            _move_point(displacement, velocity, inverse_mass, force_scale, sample_nodes, sample_weights, s,
                        move, dt, applied_forces, sample_forces)
    for r in range(3):
        total[r] = 0.0
        for s in range(engaged.shape[0]):
            total[r] += sample_forces[s, r]


class SharpTipContact:
    """A conical or bevelled tip's contact: which surface samples touch, the material point each
    holds, and the arrays the kernels write (made once). Two modes:

    - before a puncture (:meth:`begin`): the samples touch the membrane one by one as the tip
      goes in (:meth:`take_new` says when), and the caller bonds each to the point it touched
      (a :class:`~tissue_sim_ros.engine.needle.contact.ContactPatch` rebuilt as points join), so
      the loaded area grows;
    - while the needle cuts its way in (:meth:`follow`): the tissue the tip displaces is pushed out
      sideways, frictionless (the cutting force itself acts along the axis at the
      same samples), taken afresh at the samples and let go behind the heel: a bevel's face
      pushes the tissue sideways and the tissue pushes the needle toward the sharp point.
    """

    def __init__(self, radius: float, tip):
        self.offsets, self.normals = tip_samples(radius, tip)
        self.params = tip_parameters(radius, tip)
        self.reach = radius + tip_length(radius, tip)
        s = len(self.offsets)
        self.new = np.zeros(s, dtype=np.bool_)        # touched since the last take_new
        self.engaged = np.zeros(s, dtype=np.bool_)
        self.touch_order = np.zeros(s, dtype=np.int64)
        self._touches = 0
        self.nodes = np.zeros((s, 4), dtype=np.int64)
        self.weights = np.zeros((s, 4))
        self.forces = np.zeros((s, 3))
        self.points = np.zeros((s, 3))
        self.total = np.zeros(3)
        self.elements = np.full(s, -1, dtype=np.int64)
        self._found_offsets = np.zeros((s, 3))
        self._found_nodes = np.zeros((s, 4), dtype=np.int64)
        self._found_weights = np.zeros((s, 4))
        self._weights = np.zeros(4)
        self._candidates = np.zeros(0, dtype=np.int64)
        self._near_boxes = np.zeros((0, 6))
        # engage_samples' scratch (room for every surface triangle, made at the first contact)
        self._boxes = np.zeros((0, 4))
        self._subset = np.zeros((0, 3), dtype=np.int64)
        self._subset_cells = np.zeros(0, dtype=np.int64)
        self.release()

    def release(self):
        self.active = False
        self.cutting = False
        self.region = -1
        self.on_surface = True
        self.engaged[:] = False
        self.new[:] = False
        self.forces[:] = 0.0
        self.total[:] = 0.0

    def begin(self, region: int, on_surface: bool):
        """A contact with a membrane of ``region``: at the tissue's outer surface, or at a layer."""
        self.release()
        self.active, self.region, self.on_surface = True, int(region), bool(on_surface)
        self.elements[:] = -1

    def follow(self):
        """The needle is inside and cutting: the faces push the displaced tissue (frictionless)."""
        self.release()
        self.cutting = True

    def take_new(self) -> bool:
        """Whether samples have touched since the last call (they are numbered in touch order)."""
        if not self.new.any():
            return False
        self._touches += 1
        self.touch_order[self.new] = self._touches
        self.new[:] = False
        return True

    def engaged_samples(self):
        """(offsets, nodes, weights) of the touching samples, for the bonded patch: the first to
        touch each triangle (or element) only. Two bonds on one coarse triangle a tenth of its
        size apart clamp its rotation with that short lever: they hold each other with large
        forces, and the force jumps when the next point joins."""
        engaged = np.flatnonzero(self.engaged)
        engaged = engaged[np.argsort(self.touch_order[engaged], kind='stable')]
        _, first = np.unique(np.sort(self.nodes[engaged], axis=1), axis=0, return_index=True)
        bonded = engaged[np.sort(first)]
        return self.offsets[bonded], self.nodes[bonded], self.weights[bonded]

    def engage_on_surface(self, rest, displacement, triangles, rest_boxes, surface_nodes, tip, rotation, axis, back):
        return engage_samples(rest, displacement, triangles, rest_boxes, surface_nodes, tip, rotation, axis,
                              self.offsets, self.engaged, self.new, back, self.reach + back,
                              *self.surface_scratch(triangles), self.nodes, self.weights)

    def surface_scratch(self, triangles):
        """engage_samples' scratch arrays (candidates, near_boxes, boxes, subset, subset_cells),
        with room for ``triangles``."""
        self._room_for(len(triangles))
        if len(self._boxes) < len(triangles):
            self._boxes = np.zeros((len(triangles), 4))
            self._subset = np.zeros((len(triangles), 3), dtype=triangles.dtype)
            self._subset_cells = np.zeros(len(triangles), dtype=np.int64)
        return self._candidates, self._near_boxes, self._boxes, self._subset, self._subset_cells


    def _room_for(self, n_cells):
        if len(self._candidates) < n_cells:
            self._candidates = np.zeros(n_cells, dtype=np.int64)
            self._near_boxes = np.zeros((n_cells, 6))

    def engage_in_region(self, rest, displacement, tetrahedra, neighbours, element_boxes, nodes, tip, rotation,
                         selectors, tags):
        """Inside the tissue: samples whose material point (found by a walk) lies in the layer's
        region take it."""
        waiting = np.flatnonzero(~self.engaged)
        if waiting.size == 0:
            return 0
        elements = self.elements[waiting]
        self._room_for(len(tetrahedra))
        n = follow_rigid_samples(rest, displacement, tetrahedra, neighbours, element_boxes, nodes, tip, rotation,
                                 self.offsets[waiting], elements, self._found_offsets, self._found_nodes,
                                 self._found_weights, self._weights, self._candidates, self._near_boxes)
        self.elements[waiting] = elements
        if n == 0:
            return 0
        inside = waiting[elements >= 0]
        rest_points = np.einsum('sk,skr->sr', self._found_weights[:n], rest[self._found_nodes[:n]])
        element_tags = None if tags is None else tags[elements[elements >= 0]]
        in_layer = selectors.regions_of(rest_points, element_tags) == self.region
        taken = inside[in_layer]
        self.engaged[taken] = True
        self.new[taken] = True
        self.nodes[taken] = self._found_nodes[:n][in_layer]
        self.weights[taken] = self._found_weights[:n][in_layer]
        return int(in_layer.sum())

    def engage_found(self, sample_elements, found_nodes, found_weights):
        """Cutting: the samples found in the tissue that hold no point take theirs (take_found)."""
        take_found(sample_elements, found_nodes, found_weights, self.engaged, self.new, self.nodes, self.weights)

    def solve(self, rest, displacement, velocity, inverse_mass, force_scale, tip, rotation, dt, applied_forces,
              limit=math.inf):
        """One step of the cutting push; the total force on the tissue (the contact's array).
        ``limit``: the most force a point takes along its push (the tissue splits beyond it)."""
        tip_contact_solve(rest, displacement, velocity, inverse_mass, force_scale, self.nodes, self.weights,
                          self.engaged, limit, self.params, tip, rotation, dt, 2, self.forces, self.points,
                          applied_forces, self.total)
        return self.total
