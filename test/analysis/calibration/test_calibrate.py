"""tissue-sim calibrate (analysis/calibration/calibrate.py): data made by the simulator with known
parameters, plus noise, calibrated from a start 30-50 % off.

The truth: the parameters that made the data (they must come back), the noise added (the
held-out speed must be predicted at its level, and better than reusing the other speeds'
measurements), and the uninterrupted run (a resumed, pooled or Dask run must give its result)."""

import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from support.calibration import (CHEAP_FITS, CHEAP_MESH, FITS, MESH, NOISE_N, START, TRUE, cheap_run,
                                 sets, write_study)
from tissue_sim_ros.analysis.calibration import calibrate as calibration
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials


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
    saved = json.loads((tmp_path / 'out' / 'calibrate.json').read_text())
    assert saved['fit']['nrmse_mean'] == pytest.approx(report['fit']['nrmse_mean'])
    for name in ('calibrate.md', 'calibrate.csv', 'evaluations.jsonl', 'calibrate_held_out_3mm_s.png'):
        assert (tmp_path / 'out' / name).stat().st_size > 0


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
    assert 'Leave one speed out' in (tmp_path / 'out' / 'calibrate.md').read_text()
    assert (tmp_path / 'out' / 'calibrate.csv').read_text().count('left out') == 3


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
    assert done_before >= 4 and not (tmp_path / 'cut' / 'calibrate.json').exists()
    resumed = cheap_run(cheap_study, tmp_path / 'cut', workers=1)
    print(f'killed after {done_before} evaluations; resumed: '
          f"{resumed['simulations']} simulations run of {whole['simulations']}")
    assert resumed['simulations'] < whole['simulations']      # what it had done, it did not redo
    for key in whole['parameters']:
        assert resumed['parameters'][key]['value'] == whole['parameters'][key]['value']


def test_coarse_to_fine_finishes_on_the_scene_as_asked_and_says_whose_jacobian_the_errors_use(cheap_study, tmp_path):
    """Searched on a coarser mesh, the calibration still lands on the data's values (synthetic,
    known) once the fine finish has run on the scene as asked; the report names that Jacobian."""
    report = cheap_run(cheap_study, tmp_path / 'coarse', workers=2, coarse_sets=['mesh.divisions=[4,4,3]'])
    for key in ('regions[0].young_modulus_pa', 'regions[0].cutting_force_n'):
        print(key, report['parameters'][key]['value'], TRUE[key])
        assert report['parameters'][key]['value'] == pytest.approx(TRUE[key], rel=0.10)
    assert report['jacobian'] == "the scene as asked, before the fine finish's steps"
    assert 'before the fine finish' in (tmp_path / 'coarse' / 'calibrate.md').read_text()


@pytest.mark.parametrize('fit, says', [
    ('model.relaxation[0].relative_modulus=0.2:1.2', 'the relative moduli sum to 1.2'),
    ('model.relaxation[1].time_constant_s=0.5:5', 'model.relaxation[1]: the list has 1 entry'),
    ('regions[2].young_modulus_pa=1000:9000', 'regions[2]: the list has 2 entries'),
    ('regions[0].select.below_z_m=-0.01:0', "regions[0].select = 'all' has no below_z_m"),
])
def test_a_fit_key_that_cannot_be_applied_is_refused_before_any_simulation(tmp_path, fit, says, monkeypatch, capsys):
    """calibrate refuses the key naming it before the first evaluation: no simulation runs."""
    import yaml

    from support.scenes import TWO_LAYERS
    from tissue_sim_ros.analysis.compare import trial_simulation
    from tissue_sim_ros.analysis.synthetic_curves import layered_curve
    from tissue_sim_ros.cli import main
    from tissue_sim_ros.engine.scene.keys import set_key
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


