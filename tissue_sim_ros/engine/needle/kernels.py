"""The needle's numba kernels: surface ray casts, point location and the per-step constraints.

Geometric queries (:func:`first_surface_hit`, :func:`locate_point`) run when the needle meets
the surface or adds a shaft point; the constraint kernels run every step and allocate nothing:
the bonded-contact solve (:func:`patch_solve`, :func:`patch_apply`), the shaft's lateral hold and
modified-Karnopp friction (:func:`shaft_solve`, Okamura et al. 2004), and the reaction wrench
(:func:`wrench_about`). The physics they implement is described in :mod:`.interaction`.
"""
import math

import numpy as np
from numba import njit

__all__ = ['dot3', 'applied_work', 'first_surface_hit', 'near_surface_hit', 'approach_hit', 'cell_boxes',
           'locate_point', 'locate_walk', 'cells_near', 'follow_rigid_samples', 'patch_solve', 'patch_apply',
           'needle_kinematics', 'put_rigid_points', 'put_axis_points', 'put_rows', 'wrench_about',
           'length_shares', 'karnopp_impulse', 'shaft_solve']


@njit(cache=True)
def dot3(a, b):
    """a . b of two 3-vectors, summed in order: the Python that decides a contact step and the
    compiled contact step (engine.compiled.substeps) call this one function, so they agree to the
    last bit (numpy's dot of 3-vectors goes through BLAS, whose kernels may fuse and reorder)."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@njit(cache=True)
def applied_work(applied_forces, velocity):
    """The power of the needle's nodal forces, sum f . v over the mesh, summed node by node (one
    function for the general step and the compiled contact step)."""
    work = 0.0
    for i in range(applied_forces.shape[0]):
        for r in range(3):
            work += applied_forces[i, r] * velocity[i, r]
    return work


# -- geometric queries (numba) ------------------------------------------------------------------
@njit(cache=True)
def first_surface_hit(rest, displacement, triangles, origin, direction, t_min, t_max):
    """Nearest-to-t_min crossing of the ray origin + t direction (t in [t_min, t_max]) with the
    deformed surface triangles (Moller-Trumbore). Returns (triangle, t, w0, w1, w2) or -1."""
    return _nearest_crossing(rest, displacement, triangles, _NO_BOXES, 0.0, origin, direction, t_min, t_max)


@njit(cache=True)
def cell_boxes(rest, cells):
    """(k, 6) each cell's (rows of node indices: triangles or tetrahedra) bounding box in the
    rest configuration: x, y, z lows then highs (:func:`near_surface_hit`, :func:`cells_near`)."""
    boxes = np.empty((cells.shape[0], 6))
    for k in range(cells.shape[0]):
        for r in range(3):
            low, high = np.inf, -np.inf
            for j in range(cells.shape[1]):
                x = rest[cells[k, j], r]
                low, high = min(low, x), max(high, x)
            boxes[k, r] = low
            boxes[k, 3 + r] = high
    return boxes


@njit(cache=True, inline='always')
def _grown(displacement, nodes):
    """The largest displacement component over ``nodes``, plus 1e-12 m: a deformed cell of those
    nodes lies inside its rest box grown by it (the margin is far above the rounding of a sum of
    rest position and displacement, and of an accepted crossing, 1e-17 m)."""
    grown = 0.0
    for i in nodes:
        for r in range(3):
            grown = max(grown, abs(displacement[i, r]))
    return grown + 1e-12


@njit(cache=True)
def near_surface_hit(rest, displacement, triangles, boxes, surface_nodes, origin, direction, t_min, t_max):
    """:func:`first_surface_hit`, the same result, testing only the triangles whose rest box
    (``cell_boxes``) grown by the surface's largest displacement component (over
    ``surface_nodes``) meets the segment's box: a deformed triangle lies inside its grown box.
    The needle's test for the surface every step of its approach: tested whole, the default
    scene's 2244 triangles would be the step's largest cost outside the force kernel."""
    return _nearest_crossing(rest, displacement, triangles, boxes, _grown(displacement, surface_nodes), origin,
                             direction, t_min, t_max)


_NO_BOXES = np.zeros((0, 6))


@njit(cache=True, inline='always')
def _nearest_crossing(rest, displacement, triangles, boxes, grown, origin, direction, t_min, t_max):
    """The ray test of the two functions above: every triangle (``boxes`` without rows), or those
    whose box grown by ``grown`` meets the segment's box."""
    filtered = boxes.shape[0] > 0
    a0, b0 = origin[0] + t_min * direction[0], origin[0] + t_max * direction[0]
    a1, b1 = origin[1] + t_min * direction[1], origin[1] + t_max * direction[1]
    a2, b2 = origin[2] + t_min * direction[2], origin[2] + t_max * direction[2]
    low0, high0 = min(a0, b0) - grown, max(a0, b0) + grown
    low1, high1 = min(a1, b1) - grown, max(a1, b1) + grown
    low2, high2 = min(a2, b2) - grown, max(a2, b2) + grown
    best, best_t, w0, w1, w2 = -1, np.inf, 0.0, 0.0, 0.0
    for k in range(triangles.shape[0]):
        if filtered and (boxes[k, 0] > high0 or boxes[k, 3] < low0 or boxes[k, 1] > high1 or boxes[k, 4] < low1
                         or boxes[k, 2] > high2 or boxes[k, 5] < low2):
            continue
        t, u, v = _triangle_crossing(rest, displacement, triangles[k, 0], triangles[k, 1], triangles[k, 2],
                                     origin, direction)
        if t_min <= t <= t_max and t < best_t:
            best, best_t, w0, w1, w2 = k, t, 1.0 - u - v, u, v
    return best, best_t, w0, w1, w2


