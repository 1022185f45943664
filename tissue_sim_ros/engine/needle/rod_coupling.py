"""The elastic shaft (:mod:`.rod`) coupled to the tissue: held in its channel, pushing it, sliding.

Inside the tissue the shaft's material points (:mod:`.inside`) are held on the rod's centreline
instead of the straight axis, and the rod is where the tissue, the tip's loads and its own
stiffness put it. Each step, after the tissue's:

1. **The guide.** The shaft outside the tissue runs in a guide that follows the base pose (the
   telescoping support of steering experiments, Webster et al. 2006, which keeps a slender
   needle from buckling against the surface): the nodes from the base to the entry, the arc
   length of the shallowest shaft point, are held on the base frame's axis, and the rod is
   clamped there (:func:`guide_nodes`). Before the puncture, or once out, the whole needle is
   in the guide: straight, the rigid needle.
2. **The shaft's points on the rod, two ways** (:func:`rod_shaft_solve`). A point at arc length
   s (its closest point on the centreline, :func:`~.rod.locate_on_rod`) is to lie on the
   centreline c(s) plus the lateral offset the tip's faces gave it (tapering behind the heel,
   as on the rigid needle: :func:`~.kernels.shaft_solve`). Over the step the tissue point moves
   as its nodes' masses allow, so closing a lateral gap d there takes the force K d, K = the
   point's mass-weighted stiffness over the step across the tangent, (1 + dt gamma) (P W P)^+ /
   dt^2 (W: sum_k w_k^2 / m_k per axis; the same law the rigid needle's projection follows).
   The rod and the tissue points are solved together: Newton's step on the rod's potential plus
   1/2 d^T K d + Lambda . c over every held point (Lambda: what the point has already taken this
   step), then each point is moved onto the new centreline by the mass-weighted projection,
   its force recorded as the rigid needle's is; twice (a second sweep for points that share
   nodes, as the rigid projection's). The solve is implicit in the rod and in the tissue's
   inertia over the step, so a shaft far stiffer than the tissue's step is stable at any step
   the tissue takes, with no substeps; the tissue's elastic forces enter in its own next step,
   as they do for the rigid needle. Two Newton steps a step converge the rod's nonlinearity over
   the steps it moves by micrometres.
3. **Friction** along the rod's local tangent at each point, the modified Karnopp law of the
   rigid needle (:func:`~.kernels.karnopp_impulse`), the needle's velocity there the rod's own
   motion over the step.
4. **The tip** (:func:`tip_frame`): the rod's last node is the apex, its last segment's
   transported frame the tip's frame. The tip's kernels (cutting samples, the faces' push, the
   cutting law, the apex's walk) run unchanged in that frame, so the tip cuts where the rod's tip
   is, and the channel follows the tip's path.
5. **The loads for the next step** (:func:`add_point_load`): every force the tip's samples and
   the friction put on the tissue, reversed, on the rod at its arc length, with the couple of
   its offset from the centreline. They are bounded (the cutting law's limit, the friction law's)
   and lag one step.

Points of action for the reaction wrench are on the bent centreline, so the torque about the base
is the moment of the forces where they act on the needle.
"""
import math

import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle.kernels import karnopp_impulse, length_shares
from tissue_sim_ros.engine.needle.rod import (BANDS, RodSection, add_block, assemble, band_solve, keep_lengths,
                                              locate_on_rod, straight_nodes, transport_frames)

__all__ = ['RodState', 'guide_nodes', 'rod_shaft_solve', 'tip_frame', 'add_load', 'add_tip_loads',
           'centreline_points']


