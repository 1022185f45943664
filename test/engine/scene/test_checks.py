"""Scene values' checks (engine/scene/checks.py): each refusal names its path in the scene, the value
and the bound; units beside numbers; needle lists."""

import pytest

from support.scenes import small_scene
from tissue_sim_ros.engine.scene.checks import Range, check_value, unit_of
from tissue_sim_ros.engine.scene.keys import set_key
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import InputError, SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


@pytest.mark.parametrize('key, value', [('poisson_ratio', 0.6), ('poisson_ratio', -1.0),
                                        ('young_modulus_pa', -5.0), ('density_kg_per_m3', 0.0)])
def test_a_region_value_is_refused_with_its_path(key, value):
    regions = [{'name': 'a'}, {'name': 'b', 'select': {'below_z_m': -0.02}, key: value}]
    with pytest.raises(SceneError) as info:
        Scene.from_file(None, mesh=COARSE, regions=regions)
    assert str(info.value).startswith(f'regions[1].{key} = {value!r}')


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


def test_scene_keys_unknown_and_impossible_values_are_named():
    with pytest.raises(SceneError, match='unknown scene key model.geometrik'):
        Scene.from_file(model={'geometrik': True})
    with pytest.raises(SceneError, match='poisson_ratio'):
        small_scene(region={'poisson_ratio': 0.5})
    with pytest.raises(SceneError, match=r'solver.mass_scaling = -1'):
        small_scene(solver={'mass_scaling': -1})
    with pytest.raises(SceneError, match=r'regions\[0\].membrane.criterion'):
        small_scene(region={'membrane': {'criterion': 'strength'}})


@pytest.mark.parametrize('needles, words', [
    ([{'name': 'a'}, {'name': 'a', 'initial_position_m': [0.01, 0, 0.159]}], r'needles\[1\].name .*unique'),
    ([{'name': 'with space'}], r'needles\[0\].name'),
    ([{'initial_position_m': [0, 0, 0.159]}], r'needles\[0\] = .*non-empty name'),
    ([{'name': 'a', 'diameter': 0.001}], r'unknown scene key needles\[0\].diameter'),
    ([{'name': 'a', 'length_m': -1.0}], r'needles\[0\].length_m = -1.0'),
    ([{'name': 'a'}, {'name': 'b', 'initial_position_m': [0.0, 0.0, -0.01]}],
     r'needles\[1\].initial_pose = .*starts inside the tissue'),
])
def test_bad_needle_lists_are_refused_by_name(needles, words):
    """Refused as input (a SceneError for the keys, a PoseError for where the needle starts)."""
    with pytest.raises(InputError, match=words):
        Scene.from_file(None, mesh={'generator': 'box', 'divisions': [4, 4, 3]}, needles=needles)


def test_a_unit_of_another_quantity_is_refused_naming_the_key():
    with pytest.raises(SceneError, match=r"mesh.fine_size_m = '1.5 kPa': unknown unit 'kPa'.*mm"):
        set_key({}, 'mesh.fine_size_m', '1.5 kPa')


def test_units_and_ranges_of_the_schema():
    assert unit_of('young_modulus_pa') == 'Pa' and unit_of('damping_per_s') == '1/s'
    assert unit_of('insertion_viscous_n_s_per_m2') == 'N s/m^2' and unit_of('growth') == '-'
    assert check_value('x', 0.49, Range(-1.0, 0.5)) == 0.49
    for bad in (0.5, -1.0, float('nan'), 'a'):
        with pytest.raises(SceneError, match=r'x = .*expected'):
            check_value('x', bad, Range(-1.0, 0.5))
