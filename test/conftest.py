"""Shared fixtures: small meshes and a liver-like material."""
import numpy as np
import pytest

import tissue_sim_ros as ts


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: takes tens of seconds (deselect with -m "not slow")')


@pytest.fixture(scope='session')
def liver():
    return ts.Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)


@pytest.fixture(scope='session')
def jittered_block():
    """An irregular mesh: a 4x3x3 box whose interior nodes are moved randomly (still valid)."""
    mesh = ts.box_mesh(size=(0.04, 0.03, 0.03), divisions=(4, 3, 3))
    positions = mesh.rest_positions.copy()
    interior = np.setdiff1d(np.arange(mesh.n_nodes), mesh.surface_nodes())
    rng = np.random.default_rng(7)
    positions[interior] += rng.uniform(-0.002, 0.002, size=(len(interior), 3))
    return ts.make_mesh(positions, mesh.tetrahedra)


def static_solve(model, constrained_dofs, prescribed_values):
    """Solve K u = 0 on the free DOFs with u fixed on ``constrained_dofs`` (scipy, independent of the explicit solver)."""
    import scipy.sparse.linalg
    stiffness = model.stiffness_matrix().tocsr()
    n_dofs = stiffness.shape[0]
    u = np.zeros(n_dofs)
    u[constrained_dofs] = prescribed_values
    free = np.setdiff1d(np.arange(n_dofs), constrained_dofs)
    rhs = -stiffness[free][:, constrained_dofs] @ u[constrained_dofs]
    u[free] = scipy.sparse.linalg.spsolve(stiffness[free][:, free].tocsc(), rhs)
    return u.reshape(-1, 3)
