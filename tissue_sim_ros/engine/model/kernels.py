"""Internal force kernels of the tensor-mass model (numba): the element pass.

Two formulations of the same forces, held equal by the tests:

* ``element_kernel``: the element loop used on the hot path. For each tetrahedron the
  displacement gradient H = sum_k u_k a_k^T (a_k: shape-function gradients; docs/method.md,
  "Shape-function gradients") gives the stress, and the force on vertex j is f_j = -V P a_j,
  where P is
    - linear (Cotin et al., seed section 3/4.1):  sigma = lambda tr(eps) I + 2 mu eps, eps = sym(H)
    - physically non-linear (4.1): the same with lambda + dlambda(q), mu + dmu(q), q the element's
      Liu-Joe mean ratio relative to its rest value
    - geometrically non-linear (4.2, St Venant-Kirchhoff): P = F S, F = I + H,
      E = (F^T F - I) / 2, S = lambda tr(E) I + 2 mu E
    - Kelvin-Voigt viscosity (4.3): the same linear law on the rate of deformation, sym(dH/dt)
      (or sym(F^T dF/dt) with the geometric model, so rigid motion is force-free).
  A non-linearity threshold (seed section 6) sends elements whose |H|_F is below it down the
  linear path. f_j = -V sigma a_j is the element form of -sum_k K_jk u_k (docs/method.md,
  "Linear tensor-mass").
* ``edge_form.edge_forces``: the paper's assembled form, f_i = -(K_ii u_i + sum_j K_ij u_j)
  (linear only, as in the paper).

The element loop runs in SIMD blocks of BLOCK elements (see the section below). Parallel loops
are race-free: elements are split into contiguous chunks of whole blocks (spatially ordered
meshes keep each chunk's nodes local), each chunk accumulates into its own buffer, and a node
loop reduces the buffers it touches and clears them for the next call. Nothing is allocated.
"""
import functools
import types

import numpy as np
from numba import njit, prange
from numba.extending import register_jitable

from tissue_sim_ros.engine.compiled import cache as compile_cache  # noqa: F401  (compile_cache reports compiles)
from tissue_sim_ros.engine.model import simd_lanes
from tissue_sim_ros.engine.model.inversion_safeguard import STRETCH_CLAMP, safeguarded_piola  # noqa: F401
from tissue_sim_ros.engine.model.simd_lanes import gather_difference_lanes, pack_node_state, scatter_force_lanes

# Floating-point contraction and reassociation are fine here; NaN and inf must stay detectable
# (the watchdog looks for them), so no 'nnan' / 'ninf'.
FASTMATH = {'contract', 'reassoc', 'nsz', 'arcp', 'afn'}

# The literals of the element arithmetic, typed float32. Against a float64 value they widen
# exactly (all are powers of two), so the float64 pass is unchanged; in a float32 pass
# (model.precision) they keep the arithmetic in float32, where a float64 literal would widen every
# lane to float64 and halve the vector width.
ZERO, HALF, ONE, TWO, FOUR = (np.float32(value) for value in (0.0, 0.5, 1.0, 2.0, 4.0))

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


@njit(cache=True, inline='always')
def _product3(x00, x01, x02, x10, x11, x12, x20, x21, x22, y00, y01, y02, y10, y11, y12, y20, y21, y22):
    """X Y of two 3x3 matrices given row-major as nine scalars each; row-major nine scalars."""
    return (x00 * y00 + x01 * y10 + x02 * y20, x00 * y01 + x01 * y11 + x02 * y21,
            x00 * y02 + x01 * y12 + x02 * y22, x10 * y00 + x11 * y10 + x12 * y20,
            x10 * y01 + x11 * y11 + x12 * y21, x10 * y02 + x11 * y12 + x12 * y22,
            x20 * y00 + x21 * y10 + x22 * y20, x20 * y01 + x21 * y11 + x22 * y21,
            x20 * y02 + x21 * y12 + x22 * y22)


@njit(cache=True, inline='always')
def gradient_of_differences(d1x, d1y, d1z, d2x, d2y, d2z, d3x, d3y, d3z,
                            a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z):
    """G = sum_{k=1..3} d_k a_k^T = D^T A (rows of D: d_k, of A: a_k), row-major as nine scalars,
    from the differences d_k = w_k - w_0 of a nodal field w over one tetrahedron (docs/method.md,
    "Shape-function gradients": G = sum_k w_k a_k^T, a_0 = -(a_1 + a_2 + a_3))."""
    return _product3(d1x, d2x, d3x, d1y, d2y, d3y, d1z, d2z, d3z,
                     a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)


@njit(cache=True, inline='always')
def element_gradient(field, i0, i1, i2, i3, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z):
    """Gradient of a nodal field over one tetrahedron (nodes i0..i3), row-major 3x3 as nine scalars."""
    return gradient_of_differences(
        field[i1, 0] - field[i0, 0], field[i1, 1] - field[i0, 1], field[i1, 2] - field[i0, 2],
        field[i2, 0] - field[i0, 0], field[i2, 1] - field[i0, 1], field[i2, 2] - field[i0, 2],
        field[i3, 0] - field[i0, 0], field[i3, 1] - field[i0, 1], field[i3, 2] - field[i0, 2],
        a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)


