"""Scene values by key path (engine.scene.keys), their checks (engine.scene.checks), the
builder every caller uses (engine.scene.build), the generated key list (docs/scenes.md) and the
auto keys resolved above the engine (analysis.charting.auto_keys)."""
from pathlib import Path

import pytest
import yaml

from tissue_sim_ros.engine.scene.checks import Range, apply_schema, check_value, unit_of
from tissue_sim_ros.engine.scene.keys import (apply_overrides, get_key, override_text, parse_override,
                                              set_key)
from tissue_sim_ros.engine.scene.schema import SCHEMA, keys_markdown
from tissue_sim_ros.engine.scene.scene import Scene, read_scene_keys
from tissue_sim_ros.errors import SceneError

ROOT = Path(__file__).resolve().parents[1]
COARSE = {'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]}


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


def test_the_scene_keys_page_is_the_schema():
    """docs/scenes.md is generated (tissue-sim scene-keys --markdown): stale when it differs."""
    page = (ROOT / 'docs' / 'scenes.md').read_text()
    assert page == keys_markdown(), 'docs/scenes.md is stale: tissue-sim scene-keys --markdown > docs/scenes.md'
    for dotted in ('regions[].young_modulus_pa', 'model.relaxation[].time_constant_s', 'solver.mass_scaling'):
        assert f'`{dotted}`' in page


def test_keys_that_cannot_go_together_are_refused_naming_both():
    with pytest.raises(SceneError, match="solver.integrator = 'implicit' needs model.precision = float64"):
        Scene.from_file(None, values={**COARSE, 'solver.integrator': 'implicit', 'model.precision': 'float32'})


def test_the_plate_compression_cube_gets_every_model_key_of_the_scene():
    """The chart's compression task builds its cube with the scene's builder: the relaxation and
    the precision reach it."""
    from tissue_sim_ros.analysis.charting.compression import scene_block
    scene = Scene.from_file(None, values={**COARSE, 'model.precision': 'float32',
                                          'model.relaxation': [{'relative_modulus': 0.3, 'time_constant_s': 1.0}]})
    block = scene_block(scene, 0.005, divisions=2)
    model = block.simulation.model
    assert model.precision == 'float32' and model.relaxation is not None
    assert model.geometric == scene.model.geometric and model.viscous == scene.model.viscous
    assert block.simulation.dt == pytest.approx(scene.spec['solver']['time_step_safety']
                                               * block.simulation.critical_time_step(), rel=1e-9)


def test_an_auto_scene_is_refused_by_the_engine_and_resolved_above_it(tmp_path, monkeypatch):
    """The engine names the key it cannot choose; the analysis layer chooses it (here a stand-in
    rule) and writes the concrete scene a study reloads in its workers."""
    from tissue_sim_ros.analysis.charting import auto_keys, mass_scaling_rule
    path = tmp_path / 'auto.yaml'
    path.write_text(yaml.safe_dump({'solver': {'mass_scaling': 'auto'}, 'mesh': {'fine_size_m': 0.004,
                                                                                'divisions': [5, 5, 4]}}))
    with pytest.raises(SceneError, match="solver.mass_scaling = 'auto': chosen by measuring"):
        Scene.from_file(path)
    monkeypatch.setattr(mass_scaling_rule, 'auto_mass_scaling', lambda spec, base_dir, quiet=False: (37.0, {'rule': 1}))
    scene = auto_keys.load_scene(path)
    assert scene.simulation.mass_scaling == 37.0 and scene.auto_choices == {'solver.mass_scaling': {'rule': 1}}
    concrete, sets = auto_keys.concrete_scene_file(path, [], tmp_path / 'study')
    assert sets == [] and read_scene_keys(concrete)[0]['solver']['mass_scaling'] == 37.0
    plain = tmp_path / 'plain.yaml'
    plain.write_text('solver: {mass_scaling: 100}\n')
    assert auto_keys.concrete_scene_file(plain, ['model.geometric=false'], tmp_path / 'x') == (plain, ['model.geometric=false'])


def test_a_mistyped_mesh_size_is_refused_at_once_in_bounded_memory():
    """fine_size_m 1e-5 m (a millimetre value written as metres) asks for about 2e7 tetrahedra:
    refused before meshing, naming the key, the estimate and the limit, in a fresh process that
    stays small (before the check existed it grew to 8 GB in 10 s)."""
    import subprocess
    import sys
    import textwrap
    code = textwrap.dedent('''
        import resource, sys, time
        from tissue_sim_ros.engine.scene.scene import Scene
        from tissue_sim_ros.errors import SceneError
        t = time.perf_counter()
        try:
            Scene.from_file(None, values={'mesh.fine_size_m': 0.00001})
        except SceneError as exc:
            print(time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, exc)
            sys.exit(0)
        sys.exit('not refused')''')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    seconds, kilobytes, message = done.stdout.split(' ', 2)
    assert float(seconds) < 1.0 and int(kilobytes) < 600_000
    assert 'mesh.fine_size_m = 1e-05' in message and 'tetrahedra' in message and 'mesh.max_elements' in message


def test_the_mesh_limit_is_a_key_and_a_large_mesh_is_announced(capsys, monkeypatch):
    from tissue_sim_ros.engine.mesh.generators import box_axes, grid_elements
    from tissue_sim_ros.engine.scene import build
    assert grid_elements(box_axes((1, 1, 1), (3, 4, 5))) == 6 * 3 * 4 * 5
    with pytest.raises(SceneError, match=r'about 480 tetrahedra, more than mesh.max_elements = 100'):
        Scene.from_file(None, values={'mesh.generator': 'box', 'mesh.divisions': [4, 4, 5], 'mesh.max_elements': 100})
    monkeypatch.setattr(build, 'ANNOUNCE_ELEMENTS', 100)
    scene = Scene.from_file(None, values={'mesh.generator': 'box', 'mesh.divisions': [4, 4, 5]})
    assert scene.mesh.n_elements == 480
    assert 'building a mesh of about 480 tetrahedra' in capsys.readouterr().err


@pytest.mark.parametrize('text', ['', '# only a comment\n', '{}\n'])
def test_an_empty_scene_file_is_refused_saying_what_it_would_run(tmp_path, text):
    path = tmp_path / 'empty.yaml'
    path.write_text(text)
    with pytest.raises(SceneError, match=r"scene_file = '.*empty.yaml': no scene keys .*force stays 0 N"):
        Scene.from_file(path)
