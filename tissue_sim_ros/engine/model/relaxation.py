"""Stress relaxation: a generalized Maxwell (Prony series) model on the deviatoric stress.

The form FEBio and Abaqus users know (Abaqus Theory Manual, "Time domain viscoelasticity";
Simo and Hughes, Computational Inelasticity, 1998, section 10.3; Taylor, Pister and Goudreau
1970 for the recursion). The shear relaxation modulus is

    G_R(t) = mu (1 - sum_i g_i (1 - exp(-t / tau_i))),   0 < g_i,  sum_i g_i < 1,  tau_i > 0,

so the instantaneous response is the elastic model as configured (its mu) and the long-term one
has mu (1 - sum_i g_i). The bulk modulus K = lambda + 2 mu / 3 does not relax.

Per element (strain and stresses constant over a linear tetrahedron), with E the strain the model
uses (Green-Lagrange E = (F^T F - I) / 2 for the geometric model, sym(H) for the linear one),
E_dev = E - tr(E) I / 3, and S0 = 2 mu E_dev the instantaneous deviatoric stress:

* Maxwell branch i carries the stress h_i(t) = g_i int_0^t exp(-(t - s) / tau_i) dS0/ds ds,
  advanced once per time step dt, exactly for a strain linear over the step:

      h_i^{n+1} = exp(-dt / tau_i) h_i^n + g_i (1 - exp(-dt / tau_i)) / (dt / tau_i) (S0^{n+1} - S0^n)

  (dt -> 0: h_i^{n+1} = h_i^n + g_i (S0^{n+1} - S0^n), the instantaneous elastic response).
* The second Piola-Kirchhoff stress is the elastic one plus the relaxation stress
  Q = sum_i h_i - (sum_i g_i) S0: Q = 0 right after a sudden strain (h_i = g_i S0), and
  Q -> -(sum_i g_i) S0 under a held strain (h_i -> 0): the deviatoric stress relaxes to
  (1 - sum_i g_i) S0.
* Nodal force, added to the elastic one (docs/method.md, "St Venant-Kirchhoff": f_j = -V P a_j
  with P = F S):

      f_j = -V F Q a_j = +V F ((sum_i g_i) S0 - sum_i h_i) a_j,   F = I for the linear model,

  a_j the shape-function gradients. With the Green strain a rigid rotation leaves E, S0, h_i
  and Q unchanged and only turns the force: the relaxation is objective.
* Stored (Helmholtz free) energy, what the watchdog weighs:

      Psi = V [ K/2 tr(E)^2 + mu (1 - sum_i g_i) E_dev : E_dev + sum_i h_i : h_i / (4 g_i mu) ]
          = W_elastic - V (sum_i g_i) mu E_dev : E_dev + V sum_i h_i : h_i / (4 g_i mu).

  Under a held strain h_i decays and Psi falls to the long-term elastic energy; the branch
  dissipation h_i : h_i / (2 g_i mu tau_i) >= 0 (Simo and Hughes, 10.3) never creates energy.

The internal variables advance only on a time step (``Relaxation.accumulate`` with a time step);
any other force evaluation (a probe, the critical time step) applies the relaxation stress Q of
the last step, pushed through the current F: a sudden change of strain meets the instantaneous
(elastic) stiffness, as the dt -> 0 limit above says. The relaxing modulus is the element's
configured mu; the physically non-linear law's corrections stay elastic.

Storage: per element V S0, V h_1, ..., V h_N (six numbers each: 00, 11, 22, 01, 02, 12), the
volume folded in as the element pass folds it, kept in the element pass's SIMD blocks.

The pass runs after the element pass (kernels.py), into its per-chunk buffers, in its blocks of
BLOCK elements with the lanes vectorized. Its cost is mostly what it repeats of that pass (gather
the displacements, the gradient, scatter the forces): on the default scene (13872 tetrahedra, one
thread) one term takes about 280-300 us, as much as the element pass, about 250 us (65 %) more
per whole step.
"""
import math

import numpy as np
from numba import njit, prange
from numba.extending import register_jitable

from tissue_sim_ros.engine.model.kernels import (BLOCK, FASTMATH, MU, _at, _element_nodes, _first_piola,
                                          _gather_differences, _get9, _lane_gradient, _piola_forces,
                                          _scatter_forces, _set9, element_gradient, green_strain)
