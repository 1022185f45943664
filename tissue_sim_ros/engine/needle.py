"""A rigid needle against the tissue: contact, puncture, cutting, friction, reaction wrench.

The needle is a straight rigid cylinder given by the pose of its base frame (position, unit
quaternion x y z w); its axis is the frame's +z and the tip is at +z * length (DESIGN.md). The
tissue is a :class:`~tissue_sim_ros.engine.solver.Simulation`. Each time step the scene moves the needle
(:meth:`NeedleTissue.set_pose`), calls ``Simulation.step`` and then
:meth:`NeedleTissue.after_step`, which applies the needle's constraints and forces as follows.

Material points. The needle acts on *material points* of the tissue: a point inside an element
(barycentric weights over its 4 nodes) or on a surface triangle (3 nodes), located once in the
deformed mesh and then carried by the tissue. A force on a point goes to its nodes by the same
weights, so elements larger than the needle are handled, and the needle's footprint is resolved
as soon as the mesh is finer than it.

Contact (phase ``contact``). When the tip crosses the deformed surface, the needle's flat end is
sampled by points on rings (centre, 6 at r/2, 12 at r) and each is bonded to the surface point
under it. A sample bonds its whole triangle, so on a mesh coarser than the needle radius the
punch is as wide as the triangles under it (elements larger than the needle are handled, the
force is overestimated). Where the surface triangles are smaller than the radius, the surface
nodes under the end are bonded instead (with at least 3 of them), and the force converges to the
rigid bonded flat punch as the mesh is refined: 2 a E delta / (1 - nu^2) (Sneddon) times
(1 - nu) ln(3 - 4 nu) / (1 - 2 nu) for no slip (Mossakovskii), within 2 % at 0.5 mm cells.
The bond is a hard constraint solved exactly each step: the mass-weighted smallest
correction that puts every sample point on its target (a rigid-body point of the needle end),
Delta u = M^-1 W^T lambda with (W M^-1 W^T) lambda = -(W x - T); the force on the tissue is
W^T lambda / dt^2. The pseudo-inverse of W M^-1 W^T is computed once per contact, so samples that
share one coarse triangle are fine. The contact lets go when the needle, not advancing, would
pull the tissue (while it advances, a momentary pull from the tissue's rebound keeps the bond:
letting go there made the contact chatter on visco-elastic tissue).

Puncture (the region's membrane). Criterion ``force``: the axial contact force reaches
``rupture_force_n`` (checked every step, so puncture happens within one step of the crossing).
Criterion ``energy``: the work the needle has done on the tissue since contact reaches
``toughness_j_per_m2`` times the needle's cross-section area (fracture-mechanics view of
Mahvash and Dupont 2010); viscous work counts, so a faster insertion ruptures earlier. With
F = f(d) + v beta(d), dF_rupture/dv = beta(d) - F'(d) B(d) / F (B the integral of beta): the rupture
force falls with speed where the curve stiffens faster than the viscous force grows (a stiffening
law; a flat punch on a linear material is about neutral). At puncture the contact is released and the tissue relaxes.

Inside (phases ``inserted``, ``retracting``). Shaft points are material points created at the
tip each ``shaft_point_spacing_m`` of advance. Each is held on the needle axis (lateral
constraint, so the tissue follows the needle sideways) and dragged along it by friction: a
modified Karnopp law per unit length (Okamura et al. 2004) with the inserted length shared
equally between the points. Relative velocity v (needle minus tissue, along the axis): inside
the stick band |v| <= stick_band / 2 the impulse that stops the relative motion is applied, up
to the static limit D; outside, the slip force (C + b |v|) opposes v. The slip force is solved
implicitly (the tissue point's velocity after the impulse enters b |v|), so it is stable for any
step. Insertion uses the ``insertion`` coefficients, retraction the ``retraction`` ones
(magnitudes). A shaft point the tip has passed back over is released; the needle is out when
none is left.

Cutting. The material points under the needle end (the disc samples, relocated at each new
shaft point) are pushed along the axis by the same velocity-level solve with a one-sided limit:
the tip carries the tissue in front of it at its own speed until that takes more than the
region's ``cutting_force_n`` (shared between the samples); then the tissue is cut and the force
is the cutting force. It never pulls, so retraction has no cutting force, and a needle stopped
inside still feels the compressed tissue push back (up to the cutting force).

Layers. When a new shaft point lies in another region that has a membrane, the needle end is
bonded to the material points in front of it and that membrane must be punctured in turn.

Reaction wrench. Every force the needle puts on the tissue is recorded with its point of action
on the needle; the wrench on the needle is their negative sum, and the torque about the base
origin is sum (r - p) x (-f). Both are available in the world or the needle frame.
"""
import logging
import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

_log = logging.getLogger('tissue_sim_ros.needle')

PHASES = ('approach', 'contact', 'inserted', 'retracting')
QUATERNION_NORM_TOLERANCE = 0.01     # |‖q‖ - 1| above this is an error, below it q is normalised


class NeedleInputError(ValueError):
    """A needle pose or parameter the engine refuses; names the field and the value."""

    def __init__(self, field_name, value, expected):
        self.field = field_name
        self.value = value
        super().__init__(f'{field_name} = {value!r}: {expected}')


