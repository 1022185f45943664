"""One builder of a scene's parts (engine/scene/build.py): a time step above the critical one and
keys that cannot go together are refused naming both."""

import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}

COARSE_VALUES = {'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]}


def test_a_time_step_above_the_critical_step_is_refused_naming_both():
    """3.1x and 5x the stable limit were accepted and the node diverged and reset over and over.
    The refusal names the critical step the simulation estimates itself (independent of the
    check: the same scene with a null step runs at time_step_safety x that estimate)."""
    ok = Scene.from_file(None, mesh=COARSE)
    critical = float(ok.simulation.critical_time_step())
    assert ok.dt == pytest.approx(ok.spec['solver']['time_step_safety'] * critical, rel=1e-12)
    Scene.from_file(None, mesh=COARSE, solver={'time_step_s': 0.99 * critical})  # below: accepted
    for factor in (1.01, 3.1, 5.0):
        with pytest.raises(SceneError) as info:
            Scene.from_file(None, mesh=COARSE, solver={'time_step_s': factor * critical})
        text = str(info.value)
        assert text.startswith(f'solver.time_step_s = {factor * critical!r}')
        assert f'{critical:.4g} s' in text
    with pytest.raises(SceneError, match=r'solver.time_step_safety = 1.5: expected at most 1'):
        Scene.from_file(None, mesh=COARSE, solver={'time_step_safety': 1.5})


def test_keys_that_cannot_go_together_are_refused_naming_both():
    with pytest.raises(SceneError, match="solver.integrator = 'implicit' needs model.precision = float64"):
        Scene.from_file(None, values={**COARSE_VALUES, 'solver.integrator': 'implicit', 'model.precision': 'float32'})