class RodState:
    """One flexible needle's rod: its nodes, frames and tip, the shaft points' places on it, and
    the arrays the coupled step writes (made once: no allocation in the step).

    diameter_m, length_m: the needle's (outer diameter, base to apex); shaft: its
    :class:`~.parameters.FlexibleShaft`; capacity: room for this many shaft points; mesh_nodes:
    the tissue's nodes."""

    def __init__(self, diameter_m, length_m, shaft, capacity, mesh_nodes):
        self.section = RodSection(diameter_m, shaft.inner_diameter_m, shaft.young_modulus_pa)
        self.segments = int(shaft.segments)
        self.length_m = float(length_m)
        self.h = self.length_m / self.segments
        self.radius = 0.5 * float(diameter_m)
        self.bending = self.section.bending_stiffness_nm2
        self.axial = self.section.axial_stiffness_n
        n_nodes = self.segments + 1
        self.nodes = np.zeros((n_nodes, 3))
        self.previous = np.zeros((n_nodes, 3))        # the nodes at the end of the last step
        self.before = np.zeros((n_nodes, 3))          # the nodes before a Newton step
        self.loads = np.zeros((n_nodes, 3))           # the tip's and the friction's, for the next step
        self.frames = np.zeros((self.segments, 3, 3))
        self.gradient = np.zeros((n_nodes, 3))
        self.band = np.zeros((3 * n_nodes, BANDS + 1))
        self.step = np.zeros(3 * n_nodes)
        self.scratch = np.zeros((6, 3))
        self.held = np.zeros(capacity, dtype=np.bool_)
        self.point_stiffness = np.zeros((capacity, 3, 3))
        self.point_pull = np.zeros((capacity, 3))
        self.node_share = np.zeros(mesh_nodes)
        self.point_segments = np.zeros(capacity, dtype=np.int64)
        self.point_fractions = np.zeros(capacity)
        self.tip_rotation = np.eye(3)
        self.tip_axis = np.zeros(3)
        self.virtual_base = np.zeros(3)
        self.tip_velocity = np.zeros(3)
        self.no_rate = np.zeros(3)

    def straighten(self, position, rotation, velocity=None):
        """The rod straight along the base frame at ``position`` (in its guide: nothing bends it);
        the tip moving with the base at ``velocity``."""
        self.nodes[:] = straight_nodes(position, rotation[:, 2], self.length_m, self.segments)
        self.previous[:] = self.nodes
        self.frames[:] = rotation[None, :, :]
        self.tip_rotation[:] = rotation
        self.tip_axis[:] = rotation[:, 2]
        self.virtual_base[:] = position
        self.tip_velocity[:] = 0.0 if velocity is None else velocity
        self.loads[:] = 0.0

    def add_point(self, k):
        """Shaft point ``k`` made at the apex: on the last segment, at its end."""
        self.point_segments[k] = self.segments - 1
        self.point_fractions[k] = 1.0

    def keep_points(self, keep, n):
        """Shaft points compacted to those where ``keep`` (of the first ``n``)."""
        m = int(keep.sum())
        self.point_segments[:m] = self.point_segments[:n][keep]
        self.point_fractions[:m] = self.point_fractions[:n][keep]

    def arguments(self):
        """The rod's arguments of :func:`~.rod_step.rod_inserted_step`, in their order (but the
        last, ``rod_shaft_step``'s)."""
        return (self.nodes, self.previous, self.h, self.radius, self.bending, self.axial, self.loads, self.frames,
                self.gradient, self.band, self.step, self.before, self.scratch, self.held, self.point_stiffness,
                self.point_pull, self.node_share, self.point_segments, self.point_fractions, self.tip_rotation,
                self.tip_axis, self.virtual_base, self.tip_velocity, self.no_rate)

    def deflection(self, position, axis):
        """The tip's distance [m] from the base frame's axis through ``position``."""
        offset = self.nodes[-1] - position
        return float(np.linalg.norm(offset - (offset @ axis) * axis))


#: the guide's hold on the node it is letting go, at full strength, in units of the rod's own
#: bending stiffness over one segment, EI / h^3 (a stiff clamp that still leaves the matrix well
#: conditioned)
GUIDE_STIFFNESS = 100.0


