"""The element pass's vector gather and scatter (simd_lanes) against numpy doing the same
arithmetic element by element, and the whole pass against the scalar element formula on a mesh
whose last block is partial."""

import numpy as np
import pytest
from numba import njit

from tissue_sim_ros.engine.mesh.generators import box_mesh
from tissue_sim_ros.engine.model import kernels as forces, simd_lanes
from tissue_sim_ros.engine.model.kernels import BLOCK
from tissue_sim_ros.engine.model.material import Material, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel

N_NODES = 50
N_ELEMENTS = 5 * BLOCK


@pytest.fixture
def rng():
    return np.random.default_rng(20261127)


@njit
def _gather(work, row, state, tetrahedra, base, with_velocity):
    if with_velocity:
        simd_lanes.gather_difference_lanes(work, row, forces._DU, forces._DV, state, tetrahedra, base, True)
    else:
        simd_lanes.gather_difference_lanes(work, row, forces._DU, forces._DV, state, tetrahedra, base, False)


@njit
def _scatter(buffer, work, row, tetrahedra, base):
    simd_lanes.scatter_force_lanes(buffer, work, row, forces._FORCE, tetrahedra, base)


def _random_elements(rng):
    """Elements of 4 distinct nodes each, neighbours sharing nodes (as in a mesh)."""
    return np.array([rng.choice(N_NODES // 2, 4, replace=False) + (e % 2) * (N_NODES // 2)
                     for e in range(N_ELEMENTS)], dtype=np.int32)


def _field(work, row, field, k):
    """Field ``field + k`` of every lane of a work row."""
    return work[row, (field + k) * BLOCK:(field + k + 1) * BLOCK]


@pytest.mark.parametrize('state_dtype, work_dtype', [(np.float64, np.float64), (np.float64, np.float32),
                                                     (np.float32, np.float32)])
@pytest.mark.parametrize('with_velocity', [True, False])
def test_gather_gives_each_lanes_node_differences_exactly(rng, state_dtype, work_dtype, with_velocity):
    tetrahedra = _random_elements(rng)
    state = np.zeros((N_NODES, simd_lanes.STATE_WIDTH), dtype=state_dtype)
    state[:, 0:3] = rng.normal(size=(N_NODES, 3))
    state[:, 4:7] = rng.normal(size=(N_NODES, 3))
    sentinel = work_dtype(-7.5)
    work = np.full((3, forces.N_WORK * BLOCK + 5), sentinel, dtype=work_dtype)
    for block in range(N_ELEMENTS // BLOCK):
        base = block * BLOCK
        _gather(work, 1, state, tetrahedra, base, with_velocity)
        nodes = tetrahedra[base:base + BLOCK]
        for field, columns in ((forces._DU, slice(0, 3)), (forces._DV, slice(4, 7))):
            values = state[:, columns]
            for corner in range(1, 4):
                # the difference in the state's precision, then rounded to the row's
                expected = (values[nodes[:, corner]] - values[nodes[:, 0]]).astype(work_dtype)
                for r in range(3):
                    got = _field(work, 1, field, 3 * (corner - 1) + r)
                    if field == forces._DV and not with_velocity:
                        assert np.all(got == sentinel)       # not written
                    else:
                        np.testing.assert_array_equal(got, expected[:, r])
    # the other rows are untouched
    assert np.all(work[0] == sentinel) and np.all(work[2] == sentinel)


@pytest.mark.parametrize('work_dtype', [np.float64, np.float32])
def test_scatter_adds_each_lanes_forces_in_the_scalar_order(rng, work_dtype):
    """buffer[node] gets f_1..f_3 at corners 1..3 and -(f_1 + f_2 + f_3) at corner 0, lane after
    lane: np.add.at over the elements in order does the same additions in the same order."""
    tetrahedra = _random_elements(rng)
    work = rng.normal(size=(2, forces.N_WORK * BLOCK)).astype(work_dtype)
    start = rng.normal(size=(N_NODES, 3))
    buffer = np.zeros((N_NODES, simd_lanes.BUFFER_WIDTH))
    buffer[:, :3] = start
    expected = start.copy()
    for block in range(N_ELEMENTS // BLOCK):
        base = block * BLOCK
        _scatter(buffer, work, 1, tetrahedra, base)
        f = np.stack([np.stack([_field(work, 1, forces._FORCE, 3 * k + r) for r in range(3)], axis=1)
                      for k in range(3)])                 # (corner 1..3, lane, xyz)
        f0 = -((f[0] + f[1]) + f[2])                      # in the row's precision
        for lane in range(BLOCK):
            for corner, value in enumerate((f0[lane], f[0, lane], f[1, lane], f[2, lane])):
                np.add.at(expected, tetrahedra[base + lane, corner], value.astype(np.float64))
    np.testing.assert_allclose(buffer[:, :3], expected, rtol=0, atol=4 * np.finfo(work_dtype).eps * np.abs(expected).max())
    assert np.all(buffer[:, 3] == 0.0)                 # the padding stays zero
    if work_dtype == np.float64:
        np.testing.assert_array_equal(buffer[:, :3], expected)


@pytest.mark.parametrize('precision', ['float64', 'float32'])
def test_the_pass_with_a_partial_last_block_matches_the_element_formula(rng, precision):
    """Full model with viscosity on 108 elements (13 whole blocks and a partial one): every
    element's forces f_j = -V P a_j, summed by numpy, equal the pass's (whole blocks through
    simd_lanes, the last one lane by lane), to round-off in float64 and float32's in float32."""
    mesh = box_mesh(size=(0.03, 0.03, 0.02), divisions=(3, 3, 2))
    law = MeanRatioLaw.exponential(lambda_amplitude=0.5, lambda_rate=8.0, mu_amplitude=1.5, mu_rate=12.0)
    material = Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)
    model = TensorMassModel(mesh, material, geometric=True, physical=law, viscosity=Viscosity(5.0, 2.0),
                            precision=precision)
    assert model.tetrahedra.shape[0] % BLOCK != 0
    u = 5e-4 * rng.normal(size=(mesh.n_nodes, 3))        # strains of a few per cent: no safeguard
    v = 1e-2 * rng.normal(size=(mesh.n_nodes, 3))
    got = model.internal_forces(u, v)
    assert model.safeguarded_count == 0 and model._nonlinear_counts.sum() == model.tetrahedra.shape[0]
    reference = TensorMassModel(mesh, material, geometric=True, physical=law, viscosity=Viscosity(5.0, 2.0))
    expected = _element_by_element(reference, u, v)
    scale = np.abs(expected).max()
    tolerance = 1e-12 if precision == 'float64' else 2e-6
    np.testing.assert_allclose(got, expected, rtol=0, atol=tolerance * scale)


def _element_by_element(model, u, v):
    """Internal forces summed one element at a time in numpy: St Venant-Kirchhoff with the mean
    ratio law and Kelvin-Voigt viscosity (forces.py's formulas, FORMULAS.md)."""
    out = np.zeros((model.mesh.n_nodes, 3))
    law_kind, law_params = model.law_kind, model.law_params
    for e, nodes in enumerate(model.tetrahedra):
        a = model.shape_gradients[e]                       # rows a_1..a_3
        h = (u[nodes[1:]] - u[nodes[0]]).T @ a             # H = sum_k d_k a_k^T
        r = (v[nodes[1:]] - v[nodes[0]]).T @ a
        f = np.eye(3) + h
        strain = 0.5 * (f.T @ f - np.eye(3))
        c = f.T @ f
        gram = model.edge_gram[e]
        g = np.array([[gram[0], gram[3], gram[4]], [gram[3], gram[1], gram[5]], [gram[4], gram[5], gram[2]]])
        quality = model.mean_ratio_scale[e] * abs(np.linalg.det(f)) ** (2.0 / 3.0) / np.trace(c @ g)
        distortion = max(0.0, 1.0 - quality)
        lam, mu = model.volume_lambda[e], model.volume_mu[e]
        if distortion > forces.DISTORTION_FLOOR:
            assert law_kind == forces.LAW_EXPONENTIAL
            lam *= 1.0 + law_params[0] * (np.exp(law_params[1] * distortion) - 1.0)
            mu *= 1.0 + law_params[2] * (np.exp(law_params[3] * distortion) - 1.0)
        stress = lam * np.trace(strain) * np.eye(3) + 2.0 * mu * strain
        rate = 0.5 * (f.T @ r + r.T @ f)
        stress += model.viscous_lambda[e] * np.trace(rate) * np.eye(3) + 2.0 * model.viscous_mu[e] * rate
        p = f @ stress
        forces_k = -(a @ p.T)                              # rows f_k = -V P a_k, V folded in
        out[nodes[1:]] += forces_k
        out[nodes[0]] -= forces_k.sum(axis=0)
    return out


def test_the_pass_refuses_buffers_without_the_padded_rows():
    """The vector code writes whole padded rows: a (workers, n, 3) buffer is refused, not overrun."""
    mesh = box_mesh(size=(0.01, 0.01, 0.01), divisions=(2, 2, 2))
    model = TensorMassModel(mesh, Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0))
    model._buffers = np.zeros(model._buffers.shape[:2] + (3,))
    with pytest.raises(ValueError, match=r'buffers \(workers, n, 4\)'):
        model.accumulate_forces(np.zeros((mesh.n_nodes, 3)))
