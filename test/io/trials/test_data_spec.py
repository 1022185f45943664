"""A study described once (a YAML data description): globs, columns, units and signs, the speed
and repeat in the file names, the stage's motion, grouping by speed, and the refusals of a bad
description."""

import numpy as np
import pytest
import yaml

from tissue_sim_ros.errors import DataError, DataSpecError
from tissue_sim_ros.io.trials.data_spec import (DataSpec, file_name_labels, group_by_speed, load_trials,
                                                speed_from_text)
from tissue_sim_ros.io.trials.trial import Trial

PATTERN = r'sample_(?P<speed>\d+(?:[_p]\d+)?)_(?P<repeat>\d+)_(?P<date>\d{8})'
SPEC = {
    'files': ['raw/*.csv'],
    'time': {'column': 'time', 'unit': 'us'},
    'force': {'column': 'fz', 'unit': 'N', 'sign': -1},
    'torque': {'columns': ['tx', 'ty', 'tz'], 'unit': 'N mm'},
    'position': {'column': 'pz', 'unit': 'mm'},
    'file_name': {'pattern': PATTERN, 'speed_unit': 'mm/s'},
}


def write_study(root, speeds_text=('2_0', '2_0', '0p5', '10'), n_samples=50):
    """One CSV per trial: force = -(speed in mm/s + repeat + sample/1000) N, position = sample
    x 0.1 mm, time in us; returns {file name: (speed [m/s], repeat, axial force [N])}."""
    raw = root / 'raw'
    raw.mkdir(parents=True, exist_ok=True)
    truth = {}
    for repeat, speed_text in enumerate(speeds_text, start=1):
        speed_mm_s = float(speed_text.replace('_', '.').replace('p', '.'))
        axial = (speed_mm_s + repeat + np.arange(n_samples) / 1000.0).tolist()
        name = f'sample_{speed_text}_{repeat}_20240101.csv'
        rows = [f'{1000 * k + 7},0,0,{-f!r},1,2,3,0,0,{0.1 * k!r}' for k, f in enumerate(axial)]
        (raw / name).write_text('time,fx,fy,fz,tx,ty,tz,px,py,pz\n' + '\n'.join(rows) + '\n')
        truth[name] = (speed_mm_s * 1e-3, repeat, axial)
    return truth


def spec_file(root, spec):
    path = root / 'study.yaml'
    path.write_text(yaml.safe_dump(spec))
    return path


def test_a_study_loads_with_speed_repeat_labels_and_units(tmp_path):
    truth = write_study(tmp_path)
    trials = load_trials(spec_file(tmp_path, SPEC))
    assert [t.file for t in trials] == sorted(str(tmp_path / 'raw' / n) for n in truth)
    for trial in trials:
        speed_m_s, repeat, axial = truth[trial.file.rsplit('/', 1)[-1]]
        assert trial.speed_m_s == pytest.approx(speed_m_s, rel=1e-15)
        assert trial.repeat == repeat and trial.labels['date'] == '20240101'
        np.testing.assert_allclose(trial.axial_force_n, axial, rtol=1e-15)
        np.testing.assert_allclose(trial.time_s, (1000 * np.arange(50) + 7) * 1e-6, rtol=1e-15)
        np.testing.assert_allclose(trial.travel_m, 1e-4 * np.arange(50), atol=1e-16)
        np.testing.assert_allclose(trial.torque_nm, np.tile([1e-3, 2e-3, 3e-3], (50, 1)))
        assert trial.motion is None


def test_group_by_speed_gathers_repeats_slowest_first(tmp_path):
    write_study(tmp_path)
    groups = group_by_speed(load_trials(spec_file(tmp_path, SPEC)))
    assert list(groups) == [0.0005, 0.002, 0.01]
    assert [sorted(t.repeat for t in group) for group in groups.values()] == [[3], [1, 2], [4]]
    unknown = Trial(file='x', time_s=np.array([0.0, 1.0]), axial_force_n=np.zeros(2))
    assert list(group_by_speed([unknown, *groups[0.002]])) == [0.002, None]


def test_motion_speed_wins_over_the_file_name_and_is_in_si(tmp_path):
    write_study(tmp_path)
    spec = {**SPEC, 'position': None,
            'motion': {'speed_mm_s': 1.5, 'start_s': 1.0, 'travel_mm': 25.0, 'hold_s': 5.0,
                       'retract': True}}
    trials = load_trials(DataSpec.from_dict(spec, tmp_path))
    assert len(trials) == 4
    assert all(t.speed_m_s == pytest.approx(1.5e-3) and t.travel_m is None for t in trials)
    assert trials[0].motion == pytest.approx({'speed_m_s': 1.5e-3, 'start_s': 1.0,
                                              'travel_m': 0.025, 'hold_s': 5.0, 'retract': True})


def test_speed_from_the_file_name_reaches_the_motion(tmp_path):
    write_study(tmp_path, speeds_text=('0p5',))
    trial, = load_trials(DataSpec.from_dict({**SPEC, 'motion': {'travel_mm': 10}}, tmp_path))
    assert trial.motion['speed_m_s'] == pytest.approx(5e-4) == trial.speed_m_s
    assert trial.motion['travel_m'] == pytest.approx(0.010) and trial.motion['start_s'] is None


