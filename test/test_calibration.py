"""tissue-sim calibrate: data made by the simulator with known parameters, plus noise, calibrated
from a start 30-50 % off.

The truth: the parameters that made the data (they must come back), the noise added (the
held-out speed must be predicted at its level, and better than reusing the other speeds'
measured curves), and runs that must agree with each other (serial, process pool, Dask
LocalCluster; interrupted and resumed against uninterrupted).
"""
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.analysis.calibration import calibrate as calibration
from tissue_sim_ros.analysis.calibration.objective import FAILED_RESIDUAL, Objective
from tissue_sim_ros.analysis.calibration.parameters import parse_fit
from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials

# the tests' own tissue, not the default scene's calibrated values (they move when it is calibrated again)
TISSUE = ['regions[0].friction.insertion_coulomb_n_per_m=10.57']
MESH = ['mesh.generator=box', 'mesh.divisions=[8,8,6]'] + TISSUE
TRUE = {'regions[0].young_modulus_pa': 20000.0, 'regions[0].membrane.rupture_force_n': 0.6,
        'regions[0].cutting_force_n': 0.5}
START = {'regions[0].young_modulus_pa': 13000.0, 'regions[0].membrane.rupture_force_n': 0.85,
         'regions[0].cutting_force_n': 0.33}              # -35 %, +42 %, -34 %
FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].membrane.rupture_force_n=0.2:2',
        'regions[0].cutting_force_n=0.1:1.5']
NOISE_N = 0.005


def sets(values):
    return [f'{key}={value!r}' for key, value in values.items()]


def write_study(directory: Path, speeds_mm_s, scene_sets, *, travel_m=0.02, repeats=2, seed=1) -> Path:
    return write_synthetic_study(directory, scene_sets, speeds_mm_s, travel_m=travel_m, repeats=repeats,
                                 noise_n=NOISE_N, seed=seed)


def test_known_parameters_come_back_and_predict_a_held_out_speed_at_the_noise_level(tmp_path):
    fit_spec = write_study(tmp_path / 'fit', [2.0, 4.0], MESH + sets(TRUE))
    held_spec = write_study(tmp_path / 'held', [3.0], MESH + sets(TRUE), seed=2)
    t0 = time.perf_counter()
    report = calibration.main(data_spec=fit_spec, validate_spec=held_spec, fits=FITS, sets=MESH + sets(START),
                              out=tmp_path / 'out', workers=2)
    wall = time.perf_counter() - t0
    for key, truth in TRUE.items():
        value = report['parameters'][key]['value']
        print(f'{key}: {value:.5g} (true {truth:g}, start {START[key]:g}; '
              f"stderr {report['parameters'][key]['stderr']:.2g})")
        assert value == pytest.approx(truth, rel=0.10)
    held = report['validation']['speeds'][0]
    print(f"held-out 3 mm/s: NRMSE {held['nrmse_calibrated']:.4f} (start {held['nrmse_start']:.4f}), noise floor "
          f"{held['noise_floor_nrmse']:.4f}, nearest speed's data {held['nearest_speed_nrmse']:.4f}; "
          f"{report['evaluations']} evaluations in {wall:.0f} s")
    assert held['nrmse_calibrated'] < 1.5 * held['noise_floor_nrmse']
    assert held['nrmse_calibrated'] < held['nearest_speed_nrmse']
    assert held['nrmse_start'] > 5 * held['noise_floor_nrmse']       # the start was far off
    # the outputs: a scene every command accepts, that reproduces the fit
    calibrated = Scene.from_file(tmp_path / 'out' / 'calibrated.yaml')
    for key, entry in report['parameters'].items():
        from tissue_sim_ros.analysis.calibration.parameters import read_key
        assert read_key(calibrated.spec, key) == pytest.approx(entry['value'], rel=1e-9)
    saved = json.loads((tmp_path / 'out' / 'report.json').read_text())
    assert saved['fit']['nrmse_mean'] == pytest.approx(report['fit']['nrmse_mean'])
    for name in ('report.md', 'calibration.csv', 'evaluations.jsonl', 'calibration_held_out_3mm_s.png'):
        assert (tmp_path / 'out' / name).stat().st_size > 0


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
    insertion) stops each simulation after the last sample of those phases (plus its margin);
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
    partial = {phases: objective.evaluate(u, phases) for phases in (('loading',), 'events', ('inserted',))}
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
    assert partial[('loading',)].results[0].steps < partial[('inserted',)].results[0].steps
    monkeypatch.setattr(calibration_objective, 'HORIZON_MARGIN_S', -1.0)
    short = Objective(trials, scene, keys, workers=1)
    short.evaluate([0.5, 0.5, 0.5])
    rerun = short.evaluate(u, ('loading',))
    assert rerun.phases is None and rerun.results[0].steps == steps
    np.testing.assert_allclose(rerun.residuals, whole.residuals, rtol=0, atol=1e-12)


CHEAP_MESH = ['mesh.generator=box', 'mesh.divisions=[6,6,5]', 'regions[0].membrane.criterion=none'] + TISSUE
CHEAP_FITS = ['regions[0].young_modulus_pa=5000:50000:log', 'regions[0].cutting_force_n=0.1:1.5']


