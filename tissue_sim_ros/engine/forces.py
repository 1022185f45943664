"""Internal force kernels of the tensor-mass model (numba).

Two formulations of the same forces, held equal by the tests:

* ``element_kernel``: the element loop used on the hot path. For each tetrahedron the
  displacement gradient H = sum_k u_k a_k^T (a_k: shape-function gradients, FORMULAS.md) gives
  the stress, and the force on vertex j is f_j = -V P a_j, where P is
    - linear (Cotin et al., seed section 3/4.1):  sigma = lambda tr(eps) I + 2 mu eps, eps = sym(H)
    - physically non-linear (4.1): the same with lambda + dlambda(q), mu + dmu(q), q the element's
      Liu-Joe mean ratio relative to its rest value
    - geometrically non-linear (4.2, St Venant-Kirchhoff): P = F S, F = I + H,
      E = (F^T F - I) / 2, S = lambda tr(E) I + 2 mu E
    - Kelvin-Voigt viscosity (4.3): the same linear law on the rate of deformation, sym(dH/dt)
      (or sym(F^T dF/dt) with the geometric model, so rigid motion is force-free).
  A non-linearity threshold (seed section 6) sends elements whose |H|_F is below it down the
  linear path. f_j = -V sigma a_j is the element form of -sum_k K_jk u_k (FORMULAS.md).
* ``edge_forces``: the paper's assembled form, f_i = -(K_ii u_i + sum_j K_ij u_j), with vertex
  tensors K_ii and edge tensors K_ij summed over the elements around a vertex or edge; lambda and
  mu parts stored separately. Linear only, as in the paper.

Parallel loops are race-free: elements are split into contiguous chunks (spatially ordered
meshes keep each chunk's nodes local), each chunk accumulates into its own buffer, and a node
loop reduces the buffers it touches and clears them for the next call. Nothing is allocated.
"""
import functools

import numpy as np
from numba import njit, prange

# Floating-point contraction and reassociation are fine here; NaN and inf must stay detectable
# (the watchdog looks for them), so no 'nnan' / 'ninf'.
FASTMATH = {'contract', 'reassoc', 'nsz', 'arcp', 'afn'}

# Physically non-linear law kinds (see material.MeanRatioLaw); the parameters are a flat array.
LAW_NONE = 0
LAW_POLYNOMIAL = 1   # dlambda/lambda = sum_k p_lk s^k, dmu/mu = sum_k p_mk s^k; params [K, p_l1..p_lK, p_m1..p_mK]
LAW_EXPONENTIAL = 2  # dlambda/lambda = a_l (exp(b_l s) - 1), same for mu; params [a_l, b_l, a_m, b_m]


@njit(cache=True, inline='always')
def _law_correction(law_kind, law_params, distortion):
    """Relative Lamé corrections (dlambda/lambda, dmu/mu) for a distortion s = 1 - q/q_rest."""
    if law_kind == LAW_POLYNOMIAL:
        order = int(law_params[0])
        corr_lambda = 0.0
        corr_mu = 0.0
        power = 1.0
        for k in range(order):
            power *= distortion
            corr_lambda += law_params[1 + k] * power
            corr_mu += law_params[1 + order + k] * power
        return corr_lambda, corr_mu
    if law_kind == LAW_EXPONENTIAL:
        # a zero amplitude (a law on one coefficient only) costs no exponential
        corr_lambda = law_params[0] * (np.exp(law_params[1] * distortion) - 1.0) if law_params[0] != 0.0 else 0.0
        corr_mu = law_params[2] * (np.exp(law_params[3] * distortion) - 1.0) if law_params[2] != 0.0 else 0.0
        return corr_lambda, corr_mu
    return 0.0, 0.0


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


