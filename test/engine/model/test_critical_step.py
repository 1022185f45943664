"""The explicit solver's critical step (engine/model/critical_step.py) against the dense
eigenproblem."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from support.meshes import _bottom


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