@pytest.fixture(scope='module')
def cheap_study(tmp_path_factory):
    directory = tmp_path_factory.mktemp('cheap')
    return write_study(directory, [3.0], CHEAP_MESH + sets(TRUE), travel_m=0.012, repeats=1)


def cheap_run(spec, out, **options):
    return calibration.main(data_spec=spec, fits=CHEAP_FITS, sets=CHEAP_MESH + sets(START), out=out,
                            max_evaluations=40, **options)


def test_leave_one_speed_out_predicts_each_speed_from_the_others_at_the_noise_level(tmp_path):
    """Three speeds of data made with known keys: each fold calibrates on the two other speeds
    and predicts the third; with the keys that made the data recoverable, every prediction is
    within about twice the data's own noise (5 mN over a force range of 0.55 N: NRMSE 0.009) and
    each fold's values are the truth's within 10 %. The report's cross-validation is each fold's held-out row.
    The start is stiffer than the truth: a softer one would run stiffer trials at a raised mass
    scaling (the affordable-stiffness rule), not the data's, and fit around that difference."""
    spec = write_study(tmp_path / 'data', [2.0, 3.0, 4.0], CHEAP_MESH + sets(TRUE), travel_m=0.012, repeats=1)
    stiff_start = dict(START, **{'regions[0].young_modulus_pa': 27000.0})            # +35 %
    report = calibration.main(data_spec=spec, fits=CHEAP_FITS, sets=CHEAP_MESH + sets(stiff_start), out=tmp_path / 'out',
                              leave_one_speed_out=True, max_evaluations=40, workers=2)
    folds = report['cross_validation']['speeds']
    assert [row['speed_m_s'] for row in folds] == [0.002, 0.003, 0.004]
    noise = max(NOISE_N / np.ptp(t.axial_force_n) for t in load_trials(DataSpec.from_file(spec)))
    for row in folds:
        fold = json.loads(Path(row['report']).read_text())
        print(f"without {row['speed_m_s'] * 1e3:g} mm/s: predicted at NRMSE {row['nrmse_calibrated']:.4f} "
              f"(start {row['nrmse_start']:.4f}); {row['parameters']}")
        assert fold['validation']['speeds'][0]['nrmse_calibrated'] == row['nrmse_calibrated']
        assert [r['speed_m_s'] for r in fold['fit']['speeds']] == [s for s in (0.002, 0.003, 0.004)
                                                                   if s != row['speed_m_s']]
        assert row['nrmse_calibrated'] < 2.2 * noise < 0.05 < row['nrmse_start']
        for key, value in row['parameters'].items():
            assert value == pytest.approx(TRUE[key], rel=0.10)
    assert report['cross_validation']['nrmse_mean'] == pytest.approx(np.mean([r['nrmse_calibrated'] for r in folds]))
    assert 'Leave one speed out' in (tmp_path / 'out' / 'report.md').read_text()
    assert (tmp_path / 'out' / 'calibration.csv').read_text().count('left out') == 3


def test_leave_one_speed_out_refuses_data_it_cannot_split(cheap_study, tmp_path):
    with pytest.raises(ValueError, match='1 speed'):
        cheap_run(cheap_study, tmp_path / 'one', leave_one_speed_out=True)
    with pytest.raises(ValueError, match='give one'):
        cheap_run(cheap_study, tmp_path / 'both', leave_one_speed_out=True, validate_spec=cheap_study)


def test_serial_process_pool_and_dask_give_one_result(cheap_study, tmp_path):
    distributed = pytest.importorskip('distributed')
    serial = cheap_run(cheap_study, tmp_path / 'serial', workers=1)
    pool = cheap_run(cheap_study, tmp_path / 'pool', workers=2)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        dask = cheap_run(cheap_study, tmp_path / 'dask', scheduler=client)
    for key in serial['parameters']:
        values = [r['parameters'][key]['value'] for r in (serial, pool, dask)]
        print(f'{key}: serial {values[0]!r}, pool {values[1]!r}, dask {values[2]!r}')
        # equal to rounding: a pool worker starts with NUMBA_NUM_THREADS=1, which changes how
        # numba chunks a parallel reduction (the last digits of a sum), not the search
        assert values[1] == pytest.approx(values[0], rel=1e-9)
        assert values[2] == pytest.approx(values[0], rel=1e-9)
    assert pool['evaluations'] == serial['evaluations'] == dask['evaluations']


