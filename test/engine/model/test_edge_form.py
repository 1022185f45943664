"""The paper's vertex/edge tensor form (engine/model/edge_form.py) against the element kernel and
the stiffness matrix."""

import numpy as np
import pytest

import tissue_sim_ros as ts


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