@njit(cache=True)
def guide_nodes(nodes, base, axis, previous_base, h, entry):
    """Hold the nodes up to arc length ``entry - h`` [m] on the base's axis (the guide; ``entry``:
    where the shaft enters the tissue), move the others with the base's translation since the last
    step (the next solve's start); returns the first free node (the number of nodes where all are
    held: the rod straight). The first free node is still held by a lateral spring of strength
    (entry - s) / h (:func:`_guide_spring`), so the guide lets a node go over one segment's
    advance instead of at once: the clamp's place moves with the entry continuously."""
    n = nodes.shape[0]
    guided = max(0, min(n - 1, int(math.floor(entry / h - 1.0 + 1e-9))))
    for k in range(n):
        if k <= guided:
            for r in range(3):
                nodes[k, r] = base[r] + k * h * axis[r]
        else:
            for r in range(3):
                nodes[k, r] += base[r] - previous_base[r]
    return guided + 1 if guided < n - 1 else n


@njit(cache=True, inline='always')
def _point_position(rest, displacement, point_nodes, point_weights, s, out):
    for r in range(3):
        x = 0.0
        for k in range(4):
            i = point_nodes[s, k]
            x += point_weights[s, k] * (rest[i, r] + displacement[i, r])
        out[r] = x


@njit(cache=True, inline='always')
def _held(along, free_beyond, closing_m):
    """How much of its offset a point at arc length ``along`` is held at (shaft_solve's taper)."""
    if closing_m > 0.0:
        return min(1.0, max(0.0, 1.0 - (free_beyond - along) / closing_m))
    return 1.0


@njit(cache=True, inline='always')
def _target(nodes, frames, segment, fraction, offsets, s, held, out):
    """The point's place: the centreline at its arc length plus ``held`` of its offset (world),
    across the segment's tangent."""
    along = offsets[s, 0] * frames[segment, 0, 2] + offsets[s, 1] * frames[segment, 1, 2] \
        + offsets[s, 2] * frames[segment, 2, 2]
    for r in range(3):
        out[r] = ((1.0 - fraction) * nodes[segment, r] + fraction * nodes[segment + 1, r]
                  + held * (offsets[s, r] - along * frames[segment, r, 2]))


@njit(cache=True)
def _node_shares(point_nodes, point_weights, n_points, point_depths, free_beyond, node_share):
    """node_share[i] += the sum of the held points' weights on node i."""
    for s in range(n_points):
        if point_depths[s] > free_beyond:
            continue
        for k in range(4):
            node_share[point_nodes[s, k]] += point_weights[s, k]


@njit(cache=True)
def _lateral_stiffness(inverse_mass, force_scale, point_nodes, point_weights, node_share, s, frames, segment, dt,
                       out):
    """(3, 3) K = (1 + dt gamma) (P W P)^+ / dt^2 of point ``s`` across the tangent (the segment
    frame's d1, d2 span it): the force per metre that moves it laterally over the step. W, the
    point's compliance, is that of all the held points pulled the same way, sum_k w_k / m_k
    (sum_q w_qk) over its nodes k (``node_share``: sum_q w_qk, the weights of every held point on
    node k): the mode a rod stiffer than the tissue moves them in, where points that share nodes
    move together, and an upper bound of the compliance in any other mode (Gershgorin), so the
    points' simultaneous projection with it never overshoots. Returns False for a point whose
    nodes cannot move across the tangent."""
    w0 = w1 = w2 = 0.0
    scale = 0.0
    for k in range(4):
        i = point_nodes[s, k]
        w = point_weights[s, k]
        scale += w * force_scale[i]
        share = w * node_share[i]
        w0 += share * inverse_mass[i, 0]
        w1 += share * inverse_mass[i, 1]
        w2 += share * inverse_mass[i, 2]
    u0, u1, u2 = frames[segment, 0, 0], frames[segment, 1, 0], frames[segment, 2, 0]
    v0, v1, v2 = frames[segment, 0, 1], frames[segment, 1, 1], frames[segment, 2, 1]
    a = u0 * u0 * w0 + u1 * u1 * w1 + u2 * u2 * w2
    b = u0 * v0 * w0 + u1 * v1 * w1 + u2 * v2 * w2
    c = v0 * v0 * w0 + v1 * v1 * w1 + v2 * v2 * w2
    det = a * c - b * b
    if not det > 1e-12 * (a + c) ** 2 or scale <= 0.0:
        return False
    factor = scale / (dt * dt * det)
    i00, i01, i11 = c * factor, -b * factor, a * factor          # [[a, b], [b, c]]^-1 scale / dt^2
    for r in range(3):
        ur, vr = frames[segment, r, 0], frames[segment, r, 1]
        for q in range(3):
            uq, vq = frames[segment, q, 0], frames[segment, q, 1]
            out[r, q] = ur * (i00 * uq + i01 * vq) + vr * (i01 * uq + i11 * vq)
    return True