@njit(cache=True)
def approach_hit(rest, displacement, triangles, boxes, surface_nodes, tip, travel, axis, diameter, ray_origin):
    """Where the tip's last step crossed the deformed surface: (triangle, t, w0, w1, w2, back)
    of :func:`near_surface_hit` on the ray from ``back`` = |travel| + ``diameter`` behind the tip
    along ``axis`` (written to ``ray_origin``), triangle -1 for none or while the tip goes back
    (``travel`` against ``axis``: the tip coming up through the surface it left is no contact)."""
    if travel[0] * axis[0] + travel[1] * axis[1] + travel[2] * axis[2] < 0.0:
        return -1, 0.0, 0.0, 0.0, 0.0, 0.0
    back = math.sqrt(travel[0] * travel[0] + travel[1] * travel[1] + travel[2] * travel[2]) + diameter
    for r in range(3):
        ray_origin[r] = axis[r] * -back + tip[r]
    hit, t, w0, w1, w2 = near_surface_hit(rest, displacement, triangles, boxes, surface_nodes, ray_origin, axis,
                                          0.0, back)
    return hit, t, w0, w1, w2, back


@njit(cache=True, inline='always')
def _triangle_crossing(rest, displacement, ia, ib, ic, origin, direction):
    """(t, u, v) where the ray origin + t direction crosses the deformed triangle (ia, ib, ic)
    at barycentric (1 - u - v, u, v); t = inf where it does not (Moller-Trumbore)."""
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
        return np.inf, 0.0, 0.0
    inv = 1.0 / det
    tx, ty, tz = origin[0] - ax, origin[1] - ay, origin[2] - az
    u = (tx * px + ty * py + tz * pz) * inv
    if u < 0.0 or u > 1.0:
        return np.inf, 0.0, 0.0
    qx = ty * e1z - tz * e1y
    qy = tz * e1x - tx * e1z
    qz = tx * e1y - ty * e1x
    v = (direction[0] * qx + direction[1] * qy + direction[2] * qz) * inv
    if v < 0.0 or u + v > 1.0:
        return np.inf, 0.0, 0.0
    return (e2x * qx + e2y * qy + e2z * qz) * inv, u, v


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


