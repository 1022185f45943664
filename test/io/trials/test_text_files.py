"""Importing text recordings (io/trials/text_files.py) into Trials in SI, checked against the arrays
the synthetic files were written from, in other units, signs, time origins and separators; each
bad file against the error it must get."""

import numpy as np
import pytest

from tissue_sim_ros.errors import DataError, DataSpecError
from tissue_sim_ros.io.trials.text_files import read_text_trial

# Independent definitions: standard gravity, the avoirdupois pound, the inch.
G0 = 9.80665
LBF_N = 0.45359237 * G0


def known_insertion(n_samples=700, seed=3):
    """Sample times with 88-100 Hz jitter (whole microseconds from a timer that started at
    12.345678 s), travel [m] (2 mm/s to 10 mm, hold, retract), an axial force [N] that rises,
    drops at a puncture and goes negative in retraction, lateral forces and torques."""
    rng = np.random.default_rng(seed)
    steps_us = rng.integers(10_000, 11_364, n_samples - 1)
    time_us = 12_345_678 + np.concatenate([[0], np.cumsum(steps_us)])
    time_s = (time_us - time_us[0]) * 1e-6
    travel_m = np.clip(np.minimum(0.002 * time_s, 0.010 - 0.002 * (time_s - 4.5 - 1.5)), 0, 0.010)
    axial_n = 40 * travel_m + 0.3 * np.sin(3 * time_s) - 0.5 * (time_s > 3.5)
    axial_n[time_s > 6.0] = -0.2 - 20 * travel_m[time_s > 6.0]
    lateral_n = rng.normal(0, 0.05, (n_samples, 2))
    torque_nm = rng.normal(0, 2e-3, (n_samples, 3))
    return time_us, travel_m, axial_n, lateral_n, torque_nm


def write_table(path, header, columns, delimiter=',', preamble=()):
    """A text file: preamble lines, a header (None: none), then one row per sample."""
    lines = list(preamble)
    if header is not None:
        lines.append(delimiter.join(header))
    lines += [delimiter.join(f'{value!r}' for value in row)
              for row in zip(*[np.asarray(c).tolist() for c in columns])]
    path.write_text('\n'.join(lines) + '\n')
    return path


def test_six_axis_csv_in_microseconds_millinewtons_and_millimetres(tmp_path):
    time_us, travel_m, axial_n, lateral_n, torque_nm = known_insertion()
    stage_mm = 3.7 - 1e3 * travel_m  # the stage moves toward -z while inserting
    path = write_table(tmp_path / 'trial.csv', 'time,fx,fy,fz,tx,ty,tz,px,py,pz'.split(','), [
        time_us, 1e3 * lateral_n[:, 0], 1e3 * lateral_n[:, 1], -1e3 * axial_n,
        *(1e3 * torque_nm.T), np.zeros_like(time_us), np.zeros_like(time_us), stage_mm],
        preamble=['# exported by the rig logger', '# force in mN'])
    trial = read_text_trial(path, time={'column': 'time', 'unit': 'us'},
                            force={'column': 'fz', 'unit': 'mN', 'sign': -1},
                            torque={'columns': ['tx', 'ty', 'tz'], 'unit': 'N mm'},
                            position={'column': 'pz', 'unit': 'mm', 'sign': -1})
    np.testing.assert_allclose(trial.time_s, time_us * 1e-6, rtol=1e-15)  # origin kept
    np.testing.assert_allclose(trial.time_from_start_s, (time_us - time_us[0]) * 1e-6,
                               atol=1e-12)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(trial.travel_m, travel_m, atol=1e-15)
    np.testing.assert_allclose(trial.torque_nm, torque_nm, rtol=1e-12, atol=1e-18)
    assert trial.force_n is None and trial.nan_rows_dropped == 0
    assert trial.axial_force_n.min() < 0 < trial.axial_force_n.max()  # retraction stays negative
    assert trial.sample_rate_hz == pytest.approx(1e6 / np.median(np.diff(time_us)))
    assert 88 <= trial.sample_rate_hz <= 100
    assert trial.duration_s == pytest.approx((time_us[-1] - time_us[0]) * 1e-6)


