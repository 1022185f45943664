"""The engine tests' shared model: a 3 x 3 x 3 box of the liver-like material (module scope)."""

import pytest

import tissue_sim_ros as ts


@pytest.fixture(scope='module')
def small_model(liver):
    mesh = ts.box_mesh(size=(0.03, 0.03, 0.03), divisions=(3, 3, 3))
    return ts.TensorMassModel(mesh, liver)