@njit(cache=True, inline='always')
def element_gradient(field, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z):
    """Gradient of a nodal field over one tetrahedron, row-major 3x3 as nine scalars:
    G = sum_k w_k a_k^T = sum_{k=1..3} (w_k - w_0) a_k^T (FORMULAS.md; a_0 = -(a_1 + a_2 + a_3))."""
    d1x = field[i1, 0] - field[i0, 0]
    d1y = field[i1, 1] - field[i0, 1]
    d1z = field[i1, 2] - field[i0, 2]
    d2x = field[i2, 0] - field[i0, 0]
    d2y = field[i2, 1] - field[i0, 1]
    d2z = field[i2, 2] - field[i0, 2]
    d3x = field[i3, 0] - field[i0, 0]
    d3y = field[i3, 1] - field[i0, 1]
    d3z = field[i3, 2] - field[i0, 2]
    return (d1x * a1x + d2x * a2x + d3x * a3x, d1x * a1y + d2x * a2y + d3x * a3y,
            d1x * a1z + d2x * a2z + d3x * a3z, d1y * a1x + d2y * a2x + d3y * a3x,
            d1y * a1y + d2y * a2y + d3y * a3y, d1y * a1z + d2y * a2z + d3y * a3z,
            d1z * a1x + d2z * a2x + d3z * a3x, d1z * a1y + d2z * a2y + d3z * a3y,
            d1z * a1z + d2z * a2z + d3z * a3z)


# Elements whose displacement gradient is this small cannot need the inversion safeguard:
# sigma_min(I + H) >= 1 - |H|_2 >= 1 - |H|_F > STRETCH_CLAMP, and det F > 0.
SAFEGUARD_FREE_NORM_SQ = (1.0 - STRETCH_CLAMP) ** 2


@njit(cache=True, inline='always')
def deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """det F of F = I + H (volume ratio; <= 0 for an inverted element)."""
    return ((1.0 + h00) * ((1.0 + h11) * (1.0 + h22) - h12 * h21) - h01 * (h10 * (1.0 + h22) - h12 * h20)
            + h02 * (h10 * h21 - (1.0 + h11) * h20))


@njit(cache=True, inline='always')
def green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """Green-Lagrange strain E = (H + H^T + H^T H) / 2 as (e00, e11, e22, e01, e02, e12)."""
    return (0.5 * (h00 + h00 + h00 * h00 + h10 * h10 + h20 * h20),
            0.5 * (h11 + h11 + h01 * h01 + h11 * h11 + h21 * h21),
            0.5 * (h22 + h22 + h02 * h02 + h12 * h12 + h22 * h22),
            0.5 * (h01 + h10 + h00 * h01 + h10 * h11 + h20 * h21),
            0.5 * (h02 + h20 + h00 * h02 + h10 * h12 + h20 * h22),
            0.5 * (h12 + h21 + h01 * h02 + h11 * h12 + h21 * h22))


@njit(cache=True, inline='always')
def _viscous_stress(h00, h01, h02, h10, h11, h12, h20, h21, h22,
                    r00, r01, r02, r10, r11, r12, r20, r21, r22, lam_v, mu_v):
    """Kelvin-Voigt second Piola stress on dE/dt = sym(F^T dF/dt), as (v00, v11, v22, v01, v02, v12)."""
    q00 = (1.0 + h00) * r00 + h10 * r10 + h20 * r20
    q11 = h01 * r01 + (1.0 + h11) * r11 + h21 * r21
    q22 = h02 * r02 + h12 * r12 + (1.0 + h22) * r22
    q01 = 0.5 * ((1.0 + h00) * r01 + h10 * r11 + h20 * r21 + h01 * r00 + (1.0 + h11) * r10 + h21 * r20)
    q02 = 0.5 * ((1.0 + h00) * r02 + h10 * r12 + h20 * r22 + h02 * r00 + h12 * r10 + (1.0 + h22) * r20)
    q12 = 0.5 * (h01 * r02 + (1.0 + h11) * r12 + h21 * r22 + h02 * r01 + h12 * r11 + (1.0 + h22) * r21)
    tr_q = lam_v * (q00 + q11 + q22)
    return (tr_q + 2.0 * mu_v * q00, tr_q + 2.0 * mu_v * q11, tr_q + 2.0 * mu_v * q22,
            2.0 * mu_v * q01, 2.0 * mu_v * q02, 2.0 * mu_v * q12)