from tissue_sim_ros.errors import MaterialError

_SYMMETRIC = 6     # components of a symmetric 3x3 tensor: 00, 11, 22, 01, 02, 12
# Fields of a work row (kernels.py's block layout: field k of lane j at k * BLOCK + j). The first
# MU + 1 are the element constants the element pass packs (kernels.pack_element_blocks: a_1..a_3,
# V lambda, V mu), copied as they are.
_DU = MU + 1                     # 9: u_k - u_0, k = 1..3
_FORCE = _DU + 9                 # 9: f_1, f_2, f_3
_STATE = _FORCE + 9              # 6 (N + 1): the block's state, V S0 then V h_1..V h_N


class PronySeries:
    """The terms g_i (relative modulus, dimensionless) and tau_i [s] of G_R(t) above.

    ``terms``: a sequence of mappings ``{relative_modulus: g, time_constant_s: tau}`` (the scene's
    ``model.relaxation``); ``name`` is where they come from, for the error messages.
    """

    def __init__(self, terms, name='relaxation'):
        if not isinstance(terms, (list, tuple)):
            raise MaterialError(f'{name} = {terms!r}: expected a list of '
                                '{relative_modulus: g, time_constant_s: tau} entries')
        moduli, times = [], []
        for i, term in enumerate(terms):
            if not isinstance(term, dict) or set(term) != {'relative_modulus', 'time_constant_s'}:
                raise MaterialError(f'{name}[{i}] = {term!r}: expected a mapping with exactly '
                                    'relative_modulus and time_constant_s')
            moduli.append(_positive(f'{name}[{i}].relative_modulus', term['relative_modulus'],
                                    'a relative modulus g with 0 < g < 1'))
            times.append(_positive(f'{name}[{i}].time_constant_s', term['time_constant_s'],
                                   'a time constant > 0 s'))
        if sum(moduli) >= 1.0:
            raise MaterialError(f'{name} = {terms!r}: the relative moduli sum to {sum(moduli):.6g}; '
                                'expected a sum < 1 (the long-term shear modulus mu (1 - sum g) must '
                                'stay > 0)')
        self.relative_moduli = np.array(moduli)
        self.time_constants = np.array(times)

    def __len__(self):
        return len(self.relative_moduli)

    def shear_modulus_fraction(self, t):
        """G_R(t) / mu at times ``t`` [s] (numpy)."""
        t = np.asarray(t, dtype=float)[..., None]
        return 1.0 - np.sum(self.relative_moduli * -np.expm1(-t / self.time_constants), axis=-1)

    def __repr__(self):
        terms = ', '.join(f'(g {g:g}, tau {tau:g} s)'
                          for g, tau in zip(self.relative_moduli, self.time_constants))
        return f'PronySeries([{terms}])'


def _positive(name, value, expected):
    if (isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value)
            or value <= 0):
        raise MaterialError(f'{name} = {value!r}: expected {expected}')
    return float(value)


