"""Each repeat's own draws read from its punctures (analysis.calibration.repeat_draws).

The truth: the rupture forces and the deep boundary each repeat of the synthetic two-layer study
drew (support.layered; known from the simulator that made the data), a straight line's slope, and
the mean and sample standard deviation of the offsets computed here by numpy."""
import json

import numpy as np
import pytest
import yaml

from support.layered import SPREAD
from tissue_sim_ros.analysis.calibration.repeat_draws import folded_spec, loading_slope, match_repeat_draws
from tissue_sim_ros.analysis.compare.force_events import Puncture


def test_the_loading_slope_is_read_over_the_loading_before_the_peak():
    travel = np.linspace(0.0, 0.01, 1001)
    force = np.where(travel <= 0.008, 300.0 * travel, 0.5)
    force = force + np.random.default_rng(2).normal(0.0, 0.005, travel.size)
    peak = Puncture(index=800, travel_m=0.008, force_n=2.4, drop_n=1.9, built_m=0.004)
    assert loading_slope(travel, force, peak) == pytest.approx(300.0, rel=0.05)
    assert np.isnan(loading_slope(travel[:3], force[:3], Puncture(index=1, travel_m=1e-5, force_n=0.0, drop_n=0.0)))


def test_the_written_scene_is_the_mean_repeat_with_the_matched_spread():
    from support.scenes import TWO_LAYERS
    from tissue_sim_ros.engine.scene.checks import apply_schema
    from tissue_sim_ros.engine.scene.schema import SCHEMA
    spec = apply_schema('', TWO_LAYERS, SCHEMA)
    offsets = [{0: (0.1, 0.0), 1: (-0.2, 0.0004)}, {0: (0.3, 0.0), 1: (0.1, -0.0002)}, {0: (-0.1, 0.0)}]
    folded = folded_spec(spec, offsets)
    outer, deep = folded['regions']
    assert outer['membrane']['rupture_force_n'] == pytest.approx(0.8 + 0.1)
    assert outer['membrane']['rupture_force_spread_n'] == pytest.approx(np.std([0.1, 0.3, -0.1], ddof=1))
    assert outer['select'] == 'all' and outer['depth_spread_m'] == spec['regions'][0]['depth_spread_m']
    assert deep['membrane']['rupture_force_n'] == pytest.approx(1.0 - 0.05)
    assert deep['select']['below_z_m'] == pytest.approx(-0.011 - 0.0001)
    assert deep['depth_spread_m'] == pytest.approx(np.std([0.0004, -0.0002], ddof=1))
    assert spec['regions'][1]['membrane']['rupture_force_n'] == 1.0


def test_each_repeat_is_matched_to_the_draws_that_made_it(studies):
    """Four repeats of the two-layer phantom, each simulated at the truth's moduli with the offsets
    matched to its punctures: each simulated puncture lands on the measured one in what its offset
    sets (the outer layer's force within 0.03 N, the deep layer's travel within 0.05 mm) and
    within 2.5 samples of travel for the outer one (the data's contact, which its travel counts
    from, moves by up to 2 samples with the noise, the onset's 5-sample centred average; the
    simulation's is where it lands on average); the outer rupture force and the deep boundary are
    the ones the repeat drew (less their mean, which the shared keys hold) within a third of the
    spread they were drawn with; and scored against its own draws the repeats fit at least three
    times better than against one scene. The deep layer's force is not compared: where the tip
    reaches the deep boundary already pressing harder than its rupture force, the layer gives way
    at the boundary, and any rupture force under that makes the same curve; its peak then follows
    the loading, a sample of contact jitter at 1 N/mm moving it by 0.03 N."""
    from tissue_sim_ros.analysis.calibration.objective import Objective
    from tissue_sim_ros.analysis.calibration.parameters import parse_fit
    from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures
    from tissue_sim_ros.engine.scene.keys import set_keys
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    spec_file = studies['fit']
    trials = load_trials(DataSpec.from_file(spec_file))
    truth = yaml.safe_load((studies['root'] / 'truth_2.yaml').read_text())
    nominal = set_keys(truth, {key: 0.0 for key in SPREAD})
    key = parse_fit('regions[0].young_modulus_pa=5000:100000:log')
    u = np.array([key.unit(truth['regions'][0]['young_modulus_pa'])])
    drawn = json.loads((spec_file.parent / 'truth.json').read_text())['trials']
    draws = [drawn[str(t.file).rsplit('/', 1)[-1]]['drawn'] for t in trials]
    objective = Objective(trials, Scene(nominal, base_dir=studies['root']), [key], workers=2, per_repeat=True)
    one_scene = objective.evaluate(u).objective
    offsets = match_repeat_draws(objective, u)
    matched = objective.evaluate(u)
    sample_m = trials[0].speed_m_s * float(np.median(np.diff(trials[0].time_s)))
    for comparison in matched.comparisons:
        pairs = pair_punctures(comparison.measured_punctures, comparison.simulated_punctures)
        assert len(pairs) == 2
        (outer, outer_simulated), (deep, deep_simulated) = pairs
        assert outer_simulated.force_n == pytest.approx(outer.force_n, abs=0.03)
        assert outer_simulated.travel_m == pytest.approx(outer.travel_m, abs=2.5 * sample_m)
        assert deep_simulated.travel_m == pytest.approx(deep.travel_m, abs=5e-5)
    for drawn_key, region, part, spread in (('regions[0].membrane.rupture_force_n', 0, 0, 0.1),
                                            ('regions[1].depth_offset_m', 1, 1, 0.0003)):
        truth_values = np.array([d[drawn_key] for d in draws])
        values = np.array([o[region][part] for o in offsets])
        np.testing.assert_allclose(values - values.mean(), truth_values - truth_values.mean(), atol=spread / 3)
    assert matched.objective < one_scene / 3