@njit(cache=True)
def _guide_spring(nodes, base, axis, h, bending, entry, first_free, gradient, band, block):
    """The guide's spring on the first free node (:func:`guide_nodes`): GUIDE_STIFFNESS EI / h^3
    times (entry - s) / h (0 to 1), across the axis, toward the axis."""
    k = first_free
    if k >= nodes.shape[0]:
        return
    weight = min(1.0, max(0.0, (entry - k * h) / h))
    if weight <= 0.0:
        return
    stiffness = weight * GUIDE_STIFFNESS * bending / h ** 3
    along = 0.0
    for r in range(3):
        along += (nodes[k, r] - base[r]) * axis[r]
    for r in range(3):
        off = nodes[k, r] - base[r] - along * axis[r]
        gradient[k, r] += stiffness * off
        for c in range(3):
            block[r, c] = stiffness * ((1.0 if r == c else 0.0) - axis[r] * axis[c])
    add_block(band, k, k, block, 1.0)


@njit(cache=True)
def _newton_with_points(rest, displacement, point_nodes, point_weights, n_points, nodes, first_free, base,
                        base_axis, entry, h, bending, axial, loads, frames, gradient, band, step, before,
                        free_beyond, closing_m, point_offsets, point_forces, point_segments, point_fractions,
                        point_depths, held, point_stiffness, scratch):
    """One Newton step of the rod with the held points' lateral springs (module docstring, 2):
    the rod's potential under ``loads`` plus, for each held point (``held``), 1/2 d^T K d +
    Lambda . c (K: ``point_stiffness``; Lambda: ``point_forces``, what it took earlier in the
    step). Returns False (the rod left as it was) where the matrix does not factor."""
    gradient[:] = 0.0
    band[:] = 0.0
    assemble(nodes, h, bending, axial, base_axis, gradient, band)
    for i in range(nodes.shape[0]):
        for r in range(3):
            gradient[i, r] -= loads[i, r]
    _guide_spring(nodes, base, base_axis, h, bending, entry, first_free, gradient, band, scratch[2:5])
    x, target = scratch[0], scratch[1]
    for s in range(n_points):
        if not held[s]:
            continue
        j, a = point_segments[s], min(max(point_fractions[s], 0.0), 1.0)
        stiffness = point_stiffness[s]
        _point_position(rest, displacement, point_nodes, point_weights, s, x)
        _target(nodes, frames, j, a, point_offsets, s, _held(point_depths[s], free_beyond, closing_m), target)
        for r in range(3):          # Lambda + K (c + o - x): the force the point takes from the rod
            pull = point_forces[s, r]
            for q in range(3):
                pull += stiffness[r, q] * (target[q] - x[q])
            gradient[j, r] += (1.0 - a) * pull
            gradient[j + 1, r] += a * pull
        add_block(band, j, j, stiffness, (1.0 - a) * (1.0 - a))
        add_block(band, j, j + 1, stiffness, (1.0 - a) * a)
        add_block(band, j + 1, j + 1, stiffness, a * a)
    for i in range(nodes.shape[0]):
        for r in range(3):
            step[3 * i + r] = -gradient[i, r]
    if not band_solve(band, step, first_free):
        return False
    before[:] = nodes
    for i in range(first_free, nodes.shape[0]):
        for r in range(3):
            nodes[i, r] += step[3 * i + r]
    keep_lengths(nodes, before, first_free)
    return True


@njit(cache=True)
def _locate_points(rest, displacement, point_nodes, point_weights, n_points, nodes, h, point_segments,
                   point_fractions, point_depths, x):
    for s in range(n_points):
        _point_position(rest, displacement, point_nodes, point_weights, s, x)
        j, a, along = locate_on_rod(nodes, h, x, point_segments[s])
        point_segments[s], point_fractions[s], point_depths[s] = j, a, along


