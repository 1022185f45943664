"""The needle's shaft as a discrete elastic rod: its section, energy, quasi-static solve and frames.

The shaft is a chain of ``n`` straight segments of rest length h = L / n between n + 1 nodes
x_0 .. x_n (x_0 the base, x_n the tip's apex), positions only. Its energy is that of a discrete
Kirchhoff rod (Bergou et al. 2008, "Discrete elastic rods", isotropic section, straight at rest):

- bending at each inner node i, with t_j = e_j / |e_j| the unit tangent of segment e_j =
  x_{j+1} - x_j: E_b = sum_i (EI / h) (1 - t_{i-1} . t_i) = sum_i (EI / (2 h)) |t_i - t_{i-1}|^2,
  which is (EI / 2) kappa^2 h for the turning angle phi = kappa h (1 - cos phi = phi^2 / 2 to
  a relative 1e-4 at the few degrees a node turns). The base is clamped: x_0 is held and the
  first segment turns away from the base frame's axis t_b against the half cell it has there,
  (2 EI / h) (1 - t_b . t_0) (a clamp that held x_1 as well would shorten the rod's bending
  length by h / 2: a first-order error, 1.5 / n of a cantilever's deflection); the free end
  carries no moment;
- stretching: E_s = sum_j (EA / (2 h)) (|e_j| - h)^2, the tube's own axial stiffness, so the
  length changes by the elastic strain alone (N L / EA, under a micrometre) and never drifts: the
  rest lengths are constants.

EI and EA are the tube's: I = pi (d_o^4 - d_i^4) / 64, A = pi (d_o^2 - d_i^2) / 4
(:class:`RodSection`). A round tube bends the same way in every direction, so with a straight rest
shape the centreline's equilibrium does not depend on twist; the shaft is taken torsionally
rigid: its material frame is the base frame carried along the centreline by parallel transport
(the Bishop frame, :func:`transport_frames`), so the bevel at the tip turns with the base's roll
at once (no torsional wind-up or lag, Reed et al. 2011, which needs torsional friction the scene
does not describe).

The rod is quasi-static: it has no inertia of its own. A steel or nitinol tube's bending waves
are thousands of times faster than the tissue's (an explicit rod at the tissue's time step would
need steps of a few microseconds), so its equilibrium under the loads of the step is solved
instead, by Newton's method on the total potential E - f . x (:func:`assemble`, the exact
gradient and Hessian, the compressive part of the stretching's geometric stiffness left out so
the matrix stays positive; :func:`band_solve`, a banded Cholesky factorisation: a node couples to
its two neighbours only, so the matrix has 8 bands above the diagonal and a solve costs
O(n)). :func:`static_solve` iterates to convergence with a backtracking line search (the rod
alone, loads at the nodes); the coupled step (:mod:`.rod_coupling`) takes its Newton steps with
the tissue's stiffness added.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

__all__ = ['BANDS', 'RodSection', 'rod_energy', 'assemble', 'add_block', 'band_solve', 'newton_step', 'keep_lengths',
           'static_solve', 'transport_frames', 'frame_quaternions', 'locate_on_rod', 'point_on_rod',
           'straight_nodes']

#: bands above the diagonal of the rod's Hessian (3 coordinates of 3 consecutive nodes)
BANDS = 8


@dataclass(frozen=True)
class RodSection:
    """A tube's section: outer and inner diameter [m] and Young's modulus [Pa]."""
    outer_diameter_m: float
    inner_diameter_m: float
    young_modulus_pa: float

    @property
    def second_moment_m4(self) -> float:
        """I = pi (d_o^4 - d_i^4) / 64 [m^4]."""
        return math.pi * (self.outer_diameter_m ** 4 - self.inner_diameter_m ** 4) / 64.0

    @property
    def area_m2(self) -> float:
        """A = pi (d_o^2 - d_i^2) / 4 [m^2]."""
        return math.pi * (self.outer_diameter_m ** 2 - self.inner_diameter_m ** 2) / 4.0

    @property
    def bending_stiffness_nm2(self) -> float:
        """EI [N m^2]."""
        return self.young_modulus_pa * self.second_moment_m4

    @property
    def axial_stiffness_n(self) -> float:
        """EA [N]."""
        return self.young_modulus_pa * self.area_m2


def straight_nodes(base, axis, length, segments):
    """(segments + 1, 3) nodes of the straight rod from ``base`` along the unit ``axis``."""
    s = np.linspace(0.0, length, segments + 1)
    return np.asarray(base, dtype=float)[None, :] + s[:, None] * np.asarray(axis, dtype=float)[None, :]


@njit(cache=True)
def rod_energy(nodes, h, bending, axial, base_axis):
    """E_b + E_s of the rod (module docstring) with its base clamped along ``base_axis`` [J]."""
    n = nodes.shape[0] - 1
    energy = 0.0
    previous = np.empty(3)
    tangent = np.empty(3)
    for j in range(n):
        length = 0.0
        for r in range(3):
            tangent[r] = nodes[j + 1, r] - nodes[j, r]
            length += tangent[r] * tangent[r]
        length = math.sqrt(length)
        energy += 0.5 * axial / h * (length - h) ** 2
        for r in range(3):
            tangent[r] /= length
        if j > 0:
            energy += bending / h * (1.0 - (previous[0] * tangent[0] + previous[1] * tangent[1]
                                            + previous[2] * tangent[2]))
        else:
            energy += 2.0 * bending / h * (1.0 - (base_axis[0] * tangent[0] + base_axis[1] * tangent[1]
                                                  + base_axis[2] * tangent[2]))
        for r in range(3):
            previous[r] = tangent[r]
    return energy


@njit(cache=True, inline='always')
def add_block(band, p, q, block, sign):
    """band += sign * block at the node pair (p, q), p <= q: the upper triangle of the symmetric
    matrix, stored as band[row, d] = H[row, row + d]."""
    for a in range(3):
        row = 3 * p + a
        for b in range(3):
            col = 3 * q + b
            if col >= row:
                band[row, col - row] += sign * block[a, b]


@njit(cache=True)
def assemble(nodes, h, bending, axial, base_axis, gradient, band):
    """Add the rod's energy gradient (n + 1, 3) and Hessian (banded, :func:`add_block`) at
    ``nodes``, its base clamped along ``base_axis``, to ``gradient`` and ``band``; returns the
    energy."""
    n = nodes.shape[0] - 1
    tangents = np.empty((n, 3))
    lengths = np.empty(n)
    block = np.empty((3, 3))
    energy = 0.0
    for j in range(n):
        length = 0.0
        for r in range(3):
            tangents[j, r] = nodes[j + 1, r] - nodes[j, r]
            length += tangents[j, r] ** 2
        length = math.sqrt(length)
        lengths[j] = length
        for r in range(3):
            tangents[j, r] /= length
        # stretching: dE/de = k (|e| - h) t, d2E/de2 = k (t t^T + max(0, 1 - h / |e|) P)
        k = axial / h
        energy += 0.5 * k * (length - h) ** 2
        geometric = max(0.0, 1.0 - h / length)
        for r in range(3):
            g = k * (length - h) * tangents[j, r]
            gradient[j, r] -= g
            gradient[j + 1, r] += g
            for c in range(3):
                block[r, c] = k * ((1.0 - geometric) * tangents[j, r] * tangents[j, c]
                                   + (geometric if r == c else 0.0))
        add_block(band, j, j, block, 1.0)
        add_block(band, j + 1, j + 1, block, 1.0)
        add_block(band, j, j + 1, block, -1.0)
    ga, gb = np.empty(3), np.empty(3)
    haa, hbb, hab = np.empty((3, 3)), np.empty((3, 3)), np.empty((3, 3))
    # the clamp: (2 EI / h) (1 - t_b . t_0), t_b fixed: d cos / d e_0 = (t_b - cos t_0) / |e_0|
    k = 2.0 * bending / h
    cos = base_axis[0] * tangents[0, 0] + base_axis[1] * tangents[0, 1] + base_axis[2] * tangents[0, 2]
    energy += k * (1.0 - cos)
    for r in range(3):
        gb[r] = (base_axis[r] - cos * tangents[0, r]) / lengths[0]
    for r in range(3):
        gradient[0, r] += k * gb[r]
        gradient[1, r] -= k * gb[r]
        for c in range(3):
            p_rc = (1.0 if r == c else 0.0) - tangents[0, r] * tangents[0, c]
            hbb[r, c] = -k * (-(gb[r] * tangents[0, c] + tangents[0, r] * gb[c]) / lengths[0]
                              - cos * p_rc / (lengths[0] * lengths[0]))
    add_block(band, 0, 0, hbb, 1.0)
    add_block(band, 0, 1, hbb, -1.0)
    add_block(band, 1, 1, hbb, 1.0)
    k = bending / h
    for i in range(1, n):
        a, b = i - 1, i                                # segments before and after node i
        na, nb = lengths[a], lengths[b]
        cos = tangents[a, 0] * tangents[b, 0] + tangents[a, 1] * tangents[b, 1] + tangents[a, 2] * tangents[b, 2]
        energy += k * (1.0 - cos)
        for r in range(3):
            ga[r] = (tangents[b, r] - cos * tangents[a, r]) / na      # d cos / d e_a
            gb[r] = (tangents[a, r] - cos * tangents[b, r]) / nb      # d cos / d e_b
        for r in range(3):
            gradient[i - 1, r] += k * ga[r]
            gradient[i, r] += k * (gb[r] - ga[r])
            gradient[i + 1, r] -= k * gb[r]
        # Hessian of E = k (1 - cos) in the segments: -k d2 cos / de de
        for r in range(3):
            for c in range(3):
                delta = 1.0 if r == c else 0.0
                pa_rc = delta - tangents[a, r] * tangents[a, c]
                pb_rc = delta - tangents[b, r] * tangents[b, c]
                haa[r, c] = -k * (-(ga[r] * tangents[a, c] + tangents[a, r] * ga[c]) / na - cos * pa_rc / (na * na))
                hbb[r, c] = -k * (-(gb[r] * tangents[b, c] + tangents[b, r] * gb[c]) / nb - cos * pb_rc / (nb * nb))
                papb = 0.0
                for m in range(3):
                    papb += ((1.0 if r == m else 0.0) - tangents[a, r] * tangents[a, m]) * \
                        ((1.0 if m == c else 0.0) - tangents[b, m] * tangents[b, c])
                hab[r, c] = -k * papb / (na * nb)
        # nodes (i-1, i, i+1) from e_a = x_i - x_{i-1}, e_b = x_{i+1} - x_i
        add_block(band, i - 1, i - 1, haa, 1.0)
        for r in range(3):
            for c in range(3):
                block[r, c] = hab[r, c] - haa[r, c]
        add_block(band, i - 1, i, block, 1.0)
        add_block(band, i - 1, i + 1, hab, -1.0)
        for r in range(3):
            for c in range(3):
                block[r, c] = haa[r, c] + hbb[r, c] - hab[r, c] - hab[c, r]
        add_block(band, i, i, block, 1.0)
        for r in range(3):
            for c in range(3):
                block[r, c] = hab[r, c] - hbb[r, c]
        add_block(band, i, i + 1, block, 1.0)
        add_block(band, i + 1, i + 1, hbb, 1.0)
    return energy


@njit(cache=True)
def band_solve(band, rhs, first_free):
    """Solve H x = rhs in place (rhs becomes x) for the symmetric banded H in ``band``
    (destroyed: its Cholesky factor), the coordinates of the nodes before ``first_free`` held
    (x = 0 there). Returns False where H is not positive definite on the free coordinates."""
    size = band.shape[0]
    bands = band.shape[1] - 1
    start = 3 * first_free
    for j in range(start):
        rhs[j] = 0.0
    for j in range(start, size):
        s = band[j, 0]
        for k in range(max(start, j - bands), j):
            s -= band[k, j - k] ** 2
        if not s > 0.0:
            return False
        pivot = math.sqrt(s)
        band[j, 0] = pivot
        for i in range(j + 1, min(size, j + bands + 1)):
            s = band[j, i - j]
            for k in range(max(start, i - bands), j):
                s -= band[k, j - k] * band[k, i - k]
            band[j, i - j] = s / pivot
    for j in range(start, size):                         # U^T y = rhs
        s = rhs[j]
        for k in range(max(start, j - bands), j):
            s -= band[k, j - k] * rhs[k]
        rhs[j] = s / band[j, 0]
    for j in range(size - 1, start - 1, -1):             # U x = y
        s = rhs[j]
        for i in range(j + 1, min(size, j + bands + 1)):
            s -= band[j, i - j] * rhs[i]
        rhs[j] = s / band[j, 0]
    return True


@njit(cache=True)
def newton_step(nodes, h, bending, axial, base_axis, loads, first_free, gradient, band, step):
    """One Newton step of the rod alone under node ``loads`` (n + 1, 3), the nodes before
    ``first_free`` held: ``step`` (flat, 3 (n + 1)) the move; returns (energy, |gradient| over
    the free nodes, whether the factorisation held). A matrix that is not positive (a rod far
    into compression) is shifted by a multiple of its diagonal until it is."""
    gradient[:] = 0.0
    band[:] = 0.0
    energy = assemble(nodes, h, bending, axial, base_axis, gradient, band)
    norm = 0.0
    for i in range(nodes.shape[0]):
        for r in range(3):
            energy -= loads[i, r] * nodes[i, r]
            gradient[i, r] -= loads[i, r]
            if i >= first_free:
                norm += gradient[i, r] ** 2
    return energy, math.sqrt(norm), _shifted_solve(band, gradient, first_free, step)


@njit(cache=True)
def _shifted_solve(band, gradient, first_free, step):
    """step = -H^-1 gradient, H shifted by 1e-8, 1e-6 ... of its diagonal until it factors."""
    saved = band.copy()
    shift = 0.0
    for attempt in range(8):
        if attempt:
            shift = 1e-8 * 100.0 ** (attempt - 1)
            band[:] = saved
            for j in range(band.shape[0]):
                band[j, 0] *= 1.0 + shift
        for i in range(gradient.shape[0]):
            for r in range(3):
                step[3 * i + r] = -gradient[i, r]
        if band_solve(band, step, first_free):
            return True
    return False


@njit(cache=True)
def static_solve(nodes, h, bending, axial, base_axis, loads, first_free, tolerance, max_iterations):
    """The rod's equilibrium under node ``loads`` (n + 1, 3) [N], the nodes before ``first_free``
    (at least the base) held where they are, the base clamped along ``base_axis``: Newton's
    method with a backtracking line search on E - f . x, from ``nodes`` (updated in place) until
    the free nodes' residual force is below ``tolerance`` [N]. Returns (iterations, residual)."""
    size = nodes.shape[0]
    gradient = np.zeros((size, 3))
    band = np.zeros((3 * size, BANDS + 1))
    step = np.zeros(3 * size)
    trial = nodes.copy()
    residual = np.inf
    for iteration in range(max_iterations):
        energy, residual, ok = newton_step(nodes, h, bending, axial, base_axis, loads, first_free, gradient, band,
                                           step)
        if residual < tolerance or not ok:
            return iteration, residual
        scale = 1.0
        for _ in range(30):
            for i in range(size):
                for r in range(3):
                    trial[i, r] = nodes[i, r] + scale * step[3 * i + r]
            keep_lengths(trial, nodes, first_free)
            value = rod_energy(trial, h, bending, axial, base_axis)
            for i in range(size):
                for r in range(3):
                    value -= loads[i, r] * trial[i, r]
            if value <= energy + 1e-12 * abs(energy):
                break
            scale *= 0.5
        else:
            return iteration, residual          # no decrease left above round-off
        nodes[:] = trial
    return max_iterations, residual


