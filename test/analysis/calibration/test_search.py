"""The calibration's global stage (analysis/calibration/search.py) on a linear problem whose optimum
numpy's least squares gives: it starts from the start and ends far closer to the optimum."""

import numpy as np
import pytest

from support.calibration import _LinearObjective
from tissue_sim_ros.analysis.calibration.objective import Objective
from tissue_sim_ros.analysis.calibration.parameters import parse_fit


@pytest.mark.parametrize('method', ['de', 'optuna'])
def test_the_global_stage_starts_from_the_start_and_gets_far_closer_to_the_optimum(method):
    """Either global method (scipy's differential evolution, Optuna's TPE) over a least-squares
    problem whose start is far off: the start is among what it tries, and what it returns scores
    a small fraction of the start's objective, nearer numpy's optimum."""
    pytest.importorskip(method if method == 'optuna' else 'scipy')
    from tissue_sim_ros.analysis.calibration.search import GLOBAL_METHODS
    rng = np.random.default_rng(7)
    A = rng.normal(size=(40, 3))
    b = A @ np.array([0.3, 0.7, 0.5]) + 0.01 * rng.normal(size=40)
    objective = _LinearObjective(A, b, [parse_fit(f'a{i}=0:1') for i in range(3)])
    start = np.array([0.95, 0.05, 0.95])
    u = GLOBAL_METHODS[method](objective, start, 5, 0)
    optimum = np.linalg.lstsq(A, b, rcond=None)[0]
    print(f'{method}: {len(objective.evaluations)} evaluations, objective {objective.evaluate(start).objective:.3g} '
          f'-> {objective.evaluate(u).objective:.3g}; distance to the optimum {np.max(np.abs(u - optimum)):.3f}')
    assert Objective._key(start) in objective._cache
    assert objective.evaluate(u).objective < 0.1 * objective.evaluate(start).objective
    assert np.max(np.abs(u - optimum)) < 0.5 * np.max(np.abs(start - optimum))
