"""Scene values by key path (engine/scene/keys.py): set and read back, --set overrides as the file
would, refusals where a value is set, and a scene set up at a higher mass scaling."""

import numpy as np
import pytest

from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.keys import apply_overrides, get_key, override_text, parse_override, set_key
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.errors import SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


def _checked(spec):
    return apply_schema('', spec, SCHEMA)


@pytest.mark.parametrize('key, value', [
    ('regions[0].young_modulus_pa', 12345.0),
    ('regions[1].select.below_z_m', -0.004),                  # a layer boundary's depth
    ('model.relaxation[0].time_constant_s', 2.5),             # a relaxation term
    ('needle.initial_position_m[2]', 0.2),                    # one number of a vector
    ('targets[tumour].position_m', [0.001, 0.0, -0.01]),      # an entry by name
])
def test_every_value_is_reachable_by_its_key_path(key, value):
    spec = {'regions': [{'name': 'capsule'}, {'name': 'parenchyma', 'select': {'below_z_m': -0.002}}],
            'model': {'relaxation': [{'relative_modulus': 0.3, 'time_constant_s': 1.0}]},
            'targets': [{'name': 'tumour', 'position_m': [0.0, 0.0, -0.02]}]}
    changed = _checked(set_key(spec, key, value))
    assert get_key(changed, key) == value
    assert _checked(spec) != changed                       # set on a copy: the original is as it was
    assert _checked(set_key(spec, key, value)) == changed   # and the same again


def test_a_select_takes_one_shape_and_a_new_one_replaces_it():
    spec = set_key({'regions': [{}, {'select': {'below_z_m': -0.002}}]}, 'regions[1].select.sphere_m',
                   [0.0, 0.0, -0.01, 0.003])
    assert spec['regions'][1]['select'] == {'sphere_m': [0.0, 0.0, -0.01, 0.003]}


@pytest.mark.parametrize('key, value, words', [
    ('regions[0].poisson_ratio', 0.5, ['regions[0].poisson_ratio = 0.5', '(-1, 0.5)']),
    ('regions[0].select.below_z', 1.0, ['regions[0].select.below_z', 'below_z_m']),
    ('model.relaxation[0].time_constant_s', 1.0, ['model.relaxation[0]', 'the list has 0 entries']),
    ('needle.initial_position_m[3]', 1.0, ['needle.initial_position_m[3]', 'has 3 numbers']),
    ('solver', 1.0, ['solver is a section']),
    ('regions[liver].young_modulus_pa', 1.0, ["no entry of regions named 'liver'"]),
])
def test_a_value_that_cannot_be_set_is_refused_where_it_is_set(key, value, words):
    with pytest.raises(SceneError) as info:
        set_key({}, key, value)
    for word in words:
        assert word in str(info.value)


@pytest.mark.parametrize('key, value', [
    ('solver.mass_scaling', 400.0), ('model.physical.lambda_amplitude', 1e-10), ('mesh.divisions', [5, 5, 4]),
    ('model.precision', 'float32'), ('model.geometric', False), ('solver.time_step_s', 2.5e-7),
])
def test_a_setting_reported_as_set_text_reads_back_as_the_same_value(key, value):
    """The reports' ``--set`` texts (YAML 1.1 reads 1e-10 as text: they write 1.0e-10)."""
    parts, read = parse_override(override_text(key, value))
    assert read == value and get_key(_checked(apply_overrides({}, [override_text(key, value)])), key) == value


@pytest.mark.parametrize('key, text, si', [
    ('regions[0].young_modulus_pa', '22 kPa', 22000.0), ('mesh.fine_size_m', '1.5 mm', 0.0015),
    ('solver.time_step_s', '0.5 ms', 0.0005), ('regions[0].cutting_force_n', '300 mN', 0.3),
    ('regions[0].young_modulus_pa', '2.2e4', 22000.0),
])
def test_a_number_written_with_its_unit_is_converted_once(key, text, si):
    assert get_key(_checked(set_key({}, key, text)), key) == pytest.approx(si, rel=1e-12)


def test_a_scene_set_up_at_a_higher_mass_scaling_equals_one_rescaled_at_run_time():
    """with_mass_scaling (the calibration's affordable-stiffness rule) and rescale_masses (the
    ladder's and predictions' rule) are one rule: the same masses and damping force. The step:
    the run-time one grows as sqrt(mass) (the elastic limit), the scene's own estimate faster
    (the Kelvin-Voigt limit grows with the mass itself), so the run-time step stays stable."""
    from tissue_sim_ros.engine.scene.keys import with_mass_scaling
    scene = Scene.from_file(None)
    scaling = scene.simulation.mass_scaling
    heavier = Scene(with_mass_scaling(scene.spec, 4.0 * scaling)).simulation
    sim = scene.simulation
    dt0 = sim.dt
    sim.rescale_masses(4.0 * scaling)
    np.testing.assert_allclose(heavier.mass, sim.mass, rtol=1e-12)
    np.testing.assert_allclose(heavier.damping_rate, sim.damping_rate, rtol=1e-12)
    assert sim.dt == pytest.approx(2.0 * dt0, rel=1e-12)
    assert sim.dt <= heavier.dt <= heavier.critical_time_step()


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