@njit(cache=True, inline='always')
def deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """det F of F = I + H (volume ratio; <= 0 for an inverted element)."""
    return ((ONE + h00) * ((ONE + h11) * (ONE + h22) - h12 * h21) - h01 * (h10 * (ONE + h22) - h12 * h20)
            + h02 * (h10 * h21 - (ONE + h11) * h20))


@njit(cache=True, inline='always')
def green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """Green-Lagrange strain E = (H + H^T + H^T H) / 2 as (e00, e11, e22, e01, e02, e12)."""
    return (HALF * (h00 + h00 + h00 * h00 + h10 * h10 + h20 * h20),
            HALF * (h11 + h11 + h01 * h01 + h11 * h11 + h21 * h21),
            HALF * (h22 + h22 + h02 * h02 + h12 * h12 + h22 * h22),
            HALF * (h01 + h10 + h00 * h01 + h10 * h11 + h20 * h21),
            HALF * (h02 + h20 + h00 * h02 + h10 * h12 + h20 * h22),
            HALF * (h12 + h21 + h01 * h02 + h11 * h12 + h21 * h22))


@njit(cache=True, inline='always')
def _green_strain_rate(h00, h01, h02, h10, h11, h12, h20, h21, h22,
                       r00, r01, r02, r10, r11, r12, r20, r21, r22):
    """dE/dt = sym(F^T dF/dt), F = I + H, dF/dt = R, as (q00, q11, q22, q01, q02, q12)."""
    return ((ONE + h00) * r00 + h10 * r10 + h20 * r20,
            h01 * r01 + (ONE + h11) * r11 + h21 * r21,
            h02 * r02 + h12 * r12 + (ONE + h22) * r22,
            HALF * ((ONE + h00) * r01 + h10 * r11 + h20 * r21 + h01 * r00 + (ONE + h11) * r10 + h21 * r20),
            HALF * ((ONE + h00) * r02 + h10 * r12 + h20 * r22 + h02 * r00 + h12 * r10 + (ONE + h22) * r20),
            HALF * (h01 * r02 + (ONE + h11) * r12 + h21 * r22 + h02 * r01 + h12 * r11 + (ONE + h22) * r21))


@njit(cache=True, inline='always')
def _isotropic_stress(lam, mu, e00, e11, e22, e01, e02, e12):
    """lambda tr(E) I + 2 mu E of a symmetric E, as (s00, s11, s22, s01, s02, s12)."""
    tr_e = lam * (e00 + e11 + e22)
    return (tr_e + TWO * mu * e00, tr_e + TWO * mu * e11, tr_e + TWO * mu * e22,
            TWO * mu * e01, TWO * mu * e02, TWO * mu * e12)


@njit(cache=True, inline='always')
def _viscous_stress(h00, h01, h02, h10, h11, h12, h20, h21, h22,
                    r00, r01, r02, r10, r11, r12, r20, r21, r22, lam_v, mu_v):
    """Kelvin-Voigt second Piola stress on dE/dt = sym(F^T dF/dt), as (v00, v11, v22, v01, v02, v12)."""
    q00, q11, q22, q01, q02, q12 = _green_strain_rate(h00, h01, h02, h10, h11, h12, h20, h21, h22,
                                                      r00, r01, r02, r10, r11, r12, r20, r21, r22)
    return _isotropic_stress(lam_v, mu_v, q00, q11, q22, q01, q02, q12)


@njit(cache=True, inline='always')
def _first_piola(h00, h01, h02, h10, h11, h12, h20, h21, h22, s00, s11, s22, s01, s02, s12):
    """P = F S, F = I + H, S symmetric: row-major nine scalars (P is not symmetric)."""
    return _product3(ONE + h00, h01, h02, h10, ONE + h11, h12, h20, h21, ONE + h22,
                     s00, s01, s02, s01, s11, s12, s02, s12, s22)


@njit(cache=True, inline='always')
def _piola_forces(p00, p01, p02, p10, p11, p12, p20, p21, p22,
                  a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z):
    """Nodal forces f_k = -V P a_k, k = 1..3 (V folded into P): the rows of A (-P)^T, as nine
    scalars; f_0 = -(f_1 + f_2 + f_3)."""
    return _product3(a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z,
                     -p00, -p10, -p20, -p01, -p11, -p21, -p02, -p12, -p22)


@njit(cache=True, inline='always')
def _scatter_forces(buf, i0, i1, i2, i3, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z):
    """Add an element's nodal forces f_1..f_3 and f_0 = -(f_1 + f_2 + f_3) to ``buf``."""
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


