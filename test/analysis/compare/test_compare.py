"""tissue-sim compare: the simulator's own insertion, written out as a load-cell study in other
units, signs and time origin, with jittery sampling and noise, compares back to the same scene at
the noise level, and a perturbed scene scores clearly worse.

The truth: the noise added (its level sets the floor the repeats show: sigma sqrt(1 + 1/(n-1))
over the force range), the scene that made the data, and the puncture it put there."""

from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.analysis.compare import compare
from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.engine.scene.scene import Scene

# the tests' own tissue (the default scene's cutting and friction are calibrated, and move)
SETS = ['mesh.generator=box', 'mesh.divisions=[8,8,6]', 'regions[0].cutting_force_n=0.94',
        'regions[0].friction.insertion_coulomb_n_per_m=10.57']
NO_MEMBRANE = ['regions[0].membrane.criterion=none']   # cutting and friction: a smooth curve
NOISE_N = 0.005
REPEATS = 3


def write_study(directory: Path, sets, *, seed=1, force_delay_s=0.0):
    """Three repeats of one insertion (3 mm/s, 20 mm, 1 s hold, back) as a 6-axis-sensor-like
    CSV each: time in microseconds from a timer origin 12.3 s, 88-100 Hz jitter, the axial force
    in mN with the sensor's sign (negative while the tissue resists), stage position in mm,
    decreasing as the needle goes in, with an offset. The force can lag the motion by
    ``force_delay_s``. Returns the insertion that made them and the spec's path."""
    scene = Scene.from_file(None, sets=sets)
    run = run_insertion(scene, 0.003, 0.02, hold_s=1.0, tick=0.01)
    rng = np.random.default_rng(seed)
    directory.mkdir(parents=True, exist_ok=True)
    for repeat in range(1, REPEATS + 1):
        times = [0.0]
        while times[-1] < run.time[-1] - 0.02:
            times.append(times[-1] + rng.uniform(0.010, 0.0114))
        t = np.array(times)
        force = np.interp(t - force_delay_s, run.time, run.axial_force) + rng.normal(0.0, NOISE_N, len(t))
        travel = np.interp(t, run.time, run.travel)
        with open(directory / f'trial_3p0_{repeat}.csv', 'w') as handle:
            handle.write('time,fz,pz\n')
            for us, fz, pz in zip(np.round((t + 12.3) * 1e6).astype(np.int64), -1e3 * force,
                                  50.0 - 1e3 * travel):
                handle.write(f'{us},{fz:.4f},{pz:.5f}\n')
    spec = directory / 'spec.yaml'
    spec.write_text("files: ['trial_*.csv']\n"
                    'time: {column: time, unit: us}\n'
                    'force: {column: fz, unit: mN, sign: -1}\n'
                    'position: {column: pz, unit: mm, sign: -1}\n'
                    "file_name: {pattern: 'trial_(?P<speed>[0-9p]+)_(?P<repeat>[0-9]+)', speed_unit: mm/s}\n")
    return run, spec


def expected_floor(run) -> float:
    """Each repeat against the mean of the other n - 1: the difference has variance
    sigma^2 (1 + 1/(n-1)); over the trial's range (the noise widens it by about 2 sigma)."""
    return NOISE_N * np.sqrt(1.0 + 1.0 / (REPEATS - 1)) / (np.ptp(run.axial_force) + 2 * NOISE_N)


def test_a_study_compares_back_to_its_scene_at_the_noise_level_and_a_stiffer_one_worse(tmp_path):
    run, spec = write_study(tmp_path / 'data', SETS + NO_MEMBRANE)
    report = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, out=tmp_path / 'same', workers=1)
    summary = report['summary']
    assert summary['trials'] == REPEATS and summary['simulations'] == 1   # one per speed
    floor = summary['noise_floor_nrmse']
    assert floor == pytest.approx(expected_floor(run), rel=0.25)
    print(f'\nsame scene: model NRMSE {summary["nrmse_mean"]:.4f}, noise floor {floor:.4f} '
          f'(expected {expected_floor(run):.4f})')
    for trial in report['trials']:
        assert trial['speed_m_s'] == pytest.approx(0.003) and trial['repeat'] in (1, 2, 3)
        assert trial['nrmse'] <= 2.0 * floor                 # the noise, little else
        assert trial['r2'] > 0.99
        assert abs(trial['retraction_minimum_error_n']) < 0.05 * np.ptp(run.axial_force)
    stiffer = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE + ['regions[0].young_modulus_pa=32000'],
                           out=tmp_path / 'stiffer', workers=1)
    print(f'twice as stiff: model NRMSE {stiffer["summary"]["nrmse_mean"]:.4f}')
    assert stiffer['summary']['nrmse_mean'] > 5.0 * floor
    assert stiffer['summary']['noise_floor_nrmse'] == pytest.approx(floor)   # the data's, unchanged
    out = tmp_path / 'same'
    for name in ('compare.json', 'compare.md', 'compare.csv', 'compare.png', 'compare_time.png'):
        assert (out / name).stat().st_size > 200, name
    rows = np.genfromtxt(out / 'compare.csv', delimiter=',', names=True, dtype=None, encoding=None)
    assert len(rows) == sum(t['samples_compared'] for t in report['trials']) + \
        sum(1 for r in rows if r['simulated_n'] == '' or np.isnan(r['simulated_n']))


