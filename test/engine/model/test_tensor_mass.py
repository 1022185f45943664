"""TensorMassModel (engine/model/tensor_mass.py): the stiffness matrix's symmetry and rigid modes,
options refused by name, and run-time topology change (removing elements updates the
vertex/edge tensors to what a model built from scratch holds; re-adding restores them)."""

import numpy as np
import pytest

import tissue_sim_ros as ts


@pytest.fixture
def model(jittered_block, liver):
    return ts.TensorMassModel(jittered_block, liver)


def test_remove_then_readd_restores_every_tensor(model):
    original = [a.copy() for a in (model.vertex_lambda, model.vertex_mu, model.edge_lambda, model.edge_mu)]
    n_elements = model.mesh.n_elements
    removed = model.remove_elements([0, 13, 14, 57, n_elements - 1])
    assert model.mesh.n_elements == n_elements - 5
    model.add_elements(*removed)
    restored = (model.vertex_lambda, model.vertex_mu, model.edge_lambda, model.edge_mu)
    for before, after in zip(original, restored):
        assert np.abs(after - before).max() < 1e-13 * np.abs(before).max()


def test_incremental_removal_equals_a_fresh_model(model, jittered_block, liver):
    cut = np.arange(10, 40)                      # carve a block of elements out
    model.remove_elements(cut)
    keep = np.setdiff1d(np.arange(jittered_block.n_elements), cut)
    fresh_mesh = ts.make_mesh(jittered_block.rest_positions, jittered_block.tetrahedra[keep])
    fresh = ts.TensorMassModel(fresh_mesh, liver)
    scale = np.abs(fresh.vertex_mu).max()
    assert np.abs(model.vertex_lambda - fresh.vertex_lambda).max() < 1e-13 * scale
    assert np.abs(model.vertex_mu - fresh.vertex_mu).max() < 1e-13 * scale
    index = {tuple(e): i for i, e in enumerate(model.edges.tolist())}
    rows = [index[tuple(e)] for e in fresh.edges.tolist()]
    assert np.abs(model.edge_mu[rows] - fresh.edge_mu).max() < 1e-13 * scale
    gone = np.setdiff1d(np.arange(len(model.edges)), rows)        # edges with no element left
    assert gone.size == 0 or np.abs(model.edge_mu[gone]).max() < 1e-13 * scale
    u = np.random.default_rng(0).normal(scale=1e-3, size=(jittered_block.n_nodes, 3))
    f_fresh = fresh.internal_forces(u)
    assert np.abs(model.internal_forces(u) - f_fresh).max() < 1e-12 * np.abs(f_fresh).max()
    assert np.abs(model.edge_form_forces(u) - f_fresh).max() < 1e-12 * np.abs(f_fresh).max()
    assert np.allclose(model.lumped_masses(), fresh.lumped_masses(), rtol=1e-14, atol=0)
    surface = lambda tri: sorted(map(tuple, np.sort(tri, axis=1).tolist()))
    assert surface(model.mesh.surface_triangles()) == surface(fresh_mesh.surface_triangles())


def test_simulation_follows_removal(model):
    sim = ts.Simulation(model, dt=1e-4)
    total = sim.mass.sum()
    removed_mass = model.element_mass[:6].sum()
    model.remove_elements(np.arange(6))
    sim.step()
    assert sim.mass.sum() == pytest.approx(total - removed_mass, rel=1e-12)


def test_bad_removal_named(model):
    with pytest.raises(ValueError, match='elements'):
        model.remove_elements([10**6])


def test_adding_an_element_with_new_edges_equals_a_fresh_model(liver):
    """A tetrahedron glued on a face brings three edges the model has never seen."""
    positions = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], dtype=float) * 0.01
    first = np.array([[0, 1, 2, 3]])
    second = np.array([[1, 2, 3, 4]])
    mesh = ts.make_mesh(positions, first)
    model = ts.TensorMassModel(mesh, liver)
    both = ts.make_mesh(positions, np.concatenate([first, second]))
    second = both.tetrahedra[1:]                      # oriented as make_mesh fixed it
    model.add_elements(second)
    fresh = ts.TensorMassModel(both, liver)
    assert len(model.edges) == len(fresh.edges) == 9
    u = np.random.default_rng(1).normal(scale=1e-3, size=(5, 3))
    expected = fresh.internal_forces(u)
    assert np.abs(model.edge_form_forces(u) - expected).max() < 1e-12 * np.abs(expected).max()
    assert np.abs(model.internal_forces(u) - expected).max() < 1e-12 * np.abs(expected).max()


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


def test_bad_options_named(jittered_block, liver):
    with pytest.raises(ValueError, match='nonlinearity_threshold'):
        ts.TensorMassModel(jittered_block, liver, nonlinearity_threshold=-1.0)
    with pytest.raises(TypeError, match='physical'):
        ts.TensorMassModel(jittered_block, liver, physical='exponential')
    with pytest.raises(ts.MaterialError, match='mu_v'):
        ts.Viscosity(lambda_v=1.0, mu_v=-2.0)
    with pytest.raises(ts.MaterialError, match='mu_rate'):
        ts.MeanRatioLaw.exponential(mu_rate=float('nan'))


def test_set_element_lame_refuses_bad_values(jittered_block, liver):
    model = ts.TensorMassModel(jittered_block, liver)
    m = jittered_block.n_elements
    with pytest.raises(ValueError, match='volume_lambda'):
        model.set_element_lame(np.ones(m - 1), np.ones(m))
    with pytest.raises(ValueError, match='volume_mu'):
        model.set_element_lame(np.ones(m), np.full(m, np.nan))