# The small load/store helpers below are plain calls that LLVM inlines, not inline='always':
# numba copies an inlined function's IR into every call site, and the element pass has hundreds
# of them. register_jitable, not njit: a dispatcher is compiled once per constant argument (each
# field offset its own signature, 20-odd compiles per model); these are typed on plain integers.
# Integer offsets, loads and stores only, so no floating-point flag depends on where they end up.
@register_jitable
def _element_nodes(tetrahedra, e):
    """The element's node indices, unsigned so that indexing skips the negative-index wraparound
    (e too: elements are never counted from the end)."""
    e = np.uint64(e)
    return (np.uint32(tetrahedra[e, 0]), np.uint32(tetrahedra[e, 1]), np.uint32(tetrahedra[e, 2]),
            np.uint32(tetrahedra[e, 3]))


@register_jitable
def _shape_gradients(shape_gradients, e):
    return (shape_gradients[e, 0, 0], shape_gradients[e, 0, 1], shape_gradients[e, 0, 2],
            shape_gradients[e, 1, 0], shape_gradients[e, 1, 1], shape_gradients[e, 1, 2],
            shape_gradients[e, 2, 0], shape_gradients[e, 2, 1], shape_gradients[e, 2, 2])


# ----------------------------------------------------------------------------------------------
# The element pass in SIMD blocks. BLOCK consecutive elements are one block, an element per
# lane: each element's node differences are gathered into the chunk's row of a small work array
# (simd_lanes: vector loads and a transpose), loops over the lanes do all the arithmetic on fixed
# offsets of that one row (straight-line, branch-free code with no possible aliasing, which LLVM
# vectorizes: AVX-512 does 8 lanes an instruction; the element constants are copied into the row
# because lane loops reading them in place run far slower, presumably as LLVM cannot tell the two
# arrays apart), and the nodal forces are scattered back (simd_lanes). Field k of lane j sits at
# k * BLOCK + j (_at). A block is 8 elements: the lanes of the gather's 8 x 8 transpose.
# Figures: docs/performance.md.
BLOCK = 8
assert BLOCK == simd_lanes.LANES, 'the gather and scatter transpose 8 lanes'
# per-element constants, stored block by block (pack_element_blocks) and copied into the work row
SHAPE = 0                      # 9: a_1, a_2, a_3 (x, y, z each)
LAMBDA, MU = 9, 10             # V lambda, V mu
VISCOUS_LAMBDA, VISCOUS_MU = 11, 12
GRAM = 13                      # 6: rest edge Gram matrix (xx, yy, zz, xy, xz, yz)
RATIO_SCALE = 19               # mean_ratio_scale
N_CONSTANTS = 20
# per-block work fields
_DU = 20                       # 9: u_k - u_0, k = 1..3
_DV = 29                       # 9: v_k - v_0
_H = 38                        # 9: displacement gradient
_FORCE = 47                    # 9: f_1, f_2, f_3
_NONLINEAR = 56                # 1.0 where the element takes the non-linear path
_NEEDS_LAW = 57                # 1.0 where the physical law's corrections are not zero
_DET = 58                      # det F
_TR_CG = 59                    # tr(F^T F G)
_LAMBDA_C, _MU_C = 60, 61      # corrected Lamé values
_SLOW = 62                     # 1.0 where the inversion safeguard must decide
_STRAIN = 63                   # 6: Green-Lagrange strain (e00, e11, e22, e01, e02, e12)
N_WORK = 69


