"""Two force records on one time base (analysis/compare/alignment.py): a known shift found to a
fraction of a sample and kept within its bound; resampling linear inside and NaN outside."""

import numpy as np
import pytest

from support.force_curves import sample_times
from tissue_sim_ros.analysis.compare.alignment import best_time_shift, resample


def smooth_insertion_force(time_s):
    """A smooth insertion-like force: a softplus-squared rise, a 40 % fall over ~0.1 s, a pull."""
    rise = 0.004 * np.logaddexp(0, (time_s - 3) / 0.2) ** 2
    fall = 0.4 / (1 + np.exp(-(time_s - 8) / 0.05))
    return rise * (1 - fall) - 1 / (1 + np.exp(-(time_s - 12) / 0.1))


@pytest.mark.parametrize('shift_s', [0.1234, -0.0771, 0.0051, 0.3])
def test_a_known_shift_is_found_to_a_fraction_of_a_sample(shift_s):
    rng = np.random.default_rng(int(abs(shift_s) * 1e4))
    reference_time = sample_times(rng, 15.0, (88.0, 100.0))
    other_time = sample_times(rng, 15.0, (88.0, 100.0)) + 0.2
    sample_s = np.median(np.diff(reference_time))
    found = best_time_shift(reference_time, smooth_insertion_force(reference_time), other_time,
                            smooth_insertion_force(other_time - shift_s))
    assert abs(found - shift_s) < 0.05 * sample_s
    reference_noisy = (smooth_insertion_force(reference_time)
                       + rng.normal(0, 0.01, len(reference_time)))
    other_noisy = (smooth_insertion_force(other_time - shift_s)
                   + rng.normal(0, 0.01, len(other_time)))
    noisy = best_time_shift(reference_time, reference_noisy, other_time, other_noisy)
    assert abs(noisy - shift_s) < 0.3 * sample_s


def test_the_shift_stays_within_its_bound():
    time = np.arange(0.0, 15.0, 0.01)
    lagging = smooth_insertion_force(time - 0.8)
    assert abs(best_time_shift(time, smooth_insertion_force(time), time, lagging) - 0.5) < 1e-9
    assert best_time_shift(time, smooth_insertion_force(time), time, lagging,
                           max_shift_s=1.0) == pytest.approx(0.8, abs=1e-3)


def test_resample_is_linear_inside_and_nan_outside():
    time = np.array([0.0, 1.0, 3.0])
    values = np.array([0.0, 2.0, -2.0])
    out = resample(time, values, [-0.5, 0.5, 2.0, 3.0, 3.5])
    np.testing.assert_allclose(out[1:4], [1.0, 0.0, -2.0])
    assert np.isnan(out[0]) and np.isnan(out[4])
    with pytest.raises(ValueError, match=r'time_s\[2\] = 1.0 after 1.0'):
        resample([0.0, 1.0, 1.0], [0, 1, 2], [0.5])
