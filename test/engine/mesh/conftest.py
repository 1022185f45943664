"""The mesh tests' box: 3 x 4 x 2 cells of a 30 x 50 x 20 mm box off the origin (module scope)."""

import pytest

from support.meshes import DIVISIONS, ORIGIN, SIZE
from tissue_sim_ros.engine.mesh.generators import box_mesh


@pytest.fixture(scope='module')
def box():
    return box_mesh(SIZE, DIVISIONS, ORIGIN)