def pack_element_blocks(shape_gradients, volume_lambda, volume_mu, viscous_lambda, viscous_mu,
                        edge_gram, mean_ratio_scale):
    """Per-element constants in block order (n_blocks, N_CONSTANTS * BLOCK); lanes past the last
    element are zero (they give zero force). viscous_* may be length 1 (no viscosity: zeros)."""
    m = len(volume_lambda)
    n_blocks = -(-m // BLOCK)
    columns = np.zeros((n_blocks * BLOCK, N_CONSTANTS))
    columns[:m, SHAPE:SHAPE + 9] = np.asarray(shape_gradients).reshape(m, 9)
    columns[:m, LAMBDA] = volume_lambda
    columns[:m, MU] = volume_mu
    columns[:m, VISCOUS_LAMBDA] = viscous_lambda
    columns[:m, VISCOUS_MU] = viscous_mu
    columns[:m, GRAM:GRAM + 6] = edge_gram
    columns[:m, RATIO_SCALE] = mean_ratio_scale
    return np.ascontiguousarray(columns.reshape(n_blocks, BLOCK, N_CONSTANTS).transpose(0, 2, 1)
                                .reshape(n_blocks, N_CONSTANTS * BLOCK))


# Distortions s below this are round-off of the rest state (q/q_rest is computed to ~1e-15, and
# a quarter of the elements at rest land on the s > 0 side) and count as none, skipping the
# law's pow and exponentials; their corrections would be ~1e-12 of the coefficients.
# In a float32 pass q/q_rest carries float32 round-off (~1e-7, a few ulps), so its floor is 1e-6:
# the corrections it skips are below 1e-6 times the law's slope, float32's own resolution.
DISTORTION_FLOOR = 1e-13
DISTORTION_FLOOR_FLOAT32 = 1e-6
_UNDISTORTED_CUBE = (1.0 - DISTORTION_FLOOR) ** 3
_UNDISTORTED_CUBE_FLOAT32 = (1.0 - DISTORTION_FLOOR_FLOAT32) ** 3


@register_jitable
def _at(field, j):
    """Offset of ``field`` in lane j of a work row. Unsigned, so numba does not emit the
    negative-index wraparound (four instructions on every scalar access of the gather)."""
    return np.uint64(field * BLOCK) + np.uint64(j)


@register_jitable
def _get9(work, row, field, j):
    return (work[row, _at(field, j)], work[row, _at(field + 1, j)], work[row, _at(field + 2, j)],
            work[row, _at(field + 3, j)], work[row, _at(field + 4, j)], work[row, _at(field + 5, j)],
            work[row, _at(field + 6, j)], work[row, _at(field + 7, j)], work[row, _at(field + 8, j)])


@register_jitable
def _set9(work, row, field, j, v0, v1, v2, v3, v4, v5, v6, v7, v8):
    work[row, _at(field, j)] = v0
    work[row, _at(field + 1, j)] = v1
    work[row, _at(field + 2, j)] = v2
    work[row, _at(field + 3, j)] = v3
    work[row, _at(field + 4, j)] = v4
    work[row, _at(field + 5, j)] = v5
    work[row, _at(field + 6, j)] = v6
    work[row, _at(field + 7, j)] = v7
    work[row, _at(field + 8, j)] = v8


@njit(cache=True, inline='always')
def _lane_gradient(work, row, field, j):
    """Gradient of the field whose node differences are at ``field``, lane j."""
    d1x, d1y, d1z, d2x, d2y, d2z, d3x, d3y, d3z = _get9(work, row, field, j)
    a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z = _get9(work, row, SHAPE, j)
    return gradient_of_differences(d1x, d1y, d1z, d2x, d2y, d2z, d3x, d3y, d3z,
                                   a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)


@njit(cache=True, inline='always')
def _gather_differences(work, row, field, j, values, i0, i1, i2, i3):
    for r in range(3):
        w0 = values[i0, r]
        work[row, _at(field + r, j)] = values[i1, r] - w0
        work[row, _at(field + 3 + r, j)] = values[i2, r] - w0
        work[row, _at(field + 6 + r, j)] = values[i3, r] - w0


@njit(cache=True, inline='always')
def _classify_lanes(work, row, threshold_squared, physical, undistorted_cube):
    """Displacement gradient H of every lane, and whether it takes the non-linear path
    (|H|_F^2 >= threshold^2); with the physical law also det F and tr(F^T F G), and whether the
    law's corrections can be non-zero. Returns the counts of non-linear lanes and of lanes that need
    the law (of all BLOCK): the scalar lane loops after it run only when there is work for them."""
    count = 0
    count_law = 0
    for j in range(BLOCK):
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = _lane_gradient(work, row, _DU, j)
        _set9(work, row, _H, j, h00, h01, h02, h10, h11, h12, h20, h21, h22)
        norm_sq = (h00 * h00 + h01 * h01 + h02 * h02 + h10 * h10 + h11 * h11
                   + h12 * h12 + h20 * h20 + h21 * h21 + h22 * h22)
        nonlinear = norm_sq >= threshold_squared
        work[row, _at(_NONLINEAR, j)] = ONE if nonlinear else ZERO
        count += nonlinear
        if physical:
            e00, e11, e22, e01, e02, e12 = green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
            det_f = deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22)
            # tr(C G) with C = I + 2E
            tr_cg = (work[row, _at(GRAM, j)] * (ONE + TWO * e00) + work[row, _at(GRAM + 1, j)] * (ONE + TWO * e11)
                     + work[row, _at(GRAM + 2, j)] * (ONE + TWO * e22)
                     + FOUR * (work[row, _at(GRAM + 3, j)] * e01 + work[row, _at(GRAM + 4, j)] * e02
                              + work[row, _at(GRAM + 5, j)] * e12))
            scale = work[row, _at(RATIO_SCALE, j)]
            # the mean ratio fell (s = 1 - q/q_rest > DISTORTION_FLOOR), decided on the cubes
            # without the cube root; most deformed elements of a needle dent do not distort
            distorted = scale * scale * scale * det_f * det_f < undistorted_cube * tr_cg * tr_cg * tr_cg
            work[row, _at(_NEEDS_LAW, j)] = ONE if (nonlinear & distorted) else ZERO
            count_law += nonlinear & distorted
            work[row, _at(_DET, j)] = det_f
            work[row, _at(_TR_CG, j)] = tr_cg
            work[row, _at(_STRAIN, j)] = e00
            work[row, _at(_STRAIN + 1, j)] = e11
            work[row, _at(_STRAIN + 2, j)] = e22
            work[row, _at(_STRAIN + 3, j)] = e01
            work[row, _at(_STRAIN + 4, j)] = e02
            work[row, _at(_STRAIN + 5, j)] = e12
            work[row, _at(_LAMBDA_C, j)] = work[row, _at(LAMBDA, j)]
            work[row, _at(_MU_C, j)] = work[row, _at(MU, j)]
    return count, count_law