@njit(cache=True, inline='always')
def _scatter_piola(buf, i0, i1, i2, i3, p00, p01, p02, p10, p11, p12, p20, p21, p22,
                   a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z):
    """Add the element's nodal forces f_k = -V P a_k (V folded into P), f_0 = -(f_1 + f_2 + f_3)."""
    f1x = -(p00 * a1x + p01 * a1y + p02 * a1z)
    f1y = -(p10 * a1x + p11 * a1y + p12 * a1z)
    f1z = -(p20 * a1x + p21 * a1y + p22 * a1z)
    f2x = -(p00 * a2x + p01 * a2y + p02 * a2z)
    f2y = -(p10 * a2x + p11 * a2y + p12 * a2z)
    f2z = -(p20 * a2x + p21 * a2y + p22 * a2z)
    f3x = -(p00 * a3x + p01 * a3y + p02 * a3z)
    f3y = -(p10 * a3x + p11 * a3y + p12 * a3z)
    f3z = -(p20 * a3x + p21 * a3y + p22 * a3z)
    buf[i0, 0] -= f1x + f2x + f3x
    buf[i0, 1] -= f1y + f2y + f3y
    buf[i0, 2] -= f1z + f2z + f3z
    buf[i1, 0] += f1x
    buf[i1, 1] += f1y
    buf[i1, 2] += f1z
    buf[i2, 0] += f2x
    buf[i2, 1] += f2y
    buf[i2, 2] += f2z
    buf[i3, 0] += f3x
    buf[i3, 1] += f3y
    buf[i3, 2] += f3z


@njit(cache=True, inline='always')
def _element_nodes(tetrahedra, e):
    """The element's node indices, unsigned so that indexing skips the negative-index wraparound."""
    return (np.uint32(tetrahedra[e, 0]), np.uint32(tetrahedra[e, 1]), np.uint32(tetrahedra[e, 2]),
            np.uint32(tetrahedra[e, 3]))


@njit(cache=True, inline='always')
def _shape_gradients(shape_gradients, e):
    return (shape_gradients[e, 0, 0], shape_gradients[e, 0, 1], shape_gradients[e, 0, 2],
            shape_gradients[e, 1, 0], shape_gradients[e, 1, 1], shape_gradients[e, 1, 2],
            shape_gradients[e, 2, 0], shape_gradients[e, 2, 1], shape_gradients[e, 2, 2])


@njit(cache=True, inline='always')
def _corrected_lame(lam, mu, h00, h01, h02, h10, h11, h12, h20, h21, h22, law_kind, law_params,
                    g, mean_ratio_scale):
    """Seed section 4.1: (lambda + dlambda(q), mu + dmu(q)) of one element (V folded in), q its
    mean ratio relative to rest: q/q_rest = scale |det F|^(2/3) / tr(F^T F G), G = edge Gram matrix."""
    e00, e11, e22, e01, e02, e12 = green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
    det_f = deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22)
    # tr(C G) with C = I + 2E
    tr_cg = (g[0] * (1.0 + 2.0 * e00) + g[1] * (1.0 + 2.0 * e11) + g[2] * (1.0 + 2.0 * e22)
             + 4.0 * (g[3] * e01 + g[4] * e02 + g[5] * e12))
    # no distortion (q >= q_rest: the law's corrections vanish at s = 0) decided on the cubes,
    # without the cube root; most of the deformed elements of a needle dent are there
    if mean_ratio_scale * mean_ratio_scale * mean_ratio_scale * det_f * det_f >= tr_cg * tr_cg * tr_cg:
        return lam, mu
    relative_quality = mean_ratio_scale * np.abs(det_f) ** (2.0 / 3.0) / tr_cg
    corr_lambda, corr_mu = _law_correction(law_kind, law_params, max(0.0, 1.0 - relative_quality))
    return lam * (1.0 + corr_lambda), mu * (1.0 + corr_mu)