@njit(cache=True)
def _follow_offsets(rest, displacement, point_nodes, point_weights, n_points, nodes, frames, point_segments,
                    point_fractions, point_depths, free_beyond, radius, point_offsets, x):
    """The points on the tip's faces take their offsets from the centreline (world, across the
    tangent), up to ``radius``. In the world frame, not the needle's: a needle that turns about
    its axis leaves the tissue its bevel pushed aside where it is (held in the needle's frame, that
    tissue was swept round with it, and pushed the tip aside by 20 um in the phantom's flip)."""
    for s in range(n_points):
        if point_depths[s] <= free_beyond:
            continue
        j, a = point_segments[s], point_fractions[s]
        _point_position(rest, displacement, point_nodes, point_weights, s, x)
        along = 0.0
        for r in range(3):
            x[r] -= (1.0 - a) * nodes[j, r] + a * nodes[j + 1, r]
            along += x[r] * frames[j, r, 2]
        out = 0.0
        for r in range(3):
            point_offsets[s, r] = x[r] - along * frames[j, r, 2]
            out += point_offsets[s, r] ** 2
        out = math.sqrt(out)
        if out > radius:
            for r in range(3):
                point_offsets[s, r] *= radius / out


@njit(cache=True)
def _project_points(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
                    nodes, frames, point_segments, point_fractions, point_depths, held, point_stiffness, free_beyond,
                    closing_m, point_offsets, point_pull, dt, point_forces, applied_forces, scratch):
    """Every held point pulled onto the centreline at once: lambda = K (c + o - x) with the K the
    rod was solved with (so the rod takes what the tissue is given, exactly), each node moved by
    w / m lambda dt^2 / (1 + dt gamma) of every point that holds it (and its velocity by that / dt),
    the force recorded as the rigid needle's projection records it."""
    x, target = scratch[0], scratch[1]
    for s in range(n_points):
        if not held[s]:
            continue
        j, a = point_segments[s], min(max(point_fractions[s], 0.0), 1.0)
        _point_position(rest, displacement, point_nodes, point_weights, s, x)
        _target(nodes, frames, j, a, point_offsets, s, _held(point_depths[s], free_beyond, closing_m), target)
        for r in range(3):
            pull = 0.0
            for q in range(3):
                pull += point_stiffness[s, r, q] * (target[q] - x[q])
            point_pull[s, r] = pull
    for s in range(n_points):
        if not held[s]:
            continue
        scale = 0.0
        for k in range(4):
            scale += point_weights[s, k] * force_scale[point_nodes[s, k]]
        for k in range(4):
            i, w = point_nodes[s, k], point_weights[s, k]
            for r in range(3):
                correction = w * inverse_mass[i, r] * point_pull[s, r] * dt * dt / scale
                displacement[i, r] += correction
                velocity[i, r] += correction / dt
                if inverse_mass[i, r] > 0.0:
                    f = force_scale[i] * w * point_pull[s, r] / scale
                    applied_forces[i, r] += f
                    point_forces[s, r] += f