def test_a_calibration_repeat_by_repeat_writes_the_mean_repeat_and_the_spread_it_matched(studies):
    """calibrate --per-repeat from the truth with the outer rupture force 10 % low: the fitted
    value and the scene it writes are the repeats' mean draw (within 2 %), the scene states their
    spread (the draws' sample standard deviation within 0.03 N), its report lists each repeat's
    offsets, and the budget and the log count the matching's evaluations alike; run again, it
    replays every evaluation, logs none twice and ends where it did."""
    from tissue_sim_ros.analysis.calibration import calibrate
    from tissue_sim_ros.engine.scene.keys import set_keys
    truth = yaml.safe_load((studies['root'] / 'truth_2.yaml').read_text())
    start = set_keys(truth, {**{key: 0.0 for key in SPREAD}, 'regions[0].membrane.rupture_force_n': 3.6})
    (studies['root'] / 'start_low.yaml').write_text(yaml.safe_dump(start))
    out = studies['root'] / 'calibrate_per_repeat'
    with pytest.raises(ValueError, match="expected at least 9 .* 4 matching each repeat's draws"):
        calibrate.main(data_spec=studies['fit'], scene_file=studies['root'] / 'start_low.yaml', per_repeat=True,
                       fits=['regions[0].membrane.rupture_force_n=2:6'], max_evaluations=8, out=out)
    report = calibrate.main(data_spec=studies['fit'], scene_file=studies['root'] / 'start_low.yaml', per_repeat=True,
                            fits=['regions[0].membrane.rupture_force_n=2:6'], max_evaluations=10, workers=2, out=out)
    written = yaml.safe_load((out / 'calibrated.yaml').read_text())['regions'][0]['membrane']
    draws = np.array([t['drawn']['regions[0].membrane.rupture_force_n'] for t in
                      json.loads((studies['fit'].parent / 'truth.json').read_text())['trials'].values()])
    assert written['rupture_force_n'] == pytest.approx(draws.mean(), rel=0.02)
    fitted = report['parameters']['regions[0].membrane.rupture_force_n']
    assert fitted['start'] == 3.6 and fitted['value'] == pytest.approx(written['rupture_force_n'], rel=0.005)
    assert written['rupture_force_spread_n'] == pytest.approx(draws.std(ddof=1), abs=0.03)
    assert len(report['repeat_draws']['trials']) == 4
    assert report['evaluations'] == report['evaluations_logged'] <= 10
    assert 'Each repeat simulated with its own' in (out / 'calibrate.md').read_text()
    again = calibrate.main(data_spec=studies['fit'], scene_file=studies['root'] / 'start_low.yaml', per_repeat=True,
                           fits=['regions[0].membrane.rupture_force_n=2:6'], max_evaluations=10, workers=2, out=out)
    assert again['replayed_evaluations'] == again['evaluations'] == report['evaluations']
    assert again['evaluations_logged'] == report['evaluations_logged']
    assert again['parameters'] == report['parameters']