# -- poses -------------------------------------------------------------------------------------
def rotation_matrix(quaternion):
    """3x3 rotation of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def slerp(q0, q1, s):
    """Spherical linear interpolation between unit quaternions (x, y, z, w), shortest arc."""
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(d)
    return (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)


_normalised_once = False


def validate_pose(position, orientation, field_name='pose'):
    """(position (3,), unit quaternion (4,)) as float arrays, or NeedleInputError naming the field.

    A quaternion whose norm is within QUATERNION_NORM_TOLERANCE of 1 is normalised (said once in
    the log); farther from unit it is refused.
    """
    global _normalised_once
    try:
        p = np.array(position, dtype=np.float64).reshape(-1)
        q = np.array(orientation, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise NeedleInputError(field_name, (position, orientation), 'expected numbers') from None
    if p.shape != (3,) or not np.all(np.isfinite(p)):
        raise NeedleInputError(f'{field_name}.position', p.tolist(), 'expected 3 finite numbers [m]')
    if q.shape != (4,) or not np.all(np.isfinite(q)):
        raise NeedleInputError(f'{field_name}.orientation', q.tolist(),
                               'expected 4 finite numbers (quaternion x, y, z, w)')
    norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise NeedleInputError(f'{field_name}.orientation', q.tolist(),
                               f'quaternion norm {norm:.6g}, expected 1 within {QUATERNION_NORM_TOLERANCE}')
    if abs(norm - 1.0) > 1e-9:
        if not _normalised_once:
            _log.warning('%s.orientation: quaternion norm %.9g normalised to 1 (said once)', field_name, norm)
            _normalised_once = True
        q = q / norm
    return p, q


# -- geometric queries (numba) ------------------------------------------------------------------
@njit(cache=True)
def first_surface_hit(rest, displacement, triangles, origin, direction, t_min, t_max):
    """Nearest-to-t_min crossing of the ray origin + t direction (t in [t_min, t_max]) with the
    deformed surface triangles (Moller-Trumbore). Returns (triangle, t, w0, w1, w2) or -1."""
    best, best_t, b0, b1, b2 = -1, np.inf, 0.0, 0.0, 0.0
    for k in range(triangles.shape[0]):
        ia, ib, ic = triangles[k, 0], triangles[k, 1], triangles[k, 2]
        ax = rest[ia, 0] + displacement[ia, 0]
        ay = rest[ia, 1] + displacement[ia, 1]
        az = rest[ia, 2] + displacement[ia, 2]
        e1x = rest[ib, 0] + displacement[ib, 0] - ax
        e1y = rest[ib, 1] + displacement[ib, 1] - ay
        e1z = rest[ib, 2] + displacement[ib, 2] - az
        e2x = rest[ic, 0] + displacement[ic, 0] - ax
        e2y = rest[ic, 1] + displacement[ic, 1] - ay
        e2z = rest[ic, 2] + displacement[ic, 2] - az
        px = direction[1] * e2z - direction[2] * e2y
        py = direction[2] * e2x - direction[0] * e2z
        pz = direction[0] * e2y - direction[1] * e2x
        det = e1x * px + e1y * py + e1z * pz
        if abs(det) < 1e-30:
            continue
        inv = 1.0 / det
        tx, ty, tz = origin[0] - ax, origin[1] - ay, origin[2] - az
        u = (tx * px + ty * py + tz * pz) * inv
        if u < 0.0 or u > 1.0:
            continue
        qx = ty * e1z - tz * e1y
        qy = tz * e1x - tx * e1z
        qz = tx * e1y - ty * e1x
        v = (direction[0] * qx + direction[1] * qy + direction[2] * qz) * inv
        if v < 0.0 or u + v > 1.0:
            continue
        t = (e2x * qx + e2y * qy + e2z * qz) * inv
        if t_min <= t <= t_max and t < best_t:
            best, best_t, b0, b1, b2 = k, t, 1.0 - u - v, u, v
    return best, best_t, b0, b1, b2


@njit(cache=True)
def locate_point(rest, displacement, tetrahedra, point, tolerance):
    """Element of the deformed mesh containing ``point`` and its barycentric weights, or -1.

    Brute force with a bounding-box test first (about 10 ns per element): it runs once per shaft
    point, not per step.
    """
    weights = np.zeros(4)
    px, py, pz = point[0], point[1], point[2]
    for e in range(tetrahedra.shape[0]):
        i0, i1, i2, i3 = tetrahedra[e, 0], tetrahedra[e, 1], tetrahedra[e, 2], tetrahedra[e, 3]
        x0 = rest[i0, 0] + displacement[i0, 0]
        x1 = rest[i1, 0] + displacement[i1, 0]
        x2 = rest[i2, 0] + displacement[i2, 0]
        x3 = rest[i3, 0] + displacement[i3, 0]
        if px < min(x0, x1, x2, x3) - tolerance or px > max(x0, x1, x2, x3) + tolerance:
            continue
        y0 = rest[i0, 1] + displacement[i0, 1]
        y1 = rest[i1, 1] + displacement[i1, 1]
        y2 = rest[i2, 1] + displacement[i2, 1]
        y3 = rest[i3, 1] + displacement[i3, 1]
        if py < min(y0, y1, y2, y3) - tolerance or py > max(y0, y1, y2, y3) + tolerance:
            continue
        z0 = rest[i0, 2] + displacement[i0, 2]
        z1 = rest[i1, 2] + displacement[i1, 2]
        z2 = rest[i2, 2] + displacement[i2, 2]
        z3 = rest[i3, 2] + displacement[i3, 2]
        if pz < min(z0, z1, z2, z3) - tolerance or pz > max(z0, z1, z2, z3) + tolerance:
            continue
        ax, ay, az = x1 - x0, y1 - y0, z1 - z0          # columns of D = [x1-x0, x2-x0, x3-x0]
        bx, by, bz = x2 - x0, y2 - y0, z2 - z0
        cx, cy, cz = x3 - x0, y3 - y0, z3 - z0
        rx, ry, rz = px - x0, py - y0, pz - z0
        det = ax * (by * cz - bz * cy) - bx * (ay * cz - az * cy) + cx * (ay * bz - az * by)
        if abs(det) < 1e-300:
            continue
        l1 = (rx * (by * cz - bz * cy) - bx * (ry * cz - rz * cy) + cx * (ry * bz - rz * by)) / det
        l2 = (ax * (ry * cz - rz * cy) - rx * (ay * cz - az * cy) + cx * (ay * rz - az * ry)) / det
        l3 = (ax * (by * rz - bz * ry) - bx * (ay * rz - az * ry) + rx * (ay * bz - az * by)) / det
        if l1 >= -1e-9 and l2 >= -1e-9 and l3 >= -1e-9 and l1 + l2 + l3 <= 1.0 + 1e-9:
            weights[0] = 1.0 - l1 - l2 - l3
            weights[1] = l1
            weights[2] = l2
            weights[3] = l3
            return e, weights
    return -1, weights


# -- per-step constraint kernels (numba, no allocation) ----------------------------------------
@njit(cache=True)
def _patch_solve(rest, displacement, nodes, weights, pseudo_inverse, targets, residual, multipliers,
                 sample_scale, inverse_dt2, sample_forces, total):
    """Multipliers of the bonded-contact constraint W x = T (one solve per axis,
    lambda = -(W M^-1 W^T)^+ (W x - T)), each sample's force on the tissue
    (sum_j w_sj (1 + dt gamma_j)) lambda_s / dt^2 (sample_scale holds the sum) and their total."""
    n_samples = weights.shape[0]
    for s in range(n_samples):
        for r in range(3):
            acc = -targets[s, r]
            for j in range(nodes.shape[0]):
                i = nodes[j]
                acc += weights[s, j] * (rest[i, r] + displacement[i, r])
            residual[s, r] = acc
    for r in range(3):
        total[r] = 0.0
        for s in range(n_samples):
            acc = 0.0
            for t in range(n_samples):
                acc -= pseudo_inverse[r, s, t] * residual[t, r]
            multipliers[s, r] = acc
            sample_forces[s, r] = acc * sample_scale[s] * inverse_dt2
            total[r] += sample_forces[s, r]


@njit(cache=True)
def _patch_apply(displacement, velocity, inverse_mass, force_scale, nodes, weights, multipliers, dt,
                 applied_forces):
    """The mass-weighted correction Delta u = M^-1 W^T lambda of positions (and velocities, /dt),
    recorded as the force (1 + dt gamma) m Delta u / dt^2 on each node."""
    n_samples = weights.shape[0]
    for j in range(nodes.shape[0]):
        i = nodes[j]
        for r in range(3):
            lam = 0.0
            for s in range(n_samples):
                lam += weights[s, j] * multipliers[s, r]
            correction = inverse_mass[i, r] * lam
            displacement[i, r] += correction
            velocity[i, r] += correction / dt
            if inverse_mass[i, r] > 0.0:
                applied_forces[i, r] += force_scale[i] * lam / (dt * dt)


@njit(cache=True)
def _needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel,
                       base_velocity, axis_rate):
    """Tip, tip travel over the step, base velocity and axis rate, written into the given arrays."""
    for r in range(3):
        tip[r] = position[r] + length * axis[r]
        travel[r] = tip[r] - previous_position[r] - length * previous_axis[r]
        base_velocity[r] = (position[r] - previous_position[r]) / dt
        axis_rate[r] = (axis[r] - previous_axis[r]) / dt


@njit(cache=True)
def _put_rigid_points(origin, rotation, offsets, n, points, start):
    """points[start + k] = origin + R offsets[k] for k < n (points fixed in the needle frame)."""
    for k in range(n):
        for r in range(3):
            points[start + k, r] = (origin[r] + rotation[r, 0] * offsets[k, 0] + rotation[r, 1] * offsets[k, 1]
                                    + rotation[r, 2] * offsets[k, 2])


@njit(cache=True)
def _put_axis_points(base, axis, depths, n, points, start):
    """points[start + k] = base + depths[k] axis for k < n (shaft points)."""
    for k in range(n):
        for r in range(3):
            points[start + k, r] = base[r] + depths[k] * axis[r]


@njit(cache=True)
def _put_rows(source, n, target, start):
    """target[start + k] = source[k] for k < n."""
    for k in range(n):
        for r in range(3):
            target[start + k, r] = source[k, r]


@njit(cache=True)
def _wrench(points, forces, n, base, force, torque):
    """Force and torque about ``base`` on the needle from the forces it applies at ``points``:
    F = -sum f, T = sum (p - base) x (-f)."""
    for r in range(3):
        force[r] = 0.0
        torque[r] = 0.0
    for k in range(n):
        fx, fy, fz = -forces[k, 0], -forces[k, 1], -forces[k, 2]
        rx, ry, rz = points[k, 0] - base[0], points[k, 1] - base[1], points[k, 2] - base[2]
        force[0] += fx
        force[1] += fy
        force[2] += fz
        torque[0] += ry * fz - rz * fy
        torque[1] += rz * fx - rx * fz
        torque[2] += rx * fy - ry * fx


@njit(cache=True)
def _shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
                 base, axis, base_velocity, axis_rate, dt, segment_length, friction, sweeps,
                 point_forces, point_depths, applied_forces):
    """Hold each shaft point on the needle axis (Gauss-Seidel sweeps of the mass-weighted
    projection), then apply the implicit modified-Karnopp friction along the axis.

    force_scale: (n,) 1 + dt gamma_i. The solver's implicit damping divides whatever force acts
    in a step by it, so a correction Delta u made after the step stands for the force
    (1 + dt gamma_i) m_i Delta u_i / dt^2 (and an impulse J for (1 + dt gamma_i) J / dt).
    friction = (D_ins, C_ins, b_ins, D_ret, C_ret, b_ret, stick_band) per unit length.
    Writes each point's force on the tissue (point_forces) and its axial coordinate from the base
    (point_depths); returns the total friction force on the tissue along the axis.
    """
    for s in range(n_points):
        for r in range(3):
            point_forces[s, r] = 0.0
    for _ in range(sweeps):
        for s in range(n_points):
            along = 0.0
            for k in range(4):
                i = point_nodes[s, k]
                for r in range(3):
                    along += point_weights[s, k] * (rest[i, r] + displacement[i, r] - base[r]) * axis[r]
            for r in range(3):
                lateral = -base[r] - along * axis[r]
                for k in range(4):
                    i = point_nodes[s, k]
                    lateral += point_weights[s, k] * (rest[i, r] + displacement[i, r])
                denom = 0.0
                for k in range(4):
                    denom += point_weights[s, k] ** 2 * inverse_mass[point_nodes[s, k], r]
                if denom <= 0.0:
                    continue
                lam = -lateral / denom
                for k in range(4):
                    i = point_nodes[s, k]
                    correction = point_weights[s, k] * inverse_mass[i, r] * lam
                    displacement[i, r] += correction
                    velocity[i, r] += correction / dt
                    if inverse_mass[i, r] > 0.0:
                        f = force_scale[i] * point_weights[s, k] * lam / (dt * dt)
                        applied_forces[i, r] += f
                        point_forces[s, r] += f
    total_friction = 0.0
    stick_half = 0.5 * friction[6]
    for s in range(n_points):
        along = 0.0
        tissue_velocity = 0.0
        inverse_effective = 0.0
        scale = 0.0                                  # force per impulse / dt at this point
        for k in range(4):
            i = point_nodes[s, k]
            w = point_weights[s, k]
            scale += w * force_scale[i]
            for r in range(3):
                along += w * (rest[i, r] + displacement[i, r] - base[r]) * axis[r]
                tissue_velocity += w * velocity[i, r] * axis[r]
                inverse_effective += w * w * inverse_mass[i, r] * axis[r] * axis[r]
        point_depths[s] = along
        if inverse_effective <= 0.0:
            continue
        needle_velocity = 0.0
        for r in range(3):
            needle_velocity += (base_velocity[r] + along * axis_rate[r]) * axis[r]
        relative = needle_velocity - tissue_velocity
        stop = relative / inverse_effective                    # impulse that ends the slip
        if relative >= 0.0:
            static, coulomb, viscous = friction[0], friction[1], friction[2]
        else:
            static, coulomb, viscous = friction[3], friction[4], friction[5]
        if abs(relative) <= stick_half:
            limit = static * segment_length * dt / scale
            impulse = min(max(stop, -limit), limit)
        else:
            magnitude = (segment_length * (coulomb + viscous * abs(relative)) * dt
                         / (scale + segment_length * viscous * inverse_effective * dt))
            impulse = magnitude if relative > 0.0 else -magnitude
            if abs(impulse) > abs(stop):
                impulse = stop
        for k in range(4):
            i = point_nodes[s, k]
            for r in range(3):
                dv = point_weights[s, k] * inverse_mass[i, r] * impulse * axis[r]
                velocity[i, r] += dv
                displacement[i, r] += dt * dv
                if inverse_mass[i, r] > 0.0:
                    f = force_scale[i] * point_weights[s, k] * impulse * axis[r] / dt
                    applied_forces[i, r] += f
                    point_forces[s, r] += f
        total_friction += scale * impulse / dt
    return total_friction


# -- parameters ---------------------------------------------------------------------------------
@dataclass(frozen=True)
class Friction:
    """Modified Karnopp friction per unit inserted length (Okamura et al. 2004): static limit D
    [N/m], Coulomb C [N/m], viscous b [N s/m^2] for insertion and for retraction (magnitudes), and
    the stick band [m/s] of relative velocity inside which the tissue sticks to the needle."""
    insertion_static_n_per_m: float = 0.0
    insertion_coulomb_n_per_m: float = 0.0
    insertion_viscous_n_s_per_m2: float = 0.0
    retraction_static_n_per_m: float = 0.0
    retraction_coulomb_n_per_m: float = 0.0
    retraction_viscous_n_s_per_m2: float = 0.0
    stick_band_m_per_s: float = 5e-4

    def as_array(self):
        return np.array([self.insertion_static_n_per_m, self.insertion_coulomb_n_per_m,
                         self.insertion_viscous_n_s_per_m2, self.retraction_static_n_per_m,
                         self.retraction_coulomb_n_per_m, self.retraction_viscous_n_s_per_m2,
                         self.stick_band_m_per_s])

    def slip_force(self, relative_velocity, length):
        """Slip force magnitude [N] on ``length`` metres at a relative velocity [m/s]."""
        if relative_velocity >= 0:
            return length * (self.insertion_coulomb_n_per_m + self.insertion_viscous_n_s_per_m2 * relative_velocity)
        return length * (self.retraction_coulomb_n_per_m - self.retraction_viscous_n_s_per_m2 * relative_velocity)


@dataclass(frozen=True)
class Membrane:
    """Puncture criterion of a region's boundary: 'force' (rupture_force_n) or 'energy'
    (toughness_j_per_m2 times the needle cross-section area)."""
    criterion: str = 'force'
    rupture_force_n: float = 1.0
    toughness_j_per_m2: float = 0.0


@dataclass(frozen=True)
class RegionInteraction:
    """What a region does to the needle: its membrane (None: entered without resistance), the
    cutting force at the tip [N], and the shaft friction."""
    name: str
    membrane: Membrane | None = None
    cutting_force_n: float = 0.0
    friction: Friction = field(default_factory=Friction)


@dataclass(frozen=True)
class NeedleGeometry:
    diameter_m: float = 0.0024
    length_m: float = 0.15
    shaft_point_spacing_m: float = 0.001
    max_jump_m: float = 0.005


def _disc_offsets(radius):
    """The flat end's sample points in the needle frame: centre, 6 at r/2, 12 at r (z = 0)."""
    points = [(0.0, 0.0)]
    for ring, count in ((0.5, 6), (1.0, 12)):
        for k in range(count):
            angle = 2 * math.pi * k / count
            points.append((ring * radius * math.cos(angle), ring * radius * math.sin(angle)))
    return np.array([(x, y, 0.0) for x, y in points])