@njit(cache=True)
def locate_walk(rest, displacement, tetrahedra, neighbours, start, point, max_steps, weights):
    """Element of the deformed mesh containing ``point``, walking from element ``start`` across
    the face opposite the most negative barycentric coordinate (a point that moved a little is
    found in a few steps, not by a search of the whole mesh); its barycentric weights in
    ``weights``. Returns the element, -1 when the walk leaves the mesh through its boundary, -2
    when it did not arrive within ``max_steps`` (the caller then searches: :func:`locate_point`)."""
    e = start
    px, py, pz = point[0], point[1], point[2]
    for _ in range(max_steps):
        i0, i1, i2, i3 = tetrahedra[e, 0], tetrahedra[e, 1], tetrahedra[e, 2], tetrahedra[e, 3]
        x0 = rest[i0, 0] + displacement[i0, 0]
        y0 = rest[i0, 1] + displacement[i0, 1]
        z0 = rest[i0, 2] + displacement[i0, 2]
        ax, ay, az = rest[i1, 0] + displacement[i1, 0] - x0, rest[i1, 1] + displacement[i1, 1] - y0, rest[i1, 2] + displacement[i1, 2] - z0
        bx, by, bz = rest[i2, 0] + displacement[i2, 0] - x0, rest[i2, 1] + displacement[i2, 1] - y0, rest[i2, 2] + displacement[i2, 2] - z0
        cx, cy, cz = rest[i3, 0] + displacement[i3, 0] - x0, rest[i3, 1] + displacement[i3, 1] - y0, rest[i3, 2] + displacement[i3, 2] - z0
        rx, ry, rz = px - x0, py - y0, pz - z0
        det = ax * (by * cz - bz * cy) - bx * (ay * cz - az * cy) + cx * (ay * bz - az * by)
        if abs(det) < 1e-300:
            return -2
        l1 = (rx * (by * cz - bz * cy) - bx * (ry * cz - rz * cy) + cx * (ry * bz - rz * by)) / det
        l2 = (ax * (ry * cz - rz * cy) - rx * (ay * cz - az * cy) + cx * (ay * rz - az * ry)) / det
        l3 = (ax * (by * rz - bz * ry) - bx * (ay * rz - az * ry) + rx * (ay * bz - az * by)) / det
        l0 = 1.0 - l1 - l2 - l3
        worst, k = l0, 0
        if l1 < worst:
            worst, k = l1, 1
        if l2 < worst:
            worst, k = l2, 2
        if l3 < worst:
            worst, k = l3, 3
        if worst >= -1e-9:
            weights[0], weights[1], weights[2], weights[3] = l0, l1, l2, l3
            return e
        e = neighbours[e, k]
        if e < 0:
            return -1
    return -2


@njit(cache=True)
def cells_near(rest, displacement, cells, boxes, nodes, centre, reach, candidates, near_boxes):
    """Indices of the cells (rows of node indices: triangles or tetrahedra) whose deformed
    bounding box comes within ``reach`` of ``centre`` (written into ``candidates``: room for
    every cell, in increasing order; their deformed boxes into ``near_boxes``, laid out as
    ``boxes``: room for every cell); returns how many. A cell whose rest box (``boxes``:
    :func:`cell_boxes`) grown by the largest displacement component over ``nodes`` (the nodes
    of the cells) is not within reach is skipped unread: its deformed box lies inside that one,
    so the answer is the same as testing every cell's deformed box, read through its nodes
    (4 gathers of 3 coordinates a tetrahedron against 6 contiguous values; in a retracting
    needle's step, testing all 13872 elements of the default scene would be half of its cost)."""
    grown = _grown(displacement, nodes)
    n = 0
    for k in range(cells.shape[0]):
        near = True
        for r in range(3):
            if boxes[k, r] - grown > centre[r] + reach or boxes[k, 3 + r] + grown < centre[r] - reach:
                near = False
                break
        if not near:
            continue
        for r in range(3):
            low, high = np.inf, -np.inf
            for j in range(cells.shape[1]):
                x = rest[cells[k, j], r] + displacement[cells[k, j], r]
                low, high = min(low, x), max(high, x)
            if low > centre[r] + reach or high < centre[r] - reach:
                near = False
                break
            near_boxes[n, r] = low
            near_boxes[n, 3 + r] = high
        if near:
            candidates[n] = k
            n += 1
    return n


