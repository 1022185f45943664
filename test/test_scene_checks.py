"""Scene values refused at load, each naming its path in the scene, the value and the bound."""
import pytest

from tissue_sim_ros.engine.scene import Scene, SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


@pytest.mark.parametrize('key, value', [('poisson_ratio', 0.6), ('poisson_ratio', -1.0),
                                        ('young_modulus_pa', -5.0), ('density_kg_per_m3', 0.0)])
def test_a_region_value_is_refused_with_its_path(key, value):
    regions = [{'name': 'a'}, {'name': 'b', 'select': {'below_z_m': -0.02}, key: value}]
    with pytest.raises(SceneError) as info:
        Scene.from_file(None, mesh=COARSE, regions=regions)
    assert str(info.value).startswith(f'regions[1].{key} = {value!r}')


def test_a_time_step_above_the_critical_step_is_refused_naming_both():
    """3.1x and 5x the stable limit were accepted and the node diverged and reset over and over.
    The refusal names the critical step the simulation estimates itself (independent of the
    check: the same scene with a null step runs at time_step_safety x that estimate)."""
    ok = Scene.from_file(None, mesh=COARSE)
    critical = float(ok.simulation.critical_time_step())
    assert ok.dt == pytest.approx(0.8 * critical, rel=1e-12)
    Scene.from_file(None, mesh=COARSE, solver={'time_step_s': 0.99 * critical})  # below: accepted
    for factor in (1.01, 3.1, 5.0):
        with pytest.raises(SceneError) as info:
            Scene.from_file(None, mesh=COARSE, solver={'time_step_s': factor * critical})
        text = str(info.value)
        assert text.startswith(f'solver.time_step_s = {factor * critical!r}')
        assert f'{critical:.4g} s' in text
    with pytest.raises(SceneError, match=r'solver.time_step_safety = 1.5: expected at most 1'):
        Scene.from_file(None, mesh=COARSE, solver={'time_step_safety': 1.5})


def test_a_scene_file_that_is_not_a_mapping_is_refused_by_name(tmp_path):
    path = tmp_path / 'list.yaml'
    path.write_text('- 1\n- 2\n')
    with pytest.raises(SceneError, match=r"list.yaml': expected a mapping of scene keys .* found a list"):
        Scene.from_file(path)