class _Patch:
    """A bonded contact: sample material points (weights over ``nodes``) held to targets fixed in
    the needle frame (offsets from the tip)."""

    def __init__(self, nodes, weights, offsets, inverse_mass, region):
        self.nodes = nodes.astype(np.int64)
        self.weights = weights
        self.offsets = offsets                                  # (s, 3) in the needle frame
        self.region = region
        w_scaled = weights[None, :, :] * inverse_mass[nodes].T[:, None, :]    # (3, s, j)
        system = np.einsum('rsj,tj->rst', w_scaled, weights)
        self.pseudo_inverse = np.stack([np.linalg.pinv(system[r], rcond=1e-10, hermitian=True)
                                        for r in range(3)])
        n = len(offsets)
        self.targets = np.zeros((n, 3))
        self.residual = np.zeros((n, 3))
        self.multipliers = np.zeros((n, 3))
        self.sample_forces = np.zeros((n, 3))
        self.sample_scale = np.zeros(n)          # sum_j w_sj (1 + dt gamma_j), set by set_force_scale
        self.scale_generation = -1
        self.total = np.zeros(3)
        self.work = 0.0

    def set_force_scale(self, force_scale, generation):
        self.sample_scale[:] = self.weights @ force_scale[self.nodes]
        self.scale_generation = generation


