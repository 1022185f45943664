"""The calibration's objective (analysis/calibration/objective.py): at the parameters that made
synthetic data it is the data's noise; a late puncture costs a residual smooth in its shift; a
stage's simulations stop after its phases and score as the whole run; a diverging or refused
trial scores as a miss."""

import numpy as np
import pytest

from support.calibration import CHEAP_MESH, FITS, MESH, NOISE_N, START, TRUE, sets, write_study
from tissue_sim_ros.analysis.calibration import calibrate as calibration
from tissue_sim_ros.analysis.calibration.objective import FAILED_RESIDUAL, Objective
from tissue_sim_ros.analysis.calibration.parameters import parse_fit
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials


def test_at_the_parameters_that_made_the_data_the_objective_is_its_noise(tmp_path):
    """Data made by the simulator (two repeats at three speeds, jittered sampling, white noise),
    scored at the parameters that made it: each residual is the noise over its trial's force
    range plus what the comparison's own steps add (the contact found in noisy data, the motion
    resampled and smoothed: measured 1.7x the noise alone), and no sample is a miss (the last
    sample of a jittered repeat scored 1 once, in every run: 1 / residuals, 30x the noise)."""
    spec = write_study(tmp_path / 'data', [1.0, 2.0, 3.0], MESH + sets(TRUE), travel_m=0.019)
    trials = load_trials(DataSpec.from_file(spec))
    keys = [parse_fit(text) for text in FITS]
    objective = Objective(trials, Scene.from_file(None, sets=MESH + sets(START)), keys, workers=1)
    evaluation = objective.evaluate([k.unit(TRUE[k.key]) for k in keys])
    noise = np.mean([(NOISE_N / np.ptp(t.axial_force_n)) ** 2 for t in trials])
    misses = np.abs(evaluation.residuals) * np.sqrt(evaluation.residuals.size) > 0.5
    print(f'objective at the truth {evaluation.objective:.3g}, noise alone {noise:.3g}, misses {misses.sum()}')
    assert not misses.any() and not evaluation.failures
    assert 0.5 * noise < evaluation.objective < 5.0 * noise


def test_a_late_puncture_costs_a_residual_smooth_in_its_shift_not_a_staircase_of_samples():
    """A measured curve that rises to 1 N and drops by 0.6 N at 5 mm, and simulated ones that drop
    0 to 6 scored samples later in steps of a third of one (punctures found by the detector both
    curves share): the samples between the two peaks count 0, and the shift's one residual is
    the drop over the force range times the Huber root of the shift counted in samples, so a
    trial's sum of squares grows smoothly, as the shift's square within half a sample and by one
    sample's cost per sample beyond. Scored as plain samples it is a staircase: a whole sample's
    drop squared each time the later drop passes a scored sample, flat in between; the smooth
    cost stays within one step of it."""
    from types import SimpleNamespace

    from tissue_sim_ros.analysis.calibration.objective import puncture_shift_residuals
    from tissue_sim_ros.analysis.compare.force_events import detect_punctures
    travel = np.linspace(0.0, 0.01, 20001)                    # 0.5 um a sample
    indices = np.arange(0, travel.size, 100)                   # scored every 50 um

    def curve(puncture_m):
        return np.where(travel <= puncture_m, 200.0 * travel, 0.4 + 50.0 * (travel - puncture_m))
    measured = curve(0.005)
    scale = float(np.ptp(measured))
    sums, plain, shifts_seen = [], [], []
    for samples in np.arange(0.0, 6.01, 1.0 / 3.0):
        simulated = curve(0.005 + samples * 50e-6)
        comparison = SimpleNamespace(travel_since_contact_m=travel, measured_punctures=detect_punctures(travel, measured),
                                     simulated_punctures=detect_punctures(travel, simulated))
        error = (simulated - measured)[indices] / scale
        kept, shifts = puncture_shift_residuals(comparison, indices, error, scale)
        assert np.max(np.abs(kept)) <= 50.0 * samples * 50e-6 / scale + 1e-12   # only the slopes' offset is left
        sums.append(float(kept @ kept + shifts @ shifts))
        plain.append(float(error @ error))
        shifts_seen.append(shifts[0])
    samples = np.arange(0.0, 6.01, 1.0 / 3.0)
    drop = comparison.measured_punctures[0].drop_n / scale      # the detector's, from the smoothed force
    assert 0.8 * 0.6 < drop * scale <= 0.6
    huber = np.where(samples <= 0.5, samples ** 2, samples - 0.25)
    np.testing.assert_allclose(np.square(shifts_seen), drop ** 2 * huber, atol=0.03 * drop ** 2)
    np.testing.assert_allclose(sums[1:], drop ** 2 * huber[1:], rtol=0.05, atol=0.01 * drop ** 2)
    assert np.all(np.diff(sums) > 0)                                  # smooth: every shift costs more
    assert np.sum(np.diff(plain) < 0.01 * drop ** 2) >= 10           # plain samples: flat steps...
    assert np.max(np.diff(plain)) > 0.9 * (0.6 / scale) ** 2          # ...and a whole drop at a time
    assert np.max(np.abs(np.array(sums) - plain)) < 1.1 * (0.6 / scale) ** 2   # within one step of them