@functools.lru_cache(maxsize=None)
def element_kernel(geometric, physical, viscous):
    """The element pass compiled for one model: the three flags are compile-time constants, so
    each variant holds only its own arithmetic and branches (one source, eight machine codes).

    Call it as ``kernel(tetrahedra, shape_gradients, volume_lambda, volume_mu, displacement,
    velocity, threshold_squared, law_kind, law_params, edge_gram, mean_ratio_scale,
    viscous_lambda, viscous_mu, chunk_bounds, buffers, nonlinear_counts, safeguard,
    safeguard_scratch, safeguard_counts, corrected_lambda, corrected_mu, slow_elements)``.
    """
    geometric, physical, viscous = bool(geometric), bool(physical), bool(viscous)

    @njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False)
    def kernel(tetrahedra, shape_gradients, volume_lambda, volume_mu, displacement, velocity,
               threshold_squared, law_kind, law_params, edge_gram, mean_ratio_scale,
               viscous_lambda, viscous_mu, chunk_bounds, buffers, nonlinear_counts,
               safeguard, safeguard_scratch, safeguard_counts, corrected_lambda, corrected_mu,
               slow_elements):
        """Accumulate the internal elastic (+ viscous) forces into the per-chunk ``buffers``.

        The node forces are the sum over chunks (``reduce_buffers``, or fused into the solver's
        node update through ``take_node_force``).

        shape_gradients (m, 3, 3): rows a_1, a_2, a_3 (a_0 = -(a_1 + a_2 + a_3)).
        volume_lambda, volume_mu (m,): V lambda and V mu of each element (viscous_*: V lambda_v, V mu_v).
        edge_gram (m, 6): sum over the six rest edges of e e^T (xx, yy, zz, xy, xz, yz), so the
        deformed sum of squared edge lengths is tr(F^T F G). mean_ratio_scale (m,): 12 (3 V)^(2/3)
        divided by the rest mean ratio, so q/q_rest = scale |det F|^(2/3) / tr(F^T F G).
        nonlinear_counts (n_chunks,): elements that took the non-linear path, per chunk.
        safeguard: apply the inversion safeguard on the St Venant-Kirchhoff path to elements whose
        smallest principal stretch is below STRETCH_CLAMP (|H|_F, then Sylvester's criterion on
        F^T F - STRETCH_CLAMP^2 I) or whose det F <= 0; those are set aside in ``slow_elements`` (m,) and done after the
        chunk's loop, so the loop itself holds no call. safeguard_scratch (n_chunks, 6, 3, 3);
        safeguard_counts (n_chunks,) how many elements it changed.
        corrected_lambda, corrected_mu (m,): the corrected Lamé values, kept for the safeguard pass.
        """
        clamp_squared = STRETCH_CLAMP * STRETCH_CLAMP
        n_chunks = chunk_bounds.shape[0] - 1
        for c in prange(n_chunks):
            lo = chunk_bounds[c]
            hi = chunk_bounds[c + 1]
            buf = buffers[c]
            n_nonlinear = 0
            n_slow = 0
            for e in range(lo, hi):
                i0, i1, i2, i3 = _element_nodes(tetrahedra, e)
                a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z = _shape_gradients(shape_gradients, e)
                # H = sum_k u_k a_k^T = sum_{k=1..3} (u_k - u_0) a_k^T
                h00, h01, h02, h10, h11, h12, h20, h21, h22 = element_gradient(
                    displacement, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
                # rate of the displacement gradient, for Kelvin-Voigt viscosity
                r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = 0.0
                if viscous:
                    r00, r01, r02, r10, r11, r12, r20, r21, r22 = element_gradient(
                        velocity, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
                norm_sq = 0.0
                nonlinear = False
                if geometric or physical:
                    norm_sq = (h00 * h00 + h01 * h01 + h02 * h02 + h10 * h10 + h11 * h11
                               + h12 * h12 + h20 * h20 + h21 * h21 + h22 * h22)
                    nonlinear = norm_sq >= threshold_squared
                lam = volume_lambda[e]
                mu = volume_mu[e]
                if physical and nonlinear:
                    lam, mu = _corrected_lame(lam, mu, h00, h01, h02, h10, h11, h12, h20, h21, h22,
                                              law_kind, law_params, edge_gram[e], mean_ratio_scale[e])
                    if geometric and safeguard:
                        corrected_lambda[e] = lam    # for the safeguard pass
                        corrected_mu[e] = mu
                n_nonlinear += nonlinear
                if geometric and nonlinear:
                    f00 = 1.0 + h00
                    f11 = 1.0 + h11
                    f22 = 1.0 + h22
                    e00, e11, e22, e01, e02, e12 = green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
                    if safeguard and norm_sq >= SAFEGUARD_FREE_NORM_SQ:
                        # smallest stretch above the clamp <=> C - clamp^2 I positive definite
                        # (Sylvester's criterion, C = I + 2E: exact, no eigenvalues); and det F > 0
                        m00 = 1.0 + 2.0 * e00 - clamp_squared
                        m11 = 1.0 + 2.0 * e11 - clamp_squared
                        m22 = 1.0 + 2.0 * e22 - clamp_squared
                        m01 = 2.0 * e01
                        m02 = 2.0 * e02
                        m12 = 2.0 * e12
                        minor2 = m00 * m11 - m01 * m01
                        minor3 = (m00 * (m11 * m22 - m12 * m12) - m01 * (m01 * m22 - m12 * m02)
                                  + m02 * (m01 * m12 - m11 * m02))
                        det_f = deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22)
                        if not (m00 > 0.0 and minor2 > 0.0 and minor3 > 0.0 and det_f > 0.0):
                            slow_elements[lo + n_slow] = e
                            n_slow += 1
                            continue
                    tr_e = e00 + e11 + e22
                    s00 = lam * tr_e + 2.0 * mu * e00
                    s11 = lam * tr_e + 2.0 * mu * e11
                    s22 = lam * tr_e + 2.0 * mu * e22
                    s01 = 2.0 * mu * e01
                    s02 = 2.0 * mu * e02
                    s12 = 2.0 * mu * e12
                    if viscous:
                        v00, v11, v22, v01, v02, v12 = _viscous_stress(
                            h00, h01, h02, h10, h11, h12, h20, h21, h22,
                            r00, r01, r02, r10, r11, r12, r20, r21, r22, viscous_lambda[e], viscous_mu[e])
                        s00 += v00
                        s11 += v11
                        s22 += v22
                        s01 += v01
                        s02 += v02
                        s12 += v12
                    # P = F S (not symmetric)
                    p00 = f00 * s00 + h01 * s01 + h02 * s02
                    p01 = f00 * s01 + h01 * s11 + h02 * s12
                    p02 = f00 * s02 + h01 * s12 + h02 * s22
                    p10 = h10 * s00 + f11 * s01 + h12 * s02
                    p11 = h10 * s01 + f11 * s11 + h12 * s12
                    p12 = h10 * s02 + f11 * s12 + h12 * s22
                    p20 = h20 * s00 + h21 * s01 + f22 * s02
                    p21 = h20 * s01 + h21 * s11 + f22 * s12
                    p22 = h20 * s02 + h21 * s12 + f22 * s22
                else:
                    # small strain (physical only: with the corrected coefficients)
                    tr_h = lam * (h00 + h11 + h22)
                    p00 = tr_h + 2.0 * mu * h00
                    p11 = tr_h + 2.0 * mu * h11
                    p22 = tr_h + 2.0 * mu * h22
                    p01 = mu * (h01 + h10)
                    p02 = mu * (h02 + h20)
                    p12 = mu * (h12 + h21)
                    if viscous:
                        tr_r = viscous_lambda[e] * (r00 + r11 + r22)
                        mu_v = viscous_mu[e]
                        p00 += tr_r + 2.0 * mu_v * r00
                        p11 += tr_r + 2.0 * mu_v * r11
                        p22 += tr_r + 2.0 * mu_v * r22
                        p01 += mu_v * (r01 + r10)
                        p02 += mu_v * (r02 + r20)
                        p12 += mu_v * (r12 + r21)
                    p10 = p01
                    p20 = p02
                    p21 = p12
                _scatter_piola(buf, i0, i1, i2, i3, p00, p01, p02, p10, p11, p12, p20, p21, p22,
                               a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
            nonlinear_counts[c] = n_nonlinear
            n_safeguarded = 0
            if geometric:
                n_safeguarded = _safeguarded_elements(
                    slow_elements[lo:lo + n_slow], tetrahedra, shape_gradients, volume_lambda, volume_mu,
                    displacement, velocity, physical, viscous, corrected_lambda, corrected_mu,
                    viscous_lambda, viscous_mu, safeguard_scratch[c], buf)
            safeguard_counts[c] = n_safeguarded
    return kernel


@njit(cache=True, fastmath=FASTMATH, boundscheck=False)
def _safeguarded_elements(elements, tetrahedra, shape_gradients, volume_lambda, volume_mu,
                          displacement, velocity, physical, viscous, corrected_lambda, corrected_mu,
                          viscous_lambda, viscous_mu, scratch, buf):
    """St Venant-Kirchhoff forces of the elements the force loop set aside, with the inversion
    safeguard on the elastic stress (the viscous part stays F S_v). Returns how many it changed."""
    changed = 0
    fm = scratch[4]
    pm = scratch[5]
    for e in elements:
        i0, i1, i2, i3 = _element_nodes(tetrahedra, e)
        a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z = _shape_gradients(shape_gradients, e)
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = element_gradient(
            displacement, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
        lam = corrected_lambda[e] if physical else volume_lambda[e]
        mu = corrected_mu[e] if physical else volume_mu[e]
        v00 = v11 = v22 = v01 = v02 = v12 = 0.0
        if viscous:
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = element_gradient(
                velocity, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
            v00, v11, v22, v01, v02, v12 = _viscous_stress(
                h00, h01, h02, h10, h11, h12, h20, h21, h22,
                r00, r01, r02, r10, r11, r12, r20, r21, r22, viscous_lambda[e], viscous_mu[e])
        fm[0, 0] = 1.0 + h00
        fm[0, 1] = h01
        fm[0, 2] = h02
        fm[1, 0] = h10
        fm[1, 1] = 1.0 + h11
        fm[1, 2] = h12
        fm[2, 0] = h20
        fm[2, 1] = h21
        fm[2, 2] = 1.0 + h22
        # an element at the clamp to round-off may come back unchanged, as F S
        changed += safeguarded_piola(fm, lam, mu, scratch[:4], pm)
        # add the viscous F S_v
        _scatter_piola(buf, i0, i1, i2, i3,
                       pm[0, 0] + fm[0, 0] * v00 + fm[0, 1] * v01 + fm[0, 2] * v02,
                       pm[0, 1] + fm[0, 0] * v01 + fm[0, 1] * v11 + fm[0, 2] * v12,
                       pm[0, 2] + fm[0, 0] * v02 + fm[0, 1] * v12 + fm[0, 2] * v22,
                       pm[1, 0] + fm[1, 0] * v00 + fm[1, 1] * v01 + fm[1, 2] * v02,
                       pm[1, 1] + fm[1, 0] * v01 + fm[1, 1] * v11 + fm[1, 2] * v12,
                       pm[1, 2] + fm[1, 0] * v02 + fm[1, 1] * v12 + fm[1, 2] * v22,
                       pm[2, 0] + fm[2, 0] * v00 + fm[2, 1] * v01 + fm[2, 2] * v02,
                       pm[2, 1] + fm[2, 0] * v01 + fm[2, 1] * v11 + fm[2, 2] * v12,
                       pm[2, 2] + fm[2, 0] * v02 + fm[2, 1] * v12 + fm[2, 2] * v22,
                       a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
    return changed


@njit(cache=True, inline='always')
def take_node_force(buffers, chunk_node_lo, chunk_node_hi, i):
    """Sum of the chunk buffers that can hold node i's force; those rows are cleared for the next pass."""
    fx = 0.0
    fy = 0.0
    fz = 0.0
    for c in range(buffers.shape[0]):
        if chunk_node_lo[c] <= i and i < chunk_node_hi[c]:
            fx += buffers[c, i, 0]
            fy += buffers[c, i, 1]
            fz += buffers[c, i, 2]
            buffers[c, i, 0] = 0.0
            buffers[c, i, 1] = 0.0
            buffers[c, i, 2] = 0.0
    return fx, fy, fz


@njit(cache=True, parallel=True, boundscheck=False)
def reduce_buffers(buffers, chunk_node_lo, chunk_node_hi, out):
    """out[i] = the node force gathered from the chunk buffers (which are left cleared)."""
    for i in prange(out.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = take_node_force(buffers, chunk_node_lo, chunk_node_hi, i)


def chunk_layout(tetrahedra, n_nodes, n_chunks):
    """Split the element range into contiguous chunks; return (bounds, node_lo, node_hi).

    node_lo/node_hi bound the nodes each chunk touches, so the reduction reads only the buffer
    rows a chunk can have written.
    """
    n_elements = tetrahedra.shape[0]
    n_chunks = max(1, min(n_chunks, n_elements))
    bounds = np.linspace(0, n_elements, n_chunks + 1).round().astype(np.int64)
    node_lo = np.zeros(n_chunks, dtype=np.int64)
    node_hi = np.zeros(n_chunks, dtype=np.int64)
    for c in range(n_chunks):
        block = tetrahedra[bounds[c]:bounds[c + 1]]
        if block.size:
            node_lo[c] = block.min()
            node_hi[c] = block.max() + 1
    return bounds, node_lo, node_hi


# ----------------------------------------------------------------------------------------------
# The paper's assembled form: vertex and edge tensors (linear model).

@njit(cache=True, boundscheck=False)
def accumulate_tensors(tetrahedra, shape_gradients, volume_lambda, volume_mu, element_edges,
                       elements, sign, vertex_lambda, vertex_mu, edge_lambda, edge_mu):
    """Add (sign=+1) or remove (sign=-1) the given elements' K_jk = lambda A_jk + mu B_jk.

    A_jk = V a_j a_k^T, B_jk = V [a_k a_j^T + (a_j . a_k) I] (FORMULAS.md). Vertex tensors get
    K_jj; the edge tensor of edge (p, q), p < q, gets K_jk with j, k the local indices of p, q.
    element_edges (m, 6): global edge of each local pair (0,1),(0,2),(0,3),(1,2),(1,3),(2,3).
    """
    a = np.empty((4, 3))
    for e in elements:
        for r in range(3):
            a[1, r] = shape_gradients[e, 0, r]
            a[2, r] = shape_gradients[e, 1, r]
            a[3, r] = shape_gradients[e, 2, r]
            a[0, r] = -(a[1, r] + a[2, r] + a[3, r])
        vl = sign * volume_lambda[e]
        vm = sign * volume_mu[e]
        local = 0
        for j in range(4):
            for k in range(j, 4):
                dot = a[j, 0] * a[k, 0] + a[j, 1] * a[k, 1] + a[j, 2] * a[k, 2]
                if j == k:
                    p = tetrahedra[e, j]
                    for r in range(3):
                        for s in range(3):
                            vertex_lambda[p, r, s] += vl * a[j, r] * a[j, s]
                            vertex_mu[p, r, s] += vm * (a[j, s] * a[j, r] + (dot if r == s else 0.0))
                else:
                    edge = element_edges[e, local]
                    local += 1
                    # stored as K_pq with p < q: K_jk if the local order matches, else K_kj = K_jk^T
                    jj, kk = (j, k) if tetrahedra[e, j] < tetrahedra[e, k] else (k, j)
                    for r in range(3):
                        for s in range(3):
                            edge_lambda[edge, r, s] += vl * a[jj, r] * a[kk, s]
                            edge_mu[edge, r, s] += vm * (a[kk, r] * a[jj, s] + (dot if r == s else 0.0))


@njit(cache=True, inline='always')
def _edge_tensor_times(edge_lambda, edge_mu, edge, transpose, vx, vy, vz):
    """(K_e v) or (K_e^T v) for the edge tensor K_e = lambda part + mu part, as three scalars."""
    out0 = 0.0
    out1 = 0.0
    out2 = 0.0
    for s in range(3):
        value = vx if s == 0 else (vy if s == 1 else vz)
        if transpose:
            out0 += (edge_lambda[edge, s, 0] + edge_mu[edge, s, 0]) * value
            out1 += (edge_lambda[edge, s, 1] + edge_mu[edge, s, 1]) * value
            out2 += (edge_lambda[edge, s, 2] + edge_mu[edge, s, 2]) * value
        else:
            out0 += (edge_lambda[edge, 0, s] + edge_mu[edge, 0, s]) * value
            out1 += (edge_lambda[edge, 1, s] + edge_mu[edge, 1, s]) * value
            out2 += (edge_lambda[edge, 2, s] + edge_mu[edge, 2, s]) * value
    return out0, out1, out2


@njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False)
def edge_forces(vertex_lambda, vertex_mu, edge_lambda, edge_mu, edges,
                adjacency_ptr, adjacency_edge, displacement, out):
    """f_p = -(K_pp u_p + sum over edges (p, q) of K_pq u_q), gathered per vertex: no races.

    adjacency_ptr/adjacency_edge: CSR list of the edges at each vertex. An edge stored as (p, q)
    contributes K_pq u_q to p and K_pq^T u_p to q.
    """
    for p in prange(out.shape[0]):
        fx, fy, fz = _edge_tensor_times(vertex_lambda, vertex_mu, p, False, displacement[p, 0],
                                        displacement[p, 1], displacement[p, 2])
        for slot in range(adjacency_ptr[p], adjacency_ptr[p + 1]):
            edge = adjacency_edge[slot]
            transpose = edges[edge, 0] != p
            q = edges[edge, 0] if transpose else edges[edge, 1]
            gx, gy, gz = _edge_tensor_times(edge_lambda, edge_mu, edge, transpose, displacement[q, 0],
                                            displacement[q, 1], displacement[q, 2])
            fx += gx
            fy += gy
            fz += gz
        out[p, 0] = -fx
        out[p, 1] = -fy
        out[p, 2] = -fz