@njit(cache=True)
def keep_lengths(trial, nodes, first_free):
    """A Newton step is straight in the nodes' coordinates, so a large lateral one also
    stretches the segments by its square, which the linear model behind the step does not
    intend (and the stiff stretching then takes the line search's steps down by halves for
    dozens of iterations): each segment of ``trial`` gets the length the step meant it to have,
    its length in ``nodes`` plus the step's change along its tangent, in its new direction, the
    free nodes placed from the base out. The change is of second order in the step, so the
    iteration still converges quadratically."""
    previous = np.empty(3)
    for r in range(3):
        previous[r] = trial[max(first_free, 1) - 1, r]
    for j in range(max(first_free, 1) - 1, trial.shape[0] - 1):
        before = math.sqrt((nodes[j + 1, 0] - nodes[j, 0]) ** 2 + (nodes[j + 1, 1] - nodes[j, 1]) ** 2
                           + (nodes[j + 1, 2] - nodes[j, 2]) ** 2)
        meant, after = before, 0.0
        for r in range(3):
            e = nodes[j + 1, r] - nodes[j, r]
            meant += e / before * ((trial[j + 1, r] - previous[r]) - e)
            after += (trial[j + 1, r] - previous[r]) ** 2
        after = math.sqrt(after)
        for r in range(3):
            moved = trial[j + 1, r]
            trial[j + 1, r] = trial[j, r] + (moved - previous[r]) * (meant / after)
            previous[r] = moved


