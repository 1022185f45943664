"""Curve and event errors per phase (analysis/compare/force_metrics.py), against error formulas
worked by hand on curves whose difference is known."""

import numpy as np
import pytest

from tissue_sim_ros.analysis.compare.force_events import Puncture
from tissue_sim_ros.analysis.compare.force_metrics import (curve_errors, event_errors, peak_force,
                                                           per_phase_errors, retraction_minimum)


def test_a_constant_offset_gives_its_size_and_r2_by_hand():
    measured = np.sin(np.linspace(0, 3, 200)) * 2.0
    offset = 0.3
    errors = curve_errors(measured, measured + offset)
    by_hand_r2 = 1 - len(measured) * offset ** 2 / np.sum((measured - measured.mean()) ** 2)
    assert errors['rmse_n'] == pytest.approx(offset)
    assert errors['normaliser_n'] == pytest.approx(measured.max() - measured.min())
    assert errors['nrmse'] == pytest.approx(offset / (measured.max() - measured.min()))
    assert errors['r2'] == pytest.approx(by_hand_r2)
    assert errors['bias_n'] == pytest.approx(offset)
    assert errors['max_abs_error_n'] == pytest.approx(offset)
    assert errors['count'] == 200 and errors['ignored'] == 0


def test_r2_is_one_for_a_match_and_zero_for_the_mean():
    measured = np.random.default_rng(0).normal(size=300)
    assert curve_errors(measured, measured)['r2'] == 1.0
    the_mean = np.full(300, measured.mean())
    assert curve_errors(measured, the_mean)['r2'] == pytest.approx(0.0, abs=1e-12)


def test_nan_pairs_are_left_out_and_counted_and_the_worst_error_located():
    measured = np.linspace(0.0, 4.0, 100)
    simulated = measured + 0.1
    simulated[37] += 1.0
    measured[[5, 80]] = np.nan
    simulated[[5, 90]] = np.nan
    errors = curve_errors(measured, simulated, normaliser=2.0)
    kept = np.setdiff1d(np.arange(100), [5, 80, 90])
    by_hand = np.sqrt((0.1 ** 2 * (len(kept) - 1) + 1.1 ** 2) / len(kept))
    assert errors['count'] == 97 and errors['ignored'] == 3
    assert errors['rmse_n'] == pytest.approx(by_hand)
    assert errors['normaliser_n'] == 2.0 and errors['nrmse'] == pytest.approx(by_hand / 2.0)
    assert errors['max_abs_error_index'] == 37
    assert errors['max_abs_error_n'] == pytest.approx(1.1)


def test_curve_errors_refuse_mismatched_shapes_and_a_bad_normaliser():
    with pytest.raises(ValueError, match=r'measured has shape \(3,\) and simulated \(4,\)'):
        curve_errors(np.zeros(3), np.zeros(4))
    with pytest.raises(ValueError, match='normaliser = 0.0'):
        curve_errors(np.zeros(3), np.zeros(3), normaliser=0.0)


def test_per_phase_errors_use_the_whole_trial_normaliser():
    phases = np.array(['loading'] * 50 + ['hold'] * 30 + ['retraction'] * 20)
    measured = np.concatenate([np.linspace(0, 3, 50), np.full(30, 2.5), np.full(20, -1.0)])
    offsets = {'loading': 0.2, 'hold': -0.1, 'retraction': 0.05}
    simulated = measured + np.array([offsets[p] for p in phases])
    errors = per_phase_errors(measured, simulated, phases)
    assert list(errors) == ['loading', 'hold', 'retraction']
    for phase, offset in offsets.items():
        assert errors[phase]['rmse_n'] == pytest.approx(abs(offset))
        assert errors[phase]['nrmse'] == pytest.approx(abs(offset) / 4.0)   # range 3 - (-1)
        assert errors[phase]['count'] == np.count_nonzero(phases == phase)


def test_event_errors_are_simulated_minus_measured():
    measured = [Puncture(10, 0.011, 1.4, 0.5), Puncture(40, 0.019, 2.0, 0.4)]
    simulated = [Puncture(12, 0.0118, 1.1, 0.3)]
    measured_force = np.array([0.0, 1.0, 2.6, 2.0, -0.8, -1.2, 0.0])
    simulated_force = np.array([0.0, 1.5, 2.2, 3.5, -0.5, -0.9, 0.0])
    phases = np.array(['approach', 'loading', 'inserted', 'hold', 'retraction', 'retraction',
                       'retraction'])
    simulated_phases = phases.copy()
    simulated_phases[3] = 'retraction'               # its 3.5 N is no insertion peak
    assert peak_force(simulated_force, simulated_phases != 'retraction') == 2.2
    assert retraction_minimum(measured_force, phases) == -1.2
    errors = event_errors(measured, simulated, measured_force_n=measured_force,
                          measured_phases=phases, simulated_force_n=simulated_force,
                          simulated_phases=simulated_phases)
    assert errors['measured_puncture_count'] == 2 and errors['simulated_puncture_count'] == 1
    assert errors['first_puncture_travel_error_m'] == pytest.approx(0.0008)
    assert errors['first_puncture_force_error_n'] == pytest.approx(-0.3)
    assert errors['peak_force_error_n'] == pytest.approx(2.2 - 2.6)
    assert errors['retraction_minimum_error_n'] == pytest.approx(-0.9 - -1.2)
    none_simulated = event_errors(measured, [])
    assert np.isnan(none_simulated['first_puncture_travel_error_m'])
    assert np.isnan(none_simulated['peak_force_error_n'])
