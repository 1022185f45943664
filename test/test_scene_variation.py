"""The spread between repeats as scene keys (engine.scene.variation), every scene value a key
--set and --fit reach, and a --fit key that cannot be applied refused before any simulation.

The truth: the nominal scene bit for bit (seed 0, or no spread), the normal distribution the
draws come from (their mean and standard deviation against the sampling error of that many), the
simulator's own puncture at the drawn rupture force."""
import numpy as np
import pytest

from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.keys import get_key, set_key
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.engine.scene.variation import drawn_regions
from tissue_sim_ros.errors import SceneError

TWO_LAYERS = {
    'mesh': {'generator': 'box', 'divisions': [4, 4, 3]},
    'regions': [{'name': 'outer', 'select': 'all', 'membrane': {'criterion': 'force', 'rupture_force_n': 0.8,
                                                                'rupture_force_spread_n': 0.1}},
                {'name': 'deep', 'select': {'below_z_m': -0.011}, 'depth_spread_m': 0.0005, 'young_modulus_pa': 9000.0,
                 'membrane': {'criterion': 'force', 'rupture_force_n': 1.0}}],
    'solver': {'mass_scaling': 400.0},
    'needle': {'diameter_m': 0.00127, 'tip': {'shape': 'bevel'}, 'start_gap_m': 0.001},
}


def checked(spec):
    return apply_schema('', spec, SCHEMA)


def test_the_draws_are_normal_with_the_stated_spread_and_each_seed_its_own():
    """2000 runs' draws: the rupture force's mean and standard deviation are the nominal value and
    the stated spread within 4 standard errors; the depth offset's too; seed 0 draws nothing, a
    region without a spread is not drawn, and one seed gives one draw."""
    spec = checked(TWO_LAYERS)
    forces, offsets = [], []
    for seed in range(1, 2001):
        spec['variation']['seed'] = seed
        regions, drawn = drawn_regions(spec)
        forces.append(regions[0]['membrane']['rupture_force_n'])
        offsets.append(drawn['regions[1].depth_offset_m'])
        assert regions[1]['membrane']['rupture_force_n'] == 1.0
        assert regions[1]['select']['below_z_m'] == pytest.approx(-0.011 - drawn['regions[1].depth_offset_m'])
    for values, mean, sd in ((forces, 0.8, 0.1), (offsets, 0.0, 0.0005)):
        values = np.asarray(values)
        assert abs(values.mean() - mean) < 4 * sd / np.sqrt(values.size)
        assert abs(values.std(ddof=1) - sd) < 4 * sd / np.sqrt(2 * (values.size - 1))
    spec['variation']['seed'] = 0
    assert drawn_regions(spec) == (spec['regions'], {})
    again = drawn_regions(checked(set_key(spec, 'variation.seed', 7)))
    assert again == drawn_regions(checked(set_key(spec, 'variation.seed', 7)))


def test_a_spread_of_depth_needs_a_boundary_with_a_depth():
    from tissue_sim_ros.engine.scene.build import check_combinations
    with pytest.raises(SceneError, match=r'regions\[0\].depth_spread_m = 0.001 with regions\[0\].select = .all.'):
        check_combinations(checked(set_key(TWO_LAYERS, 'regions[0].depth_spread_m', 0.001)))


def test_seed_zero_is_the_nominal_scene_bit_for_bit_and_a_seed_punctures_at_its_draw():
    """The spread keys at seed 0 change nothing: the same forces to the last bit as the scene
    without them; seed 3 punctures the outer layer at the rupture force it drew."""
    from tissue_sim_ros.analysis.insertion import run_insertion
    from tissue_sim_ros.engine.scene.scene import Scene
    plain = checked(TWO_LAYERS)
    plain['regions'][0]['membrane']['rupture_force_spread_n'] = 0.0
    plain['regions'][1]['depth_spread_m'] = 0.0
    runs = [run_insertion(Scene(spec), 0.006, 0.008, tick=0.02) for spec in (plain, TWO_LAYERS)]
    np.testing.assert_array_equal(runs[0].axial_force, runs[1].axial_force)
    drawn = Scene(set_key(TWO_LAYERS, 'variation.seed', 3))
    force = drawn.drawn['regions[0].membrane.rupture_force_n']
    run = run_insertion(drawn, 0.006, 0.010, tick=0.02)
    assert abs(force - 0.8) > 0.01 and run.puncture_events[0]['axial_force_n'] == pytest.approx(force, rel=0.01)


