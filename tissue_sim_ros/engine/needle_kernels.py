"""The needle's numba kernels: surface ray casts, point location and the per-step constraints.

Geometric queries (:func:`first_surface_hit`, :func:`locate_point`) run when the needle meets
the surface or adds a shaft point; the constraint kernels run every step and allocate nothing:
the bonded-contact solve (:func:`patch_solve`, :func:`patch_apply`), the shaft's lateral hold and
modified-Karnopp friction (:func:`shaft_solve`, Okamura et al. 2004), and the reaction wrench
(:func:`wrench_about`). The physics they implement is described in :mod:`.needle`.
"""
import numpy as np
from numba import njit

__all__ = ['first_surface_hit', 'locate_point', 'patch_solve', 'patch_apply', 'needle_kinematics',
           'put_rigid_points', 'put_axis_points', 'put_rows', 'wrench_about', 'shaft_solve']


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
def patch_solve(rest, displacement, nodes, weights, pseudo_inverse, targets, residual, multipliers,
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
def patch_apply(displacement, velocity, inverse_mass, force_scale, nodes, weights, multipliers, dt,
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
def needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel,
                       base_velocity, axis_rate):
    """Tip, tip travel over the step, base velocity and axis rate, written into the given arrays."""
    for r in range(3):
        tip[r] = position[r] + length * axis[r]
        travel[r] = tip[r] - previous_position[r] - length * previous_axis[r]
        base_velocity[r] = (position[r] - previous_position[r]) / dt
        axis_rate[r] = (axis[r] - previous_axis[r]) / dt


@njit(cache=True)
def put_rigid_points(origin, rotation, offsets, n, points, start):
    """points[start + k] = origin + R offsets[k] for k < n (points fixed in the needle frame)."""
    for k in range(n):
        for r in range(3):
            points[start + k, r] = (origin[r] + rotation[r, 0] * offsets[k, 0] + rotation[r, 1] * offsets[k, 1]
                                    + rotation[r, 2] * offsets[k, 2])


@njit(cache=True)
def put_axis_points(base, axis, depths, n, points, start):
    """points[start + k] = base + depths[k] axis for k < n (shaft points)."""
    for k in range(n):
        for r in range(3):
            points[start + k, r] = base[r] + depths[k] * axis[r]


@njit(cache=True)
def put_rows(source, n, target, start):
    """target[start + k] = source[k] for k < n."""
    for k in range(n):
        for r in range(3):
            target[start + k, r] = source[k, r]


@njit(cache=True)
def wrench_about(points, forces, n, base, force, torque):
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
def shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
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