class NeedleTissue:
    """The needle-tissue interaction state of one scene (see the module docstring).

    simulation: the tissue's Simulation. element_region: (m,) region index of each element.
    regions: list of RegionInteraction, by region index. geometry: NeedleGeometry.
    """

    def __init__(self, simulation, element_region, regions, geometry, position, orientation):
        self.simulation = simulation
        self.mesh = simulation.model.mesh
        self.element_region = np.asarray(element_region, dtype=np.int64)
        self.regions = list(regions)
        self.geometry = geometry
        self.tetrahedra = np.ascontiguousarray(simulation.model.tetrahedra, dtype=np.int64)
        self.rest = self.mesh.rest_positions
        self._surface_owner()
        self.disc_offsets = _disc_offsets(0.5 * geometry.diameter_m)
        capacity = int(math.ceil(geometry.length_m / geometry.shaft_point_spacing_m)) + 16
        self.point_nodes = np.zeros((capacity, 4), dtype=np.int64)
        self.point_weights = np.zeros((capacity, 4))
        self.point_forces = np.zeros((capacity, 3))
        self.point_depths = np.zeros(capacity)
        self.applied_forces = np.zeros((self.mesh.n_nodes, 3))
        n_disc = len(self.disc_offsets)
        self.tip_nodes = np.zeros((n_disc, 4), dtype=np.int64)     # cutting: material points at the tip
        self.tip_weights = np.zeros((n_disc, 4))
        self.tip_offsets = np.zeros((n_disc, 3))
        self.tip_forces = np.zeros((n_disc, 3))
        self.tip_depths = np.zeros(n_disc)
        # the cutting law in _shaft_solve's terms: static limit per sample (set per step), push only
        self._cutting_law = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.inf])
        self._friction_laws = [r.friction.as_array() for r in self.regions]
        # per-step work arrays (no allocation in the step loop)
        self._tip = np.zeros(3)
        self._travel = np.zeros(3)              # tip travel over the last step
        self._base_velocity = np.zeros(3)
        self._axis_rate = np.zeros(3)
        self._ray_origin = np.zeros(3)
        self.contact_force = np.zeros(3)
        self.wrench_force = np.zeros(3)         # world frame, on the needle, about the base origin
        self.wrench_torque = np.zeros(3)
        self._reserve_applied(capacity + n_disc + len(self.disc_offsets))
        self._mass_generation = 0
        self._initial_pose = validate_pose(position, orientation, 'needle.initial_pose')
        self.reset()
        self._check_outside(*self._initial_pose, 'needle.initial_pose')

    # -- set-up --------------------------------------------------------------------------------
    def _surface_owner(self):
        """Surface triangles and the element each belongs to (for the membrane of the region hit)."""
        triangles = self.mesh.surface_triangles()
        faces = np.sort(self.tetrahedra[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]], axis=2).reshape(-1, 3)
        n = np.int64(self.mesh.n_nodes)
        face_keys = (faces[:, 0] * n + faces[:, 1]) * n + faces[:, 2]
        sorted_tri = np.sort(triangles, axis=1)
        tri_keys = (sorted_tri[:, 0] * n + sorted_tri[:, 1]) * n + sorted_tri[:, 2]
        order = np.argsort(face_keys, kind='stable')
        found = order[np.searchsorted(face_keys[order], tri_keys)]
        self.surface_triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self.surface_nodes = np.unique(self.surface_triangles)
        self.surface_owner = found // 4

    def reset(self):
        """Needle back at its initial pose, out of the tissue, no forces."""
        self.position, self.orientation = (a.copy() for a in self._initial_pose)
        self.rotation = rotation_matrix(self.orientation)
        self.axis = self.rotation[:, 2].copy()
        self._previous_position = self.position.copy()
        self._previous_axis = self.axis.copy()
        self.phase = 'approach'
        self.patch = None
        self.n_points = 0
        self.region = -1
        self.n_tip = 0
        self.surface_point = None          # where the tip first touched the surface (world)
        self.puncture_events = []
        self.contact_force[:] = 0.0
        self.cutting_force = 0.0
        self.friction_force = 0.0
        self.wrench_force[:] = 0.0
        self.wrench_torque[:] = 0.0
        self.applied_forces[:] = 0.0
        self._forces_applied = False
        self.n_applied = 0
        self._mass_version = None
        self._update_tip()

    def _reserve_applied(self, capacity):
        """Room for ``capacity`` points of action (patch samples, shaft points, tip samples)."""
        old = getattr(self, '_applied_points', None)
        if old is None or len(old) < capacity:
            points, forces = np.zeros((capacity, 3)), np.zeros((capacity, 3))
            if old is not None:                    # keep what this step has written so far
                points[:len(old)] = old
                forces[:len(old)] = self._applied_point_forces
            self._applied_points, self._applied_point_forces = points, forces

    @property
    def application_points(self):
        """(k, 3) points of action [m] of the forces the needle applied in the last step (world)."""
        return self._applied_points[:self.n_applied]

    @property
    def application_forces(self):
        """(k, 3) forces [N] the needle applied to the tissue at ``application_points``."""
        return self._applied_point_forces[:self.n_applied]

    def _add_applied(self, n):
        """Start index for ``n`` more points of action."""
        start = self.n_applied
        self.n_applied += n
        return start

    def _update_tip(self):
        np.multiply(self.axis, self.geometry.length_m, out=self._tip)
        self._tip += self.position

    @property
    def tip(self):
        """Tip position (3,) [m], world frame (read only: the needle updates it in place)."""
        return self._tip

    def _check_outside(self, position, orientation, field_name):
        """Refuse a needle whose shaft or tip lies inside the (deformed) tissue."""
        axis = rotation_matrix(orientation)[:, 2]
        disp = self.simulation.displacement
        size = float(np.ptp(self.rest, axis=0).max())
        for s in np.linspace(0.0, 1.0, 33):
            point = position + s * self.geometry.length_m * axis
            element, _ = locate_point(self.rest, disp, self.tetrahedra, point, 1e-9 * size)
            if element >= 0:
                raise NeedleInputError(field_name, {'position': position.tolist(), 'orientation': orientation.tolist()},
                                       f'the needle starts inside the tissue (point {point.tolist()} m '
                                       f'lies in element {element}); start it outside')

    # -- pose -----------------------------------------------------------------------------------
    def check_pose(self, position, orientation, field_name='pose'):
        """Validate a new pose against the current one (values, unit quaternion, jump)."""
        position, orientation = validate_pose(position, orientation, field_name)
        jump_base = float(np.linalg.norm(position - self.position))
        new_tip = position + self.geometry.length_m * rotation_matrix(orientation)[:, 2]
        jump = max(jump_base, float(np.linalg.norm(new_tip - self.tip)))
        if jump > self.geometry.max_jump_m:
            raise NeedleInputError(f'{field_name}.position', position.tolist(),
                                   f'moves the needle by {jump * 1e3:.4g} mm in one call, more than '
                                   f'max_jump_m = {self.geometry.max_jump_m * 1e3:.4g} mm')
        return position, orientation

    def set_pose(self, position, orientation):
        """Move the needle (already validated) for the coming step."""
        self._previous_position[:] = self.position
        self._previous_axis[:] = self.axis
        self.position[:] = position
        self.orientation[:] = orientation
        self.rotation[:] = rotation_matrix(orientation)
        self.axis[:] = self.rotation[:, 2]
        self._update_tip()

    # -- stepping ---------------------------------------------------------------------------------
    def after_step(self, dt):
        """Contact, shaft constraints and friction after the tissue's step; puncture; wrench.

        Allocates no arrays on the way (work arrays are made in the constructor and at contact).
        """
        sim = self.simulation
        if self._forces_applied:
            self.applied_forces[:] = 0.0
        self.contact_force[:] = 0.0
        self.friction_force = 0.0
        self.cutting_force = 0.0
        self.n_applied = 0
        inverse_mass = self._inverse_mass()
        _needle_kinematics(self.position, self.axis, self._previous_position, self._previous_axis,
                           self.geometry.length_m, dt, self._tip, self._travel, self._base_velocity, self._axis_rate)
        if self.phase == 'approach':
            self._detect_surface_contact(inverse_mass)
        if self.patch is not None:
            self._enforce_patch(inverse_mass, dt)
        if self.n_points:
            n = self.n_points
            length = self.geometry.length_m - float(self.point_depths[:n].min())
            segment = max(length, 0.0) / n
            self.friction_force = _shaft_solve(
                self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.point_nodes,
                self.point_weights, n, self.position, self.axis, self._base_velocity, self._axis_rate,
                dt, segment, self._friction_laws[self.region], 2, self.point_forces, self.point_depths,
                self.applied_forces)
            start = self._add_applied(n)
            _put_axis_points(self.position, self.axis, self.point_depths, n, self._applied_points, start)
            _put_rows(self.point_forces, n, self._applied_point_forces, start)
            if self.patch is None and self.n_tip:
                self._cutting_law[0] = self.regions[self.region].cutting_force_n / self.n_tip
                self.cutting_force = _shaft_solve(
                    self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.tip_nodes,
                    self.tip_weights, self.n_tip, self.position, self.axis, self._base_velocity, self._axis_rate,
                    dt, 1.0, self._cutting_law, 0, self.tip_forces, self.tip_depths, self.applied_forces)
                start = self._add_applied(self.n_tip)
                _put_rigid_points(self._tip, self.rotation, self.tip_offsets, self.n_tip, self._applied_points, start)
                _put_rows(self.tip_forces, self.n_tip, self._applied_point_forces, start)
            self._release_passed_points()
            if self.patch is None and self.n_points:
                self._grow_shaft(inverse_mass)
        self._forces_applied = self.n_applied > 0
        if self._forces_applied:         # work of the needle's forces, for the energy watchdog
            sim.input_work += float(np.vdot(self.applied_forces, sim.velocity)) * dt
        self._update_phase(dt)
        _wrench(self._applied_points, self._applied_point_forces, self.n_applied, self.position,
                self.wrench_force, self.wrench_torque)

    def _inverse_mass(self):
        """(n, 3) inverse mass of each free DOF, 0 for held ones; rebuilt when the masses change."""
        sim = self.simulation
        if self._mass_version != (sim._topology_version, sim.dt):
            self._inverse_mass_dofs = np.where(sim.dof_kind == 0, sim.inverse_mass[:, None], 0.0)
            self._force_scale = 1.0 + sim.dt * sim.damping_rate
            self._mass_version = (sim._topology_version, sim.dt)
            self._mass_generation += 1
        return self._inverse_mass_dofs

    # -- contact and puncture ---------------------------------------------------------------------
    def _detect_surface_contact(self, inverse_mass):
        """Start a contact when the tip has crossed the deformed surface."""
        # the tip is past the surface if the surface lies within the last step's travel or one
        # diameter behind the tip (the surface may have come up to a needle at rest)
        back = math.sqrt(float(self._travel @ self._travel)) + self.geometry.diameter_m
        disp = self.simulation.displacement
        np.multiply(self.axis, -back, out=self._ray_origin)
        self._ray_origin += self._tip
        hit, t, _, _, _ = first_surface_hit(self.rest, disp, self.surface_triangles, self._ray_origin,
                                            self.axis, 0.0, back)
        if hit < 0:
            return
        self.surface_point = self.tip - (back - t) * self.axis
        region = int(self.element_region[self.surface_owner[hit]])
        reach = self.geometry.diameter_m
        radius = 0.5 * reach
        samples, nodes, weights, areas = [], [], [], []
        for offset in self.disc_offsets:
            origin = self.tip + self.rotation @ offset - reach * self.axis
            k, ts, w0, w1, w2 = first_surface_hit(self.rest, disp, self.surface_triangles, origin,
                                                  self.axis, 0.0, 2.0 * reach)
            if k < 0:
                continue
            samples.append(offset + np.array([0.0, 0.0, max(ts - reach, 0.0)]))
            nodes.append(self.surface_triangles[k])
            weights.append((w0, w1, w2))
            corners = self.rest[self.surface_triangles[k]] + disp[self.surface_triangles[k]]
            areas.append(0.5 * np.linalg.norm(np.cross(corners[1] - corners[0], corners[2] - corners[0])))
        if not samples:
            return
        # A mesh finer than the needle radius resolves the footprint: bond the surface nodes
        # under the end instead. A sample bonds its whole triangle, so the rings make a punch of
        # radius up to a + h (linear, 1 mm deep: 2.4x the flat punch with 1 mm cells, still 1.5x
        # with 0.5 mm ones) while the nodes under it converge to it (1.14, 1.01, 0.99 at 1, 0.7,
        # 0.5 mm).
        element_size = math.sqrt(2.0 * float(np.mean(areas)))       # leg of a right isosceles triangle
        if element_size <= radius:
            relative = (self.rest[self.surface_nodes] + disp[self.surface_nodes] - self.tip) @ self.rotation
            under = np.flatnonzero((np.hypot(relative[:, 0], relative[:, 1]) <= radius * (1.0 + 1e-9))
                                   & (np.abs(relative[:, 2]) <= reach))
            if len(under) >= 3:
                samples = [np.array([relative[j, 0], relative[j, 1], max(relative[j, 2], 0.0)]) for j in under]
                nodes = [np.full(3, self.surface_nodes[j]) for j in under]
                weights = [(1.0, 0.0, 0.0)] * len(under)
        self._begin_patch(np.array(samples), np.array(nodes), np.array(weights), region, inverse_mass)

    def _begin_patch(self, offsets, sample_nodes, sample_weights, region, inverse_mass):
        membrane = self.regions[region].membrane
        if membrane is None:                       # no membrane: the needle enters at once
            self._enter(region, sample_nodes[0], sample_weights[0])
            return
        unique, inverse = np.unique(sample_nodes, return_inverse=True)
        weights = np.zeros((len(offsets), len(unique)))
        np.add.at(weights, (np.repeat(np.arange(len(offsets)), sample_nodes.shape[1]), inverse.ravel()),
                  sample_weights.ravel())
        self.patch = _Patch(unique, weights, offsets, inverse_mass, region)
        self._reserve_applied(len(offsets) + len(self.point_nodes) + len(self.disc_offsets))
        self.phase = 'contact'

    def _enforce_patch(self, inverse_mass, dt):
        patch, sim = self.patch, self.simulation
        if patch.scale_generation != self._mass_generation:
            patch.set_force_scale(self._force_scale, self._mass_generation)
        n = len(patch.offsets)
        _put_rigid_points(self._tip, self.rotation, patch.offsets, n, patch.targets, 0)
        _patch_solve(self.rest, sim.displacement, patch.nodes, patch.weights, patch.pseudo_inverse, patch.targets,
                     patch.residual, patch.multipliers, patch.sample_scale, 1.0 / (dt * dt), patch.sample_forces,
                     patch.total)
        total = patch.total
        advancing = float(self._travel @ self.axis) > 0.0
        if float(total @ self.axis) < 0.0 and not advancing:   # it would pull back: contact lost
            self.patch = None
            if self.n_points == 0:
                self.phase = 'approach'
            return
        _patch_apply(sim.displacement, sim.velocity, inverse_mass, self._force_scale, patch.nodes, patch.weights,
                     patch.multipliers, dt, self.applied_forces)
        self.contact_force[:] = total
        patch.work += float(total @ self._travel)
        start = self._add_applied(n)
        _put_rows(patch.targets, n, self._applied_points, start)
        _put_rows(patch.sample_forces, n, self._applied_point_forces, start)
        membrane = self.regions[patch.region].membrane
        axial = float(total @ self.axis)
        area = 0.25 * math.pi * self.geometry.diameter_m ** 2
        if membrane.criterion == 'force':
            ruptured = axial >= membrane.rupture_force_n
        else:
            ruptured = patch.work >= membrane.toughness_j_per_m2 * area
        if ruptured:
            self.puncture_events.append({'time_s': self.simulation.time, 'tip_depth_m': self.tip_depth(),
                                         'axial_force_n': axial, 'work_j': patch.work,
                                         'region': self.regions[patch.region].name})
            centre = int(np.argmin(np.linalg.norm(patch.offsets[:, :2], axis=1)))
            row = patch.weights[centre]
            take = np.argsort(row)[::-1][:4]
            self.patch = None
            self._enter(patch.region, patch.nodes[take], row[take] / row[take].sum())

    def _enter(self, region, nodes, weights):
        """Puncture done (or no membrane): the needle is inside ``region``; first shaft point."""
        self.region = region
        self._add_point(nodes, weights)
        self._locate_tip_samples()
        self.phase = 'inserted'

    def _add_point(self, nodes, weights):
        if self.n_points == len(self.point_nodes):
            return
        k = self.n_points
        self.point_nodes[k] = 0
        self.point_weights[k] = 0.0
        self.point_nodes[k, :len(nodes)] = nodes
        self.point_weights[k, :len(weights)] = weights
        self.point_depths[k] = self.geometry.length_m
        self.n_points += 1

    def _grow_shaft(self, inverse_mass):
        """A new shaft point at the tip each spacing of advance; a new region's membrane."""
        deepest = float(self.point_depths[:self.n_points].max())
        if self.geometry.length_m - deepest < self.geometry.shaft_point_spacing_m:
            return
        disp = self.simulation.displacement
        element, weights = locate_point(self.rest, disp, self.tetrahedra, self.tip, 0.0)
        if element < 0:                     # the tip has left the mesh
            self.n_tip = 0
            return
        region = int(self.element_region[element])
        self._locate_tip_samples()
        if region != self.region and self.regions[region].membrane is not None:
            n = self.n_tip
            self.n_tip = 0
            self._begin_patch(self.tip_offsets[:n].copy(), self.tip_nodes[:n].copy(),
                              self.tip_weights[:n].copy(), region, inverse_mass)
            return
        self.region = region
        self._add_point(self.tetrahedra[element], weights)

    def _locate_tip_samples(self):
        """The material points under the needle end (disc samples) that take the cutting force."""
        disp = self.simulation.displacement
        n = 0
        for offset in self.disc_offsets:
            e, w = locate_point(self.rest, disp, self.tetrahedra, self.tip + self.rotation @ offset, 0.0)
            if e >= 0:
                self.tip_offsets[n] = offset
                self.tip_nodes[n] = self.tetrahedra[e]
                self.tip_weights[n] = w
                n += 1
        self.n_tip = n

    def _release_passed_points(self):
        """Shaft points the tip has gone back over leave the needle (retraction). Only while it
        goes back: advancing, the cutting push can carry the first point (a surface node of a
        coarse element) ahead of the tip, and releasing it took the needle out, so the same
        membrane was punctured again at once (three times in 1 mm at 10 mm/s on 2 mm cells)."""
        limit = self.geometry.length_m + 0.5 * self.geometry.shaft_point_spacing_m
        if float(self._travel @ self.axis) >= 0.0 or self.point_depths[:self.n_points].max() <= limit:
            return
        keep = self.point_depths[:self.n_points] <= limit
        n = int(keep.sum())
        for arr in (self.point_nodes, self.point_weights, self.point_depths):
            arr[:n] = arr[:self.n_points][keep]
        self.n_points = n
        if n == 0:
            self.region = -1
            self.n_tip = 0

    def _update_phase(self, dt):
        if self.patch is not None:
            self.phase = 'contact'
        elif self.n_points:
            speed = float(self._base_velocity @ self.axis)
            self.phase = 'retracting' if speed < -1e-9 else 'inserted'
        else:
            self.phase = 'approach'
            self.surface_point = None

    # -- outputs ------------------------------------------------------------------------------------
    def tip_depth(self):
        """Travel [m] of the tip along the axis past the point where it first touched the surface
        (0 before contact and once the needle is out)."""
        if self.surface_point is None:
            return 0.0
        return max(0.0, float(np.dot(self.tip - self.surface_point, self.axis)))

    def reaction_wrench(self, frame='world'):
        """(force, torque) [N, N m] the tissue exerts on the needle, about the base origin, in the
        'world' frame or the 'needle' base frame."""
        if frame == 'world':
            return self.wrench_force.copy(), self.wrench_torque.copy()
        if frame == 'needle':
            return self.rotation.T @ self.wrench_force, self.rotation.T @ self.wrench_torque
        raise NeedleInputError('frame', frame, "expected 'world' or 'needle'")
