"""Per-element materials (engine/model/elements.py): each region's coefficients on its elements."""

import numpy as np
import pytest

import tissue_sim_ros as ts


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