@pytest.mark.parametrize('reduce, direction', [('norm', None), ('projection', [0.0, 3.0, -4.0])])
def test_three_force_columns_reduced_like_numpy(tmp_path, reduce, direction):
    time_us, _, axial_n, lateral_n, _ = known_insertion(200)
    force_n = np.column_stack([lateral_n, axial_n])
    path = write_table(tmp_path / 'f.csv', ['t', 'Fx', 'Fy', 'Fz'],
                       [time_us * 1e-3, *(force_n / LBF_N).T])
    trial = read_text_trial(path, time={'column': 't', 'unit': 'ms'},
                            force={'columns': ['fx', 'fy', 'fz'], 'unit': 'lbf',
                                   'reduce': reduce, 'direction': direction})
    expected = (np.linalg.norm(force_n, axis=1) if reduce == 'norm'
                else force_n @ np.array([0.0, 0.6, -0.8]))
    np.testing.assert_allclose(trial.axial_force_n, expected, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(trial.force_n, force_n, rtol=1e-12, atol=1e-15)


def test_headerless_tsv_by_index_with_a_sample_rate(tmp_path):
    _, travel_m, axial_n, _, _ = known_insertion(300)
    path = write_table(tmp_path / 'rig.tsv', None,
                       [np.arange(300), axial_n / (1e-3 * G0), travel_m * 1e6], delimiter='\t')
    trial = read_text_trial(path, time={'rate_hz': 500}, force={'column': 1, 'unit': 'gf'},
                            position={'column': 2, 'unit': 'um'})
    np.testing.assert_allclose(trial.time_s, np.arange(300) / 500.0, rtol=1e-15)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(trial.travel_m, travel_m, atol=1e-15)


def test_whitespace_file_with_preamble_comments_and_blank_lines(tmp_path):
    time_us, _, axial_n, _, _ = known_insertion(50)
    rows = [f'{t!r}   {f!r}' for t, f in zip((time_us * 1e-9).tolist(), (axial_n / G0).tolist())]
    rows[10:10] = ['  # operator paused the logger', '']
    path = tmp_path / 'rig.dat'
    path.write_text('Rig 3 export\nsample rate 100 Hz\nTime  Force\n' + '\n'.join(rows) + '\n')
    trial = read_text_trial(path, time={'column': 'time', 'unit': 's'},
                            force={'column': 'FORCE', 'unit': 'kgf'},
                            text_format={'skip_rows': 2})
    np.testing.assert_allclose(trial.time_s, time_us * 1e-9, rtol=1e-15)
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-12, atol=1e-15)


def test_semicolon_file_matches_names_ignoring_case_and_spaces(tmp_path):
    time_us, _, axial_n, _, _ = known_insertion(40)
    path = write_table(tmp_path / 'eu.csv', [' Time (ms) ', ' Force (N) '],
                       [time_us * 1e-3, axial_n], delimiter=';')
    trial = read_text_trial(path, time={'column': 'TIME (MS)', 'unit': 'ms'},
                            force={'column': 'force (n)'})
    np.testing.assert_allclose(trial.axial_force_n, axial_n, rtol=1e-15)
    np.testing.assert_allclose(trial.time_s, time_us * 1e-6, rtol=1e-15)


TIME_US = {'column': 'time', 'unit': 'us'}
FORCE = {'column': 'fz'}


def read_lines(tmp_path, text, name='bad.csv', **options):
    path = tmp_path / name
    path.write_text(text)
    return path, lambda: read_text_trial(path, **{'time': TIME_US, 'force': FORCE, **options})


def assert_data_error(read, path, column, row, *words):
    with pytest.raises(DataError) as err:
        read()
    message = str(err.value)
    assert (err.value.file, err.value.column, err.value.row) == (str(path), column, row)
    assert str(path) in message
    assert column is None or repr(column) in message
    assert row is None or f'row {row}' in message
    assert all(word in message for word in words), message
    return message


