"""The solver tests' cube: 3 x 3 x 3 cells of a 20 mm cube (module scope)."""

import pytest

import tissue_sim_ros as ts


@pytest.fixture(scope='module')
def cube():
    return ts.box_mesh(size=(0.02, 0.02, 0.02), divisions=(3, 3, 3))