@njit(cache=True, inline='always')
def _apply_law(work, row, law_kind, law_params):
    """Seed section 4.1: lambda + dlambda(s), mu + dmu(s) of the distorted lanes (scalar: libm's
    pow and exp), s = 1 - q/q_rest, q/q_rest = scale |det F|^(2/3) / tr(F^T F G)."""
    for j in range(BLOCK):
        if work[row, _at(_NEEDS_LAW, j)] > 0.0:
            relative_quality = (work[row, _at(RATIO_SCALE, j)] * np.abs(work[row, _at(_DET, j)]) ** (2.0 / 3.0)
                                / work[row, _at(_TR_CG, j)])
            corr_lambda, corr_mu = _law_correction(law_kind, law_params, max(0.0, 1.0 - relative_quality))
            work[row, _at(_LAMBDA_C, j)] *= 1.0 + corr_lambda
            work[row, _at(_MU_C, j)] *= 1.0 + corr_mu


@njit(cache=True, inline='always')
def _stress_lanes(work, row, gradient_stored, small_strain, finite_strain, physical, viscous, safeguard,
                  clamp_squared):
    """Nodal forces f_1..f_3 of every lane from the stress: small strain, St Venant-Kirchhoff
    (finite_strain), or both and each lane takes the one its _NONLINEAR flag says; Kelvin-Voigt
    added. With the safeguard, non-linear lanes whose smallest principal stretch is below the
    clamp or that are inverted are flagged _SLOW: smallest stretch above the clamp <=> C - clamp^2 I
    positive definite (Sylvester's criterion, exact, no eigenvalues). Returns the count of _SLOW lanes."""
    count_slow = 0
    for j in range(BLOCK):
        if gradient_stored:
            h00, h01, h02, h10, h11, h12, h20, h21, h22 = _get9(work, row, _H, j)
        else:
            h00, h01, h02, h10, h11, h12, h20, h21, h22 = _lane_gradient(work, row, _DU, j)
        if physical:
            lam = work[row, _at(_LAMBDA_C, j)]
            mu = work[row, _at(_MU_C, j)]
        else:
            lam = work[row, _at(LAMBDA, j)]
            mu = work[row, _at(MU, j)]
        r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = ZERO
        lam_v = mu_v = ZERO
        if viscous:
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = _lane_gradient(work, row, _DV, j)
            lam_v = work[row, _at(VISCOUS_LAMBDA, j)]
            mu_v = work[row, _at(VISCOUS_MU, j)]
        p00 = p01 = p02 = p10 = p11 = p12 = p20 = p21 = p22 = ZERO
        if small_strain:
            # E = sym(H), and sym(dH/dt) for the viscous stress
            s00, s11, s22, s01, s02, s12 = _isotropic_stress(lam, mu, h00, h11, h22, HALF * (h01 + h10),
                                                             HALF * (h02 + h20), HALF * (h12 + h21))
            if viscous:
                v00, v11, v22, v01, v02, v12 = _isotropic_stress(
                    lam_v, mu_v, r00, r11, r22, HALF * (r01 + r10), HALF * (r02 + r20), HALF * (r12 + r21))
                s00 += v00
                s11 += v11
                s22 += v22
                s01 += v01
                s02 += v02
                s12 += v12
            p00, p01, p02, p10, p11, p12, p20, p21, p22 = s00, s01, s02, s01, s11, s12, s02, s12, s22
        if finite_strain:
            nonlinear = work[row, _at(_NONLINEAR, j)] > ZERO
            if physical:     # _classify_lanes has them
                e00 = work[row, _at(_STRAIN, j)]
                e11 = work[row, _at(_STRAIN + 1, j)]
                e22 = work[row, _at(_STRAIN + 2, j)]
                e01 = work[row, _at(_STRAIN + 3, j)]
                e02 = work[row, _at(_STRAIN + 4, j)]
                e12 = work[row, _at(_STRAIN + 5, j)]
                det_f = work[row, _at(_DET, j)]
            else:
                e00, e11, e22, e01, e02, e12 = green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
                det_f = deformation_determinant(h00, h01, h02, h10, h11, h12, h20, h21, h22)
            t00, t11, t22, t01, t02, t12 = _isotropic_stress(lam, mu, e00, e11, e22, e01, e02, e12)
            if viscous:
                v00, v11, v22, v01, v02, v12 = _viscous_stress(
                    h00, h01, h02, h10, h11, h12, h20, h21, h22,
                    r00, r01, r02, r10, r11, r12, r20, r21, r22, lam_v, mu_v)
                t00 += v00
                t11 += v11
                t22 += v22
                t01 += v01
                t02 += v02
                t12 += v12
            g00, g01, g02, g10, g11, g12, g20, g21, g22 = _first_piola(
                h00, h01, h02, h10, h11, h12, h20, h21, h22, t00, t11, t22, t01, t02, t12)
            if small_strain:
                p00 = g00 if nonlinear else p00
                p01 = g01 if nonlinear else p01
                p02 = g02 if nonlinear else p02
                p10 = g10 if nonlinear else p10
                p11 = g11 if nonlinear else p11
                p12 = g12 if nonlinear else p12
                p20 = g20 if nonlinear else p20
                p21 = g21 if nonlinear else p21
                p22 = g22 if nonlinear else p22
            else:
                p00, p01, p02, p10, p11, p12, p20, p21, p22 = g00, g01, g02, g10, g11, g12, g20, g21, g22
            m00 = ONE + TWO * e00 - clamp_squared
            m11 = ONE + TWO * e11 - clamp_squared
            m22 = ONE + TWO * e22 - clamp_squared
            m01 = TWO * e01
            m02 = TWO * e02
            m12 = TWO * e12
            minor2 = m00 * m11 - m01 * m01
            minor3 = (m00 * (m11 * m22 - m12 * m12) - m01 * (m01 * m22 - m12 * m02)
                      + m02 * (m01 * m12 - m11 * m02))
            # bitwise, not short-circuit: no branches in the lane loop
            inside = (m00 > ZERO) & (minor2 > ZERO) & (minor3 > ZERO) & (det_f > ZERO)
            slow = safeguard & nonlinear & (not inside)
            work[row, _at(_SLOW, j)] = ONE if slow else ZERO
            count_slow += slow
        a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z = _get9(work, row, SHAPE, j)
        f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z = _piola_forces(
            p00, p01, p02, p10, p11, p12, p20, p21, p22, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
        _set9(work, row, _FORCE, j, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z)
    return count_slow


def model_name(geometric, physical, viscous):
    """'linear', or the non-linear parts and viscosity a model has, e.g. 'geometric_physical_viscous'."""
    parts = [name for name, on in (('geometric', geometric), ('physical', physical), ('viscous', viscous)) if on]
    return '_'.join(parts) or 'linear'


@functools.lru_cache(maxsize=None)
def element_kernel(geometric, physical, viscous):
    """The element pass compiled for one model: the three flags are compile-time constants, so
    each variant holds only its own arithmetic and branches (one source, eight machine codes).

    Call it as ``kernel(tetrahedra, element_blocks, displacement, velocity, threshold_squared,
    law_kind, law_params, chunk_bounds, work, buffers, nonlinear_counts, safeguard,
    safeguard_counts, slow_elements, corrected_lambda, corrected_mu, shape_gradients,
    volume_lambda, volume_mu, viscous_lambda, viscous_mu, safeguard_scratch, node_state)``.

    The parallel loop only calls each thread's pass (``_thread_pass_of``): written inside the
    prange loop, the pass would go through numba's parallel passes, which copy and rewrite the
    whole loop body, and be typed and compiled twice (the loop, then its outlined body).
    """
    geometric, physical, viscous = bool(geometric), bool(physical), bool(viscous)

    def kernel(tetrahedra, element_blocks, displacement, velocity, threshold_squared, law_kind,
               law_params, chunk_bounds, work, buffers, nonlinear_counts, safeguard, safeguard_counts,
               slow_elements, corrected_lambda, corrected_mu, shape_gradients, volume_lambda,
               volume_mu, viscous_lambda, viscous_mu, safeguard_scratch, node_state):
        """Accumulate the internal elastic (+ viscous) forces into the per-chunk ``buffers``.

        The node forces are the sum over chunks (``reduce_buffers``, or fused into the solver's
        node update through ``take_node_force``).

        element_blocks: pack_element_blocks of the element arrays; chunk_bounds: multiples of
        BLOCK (chunk_layout). Worker t of n_workers = len(buffers) takes chunks t, t + n_workers,
        ... into buffers[t] (n_workers, n, 4: rows padded for simd_lanes); work (n_workers,
        >= N_WORK * BLOCK): its scratch row. node_state (n, 8): filled here from displacement and
        velocity (simd_lanes.pack_node_state), the rows whole blocks gather from.
        nonlinear_counts (n_chunks,): elements that took the non-linear path, per chunk.
        safeguard: apply the inversion safeguard on the St Venant-Kirchhoff path to elements whose
        smallest principal stretch is below STRETCH_CLAMP or whose det F <= 0; those are set aside
        in ``slow_elements`` (m,), their corrected Lamé values in ``corrected_lambda``/``_mu`` (m,),
        and done after the chunk's loop by ``_safeguarded_elements`` from the element arrays
        (shape_gradients (m, 3, 3), V lambda, V mu, V lambda_v, V mu_v). safeguard_scratch
        (n_workers, 6, 3, 3); safeguard_counts (n_chunks,) how many elements it changed.
        """
        # the vector gather and scatter read and write whole rows of these, unchecked
        if (node_state.shape[0] < displacement.shape[0] or node_state.shape[1] != simd_lanes.STATE_WIDTH
                or buffers.shape[1] < displacement.shape[0] or buffers.shape[2] != simd_lanes.BUFFER_WIDTH):
            raise ValueError('element pass: node_state must be (n, 8) and buffers (workers, n, 4)')
        pack_node_state(displacement, velocity, viscous, node_state)
        for t in prange(buffers.shape[0]):
            # _thread_pass: this model's pass (bound below). The thread index as the outlined
            # body types it (unsigned), so the pass has one signature and no index wraparound.
            _thread_pass(geometric, physical, viscous, np.uint64(t), tetrahedra, element_blocks,  # noqa: F821
                         displacement, velocity, threshold_squared, law_kind, law_params, chunk_bounds,
                         work, buffers, nonlinear_counts, safeguard, safeguard_counts, slow_elements,
                         corrected_lambda, corrected_mu, shape_gradients, volume_lambda, volume_mu,
                         viscous_lambda, viscous_mu, safeguard_scratch, node_state)

    # The pass is a global of this kernel's own: a closure holding the pass's dispatcher would
    # change numba's cache key in every process (it hashes what a closure holds, and a dispatcher
    # pickles with a new id each time).
    namespace = dict(globals(), _thread_pass=_thread_pass_of(geometric, physical, viscous))
    kernel = types.FunctionType(kernel.__code__, namespace, kernel.__name__, kernel.__defaults__,
                                kernel.__closure__)
    # One cache index per model: numba names the index after the qualified name, and processes
    # that compile different models at once (compile_cache) must not write one index together
    # (an entry can be lost, or point at another model's code).
    kernel.__qualname__ = f'element_kernel.<locals>.kernel_{model_name(geometric, physical, viscous)}'
    # nogil: the node's publishing thread runs while its engine thread is in the pass
    return njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False, nogil=True)(kernel)