def test_missing_column_lists_the_columns(tmp_path):
    path, read = read_lines(tmp_path, 'time,fx,fy\n0,1,2\n1,1,2\n')
    assert_data_error(read, path, 'fz', None, 'time, fx, fy')


def test_column_name_without_header_asks_for_an_index(tmp_path):
    path, read = read_lines(tmp_path, '0,1\n1,2\n')
    assert_data_error(read, path, 'time', None, 'no header', '0 to 1')


def test_index_out_of_range(tmp_path):
    path, read = read_lines(tmp_path, '0,1\n1,2\n', time={'column': 0}, force={'column': 5})
    assert_data_error(read, path, 5, None, '2 columns')


def test_cell_that_is_not_a_number(tmp_path):
    path, read = read_lines(tmp_path, '# comment\ntime,fz\n0,1.0\n10,"1,5"\n20,2.0\n')
    assert_data_error(read, path, 'fz', 4, "'1,5'")  # a decimal comma, quoted, is text


def test_time_going_backwards_names_the_row(tmp_path):
    path, read = read_lines(tmp_path, 'time,fz\n0,1\n10,1\n30,1\n20,1\n40,1\n')
    assert_data_error(read, path, 'time', 5, 'backwards', 'row 4')


def test_repeated_time_names_the_row(tmp_path):
    path, read = read_lines(tmp_path, 'time,fz\n0,1\n10,1\n10,2\n')
    assert_data_error(read, path, 'time', 4, 'repeats')


def test_nan_rows_refused_by_default_naming_the_first(tmp_path):
    text = 'time,fx,fz\n0,0,1\n10,0,2\n20,nan,3\n30,0,\n40,0,5\n50,0,6\n60,0\n'
    path, read = read_lines(tmp_path, text, force={'columns': ['fx', 'fx', 'fz']})
    assert_data_error(read, path, 'fx', 4, '3 row(s)', 'drop_nan_rows')


def test_nan_rows_dropped_and_counted_when_asked(tmp_path):
    text = 'time,fz,pz\n0,1,0\n10,2,1\n20,nan,2\n30,,3\n40,5,inf\n50,6,5\n60,7\n'
    path = tmp_path / 'nan.csv'
    path.write_text(text)
    trial = read_text_trial(path, time=TIME_US, force=FORCE,
                            position={'column': 'pz', 'unit': 'mm'}, drop_nan_rows=True)
    assert trial.nan_rows_dropped == 4
    np.testing.assert_allclose(trial.time_s, [0, 10e-6, 50e-6])
    np.testing.assert_allclose(trial.axial_force_n, [1, 2, 6])
    np.testing.assert_allclose(trial.travel_m, [0, 1e-3, 5e-3])


@pytest.mark.parametrize('text, words', [
    ('', ['no data rows']), ('# only a comment\n\n', ['no data rows']),
    ('time,fz\n', ['no data rows after the header']), ('time,fz\n0,1\n', ['1 sample']),
])
def test_empty_and_single_sample_files(tmp_path, text, words):
    path, read = read_lines(tmp_path, text)
    message = assert_data_error(read, path, None, 1 if 'header' in words[0] else None, *words)
    assert str(path) in message


def test_missing_file(tmp_path):
    path, read = read_lines(tmp_path, '')
    path.unlink()
    assert_data_error(read, path, None, None, 'cannot be read')


def test_unknown_unit_in_column_options_names_the_key(tmp_path):
    _, read = read_lines(tmp_path, 'time,fz\n0,1\n1,2\n', force={'column': 'fz', 'unit': 'lb'})
    with pytest.raises(DataSpecError, match=r"force\.unit: force unit 'lb' is not known; "
                                            r'known force units: N, mN, kN, gf, kgf, lbf, ozf'):
        read()