@njit(cache=True)
def transport_frames(nodes, base_rotation, frames):
    """The material frame of each segment, (n, 3, 3) with columns (d1, d2, t): the base frame's
    (``base_rotation``'s columns, t its +z) carried from segment to segment by parallel transport
    (the smallest rotation taking t_{j-1} to t_j: d' = d - ((t_j . d) / (1 + t_{j-1} . t_j))
    (t_{j-1} + t_j)), so it does not twist about the centreline."""
    n = nodes.shape[0] - 1
    previous = np.empty(3)
    for r in range(3):
        previous[r] = base_rotation[r, 2]
    d1, d2 = np.empty(3), np.empty(3)
    for r in range(3):
        d1[r] = base_rotation[r, 0]
        d2[r] = base_rotation[r, 1]
    t = np.empty(3)
    for j in range(n):
        length = 0.0
        for r in range(3):
            t[r] = nodes[j + 1, r] - nodes[j, r]
            length += t[r] * t[r]
        length = math.sqrt(length)
        for r in range(3):
            t[r] /= length
        cos = previous[0] * t[0] + previous[1] * t[1] + previous[2] * t[2]
        f1 = (t[0] * d1[0] + t[1] * d1[1] + t[2] * d1[2]) / (1.0 + cos)
        f2 = (t[0] * d2[0] + t[1] * d2[1] + t[2] * d2[2]) / (1.0 + cos)
        for r in range(3):
            d1[r] -= f1 * (previous[r] + t[r])
            d2[r] -= f2 * (previous[r] + t[r])
        # the round-off of many transports: d1 made unit and normal to t again, d2 = t x d1
        dot = d1[0] * t[0] + d1[1] * t[1] + d1[2] * t[2]
        norm = 0.0
        for r in range(3):
            d1[r] -= dot * t[r]
            norm += d1[r] * d1[r]
        norm = math.sqrt(norm)
        for r in range(3):
            d1[r] /= norm
        d2[0] = t[1] * d1[2] - t[2] * d1[1]
        d2[1] = t[2] * d1[0] - t[0] * d1[2]
        d2[2] = t[0] * d1[1] - t[1] * d1[0]
        for r in range(3):
            frames[j, r, 0] = d1[r]
            frames[j, r, 1] = d2[r]
            frames[j, r, 2] = t[r]
            previous[r] = t[r]