class Relaxation:
    """The internal variables of a PronySeries over a model's elements, and their passes.

    The state is stored in the element pass's blocks (``state[b]``: field k of the block's lane j
    at k * BLOCK + j, fields V S0, V h_1, ..., V h_N, six each); ``element_state`` is the same by
    element. Arrays are made here, by ``allocate`` (the model's thread layout) and when elements
    are removed or added, never on a step.
    """

    def __init__(self, series: PronySeries, n_elements: int):
        self.series = series
        self.n_fields = _SYMMETRIC * (len(series) + 1)
        self.state = _by_block(np.zeros((n_elements, self.n_fields)))
        self.n_elements = n_elements
        self._modulus_sum = float(series.relative_moduli.sum())
        self._time_step = None
        self._coefficients_for(0.0)
        self._work = np.zeros((1, 0))

    def allocate(self, n_workers):
        """A work row per worker of the element pass (16 spare doubles: no shared cache line)."""
        self._work = np.zeros((n_workers, (_STATE + self.n_fields) * BLOCK + 16))

    def reset(self):
        """No history: every element at rest, unloaded."""
        self.state[:] = 0.0

    @property
    def element_state(self):
        """The state by element (m, 6 (N + 1)): V S0, V h_1, ..., V h_N (a copy)."""
        n_blocks = self.state.shape[0]
        return (self.state.reshape(n_blocks, self.n_fields, BLOCK).transpose(0, 2, 1)
                .reshape(-1, self.n_fields)[:self.n_elements].copy())

    def keep(self, kept):
        """Keep the history of the elements ``kept`` (a boolean mask over the current ones)."""
        rows = self.element_state[kept]
        self.state, self.n_elements = _by_block(rows), len(rows)

    def add(self, n_elements):
        """Append ``n_elements`` elements with no history (their first step loads them at once)."""
        rows = np.concatenate([self.element_state, np.zeros((n_elements, self.n_fields))])
        self.state, self.n_elements = _by_block(rows), len(rows)

    def _coefficients_for(self, time_step):
        """exp(-dt / tau_i) and g_i (1 - exp(-dt / tau_i)) / (dt / tau_i) as tuples, kept while dt
        is unchanged (dt = 0: 1 and g_i, the instantaneous response)."""
        if time_step != self._time_step:
            ratio = time_step / self.series.time_constants
            gain = self.series.relative_moduli * np.where(
                ratio > 0.0, -np.expm1(-ratio) / np.where(ratio > 0.0, ratio, 1.0), 1.0)
            self._decay_terms = tuple(np.exp(-ratio).tolist())
            self._gain_terms = tuple(gain.tolist())
            self._time_step = time_step

    def accumulate(self, model, displacement, time_step=None):
        """Add the relaxation forces at ``displacement`` to the model's per-chunk force buffers.

        ``time_step`` [s]: the state advances to ``displacement`` first, ``time_step`` after the
        previous step (0: loaded at once). None: the last step's relaxation stress, unchanged.
        """
        advance = time_step is not None
        if advance:
            if not (math.isfinite(time_step) and time_step >= 0.0):
                raise ValueError(f'time_step = {time_step!r}: expected a finite time >= 0 s')
            self._coefficients_for(float(time_step))
        relaxation_pass(model.tetrahedra, model._element_blocks, displacement, model.geometric,
                        self._modulus_sum, self._decay_terms, self._gain_terms, advance, self.state,
                        model.chunk_bounds, self._work, model._buffers)

    def energy_change(self, model, displacement):
        """Psi - W_elastic [J] at ``displacement`` with the current state (see the module docstring)."""
        return relaxation_energy_change(model.tetrahedra, model.shape_gradients, model.volume_mu,
                                        displacement, model.geometric, self.series.relative_moduli,
                                        self.state)


def _by_block(rows):
    """(m, fields) rows by element -> (blocks, fields * BLOCK), lanes past the last element zero."""
    m, n_fields = rows.shape
    n_blocks = -(-m // BLOCK)
    padded = np.zeros((n_blocks * BLOCK, n_fields))
    padded[:m] = rows
    return np.ascontiguousarray(padded.reshape(n_blocks, BLOCK, n_fields).transpose(0, 2, 1)
                                .reshape(n_blocks, n_fields * BLOCK))


@njit(cache=True, inline='always')
def _deviatoric(geometric, h00, h01, h02, h10, h11, h12, h20, h21, h22):
    """E_dev of the strain the model uses (Green-Lagrange or sym(H)), as (00, 11, 22, 01, 02, 12)."""
    if geometric:
        e00, e11, e22, e01, e02, e12 = green_strain(h00, h01, h02, h10, h11, h12, h20, h21, h22)
    else:
        e00, e11, e22 = h00, h11, h22
        e01, e02, e12 = 0.5 * (h01 + h10), 0.5 * (h02 + h20), 0.5 * (h12 + h21)
    mean = (e00 + e11 + e22) / 3.0
    return e00 - mean, e11 - mean, e22 - mean, e01, e02, e12


@njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False, nogil=True)
def relaxation_pass(tetrahedra, element_blocks, displacement, geometric, modulus_sum, decay, gain,
                    advance, state, chunk_bounds, work, buffers):
    """f_j = -V F Q a_j of every element into the per-chunk ``buffers``, in the element pass's
    layout (kernels.element_kernel: worker t takes chunks t, t + n_workers, ... into buffers[t],
    so no two threads write one row) and its SIMD blocks. With ``advance``, each element's S0 and
    h_i move to ``displacement`` first. decay, gain: tuples (one entry per term, so the term loop
    is unrolled and the lane loop vectorizes) of exp(-dt / tau_i) and g_i (1 - exp(-dt / tau_i)) /
    (dt / tau_i); modulus_sum = sum_i g_i. work: (n_workers, >= (_STATE + 6 (N + 1)) * BLOCK)."""
    for t in prange(buffers.shape[0]):
        _thread_pass(np.uint64(t), tetrahedra, element_blocks, displacement, geometric, modulus_sum,
                     decay, gain, advance, state, chunk_bounds, work, buffers)