@functools.lru_cache(maxsize=None)
def _thread_pass_of(geometric, physical, viscous):
    """Thread t's chunks of the element pass for one model, the flags closed over as constants
    (the is_* arguments are the kernel's: they keep its cache key apart per model). Not cached on
    its own: the kernel's cache entry holds it."""
    nonlinear_model = geometric or physical
    # the constants this model reads (they are stored in this order)
    n_constants = N_CONSTANTS if physical else (VISCOUS_MU + 1 if viscous else MU + 1)

    @njit(fastmath=FASTMATH, boundscheck=False)
    def thread_pass(is_geometric, is_physical, is_viscous, t, tetrahedra, element_blocks, displacement,
                    velocity, threshold_squared, law_kind, law_params, chunk_bounds, work, buffers,
                    nonlinear_counts, safeguard, safeguard_counts, slow_elements, corrected_lambda,
                    corrected_mu, shape_gradients, volume_lambda, volume_mu, viscous_lambda, viscous_mu,
                    safeguard_scratch, node_state):
        # the pass's scalars in the work array's precision (float32 arithmetic stays float32)
        real = work.dtype.type
        clamp_squared = real(STRETCH_CLAMP * STRETCH_CLAMP)
        nonlinear_from = real(threshold_squared)
        # the float64 floor rounds to none in float32 (1 - 1e-13 is 1): then float32's own
        undistorted_cube = (real(_UNDISTORTED_CUBE) if real(_UNDISTORTED_CUBE) < real(1.0)
                            else real(_UNDISTORTED_CUBE_FLOAT32))
        n_chunks = chunk_bounds.shape[0] - 1
        n_workers = buffers.shape[0]
        buf = buffers[t]
        for c in range(t, n_chunks, n_workers):
            lo = chunk_bounds[c]
            hi = chunk_bounds[c + 1]
            n_nonlinear = 0
            n_slow = 0
            for base in range(lo, hi, BLOCK):
                n = min(BLOCK, hi - base)
                block = base // BLOCK
                for k in range(n_constants * BLOCK):
                    work[t, k] = element_blocks[block, k]
                if n == BLOCK:   # a whole block: vector loads and transposes (simd_lanes)
                    gather_difference_lanes(work, t, _DU, _DV, node_state, tetrahedra, base, viscous)
                else:            # the last, partial one: lane by lane from the same rows, zeros past its elements
                    for j in range(n):
                        i0, i1, i2, i3 = _element_nodes(tetrahedra, base + j)
                        _gather_differences(work, t, _DU, j, node_state[:, 0:3], i0, i1, i2, i3)
                        if viscous:
                            _gather_differences(work, t, _DV, j, node_state[:, 4:7], i0, i1, i2, i3)
                    for j in range(n, BLOCK):
                        for k in range(9):
                            work[t, _at(_DU + k, j)] = 0.0
                            work[t, _at(_DV + k, j)] = 0.0
                lanes_nonlinear = 0
                if nonlinear_model:
                    lanes_nonlinear, lanes_law = _classify_lanes(work, t, nonlinear_from, physical, undistorted_cube)
                    if n == BLOCK:
                        n_nonlinear += lanes_nonlinear
                    else:   # lanes past the last element have zero gradients, but count only real ones
                        for j in range(n):
                            n_nonlinear += work[t, _at(_NONLINEAR, j)] > 0.0
                    if physical and lanes_law > 0:
                        _apply_law(work, t, law_kind, law_params)
                # each lane loop holds only the stress it needs (the flags are constants)
                if geometric and lanes_nonlinear == BLOCK:
                    lanes_slow = _stress_lanes(work, t, True, False, True, physical, viscous,
                                               safeguard, clamp_squared)
                elif geometric and lanes_nonlinear > 0:
                    lanes_slow = _stress_lanes(work, t, True, True, True, physical, viscous,
                                               safeguard, clamp_squared)
                else:
                    lanes_slow = _stress_lanes(work, t, nonlinear_model, True, False, physical,
                                               viscous, safeguard, clamp_squared)
                # lane by lane only for elements set aside, and for the last, partial block
                if lanes_slow > 0 or n < BLOCK:
                    for j in range(n):
                        e = base + j
                        if geometric and lanes_slow > 0 and work[t, _at(_SLOW, j)] > 0.0:
                            slow_elements[lo + n_slow] = e
                            n_slow += 1
                            if physical:
                                corrected_lambda[e] = work[t, _at(_LAMBDA_C, j)]
                                corrected_mu[e] = work[t, _at(_MU_C, j)]
                            # set aside: its lane adds zeros below, the safeguard its forces later
                            for k in range(9):
                                work[t, _at(_FORCE + k, j)] = ZERO
                        elif n < BLOCK:
                            i0, i1, i2, i3 = _element_nodes(tetrahedra, e)
                            f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z = _get9(work, t, _FORCE, j)
                            _scatter_forces(buf, i0, i1, i2, i3, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z)
                if n == BLOCK:
                    scatter_force_lanes(buf, work, t, _FORCE, tetrahedra, base)
            nonlinear_counts[c] = n_nonlinear
            n_safeguarded = 0
            if geometric:
                n_safeguarded = _safeguarded_elements(
                    slow_elements[lo:lo + n_slow], tetrahedra, shape_gradients, volume_lambda, volume_mu,
                    displacement, velocity, physical, viscous, corrected_lambda, corrected_mu,
                    viscous_lambda, viscous_mu, safeguard_scratch[t], buf)
            safeguard_counts[c] = n_safeguarded
    return thread_pass