@njit(cache=True)
def follow_rigid_samples(rest, displacement, tetrahedra, neighbours, boxes, nodes, origin, rotation, offsets,
                         elements, found_offsets, found_nodes, found_weights, weights, candidates, near_boxes):
    """The material under points fixed in the needle frame (``origin + R offsets[k]``), found
    again: each by a walk from ``elements[k]`` (where it was found last; updated) or, for a point
    that was outside, from the last sample found in this call (a walk that leaves the mesh means
    outside); when there is none or the walk is lost, by a search of the elements near
    ``origin`` only (:func:`cells_near`, made once per call when needed, ``boxes`` the elements'
    rest boxes, ``nodes`` those they use; ``candidates``, ``near_boxes``: room for every element),
    each candidate tried only where its deformed box, padded, holds the point (the containment
    test accepts a point 1e-9 of a barycentric coordinate outside: within 4e-9 of the box's
    extent; the pad is 1e-6 of it and 1e-12 m): the same element as trying every candidate, for
    6 comparisons instead of 12 gathers, which counts where a needle leaves the tissue: most
    samples are outside there, with no walk to start from, and each tries all ~340 candidates on
    the default scene. The search is near ``origin`` only, not over the whole mesh, so that the
    samples in the hole behind a sharp tip do not make every step dearer. Writes the found points'
    offsets, element nodes and weights compactly; returns how many were inside the mesh."""
    n = 0
    n_near = -1
    hint = -1
    reach = 0.0
    for k in range(offsets.shape[0]):
        reach = max(reach, math.sqrt(offsets[k, 0] ** 2 + offsets[k, 1] ** 2 + offsets[k, 2] ** 2))
    point = np.empty(3)
    for k in range(offsets.shape[0]):
        for r in range(3):
            point[r] = (origin[r] + rotation[r, 0] * offsets[k, 0] + rotation[r, 1] * offsets[k, 1]
                        + rotation[r, 2] * offsets[k, 2])
        e = -2
        start = elements[k] if elements[k] >= 0 else hint
        if start >= 0:
            e = locate_walk(rest, displacement, tetrahedra, neighbours, start, point, 64, weights)
        if e == -2:
            if n_near < 0:
                n_near = cells_near(rest, displacement, tetrahedra, boxes, nodes, origin, reach + 1e-9, candidates,
                                    near_boxes)
            e = -1
            for c in range(n_near):
                inside = True
                for r in range(3):
                    pad = 1e-6 * (near_boxes[c, 3 + r] - near_boxes[c, r]) + 1e-12
                    if point[r] < near_boxes[c, r] - pad or point[r] > near_boxes[c, 3 + r] + pad:
                        inside = False
                        break
                if inside and locate_walk(rest, displacement, tetrahedra, neighbours, candidates[c], point, 1,
                                          weights) >= 0:
                    e = candidates[c]
                    break
        elements[k] = e
        if e >= 0:
            hint = e
        if e >= 0:
            for r in range(3):
                found_offsets[n, r] = offsets[k, r]
            for j in range(4):
                found_nodes[n, j] = tetrahedra[e, j]
                found_weights[n, j] = weights[j]
            n += 1
    return n


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
def length_shares(depths, n, tip_depth, shares):
    """The inserted length each shaft point stands for, by the trapezoid rule along the axis
    (points in insertion order: their axial coordinates ``depths`` from the base increase):
    half the way to each neighbour, the deepest one to the tip at ``tip_depth``. The shares sum
    to the inserted length, tip_depth - depths[0], whatever the points: a new point at the tip
    takes its share from the one before it, so the total friction does not jump when points are
    added (equal shares would make it dip at every spacing)."""
    if n == 1:
        shares[0] = max(tip_depth - depths[0], 0.0)
        return
    shares[0] = max(0.5 * (depths[1] - depths[0]), 0.0)
    for k in range(1, n - 1):
        shares[k] = max(0.5 * (depths[k + 1] - depths[k - 1]), 0.0)
    shares[n - 1] = max(tip_depth - 0.5 * (depths[n - 2] + depths[n - 1]), 0.0)


@njit(cache=True, inline='always')
def karnopp_impulse(relative, inverse_effective, scale, segment, inserted, friction, stick_half, dt):
    """The friction impulse along the needle at one point (:func:`shaft_solve`'s law): ``relative``
    the needle's speed past the tissue point [m/s], ``inverse_effective`` the point's inverse mass
    along the needle, ``scale`` its force per impulse / dt, ``segment`` the length it stands for
    [m], ``inserted`` the inserted length (the constant terms' share), ``friction`` the law's
    coefficients, ``stick_half`` half the stick band. Inside the band the impulse that stops the
    slip, within the static limit; outside it the slip force, solved implicitly in the viscous
    term and never past the impulse that stops the slip."""
    stop = relative / inverse_effective                    # impulse that ends the slip
    if relative >= 0.0:
        static, coulomb, viscous, constant = friction[0], friction[1], friction[2], friction[7]
    else:
        static, coulomb, viscous, constant = friction[3], friction[4], friction[5], friction[8]
    fixed = constant * segment / inserted if inserted > 0.0 else 0.0   # the constant's share
    if abs(relative) <= stick_half:
        limit = (static * segment + fixed) * dt / scale
        impulse = min(max(stop, -limit), limit)
    else:
        magnitude = ((segment * (coulomb + viscous * abs(relative)) + fixed) * dt
                     / (scale + segment * viscous * inverse_effective * dt))
        impulse = magnitude if relative > 0.0 else -magnitude
        if abs(impulse) > abs(stop):
            impulse = stop
    return impulse