def test_a_stage_runs_its_simulations_only_as_far_as_its_phases_and_scores_them_as_a_whole_run(tmp_path, monkeypatch):
    """The objective's horizons: an evaluation for the loading (or the puncture, or the steady
    insertion, or the pause) stops each simulation after the last sample of those phases (plus its
    margin);
    the simulation is deterministic, so those phases' residuals are the whole run's to rounding,
    for a fraction of its steps. A horizon that falls short of a sample (a margin made negative
    here) is run again whole, never scored as a miss."""
    from tissue_sim_ros.analysis.calibration import objective as calibration_objective
    punctured = dict(TRUE, **{'regions[0].membrane.rupture_force_n': 1.0})   # 0.6 drops too little to detect
    spec = write_study(tmp_path, [3.0], MESH + sets(punctured), repeats=1)
    trials = load_trials(DataSpec.from_file(spec))
    scene = Scene.from_file(None, sets=MESH + sets(START))
    keys = [parse_fit(text) for text in FITS]
    objective = Objective(trials, scene, keys, workers=1)
    first = objective.evaluate([0.5, 0.5, 0.5])
    assert first.phases is None and first.comparisons[0].measured_punctures
    u = [keys[0].unit(18000.0), keys[1].unit(1.1), keys[2].unit(0.45)]
    partial = {phases: objective.evaluate(u, phases)
               for phases in (('loading',), 'events', ('inserted',), ('hold',))}
    whole = objective.evaluate(u)
    assert whole.phases is None and objective.best is not None and all(
        e.phases is None for e in (objective.best, first))          # a partial run is never the best
    steps = whole.results[0].steps
    for phases, evaluation in partial.items():
        share = evaluation.results[0].steps / steps
        print(f'{phases}: {share:.0%} of the whole run\'s steps')
        assert evaluation.phases == phases and share < 0.9
        np.testing.assert_allclose(objective.stage_residuals(evaluation, phases),
                                   objective.stage_residuals(whole, phases), rtol=0, atol=1e-12)
    assert partial[('loading',)].results[0].steps < partial[('inserted',)].results[0].steps \
        < partial[('hold',)].results[0].steps
    monkeypatch.setattr(calibration_objective, 'HORIZON_MARGIN_S', -1.0)
    short = Objective(trials, scene, keys, workers=1)
    short.evaluate([0.5, 0.5, 0.5])
    rerun = short.evaluate(u, ('loading',))
    assert rerun.phases is None and rerun.results[0].steps == steps
    np.testing.assert_allclose(rerun.residuals, whole.residuals, rtol=0, atol=1e-12)


def test_a_diverging_or_refused_trial_scores_as_a_miss_and_the_search_goes_on(cheap_study, tmp_path):
    trials = load_trials(DataSpec.from_file(cheap_study))
    scene = Scene.from_file(None, sets=CHEAP_MESH + sets(START))
    refused = Objective(trials, scene, [parse_fit('regions[0].poisson_ratio=0.3:0.6')], workers=1).evaluate([1.0])
    strong_law = 'model.physical.mu_rate=1:300:log'          # an exponential law this strong diverges
    diverged = Objective(trials, scene, [parse_fit(strong_law)], workers=1).evaluate([1.0])
    for evaluation, reason in ((refused, 'poisson_ratio'), (diverged, 'diverged')):
        print(f'{reason}: {evaluation.failures[0][:110]}')
        assert evaluation.failures and reason in evaluation.failures[0]
        assert np.all(evaluation.residuals * np.sqrt(evaluation.residuals.size) == pytest.approx(FAILED_RESIDUAL))
        assert np.isfinite(evaluation.objective)
    report = calibration.main(data_spec=cheap_study, fits=[strong_law, 'regions[0].cutting_force_n=0.1:1.5'],
                              sets=CHEAP_MESH + sets(START), out=tmp_path / 'out', workers=2, max_evaluations=60,
                              global_search='de')
    assert any('failed and scored as misses' in w for w in report['warnings'])   # the global stage met them
    print(f"mu_rate {report['parameters']['model.physical.mu_rate']['value']:.4g} (true 4)")
    assert report['parameters']['model.physical.mu_rate']['value'] < 100
    assert report['fit']['nrmse_mean'] < 0.5 * report['fit']['nrmse_mean_start']
