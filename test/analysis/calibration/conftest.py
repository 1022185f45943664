"""The calibration tests' studies: a cheap one (one speed, one repeat, no membrane; module
scope) and the synthetic layered ones (support.layered; made once per session)."""

import pytest

from support.calibration import CHEAP_MESH, TRUE, sets, write_study
from support.layered import write_studies


@pytest.fixture(scope='module')
def cheap_study(tmp_path_factory):
    directory = tmp_path_factory.mktemp('cheap')
    return write_study(directory, [3.0], CHEAP_MESH + sets(TRUE), travel_m=0.012, repeats=1)


@pytest.fixture(scope='session')
def studies(tmp_path_factory):
    return write_studies(tmp_path_factory.mktemp('layered'))
