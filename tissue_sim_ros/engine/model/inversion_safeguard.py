"""Inversion safeguard of the St Venant-Kirchhoff element force (numba), used by kernels.py.

Irving, Teran and Fedkiw, "Invertible finite elements for robust simulation of large
deformation" (2004): only elements whose smallest principal stretch is below STRETCH_CLAMP, or
that are inverted, take this path; every other element's stress is St Venant-Kirchhoff exactly.
"""
import numpy as np
from numba import njit

# Inversion safeguard (Irving, Teran and Fedkiw, "Invertible finite elements", 2004): St Venant-
# Kirchhoff softens in compression (its uniaxial stress has a limit point at a stretch of
# 1/sqrt(3)) and pushes an inverted element further inside out. Below STRETCH_CLAMP the principal
# stresses are continued linearly with a slope of at least mu, and an inverted element's smallest
# principal stretch is taken negative (F = U diag(s) V^T with U, V rotations), so the force always
# pushes the element back out.
STRETCH_CLAMP = 0.6


@njit(cache=True, inline='always')
def _principal_stress(s0, s1, s2, lam, mu):
    """St Venant-Kirchhoff principal first Piola stress P_i = s_i (lam/2 sum(s^2-1) + mu (s_i^2 - 1))."""
    half_trace = 0.5 * (s0 * s0 + s1 * s1 + s2 * s2 - 3.0)
    return (s0 * (lam * half_trace + mu * (s0 * s0 - 1.0)),
            s1 * (lam * half_trace + mu * (s1 * s1 - 1.0)),
            s2 * (lam * half_trace + mu * (s2 * s2 - 1.0)))


@njit(cache=True, boundscheck=False)
def _symmetric_eigen(a, vectors):
    """Cyclic Jacobi on the 3x3 symmetric ``a`` (overwritten): eigenvalues on its diagonal,
    eigenvectors in the columns of ``vectors``. A few sweeps reach round-off for 3x3."""
    for r in range(3):
        for c in range(3):
            vectors[r, c] = 1.0 if r == c else 0.0
    for _ in range(12):
        off = a[0, 1] * a[0, 1] + a[0, 2] * a[0, 2] + a[1, 2] * a[1, 2]
        if off < 1e-30 * (a[0, 0] * a[0, 0] + a[1, 1] * a[1, 1] + a[2, 2] * a[2, 2]):
            break
        for p, q in ((0, 1), (0, 2), (1, 2)):
            if a[p, q] == 0.0:
                continue
            theta = 0.5 * (a[q, q] - a[p, p]) / a[p, q]
            t = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
            cos = 1.0 / np.sqrt(t * t + 1.0)
            sin = t * cos
            for k in range(3):        # a <- J^T a J
                akp = a[k, p]
                akq = a[k, q]
                a[k, p] = cos * akp - sin * akq
                a[k, q] = sin * akp + cos * akq
            for k in range(3):
                apk = a[p, k]
                aqk = a[q, k]
                a[p, k] = cos * apk - sin * aqk
                a[q, k] = sin * apk + cos * aqk
            for k in range(3):
                vkp = vectors[k, p]
                vkq = vectors[k, q]
                vectors[k, p] = cos * vkp - sin * vkq
                vectors[k, q] = sin * vkp + cos * vkq