@njit(cache=True)
def shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
                 base, axis, rotation, base_velocity, axis_rate, dt, tip_depth, friction, sweeps, free_beyond,
                 closing_m, point_offsets, point_forces, point_depths, shares, applied_forces):
    """Hold each point at its lateral offset from the needle axis (Gauss-Seidel sweeps of the
    mass-weighted projection), then apply the implicit modified-Karnopp friction along the axis.

    point_offsets: (n, 3) each point's lateral offset in the needle frame (0: on the axis). A
    point further than ``free_beyond`` from the base is along a sharp tip's faces, which push it
    (:mod:`.tip`): it is not held, and its offset follows it, so once it passes the heel the shaft
    holds the tissue where the faces put it (a bevel displaces the tissue to one side, and that
    tissue presses on the shaft, instead of being pulled back to the axis). Behind the heel the
    held offset tapers linearly to 0 over ``closing_m`` (the tissue closes around the shaft): held
    along the whole shaft, the bevel's lateral force would grow with the inserted length (past the
    axial force after 16 mm on the default scene), which a cut that closes does not do.

    force_scale: (n,) 1 + dt gamma_i. The solver's implicit damping divides whatever force acts
    in a step by it, so a correction Delta u made after the step stands for the force
    (1 + dt gamma_i) m_i Delta u_i / dt^2 (and an impulse J for (1 + dt gamma_i) J / dt).
    friction = (D_ins, C_ins, b_ins, D_ret, C_ret, b_ret, stick_band, C0_ins, C0_ret): per unit
    length, then constant terms [N] for the whole inserted length. ``tip_depth`` > 0: each point
    stands for its :func:`length_shares` of the inserted length (``shares``, written) and the
    constant terms are shared in proportion; ``tip_depth`` <= 0: each point stands for a unit
    length and no constant term (the cutting samples: the law's own limits per sample).
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
            if along > free_beyond:                   # on the tip's faces: its offset follows it
                for c in range(3):
                    off = 0.0
                    for r in range(3):
                        x = -base[r] - along * axis[r]
                        for k in range(4):
                            i = point_nodes[s, k]
                            x += point_weights[s, k] * (rest[i, r] + displacement[i, r])
                        off += rotation[r, c] * x
                    point_offsets[s, c] = off
                continue
            held = 1.0
            if closing_m > 0.0:
                held = min(1.0, max(0.0, 1.0 - (free_beyond - along) / closing_m))
            for r in range(3):
                lateral = -base[r] - along * axis[r]
                for c in range(3):
                    lateral -= held * rotation[r, c] * point_offsets[s, c]
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
    for s in range(n_points):
        along = 0.0
        for k in range(4):
            i = point_nodes[s, k]
            for r in range(3):
                along += point_weights[s, k] * (rest[i, r] + displacement[i, r] - base[r]) * axis[r]
        point_depths[s] = along
    inserted = 0.0
    if tip_depth > 0.0 and n_points > 0:
        length_shares(point_depths, n_points, tip_depth, shares)
        inserted = max(tip_depth - point_depths[0], 0.0)
    total_friction = 0.0
    stick_half = 0.5 * friction[6]
    for s in range(n_points):
        along = point_depths[s]
        tissue_velocity = 0.0
        inverse_effective = 0.0
        scale = 0.0                                  # force per impulse / dt at this point
        for k in range(4):
            i = point_nodes[s, k]
            w = point_weights[s, k]
            scale += w * force_scale[i]
            for r in range(3):
                tissue_velocity += w * velocity[i, r] * axis[r]
                inverse_effective += w * w * inverse_mass[i, r] * axis[r] * axis[r]
        if inverse_effective <= 0.0:
            continue
        needle_velocity = 0.0
        for r in range(3):
            needle_velocity += (base_velocity[r] + along * axis_rate[r]) * axis[r]
        relative = needle_velocity - tissue_velocity
        impulse = karnopp_impulse(relative, inverse_effective, scale, shares[s] if tip_depth > 0.0 else 1.0,
                                  inserted, friction, stick_half, dt)
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
