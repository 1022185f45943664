"""Scene values refused at load, each naming its path in the scene, the value and the bound."""
import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

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


def test_a_scene_file_that_is_not_a_mapping_is_refused_by_name(tmp_path):
    path = tmp_path / 'list.yaml'
    path.write_text('- 1\n- 2\n')
    with pytest.raises(SceneError, match=r"list.yaml': expected a mapping of scene keys .* found a list"):
        Scene.from_file(path)


def test_set_overrides_reach_the_scene_as_the_file_would():
    """--set KEY=VALUE: the same scene as writing the value in the file (the keys compared, and
    the model built from them), regions picked by index or by name."""
    from tissue_sim_ros.engine.scene.keys import apply_overrides
    regions = [{'name': 'liver'}, {'name': 'capsule', 'select': {'above_z_m': -0.002}}]
    by_set = Scene.from_file(None, mesh=COARSE, regions=regions, sets=[
        'regions[capsule].membrane.rupture_force_n=2.1', 'regions[0].young_modulus_pa=20000',
        'model.geometric=false', 'needle.initial_position_m=[0.001, 0.0, 0.16]'])
    in_file = Scene.from_file(None, mesh=COARSE, model={'geometric': False},
                              needle={'initial_position_m': [0.001, 0.0, 0.16]},
                              regions=[{'name': 'liver', 'young_modulus_pa': 20000.0},
                                       {'name': 'capsule', 'select': {'above_z_m': -0.002},
                                        'membrane': {'rupture_force_n': 2.1}}])
    assert by_set.spec == in_file.spec
    assert not by_set.model.geometric and by_set.spec['regions'][1]['membrane']['rupture_force_n'] == 2.1
    assert apply_overrides({}, ['solver.mass_scaling=100']) == {'solver': {'mass_scaling': 100}}


def test_an_exponent_without_a_dot_is_a_number_in_a_file_and_in_a_set(tmp_path):
    """YAML 1.1 reads 2e4 (no dot) as a string: the scene takes it as the number it is, from a
    file and from --set, and still refuses what is not a number, naming it."""
    path = tmp_path / 'exponents.yaml'
    path.write_text('regions:\n  - name: liver\n    young_modulus_pa: 2e4\n')
    from_file = Scene.from_file(path, mesh=COARSE, sets=['solver.newton_tolerance=1e-6', 'solver.mass_scaling=1e2'])
    assert from_file.spec['regions'][0]['young_modulus_pa'] == 20000.0
    assert from_file.spec['solver']['newton_tolerance'] == 1e-6
    assert from_file.spec['solver']['mass_scaling'] == 100.0
    for text in ('nan', 'inf', '\u0665'):          # not finite, and a digit that is not ASCII
        with pytest.raises(SceneError, match='solver.newton_tolerance'):
            Scene.from_file(None, mesh=COARSE, solver={'newton_tolerance': text})
    with pytest.raises(SceneError, match=r"solver.newton_tolerance = '1e-6x': expected a finite number"):
        Scene.from_file(None, mesh=COARSE, sets=['solver.newton_tolerance=1e-6x'])


@pytest.mark.parametrize('override, words', [
    ('model.geometrc=true', ['model.geometrc', 'known keys here: geometric']),
    ('regions[kidney].young_modulus_pa=1', ["no entry of regions named 'kidney'", "'liver'"]),
    ('regions[3].young_modulus_pa=1', ['regions[3]', 'the list has 1 entry']),
    ('regions.young_modulus_pa=1', ['regions is a list', 'regions[0]']),
    ('regions[0].select.below_z=1', ['regions[0].select.below_z', 'below_z_m']),
    ('model.relaxation[0].time_constant_s=1', ['model.relaxation[0]', 'the list has 0 entries']),
    ('mesh=3', ['mesh is a section', 'generator']),
    ('solver.mass_scaling', ['expected KEY=VALUE']),
    ('solver.mass_scaling=-1', ['solver.mass_scaling = -1', ">= 1 or 'auto'"]),   # the file's own check
    ('solver.mass_scaling=[1', ['not valid YAML']),
])
def test_a_bad_override_is_refused_naming_it(override, words):
    with pytest.raises(SceneError) as info:
        Scene.from_file(None, mesh=COARSE, sets=[override])
    for word in words:
        assert word in str(info.value), str(info.value)


@pytest.mark.parametrize('gap', [0.0005, 0.004, 0.02])
def test_start_gap_puts_the_tip_that_far_above_the_surface(gap):
    """needle.start_gap_m: the tip moves along the axis to that distance from the surface; the
    distance is measured by the tip itself: driving it gap + 1 mm makes contact, gap - 0.2 mm
    does not."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    scene = Scene.from_file(None, mesh=COARSE, needle={'start_gap_m': gap})
    assert scene.start_gap_m == pytest.approx(gap, abs=1e-12)
    position, orientation = scene.needle_pose
    axis = scene.needle.axis.copy()
    driver = SimulationDriver(scene)
    for travel, touches in ((gap - 0.0002, False), (gap + 0.001, True)):
        driver.reset()
        pushed = 0.0                      # the largest axial force the tissue put on the needle
        steps = max(1, int(max(travel, 0.0) / 0.002) + 1)
        for k in range(1, steps + 1):
            driver.advance(0.02, position + max(travel, 0.0) * k / steps * axis, orientation)
            pushed = max(pushed, -float(driver.force @ axis))
        assert (pushed > 1e-6) == touches, (travel, pushed)