def test_the_first_puncture_compares_back_to_its_depth_and_force(tmp_path):
    run, spec = write_study(tmp_path / 'data', SETS)
    event = run.puncture_events[0]
    report = compare.main(data_spec=spec, sets=SETS, out=tmp_path / 'out', workers=1)
    for trial in report['trials']:
        assert len(trial['measured_punctures']) >= 1 and len(trial['simulated_punctures']) >= 1
        assert abs(trial['first_puncture_depth_error_m']) < 0.0002
        assert abs(trial['first_puncture_force_error_n']) < 0.05 * event['axial_force_n']


def test_every_sample_of_every_repeat_is_reached_by_its_speeds_simulation(tmp_path):
    """One simulation per speed follows its median repeat; the others are compared with it on the
    clock of their own contact. With jittered sampling, and one repeat recorded 0.3 s longer (the
    needle out, the sensor still logging), every sample from contact on has a simulated force:
    a sample left out is a miss the calibration would score whatever the parameters."""
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    run, spec = write_study(tmp_path / 'data', SETS + NO_MEMBRANE)
    longer = tmp_path / 'data' / 'trial_3p0_3.csv'      # not the median repeat the simulation follows
    rows = np.loadtxt(longer, delimiter=',', skiprows=1)
    extra = rows[-1] + np.outer(np.arange(1, 31), [1e4, 0.0, 0.0])     # 30 more samples at 100 Hz
    extra[:, 1] = np.random.default_rng(3).normal(0.0, 1e3 * NOISE_N, 30)
    with open(longer, 'a') as handle:
        for us, fz, pz in extra:
            handle.write(f'{int(us)},{fz:.4f},{pz:.5f}\n')
    trials = load_trials(DataSpec.from_file(spec))
    assert len({len(t.axial_force_n) for t in trials}) > 1
    compared = compare.compare_trials(trials, Scene.from_file(None, sets=SETS + NO_MEMBRANE), workers=1,
                                      quiet=True)
    for c in compared['comparisons']:
        after_contact = c.time_since_contact_s >= 0.0
        assert np.isfinite(c.simulated_n[after_contact]).all(), (c.file, np.flatnonzero(~np.isfinite(c.simulated_n)))


def test_files_with_column_options_read_as_the_description_does(tmp_path):
    run, spec = write_study(tmp_path / 'data', SETS + NO_MEMBRANE)
    by_spec = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, out=tmp_path / 'a', workers=1)
    options = {'time.column': 'time', 'time.unit': 'us', 'force.column': 'fz', 'force.unit': 'mN',
               'force.sign': -1, 'position.column': 'pz', 'position.unit': 'mm', 'position.sign': -1,
               'file_name.pattern': 'trial_(?P<speed>[0-9p]+)_(?P<repeat>[0-9]+)'}
    files = sorted((tmp_path / 'data').glob('trial_*.csv'))
    by_options = compare.main(files=files, options=options, sets=SETS + NO_MEMBRANE,
                              out=tmp_path / 'b', workers=1)
    assert [t['nrmse'] for t in by_options['trials']] == [t['nrmse'] for t in by_spec['trials']]


def test_a_second_run_resumes_from_the_simulations_it_kept(tmp_path):
    run, spec = write_study(tmp_path / 'data', SETS + NO_MEMBRANE)
    first = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, out=tmp_path / 'out', workers=1)
    kept = sorted((tmp_path / 'out' / 'simulations').glob('*.npz'))
    stamps = [p.stat().st_mtime_ns for p in kept]
    second = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, out=tmp_path / 'out', workers=1)
    assert len(kept) == 1 and [p.stat().st_mtime_ns for p in kept] == stamps   # not run again
    assert [t['nrmse'] for t in second['trials']] == [t['nrmse'] for t in first['trials']]


def test_xcorr_and_depth_alignments_of_a_force_that_lags_the_motion(tmp_path):
    """The sensor's force lags the stage's position by 0.12 s. Aligned at contact (found in the
    force on both sides) the insertion agrees and the hold and retraction come 0.12 s apart;
    xcorr shifts the simulation by the lag of best correlation, between 0 and 0.12 s (negative:
    the simulation leads the lagging data), and fits better; the depth alignment compares the
    insertion only, as force against depth."""
    run, spec = write_study(tmp_path / 'data', SETS + NO_MEMBRANE, force_delay_s=0.12)
    contact = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, out=tmp_path / 'c', workers=1)
    xcorr = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, align='xcorr', out=tmp_path / 'x', workers=1)
    for by_contact, by_xcorr in zip(contact['trials'], xcorr['trials']):
        assert -0.13 <= by_xcorr['time_shift_s'] < 0.0
        assert by_xcorr['nrmse'] < by_contact['nrmse']
    depth = compare.main(data_spec=spec, sets=SETS + NO_MEMBRANE, align='depth', out=tmp_path / 'd', workers=1)
    for trial in depth['trials']:
        compared = {phase for phase, e in trial['phases'].items() if e['count']}
        assert compared <= {'approach', 'loading', 'inserted'} and trial['nrmse'] < 0.05