@njit(cache=True, boundscheck=False)
def safeguarded_piola(f, lam, mu, scratch, out):
    """First Piola stress (into ``out``) of F = ``f`` (3x3) with the inversion safeguard, from
    the principal stretches: P = U diag(P_i) V^T, which is F S where no stretch is clamped.

    scratch: (4, 3, 3) work space, so nothing is allocated.

    Returns True when the safeguard changed the stress (a principal stretch below the clamp or an
    inverted element).
    """
    work = scratch[0]
    vectors = scratch[1]
    v = scratch[2]
    u = scratch[3]
    for r in range(3):
        for c in range(3):
            work[r, c] = f[0, r] * f[0, c] + f[1, r] * f[1, c] + f[2, r] * f[2, c]    # C = F^T F
    _symmetric_eigen(work, vectors)
    # sort eigenpairs descending, so the smallest stretch is last
    order0, order1, order2 = 0, 1, 2
    ev = (work[0, 0], work[1, 1], work[2, 2])
    if ev[order0] < ev[order1]:
        order0, order1 = order1, order0
    if ev[order1] < ev[order2]:
        order1, order2 = order2, order1
    if ev[order0] < ev[order1]:
        order0, order1 = order1, order0
    det_f = (f[0, 0] * (f[1, 1] * f[2, 2] - f[1, 2] * f[2, 1]) - f[0, 1] * (f[1, 0] * f[2, 2] - f[1, 2] * f[2, 0])
             + f[0, 2] * (f[1, 0] * f[2, 1] - f[1, 1] * f[2, 0]))
    stretch0 = np.sqrt(max(ev[order0], 0.0))
    stretch1 = np.sqrt(max(ev[order1], 0.0))
    stretch2 = np.sqrt(max(ev[order2], 0.0))
    for k in range(3):
        v[k, 0] = vectors[k, order0]
        v[k, 1] = vectors[k, order1]
        v[k, 2] = vectors[k, order2]
    # make V a rotation
    det_v = (v[0, 0] * (v[1, 1] * v[2, 2] - v[1, 2] * v[2, 1]) - v[0, 1] * (v[1, 0] * v[2, 2] - v[1, 2] * v[2, 0])
             + v[0, 2] * (v[1, 0] * v[2, 1] - v[1, 1] * v[2, 0]))
    if det_v < 0.0:
        for k in range(3):
            v[k, 2] = -v[k, 2]
    # U = F V diag(1/s) for the two largest stretches; the third column completes a rotation
    for j in range(2):
        norm = 0.0
        for r in range(3):
            u[r, j] = f[r, 0] * v[0, j] + f[r, 1] * v[1, j] + f[r, 2] * v[2, j]
            norm += u[r, j] * u[r, j]
        norm = np.sqrt(norm)
        if norm < 1e-12:
            for r in range(3):
                u[r, j] = v[r, j]
        else:
            for r in range(3):
                u[r, j] /= norm
    dot = u[0, 0] * u[0, 1] + u[1, 0] * u[1, 1] + u[2, 0] * u[2, 1]
    norm = 0.0
    for r in range(3):
        u[r, 1] -= dot * u[r, 0]
        norm += u[r, 1] * u[r, 1]
    norm = np.sqrt(norm)
    for r in range(3):
        u[r, 1] /= norm
    u[0, 2] = u[1, 0] * u[2, 1] - u[2, 0] * u[1, 1]
    u[1, 2] = u[2, 0] * u[0, 1] - u[0, 0] * u[2, 1]
    u[2, 2] = u[0, 0] * u[1, 1] - u[1, 0] * u[0, 1]
    changed = stretch2 < STRETCH_CLAMP or det_f <= 0.0
    if det_f < 0.0:
        stretch2 = -stretch2           # inverted: the smallest stretch passes through zero
    clamped0 = max(stretch0, STRETCH_CLAMP)
    clamped1 = max(stretch1, STRETCH_CLAMP)
    clamped2 = max(stretch2, STRETCH_CLAMP)
    p0, p1, p2 = _principal_stress(clamped0, clamped1, clamped2, lam, mu)
    half_trace = 0.5 * (clamped0 * clamped0 + clamped1 * clamped1 + clamped2 * clamped2 - 3.0)
    slope_floor = mu
    slope0 = max(lam * half_trace + mu * (clamped0 * clamped0 - 1.0) + (lam + 2.0 * mu) * clamped0 * clamped0, slope_floor)
    slope1 = max(lam * half_trace + mu * (clamped1 * clamped1 - 1.0) + (lam + 2.0 * mu) * clamped1 * clamped1, slope_floor)
    slope2 = max(lam * half_trace + mu * (clamped2 * clamped2 - 1.0) + (lam + 2.0 * mu) * clamped2 * clamped2, slope_floor)
    p0 += slope0 * (stretch0 - clamped0)
    p1 += slope1 * (stretch1 - clamped1)
    p2 += slope2 * (stretch2 - clamped2)
    for r in range(3):
        for c in range(3):
            out[r, c] = u[r, 0] * p0 * v[c, 0] + u[r, 1] * p1 * v[c, 1] + u[r, 2] * p2 * v[c, 2]
    return changed
