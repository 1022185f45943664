"""The calibration tests' cheap study: one speed, one repeat, no membrane (module scope)."""

import pytest

from support.calibration import CHEAP_MESH, TRUE, sets, write_study


@pytest.fixture(scope='module')
def cheap_study(tmp_path_factory):
    directory = tmp_path_factory.mktemp('cheap')
    return write_study(directory, [3.0], CHEAP_MESH + sets(TRUE), travel_m=0.012, repeats=1)