@njit(cache=True)
def frame_quaternions(frames, out):
    """out[k] = the unit quaternion (x, y, z, w), w >= 0, of the rotation ``frames[k]`` (columns
    d1, d2, t). Shepperd's method: from the largest of the four squared components, so that no
    branch divides by less than half a unit."""
    for k in range(frames.shape[0]):
        m = frames[k]
        trace = m[0, 0] + m[1, 1] + m[2, 2]
        s0, s1 = 1.0 + 2.0 * m[0, 0] - trace, 1.0 + 2.0 * m[1, 1] - trace
        s2, s3 = 1.0 + 2.0 * m[2, 2] - trace, 1.0 + trace
        if s3 >= s0 and s3 >= s1 and s3 >= s2:
            w = 0.5 * math.sqrt(s3)
            f = 0.25 / w
            x, y, z = (m[2, 1] - m[1, 2]) * f, (m[0, 2] - m[2, 0]) * f, (m[1, 0] - m[0, 1]) * f
        elif s0 >= s1 and s0 >= s2:
            x = 0.5 * math.sqrt(s0)
            f = 0.25 / x
            y, z, w = (m[0, 1] + m[1, 0]) * f, (m[0, 2] + m[2, 0]) * f, (m[2, 1] - m[1, 2]) * f
        elif s1 >= s2:
            y = 0.5 * math.sqrt(s1)
            f = 0.25 / y
            x, z, w = (m[0, 1] + m[1, 0]) * f, (m[1, 2] + m[2, 1]) * f, (m[0, 2] - m[2, 0]) * f
        else:
            z = 0.5 * math.sqrt(s2)
            f = 0.25 / z
            x, y, w = (m[0, 2] + m[2, 0]) * f, (m[1, 2] + m[2, 1]) * f, (m[1, 0] - m[0, 1]) * f
        sign = -1.0 if w < 0.0 else 1.0
        out[k, 0], out[k, 1], out[k, 2], out[k, 3] = sign * x, sign * y, sign * z, sign * w