@njit(cache=True, inline='always')
def _thread_pass(t, tetrahedra, element_blocks, displacement, geometric, modulus_sum, decay, gain,
                 advance, state, chunk_bounds, work, buffers):
    """Worker t's chunks, block by block: gather, the lanes, scatter (as kernels.py's pass)."""
    n_chunks = chunk_bounds.shape[0] - 1
    n_workers = buffers.shape[0]
    n_state = _SYMMETRIC * (len(decay) + 1) * BLOCK
    buf = buffers[t]
    for c in range(t, n_chunks, n_workers):
        for base in range(chunk_bounds[c], chunk_bounds[c + 1], BLOCK):
            n = min(BLOCK, chunk_bounds[c + 1] - base)
            block = base // BLOCK
            for k in range((MU + 1) * BLOCK):
                work[t, k] = element_blocks[block, k]
            for k in range(n_state):
                work[t, _STATE * BLOCK + k] = state[block, k]
            for j in range(n):
                i0, i1, i2, i3 = _element_nodes(tetrahedra, base + j)
                _gather_differences(work, t, _DU, j, displacement, i0, i1, i2, i3)
            for j in range(n, BLOCK):
                for k in range(9):
                    work[t, _at(_DU + k, j)] = 0.0
            # the flags outside the lane loop, constants inside it: one branch-free loop each
            if advance and geometric:
                _lanes(work, t, True, True, modulus_sum, decay, gain)
            elif advance:
                _lanes(work, t, False, True, modulus_sum, decay, gain)
            elif geometric:
                _lanes(work, t, True, False, modulus_sum, decay, gain)
            else:
                _lanes(work, t, False, False, modulus_sum, decay, gain)
            if advance:
                for k in range(n_state):
                    state[block, k] = work[t, _STATE * BLOCK + k]
            for j in range(n):
                i0, i1, i2, i3 = _element_nodes(tetrahedra, base + j)
                f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z = _get9(work, t, _FORCE, j)
                _scatter_forces(buf, i0, i1, i2, i3, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z)