@njit(cache=True)
def rod_shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
                    nodes, previous, first_free, base, base_rotation, base_axis, entry, radius, h, bending, axial,
                    loads, frames, gradient, band, step, before, scratch, held, point_stiffness, point_pull,
                    node_share, dt, tip_depth, friction, sweeps, free_beyond, closing_m, point_offsets, point_forces,
                    point_depths, point_shares, point_segments, point_fractions, applied_forces):
    """The shaft's points and the rod together (module docstring, 2 and 3): ``sweeps`` of a
    Newton step of the rod with the held points' lateral stiffness (under the last step's
    ``loads``) and the points' simultaneous projection onto the new centreline, then friction
    along the local tangent. ``nodes`` (from the guide, :func:`guide_nodes`, free from
    ``first_free``, the guide's spring from ``entry`` on the first free one) are moved;
    ``previous``: the nodes at the end of the last step (the needle's velocity). A point on the
    tip's faces takes its offset from the centreline as it goes, up to the needle's ``radius``:
    tissue farther out is not touching the shaft, and held there behind the heel it would push the
    rod away from where the rod left it, further with every step the rod gives way (the rigid
    needle's offsets stay within the tip's solid by themselves). Work arrays: ``held`` (bool),
    ``point_stiffness`` (3, 3) and ``point_pull`` (3) per point, ``node_share`` per mesh node
    (zeros, left zero). Writes each point's force on the tissue (``point_forces``), its arc length
    (``point_depths``), segment and fraction along it; ``loads`` is cleared and gets the
    friction's reaction on the rod. Returns the total friction force on the tissue along the
    needle."""
    x = scratch[0]
    transport_frames(nodes, base_rotation, frames)
    _locate_points(rest, displacement, point_nodes, point_weights, n_points, nodes, h, point_segments,
                   point_fractions, point_depths, x)
    _node_shares(point_nodes, point_weights, n_points, point_depths, free_beyond, node_share)
    for s in range(n_points):
        held[s] = point_depths[s] <= free_beyond
        for r in range(3):
            point_forces[s, r] = 0.0
    for _ in range(sweeps):
        _follow_offsets(rest, displacement, point_nodes, point_weights, n_points, nodes, frames, point_segments,
                        point_fractions, point_depths, free_beyond, radius, point_offsets, x)
        for s in range(n_points):
            if held[s]:
                held[s] = _lateral_stiffness(inverse_mass, force_scale, point_nodes, point_weights, node_share, s,
                                             frames, point_segments[s], dt, point_stiffness[s])
        if first_free < nodes.shape[0]:
            if _newton_with_points(rest, displacement, point_nodes, point_weights, n_points, nodes, first_free,
                                   base, base_axis, entry, h, bending, axial, loads, frames, gradient, band, step,
                                   before, free_beyond, closing_m, point_offsets, point_forces, point_segments,
                                   point_fractions, point_depths, held, point_stiffness, scratch):
                transport_frames(nodes, base_rotation, frames)
        _project_points(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights,
                        n_points, nodes, frames, point_segments, point_fractions, point_depths, held,
                        point_stiffness, free_beyond, closing_m, point_offsets, point_pull, dt, point_forces,
                        applied_forces, scratch)
    for s in range(n_points):                     # node_share back to zeros
        for k in range(4):
            node_share[point_nodes[s, k]] = 0.0
    _locate_points(rest, displacement, point_nodes, point_weights, n_points, nodes, h, point_segments,
                   point_fractions, point_depths, x)
    loads[:] = 0.0
    inserted = 0.0
    if n_points > 0:
        length_shares(point_depths, n_points, tip_depth, point_shares)
        inserted = max(tip_depth - point_depths[0], 0.0)
    total_friction = 0.0
    stick_half = 0.5 * friction[6]
    reaction = scratch[1]
    for s in range(n_points):
        j, a = point_segments[s], min(max(point_fractions[s], 0.0), 1.0)
        tissue_velocity = 0.0
        inverse_effective = 0.0
        scale = 0.0
        for k in range(4):
            i = point_nodes[s, k]
            w = point_weights[s, k]
            scale += w * force_scale[i]
            for r in range(3):
                tissue_velocity += w * velocity[i, r] * frames[j, r, 2]
                inverse_effective += w * w * inverse_mass[i, r] * frames[j, r, 2] ** 2
        if inverse_effective <= 0.0:
            continue
        needle_velocity = 0.0
        for r in range(3):
            needle_velocity += ((1.0 - a) * (nodes[j, r] - previous[j, r])
                                + a * (nodes[j + 1, r] - previous[j + 1, r])) / dt * frames[j, r, 2]
        impulse = karnopp_impulse(needle_velocity - tissue_velocity, inverse_effective, scale, point_shares[s],
                                  inserted, friction, stick_half, dt)
        for r in range(3):
            reaction[r] = 0.0
        for k in range(4):
            i = point_nodes[s, k]
            for r in range(3):
                dv = point_weights[s, k] * inverse_mass[i, r] * impulse * frames[j, r, 2]
                velocity[i, r] += dv
                displacement[i, r] += dt * dv
                if inverse_mass[i, r] > 0.0:
                    f = force_scale[i] * point_weights[s, k] * impulse * frames[j, r, 2] / dt
                    applied_forces[i, r] += f
                    point_forces[s, r] += f
                    reaction[r] -= f
        add_load(nodes, loads, j, a, x, reaction, x, True)
        total_friction += scale * impulse / dt
    return total_friction