@njit(cache=True)
def locate_on_rod(nodes, h, point, segment):
    """The centreline's closest point to ``point``, searched from ``segment`` to its neighbours:
    (segment, fraction along it, arc length from the base [m]). The first and last segments
    extend past the base and the apex (a point ahead of the tip has an arc length over L)."""
    n = nodes.shape[0] - 1
    j = min(max(segment, 0), n - 1)
    fraction = 0.0
    came_from = -1
    for _ in range(n + 1):
        along, squared = 0.0, 0.0
        for r in range(3):
            e = nodes[j + 1, r] - nodes[j, r]
            along += (point[r] - nodes[j, r]) * e
            squared += e * e
        fraction = along / squared
        if fraction < 0.0 and j > 0:
            if came_from == j - 1:             # between two segments, on the outside of a bend
                fraction = 0.0
                break
            came_from, j = j, j - 1
        elif fraction > 1.0 and j < n - 1:
            if came_from == j + 1:
                fraction = 1.0
                break
            came_from, j = j, j + 1
        else:
            break
    return j, fraction, (j + fraction) * h


@njit(cache=True, inline='always')
def point_on_rod(nodes, segment, fraction, out):
    """out = the centreline point at ``fraction`` along ``segment`` (linear between its nodes)."""
    for r in range(3):
        out[r] = (1.0 - fraction) * nodes[segment, r] + fraction * nodes[segment + 1, r]