def test_the_pause_relaxation_and_the_retraction_plateau_are_fitted_to_what_made_them(tmp_path):
    """Insert, pause 2 s, retract: data made with a known relaxation term (half the modulus relaxing
    with a 1 s time constant) and a constant retraction pull of 0.3 N, plus 5 mN of noise, at two
    speeds: at 2 mm/s an indentation that stops before the puncture (its pause is the tissue's
    own relaxation), at 3 mm/s an insertion through it (its retraction pulls on the inserted
    shaft); the calibration of those three keys from a start 50 % (the part), 100 % (the time)
    and 67 % (the pull) off brings them back.

    The tolerances are what the data tell apart, from the misfit sigma of the keys that made the
    data (the RMS of simulated less measured force over every compared sample: the 5 mN of noise
    and what the comparison's own steps add, the motion rebuilt from the sampled positions, the
    contact found in noisy data) and the largest fall dF of a pause (its first samples' median
    less its last ones'): a change that moves the force by less than 2 sigma at every sample is
    within that misfit. The pull adds to the retraction
    force one for one (``Friction.slip_force``): 2 sigma. The relaxing part g scales the fall (dF
    proportional to g): |dg| / g <= 2 sigma / dF. The time constant tau moves the fall
    dF exp(-t / tau) by at most dF (d tau / tau) / e (at t = tau): |d tau| / tau <= 2 e sigma / dF."""
    from tissue_sim_ros.analysis.compare.force_events import depth_bounds
    from tissue_sim_ros.analysis.synthetic_study import write_synthetic_study
    relaxing = {'model.relaxation': [{'relative_modulus': 0.5, 'time_constant_s': 1.0}]}
    truth = {'model.relaxation[0].relative_modulus': 0.5, 'model.relaxation[0].time_constant_s': 1.0,
             'regions[0].friction.retraction_constant_n': 0.3}
    start = {'model.relaxation[0].relative_modulus': 0.25, 'model.relaxation[0].time_constant_s': 2.0,
             'regions[0].friction.retraction_constant_n': 0.1}
    fits = ['model.relaxation[0].relative_modulus=0.05:0.9', 'model.relaxation[0].time_constant_s=0.2:5:log',
            'regions[0].friction.retraction_constant_n=0:1']
    scene = [text for text in CHEAP_MESH if 'membrane' not in text] + sets(TRUE) + sets(relaxing)
    for speed, travel, seed in ((2.0, 0.0105, 1), (3.0, 0.02, 2)):     # 1.5 mm into the tissue, then 11
        spec = write_synthetic_study(tmp_path / 'data', scene + sets(truth), [speed], travel_m=travel,
                                     hold_s=2.0, repeats=2, noise_n=NOISE_N, seed=seed)
    trials = load_trials(DataSpec.from_file(spec))
    falls = []
    for trial in trials:
        first, last = depth_bounds(trial.travel_m)
        pause = trial.axial_force_n[first:last + 1]
        falls.append(np.median(pause[:10]) - np.median(pause[-10:]))
    fall = float(np.max(falls))
    from tissue_sim_ros.analysis.calibration.objective import Objective
    from tissue_sim_ros.analysis.calibration.parameters import parse_fit
    keys = [parse_fit(text) for text in fits]
    made = Objective(trials, Scene.from_file(None, sets=scene + sets(start)), keys, workers=1)
    at_truth = made.evaluate([k.unit(truth[k.key]) for k in keys]).comparisons
    misfit = np.concatenate([(c.simulated_n - c.measured_n)[np.isfinite(c.simulated_n)] for c in at_truth])
    sigma = float(np.sqrt(np.mean(misfit ** 2)))
    t0 = time.perf_counter()
    report = calibration.main(data_spec=spec, fits=fits, sets=scene + sets(start), out=tmp_path / 'out',
                              max_evaluations=70, workers=2)
    tolerance = {'model.relaxation[0].relative_modulus': 2 * sigma / fall * 0.5,
                 'model.relaxation[0].time_constant_s': 2 * np.e * sigma / fall * 1.0,
                 'regions[0].friction.retraction_constant_n': 2 * sigma}
    print(f"the pauses fall {np.round(falls, 3)} N; misfit at the truth {sigma * 1e3:.1f} mN (noise "
          f"{NOISE_N * 1e3:g} mN); {report['evaluations']} evaluations in "
          f"{time.perf_counter() - t0:.1f} s; fit NRMSE {report['fit']['nrmse_mean']:.4f} "
          f"(start {report['fit']['nrmse_mean_start']:.4f})")
    assert len(trials) == 4 and fall > 10 * NOISE_N and NOISE_N < sigma < 3 * NOISE_N
    for key, value in truth.items():
        got = report['parameters'][key]['value']
        print(f'{key}: {got:.4g} (true {value:g}, start {start[key]:g}, within {tolerance[key]:.3g})')
    for key, value in truth.items():
        assert abs(start[key] - value) > tolerance[key]         # left at its start, it would fail
        assert abs(report['parameters'][key]['value'] - value) <= tolerance[key]