@njit(cache=True, inline='always')
def _lanes(work, t, geometric, advance, modulus_sum, decay, gain):
    """Every lane of a block: with ``advance``, V S0 = 2 V mu E_dev and the recursion
    V h_i <- decay_i V h_i + gain_i (V S0_new - V S0_old); then V Q = sum_i V h_i - (sum_i g_i) V S0
    and the nodal forces f_1..f_3 = -V F Q a_k (F = I unless ``geometric``)."""
    for j in range(BLOCK):
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = _lane_gradient(work, t, _DU, j)
        if advance:
            two_mu = 2.0 * work[t, _at(MU, j)]
            d00, d11, d22, d01, d02, d12 = _deviatoric(geometric, h00, h01, h02, h10, h11, h12,
                                                       h20, h21, h22)
            s00, s11, s22 = two_mu * d00, two_mu * d11, two_mu * d22
            s01, s02, s12 = two_mu * d01, two_mu * d02, two_mu * d12
            o00, o11, o22, o01, o02, o12 = _get6(work, t, _STATE, j)       # V S0 of the last step
            c00, c11, c22, c01, c02, c12 = s00 - o00, s11 - o11, s22 - o22, s01 - o01, s02 - o02, s12 - o12
            _set6(work, t, _STATE, j, (s00, s11, s22, s01, s02, s12))
        q00, q11, q22, q01, q02, q12 = _get6(work, t, _STATE, j)
        q00, q11, q22 = -modulus_sum * q00, -modulus_sum * q11, -modulus_sum * q22
        q01, q02, q12 = -modulus_sum * q01, -modulus_sum * q02, -modulus_sum * q12
        for k in range(len(decay)):
            field = _STATE + _SYMMETRIC * (k + 1)
            b00, b11, b22, b01, b02, b12 = _get6(work, t, field, j)
            if advance:
                fade, gain_k = decay[k], gain[k]
                b00, b11, b22 = (fade * b00 + gain_k * c00, fade * b11 + gain_k * c11,
                                 fade * b22 + gain_k * c22)
                b01, b02, b12 = (fade * b01 + gain_k * c01, fade * b02 + gain_k * c02,
                                 fade * b12 + gain_k * c12)
                _set6(work, t, field, j, (b00, b11, b22, b01, b02, b12))
            q00, q11, q22, q01, q02, q12 = q00 + b00, q11 + b11, q22 + b22, q01 + b01, q02 + b02, q12 + b12
        if geometric:
            p00, p01, p02, p10, p11, p12, p20, p21, p22 = _first_piola(
                h00, h01, h02, h10, h11, h12, h20, h21, h22, q00, q11, q22, q01, q02, q12)
        else:
            p00, p01, p02, p10, p11, p12, p20, p21, p22 = q00, q01, q02, q01, q11, q12, q02, q12, q22
        a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z = _get9(work, t, 0, j)
        f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z = _piola_forces(
            p00, p01, p02, p10, p11, p12, p20, p21, p22, a1x, a1y, a1z, a2x, a2y, a2z, a3x, a3y, a3z)
        _set9(work, t, _FORCE, j, f1x, f1y, f1z, f2x, f2y, f2z, f3x, f3y, f3z)


@register_jitable
def _get6(work, row, field, j):
    return (work[row, _at(field, j)], work[row, _at(field + 1, j)], work[row, _at(field + 2, j)],
            work[row, _at(field + 3, j)], work[row, _at(field + 4, j)], work[row, _at(field + 5, j)])


@register_jitable
def _set6(work, row, field, j, values):
    for r in range(_SYMMETRIC):
        work[row, _at(field + r, j)] = values[r]


@njit(cache=True, parallel=True, fastmath=FASTMATH, boundscheck=False, nogil=True)
def relaxation_energy_change(tetrahedra, shape_gradients, volume_mu, displacement, geometric,
                             relative_moduli, state):
    """Sum over elements of -(sum g_i) V mu E_dev : E_dev + sum_i |V h_i|^2 / (4 g_i V mu)."""
    modulus_sum = relative_moduli.sum()
    energy = 0.0
    for e in prange(tetrahedra.shape[0]):
        g = shape_gradients[e]
        h00, h01, h02, h10, h11, h12, h20, h21, h22 = element_gradient(
            displacement, tetrahedra[e, 0], tetrahedra[e, 1], tetrahedra[e, 2], tetrahedra[e, 3],
            g[0, 0], g[0, 1], g[0, 2], g[1, 0], g[1, 1], g[1, 2], g[2, 0], g[2, 1], g[2, 2])
        d00, d11, d22, d01, d02, d12 = _deviatoric(geometric, h00, h01, h02, h10, h11, h12, h20, h21, h22)
        vmu = volume_mu[e]
        element = -modulus_sum * vmu * (d00 * d00 + d11 * d11 + d22 * d22
                                        + 2.0 * (d01 * d01 + d02 * d02 + d12 * d12))
        block, lane = e // BLOCK, e % BLOCK
        for k in range(relative_moduli.shape[0]):
            field = _SYMMETRIC * (k + 1)
            branch = 0.0
            for r in range(_SYMMETRIC):
                value = state[block, (field + r) * BLOCK + lane]
                branch += value * value if r < 3 else 2.0 * value * value
            element += branch / (4.0 * relative_moduli[k] * vmu)
        energy += element
    return energy


def relaxation_for(relaxation, n_elements):
    """A Relaxation over ``n_elements`` for a PronySeries or its terms; None for none (no cost)."""
    if relaxation is None:
        return None
    series = relaxation if isinstance(relaxation, PronySeries) else PronySeries(relaxation)
    return Relaxation(series, n_elements) if len(series) else None