def test_no_file_name_pattern_and_no_motion_leave_speed_unknown(tmp_path):
    write_study(tmp_path, speeds_text=('2_0',))
    trial, = load_trials(DataSpec.from_dict({**SPEC, 'file_name': None}, tmp_path))
    assert (trial.speed_m_s, trial.repeat, trial.labels) == (None, None, {})


@pytest.mark.parametrize('text, number', [('2_0', 2.0), ('0p5', 0.5), ('12', 12.0),
                                          ('2_25', 2.25), ('0_05', 0.05)])
def test_numbers_in_file_names(text, number):
    assert speed_from_text(text, 'f.csv') == number


@pytest.mark.parametrize('text', ['2_0_5', '2p5p1', 'p', 'fast'])
def test_file_name_text_that_is_not_a_number(text):
    with pytest.raises(DataError, match=f"f.csv: {text!r} in the file name is not a number"):
        speed_from_text(text, 'f.csv')


def test_file_name_pattern_of_the_issue_example():
    labels, speed_m_s, repeat = file_name_labels(
        'data/sample_2_0_5_3_20240101.csv', r'sample_(?P<speed>\d+_\d+)_(?P<repeat>\d+)_')
    assert labels == {'speed': '2_0', 'repeat': '5'}
    assert speed_m_s == pytest.approx(2.0e-3) and repeat == 5
    _, speed_um, _ = file_name_labels('v250.csv', r'v(?P<speed>\d+)', speed_unit='um/s')
    assert speed_um == pytest.approx(250e-6)
    with pytest.raises(DataError, match=r'other\.csv: the file name does not match'):
        file_name_labels('other.csv', r'sample_(?P<speed>\d+)')


@pytest.mark.parametrize('change, words', [
    ({'force': {'colum': 'fz'}}, ['unknown key force.colum', 'column, columns, unit']),
    ({'forces': {}}, ['unknown key forces']),
    ({'time': {'column': 'time', 'rate_hz': 500}}, ['time: give exactly one of time.column or '
                                                     'time.rate_hz', 'given: column, rate_hz']),
    ({'force': {'columns': ['fx', 'fy', 'fz'], 'reduce': 'projection'}}, ['force.direction']),
    ({'force': {'columns': ['fx', 'fy']}}, ['force.columns', 'a list of 3 columns']),
    ({'force': {'column': 'fz', 'sign': 2}}, ['force.sign = 2', '+1 or -1']),
    ({'force': {'column': 'fz', 'direction': [0, 0, 0]}}, ['force.direction', 'not all 0']),
    ({'position': {'column': 'pz', 'unit': 'furlong'}},
     ["position.unit: position unit 'furlong' is not known", 'm, cm, mm, um, in']),
    ({'format': {'header': 'yes'}}, ['format.header', "'auto', True, False"]),
    ({'file_name': {'pattern': 'sample_(?P<speed'}}, ['file_name.pattern', 'regular expression']),
    ({'files': ['raw/*.txt']}, ["files: 'raw/*.txt' matches no file"]),
    ({'time': None}, ['time: required to read text files such as', 'sample_0p5_3_20240101.csv']),
    ({'files': []}, ['files = []', 'a non-empty list of file globs']),
    ({'files': None}, ['files: expected a non-empty list of file globs']),
])
def test_bad_descriptions_name_the_key(tmp_path, change, words):
    write_study(tmp_path)
    path = spec_file(tmp_path, {**SPEC, **change})
    with pytest.raises(DataSpecError) as err:
        DataSpec.from_file(path)
    assert str(err.value).startswith(f'{path}: ')
    assert all(word in str(err.value) for word in words), str(err.value)


def test_mcap_files_need_the_mcap_section(tmp_path):
    (tmp_path / 'run.mcap').write_bytes(b'')
    with pytest.raises(DataSpecError, match='mcap.wrench_topic: required to read MCAP files'):
        DataSpec.from_dict({'files': ['*.mcap']}, tmp_path)


def test_invalid_yaml_names_the_file(tmp_path):
    path = tmp_path / 'study.yaml'
    path.write_text('files: [raw/*.csv\n')
    with pytest.raises(DataSpecError, match=f'{path}: not valid YAML'):
        DataSpec.from_file(path)


def test_a_command_line_description_with_absolute_files_and_indices(tmp_path):
    """What a command line that passes files and column options builds: no spec file."""
    truth = write_study(tmp_path / 'elsewhere', speeds_text=('2_0',))
    name, = truth
    spec = DataSpec.from_dict({'files': [str(tmp_path / 'elsewhere' / 'raw' / name)],
                               'time': {'rate_hz': 1000}, 'force': {'column': 3, 'sign': -1}},
                              base_dir=tmp_path / 'cwd')
    trial, = load_trials(spec)
    np.testing.assert_allclose(trial.axial_force_n, truth[name][2], rtol=1e-15)
    np.testing.assert_allclose(trial.time_s, np.arange(50) / 1000.0, rtol=1e-15)
