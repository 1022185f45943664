"""Linear tensor-mass model against independent truth: patch test, uniaxial compression, the
spectrum of K, and agreement of the element kernel with the paper's vertex/edge tensors."""
import numpy as np
import pytest

import tissue_sim_ros as ts
from conftest import static_solve


def test_material_lame_coefficients_and_refusals():
    m = ts.Material(young_modulus=1000.0, poisson_ratio=0.25, density=1000.0)
    assert m.lame_mu == pytest.approx(400.0, rel=1e-15)
    assert m.lame_lambda == pytest.approx(400.0, rel=1e-15)      # E nu / ((1+nu)(1-2nu))
    for field, kwargs in [('young_modulus', dict(young_modulus=0.0)),
                          ('young_modulus', dict(young_modulus=float('nan'))),
                          ('poisson_ratio', dict(poisson_ratio=0.5)),
                          ('poisson_ratio', dict(poisson_ratio=-1.0)),
                          ('density', dict(density=-1.0))]:
        args = dict(young_modulus=1e3, poisson_ratio=0.3, density=1e3) | kwargs
        with pytest.raises(ts.MaterialError, match=field):
            ts.Material(**args)


def test_patch_test_affine_field(jittered_block, liver):
    """u = G X + c: zero force on interior nodes; on the boundary the internal force balances
    the exact traction sigma n integrated with the linear shape functions (A/3 per vertex)."""
    mesh = jittered_block
    model = ts.TensorMassModel(mesh, liver)
    grad = np.array([[0.010, -0.004, 0.002], [0.003, -0.006, 0.001], [-0.002, 0.005, 0.008]])
    u = mesh.rest_positions @ grad.T + np.array([1e-3, -2e-3, 5e-4])
    force = model.internal_forces(u)
    strain = 0.5 * (grad + grad.T)
    stress = liver.lame_lambda * np.trace(strain) * np.eye(3) + 2 * liver.lame_mu * strain
    expected = np.zeros_like(force)
    tri = mesh.surface_triangles()
    p = mesh.rest_positions[tri]
    area_normal = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])   # n A, outward
    traction = area_normal @ stress.T / 3.0                                # sigma n A / 3
    for k in range(3):
        np.add.at(expected, tri[:, k], -traction)
    scale = np.abs(expected).max()
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.surface_nodes())
    assert len(interior) > 0
    assert np.abs(force[interior]).max() < 1e-12 * scale
    assert np.abs(force - expected).max() < 1e-12 * scale


def test_uniaxial_compression_reaction_equals_E_A_strain(liver):
    """Frictionless plates on a block with free lateral faces: F = E A strain, lateral strain -nu strain."""
    size = (0.04, 0.03, 0.02)
    mesh = ts.box_mesh(size=size, divisions=(4, 3, 4))
    model = ts.TensorMassModel(mesh, liver)
    x = mesh.rest_positions
    strain = 0.05
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    top = np.flatnonzero(np.isclose(x[:, 2], size[2]))
    origin = np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))
    corner_x = np.flatnonzero(np.all(np.isclose(x, [size[0], 0, 0]), axis=1))
    dofs = np.concatenate([3 * bottom + 2, 3 * top + 2, 3 * origin, 3 * origin + 1, 3 * corner_x + 1])
    values = np.concatenate([np.zeros(len(bottom)), np.full(len(top), -strain * size[2]),
                             np.zeros(3)])
    u = static_solve(model, dofs, values)
    force = model.internal_forces(u)
    reaction = force[top].sum(axis=0)
    area = size[0] * size[1]
    assert reaction[2] == pytest.approx(liver.young_modulus * area * strain, rel=1e-9)
    assert np.abs(reaction[:2]).max() < 1e-9 * reaction[2]
    lateral = (u[corner_x, 0] - u[origin, 0]) / size[0]
    assert lateral[0] == pytest.approx(liver.poisson_ratio * strain, rel=1e-9)


def test_stiffness_symmetric_psd_six_rigid_modes(jittered_block, liver):
    model = ts.TensorMassModel(jittered_block, liver)
    stiffness = model.stiffness_matrix().toarray()
    assert np.abs(stiffness - stiffness.T).max() <= 1e-14 * np.abs(stiffness).max()
    eigenvalues, vectors = np.linalg.eigh(stiffness)
    tol = 1e-10 * eigenvalues[-1]
    assert eigenvalues[0] > -tol                                   # positive semi-definite
    assert np.sum(np.abs(eigenvalues) < tol) == 6                  # exactly six zero modes
    assert eigenvalues[6] > 1e-6 * eigenvalues[-1]
    # the null space is spanned by 3 translations and 3 infinitesimal rotations
    x = jittered_block.rest_positions - jittered_block.rest_positions.mean(axis=0)
    rigid = [np.tile(np.eye(3)[k], (len(x), 1)).ravel() for k in range(3)]
    rigid += [np.cross(np.eye(3)[k], x).ravel() for k in range(3)]
    rigid = np.array(rigid).T
    null = vectors[:, :6]
    residual = rigid - null @ (null.T @ rigid)
    assert np.abs(residual).max() < 1e-9 * np.abs(rigid).max()


def test_element_kernel_equals_vertex_edge_tensors(jittered_block, liver):
    model = ts.TensorMassModel(jittered_block, liver)
    u = np.random.default_rng(3).normal(scale=1e-3, size=(jittered_block.n_nodes, 3))
    element = model.internal_forces(u)
    edge = model.edge_form_forces(u)
    matrix = -(model.stiffness_matrix() @ u.ravel()).reshape(-1, 3)
    scale = np.abs(element).max()
    assert np.abs(element - edge).max() < 1e-13 * scale
    assert np.abs(element - matrix).max() < 1e-13 * scale
    assert model.strain_energy(u)[0] == pytest.approx(-0.5 * np.sum(u * element), rel=1e-12)


def test_forces_do_not_depend_on_thread_count(liver):
    """Per-chunk buffers must not race: 1 and 7 chunks give the same forces to round-off."""
    mesh = ts.box_mesh(size=(0.05, 0.05, 0.05), divisions=(8, 8, 8))
    u = np.random.default_rng(1).normal(scale=1e-3, size=(mesh.n_nodes, 3))
    one = ts.TensorMassModel(mesh, liver, n_threads=1).internal_forces(u)
    many = ts.TensorMassModel(mesh, liver, n_threads=7)
    first = many.internal_forces(u)
    second = many.internal_forces(u)                       # buffers are cleared between calls
    assert np.abs(one - first).max() < 1e-12 * np.abs(one).max()
    assert np.array_equal(first, second)


def test_region_materials(liver):
    mesh = ts.box_mesh(size=(0.02, 0.02, 0.02), divisions=(2, 2, 2))
    tags = (mesh.rest_positions[mesh.tetrahedra].mean(axis=1)[:, 2] > 0.01).astype(np.int32)
    tagged = ts.make_mesh(mesh.rest_positions, mesh.tetrahedra, tags)
    stiff = ts.Material(young_modulus=2 * liver.young_modulus, poisson_ratio=0.45, density=1060.0)
    model = ts.TensorMassModel(tagged, {0: liver, 1: stiff})
    assert np.allclose(model.volume_mu[tags == 1] / model.volume_mu[tags == 1].mean(), 1.0)
    assert model.volume_mu[tags == 1].sum() == pytest.approx(2 * model.volume_mu[tags == 0].sum(), rel=1e-12)
    with pytest.raises(ts.MaterialError, match='tag'):
        ts.TensorMassModel(tagged, {0: liver})
