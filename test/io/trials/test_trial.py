"""One measured insertion in SI (io/trials/trial.py) and the checks every importer shares: the
derived times and rate against the arrays the test builds, and each refusal naming the sample."""
import numpy as np
import pytest

from tissue_sim_ros.errors import DataError
from tissue_sim_ros.io.trials.trial import Trial, check_increasing_time, drop_nonfinite_rows


def test_times_duration_and_the_median_rate_of_a_jittered_recording_with_a_gap():
    rng = np.random.default_rng(4)
    steps = 0.01 + rng.uniform(-1e-4, 1e-4, 300)               # 100 Hz with jitter...
    steps[150] = 0.5                                           # ...and one gap
    time_s = 12.0 + np.concatenate([[0.0], np.cumsum(steps)])
    trial = Trial('t.csv', time_s, np.zeros(301), travel_m=np.zeros(301))
    assert trial.n_samples == 301
    np.testing.assert_allclose(trial.time_from_start_s, time_s - 12.0, rtol=0, atol=1e-12)
    assert trial.duration_s == pytest.approx(steps.sum(), rel=1e-12)
    assert trial.sample_rate_hz == pytest.approx(1.0 / np.median(steps), rel=1e-12)
    assert 99.0 < trial.sample_rate_hz < 101.0                 # the gap does not pull it down


@pytest.mark.parametrize('name, value, words', [
    ('axial_force_n', np.zeros(4), ['axial_force_n has shape (4,)', 'expected (3,)']),
    ('force_n', np.zeros((3, 2)), ['force_n has shape (3, 2)', 'expected (3, 3)']),
])
def test_columns_of_another_length_are_refused_by_name(name, value, words):
    columns = {'axial_force_n': np.zeros(3), name: value}
    with pytest.raises(DataError) as caught:
        Trial('t.csv', np.arange(3.0), **columns)
    assert all(word in str(caught.value) for word in words) and caught.value.file == 't.csv'


def test_time_that_repeats_or_goes_backwards_is_refused_at_its_row():
    rows = np.array([10, 11, 12, 13])                          # the file's lines
    check_increasing_time('f.csv', np.array([0.0, 0.1, 0.2, 0.3]), rows, 'time')
    with pytest.raises(DataError, match=r"f\.csv, column 'time', row 12: time repeats: .*0\.1.* after .*\(row 11\)"):
        check_increasing_time('f.csv', np.array([0.0, 0.1, 0.1, 0.3]), rows, 'time')
    with pytest.raises(DataError, match=r'row 13: time goes backwards: .*0\.15.* after .*0\.2') as caught:
        check_increasing_time('f.csv', np.array([0.0, 0.1, 0.2, 0.15]), rows, 'time')
    assert caught.value.row == 13
    with pytest.raises(DataError, match='1 sample'):
        Trial('t.csv', np.array([0.0]), np.array([1.0]))


def test_rows_with_nan_inf_or_empty_cells_are_refused_or_left_out():
    rows = np.arange(2, 8)                                     # 1-based lines after a header
    force = np.array([0.1, np.nan, 0.3, 0.4, 0.5, 0.6])
    torque = np.ones((6, 3))
    torque[4, 1] = np.inf
    torque[0, 2] = np.nan
    keep = drop_nonfinite_rows('f.csv', {'force': force, 'torque': torque}, rows, drop=True)
    np.testing.assert_array_equal(keep, np.isfinite(force) & np.isfinite(torque).all(axis=1))
    with pytest.raises(DataError) as caught:
        drop_nonfinite_rows('f.csv', {'force': force, 'torque': torque}, rows, drop=False)
    assert '3 row(s)' in str(caught.value) and (caught.value.column, caught.value.row) == ('torque', 2)
    assert drop_nonfinite_rows('f.csv', {'force': np.ones(6)}, rows, drop=False).all()
