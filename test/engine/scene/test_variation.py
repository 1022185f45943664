"""The spread between repeats as scene keys (engine.scene.variation), and the layer boundaries,
relaxation terms and spread as keys --set and --fit reach.

The truth: the nominal scene bit for bit (seed 0, or no spread), the normal distribution the
draws come from (their mean and standard deviation against the sampling error of that many), the
simulator's own puncture at the drawn rupture force."""
import numpy as np
import pytest

from support.scenes import TWO_LAYERS
from tissue_sim_ros.engine.scene.checks import apply_schema
from tissue_sim_ros.engine.scene.keys import get_key, set_key
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.engine.scene.variation import MIN_RUPTURE_FRACTION, drawn_regions, moved_regions
from tissue_sim_ros.errors import SceneError


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


def test_a_repeats_offsets_move_its_rupture_force_and_its_boundary_down_and_nothing_else():
    """A repeat's own offsets: the force added (held to its least fraction), a plane, a box's
    corners and a sphere's centre moved down by the depth; a region without a depth keeps its
    selector; the nominal regions are left as they were."""
    spec = checked(TWO_LAYERS)
    regions = spec['regions'] + [dict(spec['regions'][1], select={'box_m': [[0, 0, -0.02], [0.01, 0.01, -0.01]]}),
                                 dict(spec['regions'][1], select={'sphere_m': [0, 0, -0.01, 0.003]})]
    before = [dict(r, membrane=dict(r['membrane'])) for r in regions]
    moved = moved_regions(regions, {0: (0.25, 0.002), 1: (-0.1, 0.0005), 2: (-5.0, -0.001), 3: (0.0, 0.001)})
    assert regions == before
    assert moved[0]['select'] == 'all' and moved[0]['membrane']['rupture_force_n'] == pytest.approx(0.8 + 0.25)
    assert moved[1]['select']['below_z_m'] == pytest.approx(-0.011 - 0.0005)
    assert moved[1]['membrane']['rupture_force_n'] == pytest.approx(1.0 - 0.1)
    assert moved[2]['membrane']['rupture_force_n'] == pytest.approx(MIN_RUPTURE_FRACTION * 1.0)
    assert moved[2]['select']['box_m'] == [[0, 0, pytest.approx(-0.019)], [0.01, 0.01, pytest.approx(-0.009)]]
    assert moved[3]['select']['sphere_m'] == [0, 0, pytest.approx(-0.011), 0.003]
    assert moved_regions(regions, {}) == regions


def test_a_spread_of_depth_needs_a_boundary_with_a_depth():
    """'all' has no depth: refused where the value enters; a half-space has one: its plane's
    point is moved down by the drawn offset (it once passed the check and then had no rule)."""
    from tissue_sim_ros.engine.scene.build import check_combinations
    with pytest.raises(SceneError, match=r'regions\[0\].depth_spread_m = 0.001 with regions\[0\].select = .all.'):
        check_combinations(checked(set_key(TWO_LAYERS, 'regions[0].depth_spread_m', 0.001)))
    spec = checked(set_key(set_key(TWO_LAYERS, 'regions[1].select', {'half_space_m': [0, 0, -0.011, 0, 0, 1]}),
                           'variation.seed', 2))
    check_combinations(spec)
    regions, drawn = drawn_regions(spec)
    assert regions[1]['select']['half_space_m'] == pytest.approx([0, 0, -0.011 - drawn['regions[1].depth_offset_m'],
                                                                   0, 0, 1])


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