def test_an_interrupted_calibration_resumes_to_the_uninterrupted_result(cheap_study, tmp_path):
    whole = cheap_run(cheap_study, tmp_path / 'whole', workers=1)
    command = [sys.executable, '-m', 'tissue_sim_ros.cli', 'calibrate', '--data-spec', str(cheap_study),
               '--max-evaluations', '40', '--jobs', '1', '--out', str(tmp_path / 'cut')]
    for text in CHEAP_MESH + sets(START):
        command += ['--set', text]
    for text in CHEAP_FITS:
        command += ['--fit', text]
    process = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    log = tmp_path / 'cut' / 'evaluations.jsonl'
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and (not log.exists() or len(log.read_text().splitlines()) < 4):
        time.sleep(0.2)
    process.kill()                                             # a hard stop mid-search
    process.wait()
    done_before = len(log.read_text().splitlines())
    assert done_before >= 4 and not (tmp_path / 'cut' / 'report.json').exists()
    resumed = cheap_run(cheap_study, tmp_path / 'cut', workers=1)
    print(f'killed after {done_before} evaluations; resumed: '
          f"{resumed['simulations']} simulations run of {whole['simulations']}")
    assert resumed['simulations'] < whole['simulations']      # what it had done, it did not redo
    for key in whole['parameters']:
        assert resumed['parameters'][key]['value'] == whole['parameters'][key]['value']


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
                              sets=CHEAP_MESH + sets(START), out=tmp_path / 'out', workers=2, max_evaluations=40)
    assert any('failed and scored as misses' in w for w in report['warnings'])   # the scan met them
    print(f"mu_rate {report['parameters']['model.physical.mu_rate']['value']:.4g} (true 4)")
    assert report['parameters']['model.physical.mu_rate']['value'] < 100
    assert report['fit']['nrmse_mean'] < 0.5 * report['fit']['nrmse_mean_start']


@pytest.mark.parametrize('fit, says', [
    ('regions[0].young_modulus_pa', 'expected KEY=LOW:HIGH'),
    ('regions[0].young_modulus_pa=50000:5000', 'LOW < HIGH'),
    ('regions[0].young_modulus_pa=0:5000:log', 'log scale needs LOW > 0'),
    ('regions[0].young_modulus_pa=a:5000', "'a'"),
    ('regions[0].stiffness=1:2', 'unknown scene key regions[0].stiffness'),
    ('regions[0].poisson_ratio=0.3:0.6', 'regions[0].poisson_ratio = 0.6'),
    ('model.geometric=0:1', 'is not a number'),
])
def test_a_bad_fit_option_is_one_error_line_naming_it(cheap_study, tmp_path, capsys, fit, says):
    from tissue_sim_ros.cli import main
    status = main(['calibrate', '--data-spec', str(cheap_study), '--fit', fit, '--out', str(tmp_path)])
    error = capsys.readouterr().err.strip().splitlines()[-1]
    print(error)
    assert status == 2 and error.startswith('tissue-sim calibrate: error:') and says in error


@pytest.mark.parametrize('value', [0.0, 1e-10, 2.5e-7, 1e20, 12345.678])
def test_a_fitted_value_reaches_the_scene_as_the_same_number(value):
    """A fitted value is set by its key path as a number (YAML 1.1 would read 1e-10 as text)."""
    from tissue_sim_ros.engine.scene.checks import apply_schema
    from tissue_sim_ros.engine.scene.keys import get_key, set_key
    from tissue_sim_ros.engine.scene.schema import SCHEMA
    key = 'regions[0].friction.retraction_constant_n'
    spec = apply_schema('', set_key({}, key, value), SCHEMA)
    assert get_key(spec, key) == value


def test_coarse_to_fine_finishes_on_the_scene_as_asked_and_says_whose_jacobian_the_errors_use(cheap_study, tmp_path):
    """Searched on a coarser mesh, the calibration still lands on the data's values (synthetic,
    known) once the fine finish has run on the scene as asked; the report names that Jacobian."""
    report = cheap_run(cheap_study, tmp_path / 'coarse', workers=2, coarse_sets=['mesh.divisions=[4,4,3]'])
    for key in ('regions[0].young_modulus_pa', 'regions[0].cutting_force_n'):
        print(key, report['parameters'][key]['value'], TRUE[key])
        assert report['parameters'][key]['value'] == pytest.approx(TRUE[key], rel=0.10)
    assert report['jacobian'] == "the scene as asked, before the fine finish's steps"
    assert 'before the fine finish' in (tmp_path / 'coarse' / 'report.md').read_text()


def test_a_model_farther_from_a_speeds_data_than_another_speeds_data_is_named():
    """Fitted or held out, a speed whose calibrated NRMSE is above the nearest other speed's
    measured curve is named with both figures; one below it, or without a baseline, is not."""
    from tissue_sim_ros.analysis.calibration.report import _warnings
    fit = {'failed': [], 'finish': [], 'inertia': {'error_at_optimum': 0.01, 'bound': 0.02}}
    spread = {'correlated_pairs': [], 'insensitive': []}

    def row(role, speed, model, nearest):
        return {'role': role, 'speed_m_s': speed, 'nrmse_calibrated': model, 'nearest_speed_m_s': 0.002,
                'nearest_speed_nrmse': nearest}
    rows = [row('fit', 0.001, 0.0233, 0.0137), row('fit', 0.003, 0.0100, 0.0108),
            row('held out', 0.004, 0.05, 0.03), row('fit', 0.005, 0.02, None)]
    out = _warnings(fit, rows, spread)
    assert len(out) == 2
    assert out[0].startswith('fitted 1 mm/s') and '0.023' in out[0] and '0.014' in out[0]
    assert out[1].startswith('held-out 4 mm/s') and '0.050' in out[1] and '0.030' in out[1]
