"""The explicit solver's critical step (engine/model/critical_step.py) and selective mass scaling
against the dense eigenproblem."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from support.meshes import _bottom
from tissue_sim_ros.engine.model.critical_step import selective_mass_factors


def test_critical_step_estimates_against_dense_eigenproblem(small_model):
    """Lanczos on the free body is within 1e-4 of the dense free-body limit and never above the
    constrained limit; the element bound never exceeds either."""
    sim = ts.Simulation(small_model, fixed=_bottom(small_model.mesh))
    free = (sim.dof_kind.ravel() == 0)
    stiffness = small_model.stiffness_matrix().toarray()[np.ix_(free, free)]
    inv_sqrt_m = 1.0 / np.sqrt(np.repeat(sim.mass, 3)[free])
    omega_max = np.sqrt(np.linalg.eigvalsh(stiffness * inv_sqrt_m[:, None] * inv_sqrt_m[None, :])[-1])
    true_limit = 2.0 / omega_max
    full = small_model.stiffness_matrix().toarray()
    inv_all = 1.0 / np.sqrt(np.repeat(sim.mass, 3))
    free_body_limit = 2.0 / np.sqrt(np.linalg.eigvalsh(full * inv_all[:, None] * inv_all[None, :])[-1])
    estimate = sim.critical_time_step()
    bound = small_model.critical_time_step(method='element_bound')
    assert estimate == pytest.approx(free_body_limit, rel=1e-4)
    assert estimate <= true_limit and bound <= free_body_limit
    print(f'critical step: lanczos {estimate:.4g} s, element bound {bound:.4g} s, '
          f'dense free body {free_body_limit:.4g} s, dense with the bottom fixed {true_limit:.4g} s')


def _dense_step(stiffness, masses):
    inv = 1.0 / np.sqrt(np.repeat(masses, 3))
    return 2.0 / np.sqrt(np.linalg.eigvalsh(stiffness * inv[:, None] * inv[None, :])[-1])


def test_selective_mass_factors_lift_the_whole_mesh_step_at_least_that_factor():
    """A 4 x 4 x 4 box whose centre node is pushed 6.5 mm towards its 7.5 mm neighbour: the flattened
    elements around it set the step. The factors for 1.5 lift the dense free-body step at least 1.5-fold
    (and by the least mass within the bisection's 2 %: under 1.6-fold) adding mass at under a tenth of
    the nodes, and under a quarter of what a uniform scaling needs (1.5^2 - 1); the simulation's
    Lanczos estimate with them is the dense one's."""
    box = ts.box_mesh(size=(0.03, 0.03, 0.03), divisions=(4, 4, 4))
    x = box.rest_positions.copy()
    x[np.argmin(np.linalg.norm(x - 0.015, axis=1))] += [0.0065, 0.0, 0.0]
    model = ts.TensorMassModel(ts.make_mesh(x, box.tetrahedra), ts.Material(3e4, 0.45, 1000.0))
    stiffness = model.stiffness_matrix().toarray()
    masses = model.lumped_masses()
    before = _dense_step(stiffness, masses)
    factors = selective_mass_factors(model, 1.5)
    after = _dense_step(stiffness, masses * factors)
    added = np.sum((factors - 1.0) * masses) / masses.sum()
    assert 1.5 * before <= after < 1.6 * before
    assert np.all(factors >= 1.0) and 0.0 < np.mean(factors > 1.0) < 0.1
    assert added < 0.25 * (1.5 ** 2 - 1.0)
    sim = ts.Simulation(model)
    assert sim.scale_selected_masses(1.5) == pytest.approx(added, rel=1e-12)
    assert np.array_equal(sim.node_mass_factor, factors)
    assert sim.critical_time_step() == pytest.approx(after, rel=1e-4)
    print(f'selective mass scaling 1.5: dense step {before * 1e3:.4g} -> {after * 1e3:.4g} ms, '
          f'{np.mean(factors > 1.0):.1%} of nodes, mass +{added:.2%}')