@pytest.mark.parametrize('key, value', [('regions[1].select.below_z_m', -0.004),
                                        ('model.relaxation', [{'relative_modulus': 0.3, 'time_constant_s': 1.0}]),
                                        ('model.relaxation[0].relative_modulus', 0.5),
                                        ('model.relaxation[0].time_constant_s', 2.5),
                                        ('regions[deep].membrane.rupture_force_spread_n', 0.2),
                                        ('variation.seed', 4)])
def test_layer_boundaries_relaxation_terms_and_the_spread_are_keys(key, value):
    relaxing = set_key(TWO_LAYERS, 'model.relaxation', [{'relative_modulus': 0.3, 'time_constant_s': 1.0}])
    spec = checked(set_key(relaxing, key, value))
    assert get_key(spec, key) == value


@pytest.mark.parametrize('fit, says', [
    ('model.relaxation[0].relative_modulus=0.2:1.2', 'the relative moduli sum to 1.2'),
    ('model.relaxation[1].time_constant_s=0.5:5', 'model.relaxation[1]: the list has 1 entry'),
    ('regions[2].young_modulus_pa=1000:9000', 'regions[2]: the list has 2 entries'),
    ('regions[0].select.below_z_m=-0.01:0', "regions[0].select = 'all' has no below_z_m"),
])
def test_a_fit_key_that_cannot_be_applied_is_refused_before_any_simulation(tmp_path, fit, says, monkeypatch, capsys):
    """calibrate refuses the key naming it before the first evaluation: no simulation runs."""
    import yaml

    from tissue_sim_ros.analysis.compare import trial_simulation
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.analysis.synthetic_curves import layered_curve
    scene = tmp_path / 'scene.yaml'
    scene.write_text(yaml.safe_dump(set_key(TWO_LAYERS, 'model.relaxation',
                                            [{'relative_modulus': 0.3, 'time_constant_s': 1.0}])))
    curve = layered_curve(np.random.default_rng(1), hold_s=0.0)
    rows = np.column_stack([curve.time_s, curve.force_n, curve.travel_m * 1e3])
    np.savetxt(tmp_path / 'trial.csv', rows, delimiter=',', header='time,fz,pz', comments='')
    (tmp_path / 'spec.yaml').write_text("files: [trial.csv]\ntime: {column: time}\nforce: {column: fz}\n"
                                        "position: {column: pz, unit: mm}\n")

    def no_simulation(job):
        raise AssertionError('a simulation ran')
    monkeypatch.setattr(trial_simulation, 'simulate', no_simulation)
    status = main(['calibrate', '--data-spec', str(tmp_path / 'spec.yaml'), '--scene', str(scene), '--fit', fit,
                   '--out', str(tmp_path / 'out')])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    print(error)
    assert status == 2 and error.startswith('tissue-sim calibrate: error:') and says in error


def test_the_data_description_keys_page_is_what_data_keys_prints():
    from pathlib import Path

    from tissue_sim_ros.io.trials.data_spec_keys import data_keys_markdown
    page = (Path(__file__).resolve().parents[1] / 'docs' / 'data.md').read_text()
    table = page.split('<!-- data-keys -->\n')[1].split('<!-- /data-keys -->')[0]
    assert table == data_keys_markdown(), 'docs/data.md is stale: tissue-sim data-keys --markdown'