@njit(cache=True)
def add_load(nodes, loads, segment, fraction, point, force, scratch, on_line):
    """Add ``force`` acting at ``point`` to the rod's node ``loads``: on the segment's nodes by
    ``fraction``, with the couple of its offset from the centreline there (forces +-(m x t) / l
    on the segment's ends: its moment m, t and l the segment's direction and length), none where
    ``on_line`` (a force on the centreline)."""
    for r in range(3):
        loads[segment, r] += (1.0 - fraction) * force[r]
        loads[segment + 1, r] += fraction * force[r]
    if on_line:
        return
    length = 0.0
    for r in range(3):
        scratch[r] = point[r] - ((1.0 - fraction) * nodes[segment, r] + fraction * nodes[segment + 1, r])
        length += (nodes[segment + 1, r] - nodes[segment, r]) ** 2
    length = math.sqrt(length)
    m0 = scratch[1] * force[2] - scratch[2] * force[1]
    m1 = scratch[2] * force[0] - scratch[0] * force[2]
    m2 = scratch[0] * force[1] - scratch[1] * force[0]
    t0 = (nodes[segment + 1, 0] - nodes[segment, 0]) / length
    t1 = (nodes[segment + 1, 1] - nodes[segment, 1]) / length
    t2 = (nodes[segment + 1, 2] - nodes[segment, 2]) / length
    c0, c1, c2 = (m1 * t2 - m2 * t1) / length, (m2 * t0 - m0 * t2) / length, (m0 * t1 - m1 * t0) / length
    loads[segment + 1, 0] += c0
    loads[segment + 1, 1] += c1
    loads[segment + 1, 2] += c2
    loads[segment, 0] -= c0
    loads[segment, 1] -= c1
    loads[segment, 2] -= c2


@njit(cache=True)
def add_tip_loads(nodes, loads, points, forces, start, stop, scratch):
    """The reaction on the rod of the forces ``forces[start:stop]`` the tip put on the tissue at
    ``points`` (its samples: on the tip's faces, at most a tip's length behind the apex), on
    the last segment at each point's place along it, with its couple."""
    j = nodes.shape[0] - 2
    length2 = 0.0
    for r in range(3):
        length2 += (nodes[j + 1, r] - nodes[j, r]) ** 2
    reaction = scratch[3]
    for k in range(start, stop):
        along = 0.0
        for r in range(3):
            along += (points[k, r] - nodes[j, r]) * (nodes[j + 1, r] - nodes[j, r])
            reaction[r] = -forces[k, r]
        add_load(nodes, loads, j, min(max(along / length2, 0.0), 1.0), points[k], reaction, scratch[2], False)


@njit(cache=True)
def tip_frame(nodes, previous, frames, length, dt, tip, tip_rotation, tip_axis, virtual_base, tip_velocity,
              travel):
    """The tip from the rod: the apex (the last node), its frame (the last segment's), its travel
    and velocity over the step, and the base of a straight needle with that tip (what the rigid
    needle's kernels take for the cutting law: its axis the tip's)."""
    n = nodes.shape[0] - 1
    for r in range(3):
        tip[r] = nodes[n, r]
        travel[r] = nodes[n, r] - previous[n, r]
        tip_velocity[r] = travel[r] / dt
        for c in range(3):
            tip_rotation[r, c] = frames[n - 1, r, c]
        tip_axis[r] = frames[n - 1, r, 2]
        virtual_base[r] = tip[r] - length * tip_axis[r]


@njit(cache=True)
def centreline_points(nodes, point_segments, point_fractions, n, points, start):
    """points[start + k] = the centreline at point k's place (its points of action)."""
    for k in range(n):
        j, a = point_segments[k], point_fractions[k]
        for r in range(3):
            points[start + k, r] = (1.0 - a) * nodes[j, r] + a * nodes[j + 1, r]