# compiled once per model (the flags are constants of the caller), with the kernel that holds it
@njit(fastmath=FASTMATH, boundscheck=False)
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
        f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z = _piola_forces(
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
        _scatter_forces(buf, i0, i1, i2, i3, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z)
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


@njit(cache=True, parallel=True, boundscheck=False, nogil=True)
def reduce_buffers(buffers, chunk_node_lo, chunk_node_hi, out):
    """out[i] = the node force gathered from the chunk buffers (which are left cleared)."""
    for i in prange(out.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = take_node_force(buffers, chunk_node_lo, chunk_node_hi, i)


# Chunks per worker. A needle's non-linear elements (the law's pow and exp, the safeguard) sit in
# one region of a spatially ordered mesh, which contiguous halves give to one thread. Workers take
# every n_workers-th chunk instead, so the region is shared among them.
CHUNKS_PER_WORKER = 32


def chunk_layout(tetrahedra, n_nodes, n_workers):
    """Split the element range into contiguous chunks of whole blocks, dealt round-robin to
    ``n_workers`` workers (worker t takes chunks t, t + n_workers, ...).

    Returns (bounds, node_lo, node_hi, n_workers): node_lo/node_hi (n_workers,) bound the nodes
    each worker touches, so the reduction reads only the buffer rows a worker can have written.
    """
    n_elements = tetrahedra.shape[0]
    n_blocks = -(-n_elements // BLOCK)
    n_workers = max(1, min(n_workers, n_blocks))
    n_chunks = max(n_workers, min(n_workers * CHUNKS_PER_WORKER, n_blocks))
    bounds = np.minimum(np.linspace(0, n_blocks, n_chunks + 1).round().astype(np.int64) * BLOCK, n_elements)
    node_lo = np.full(n_workers, n_nodes, dtype=np.int64)
    node_hi = np.zeros(n_workers, dtype=np.int64)
    for c in range(n_chunks):
        chunk = tetrahedra[bounds[c]:bounds[c + 1]]
        if chunk.size:
            t = c % n_workers
            node_lo[t] = min(node_lo[t], chunk.min())
            node_hi[t] = max(node_hi[t], chunk.max() + 1)
    node_lo = np.minimum(node_lo, node_hi)
    return bounds, node_lo, node_hi, n_workers
