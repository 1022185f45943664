"""Contact, punctures, phases, curve and event errors, and the time shift, each checked on
synthetic insertions whose truth the test builds: contact time, puncture travel and size, phase
boundaries, a known shift, and error formulas worked by hand."""
from __future__ import annotations

import numpy as np
import pytest

from tissue_sim_ros.analysis.compare.alignment import best_time_shift, resample
from tissue_sim_ros.analysis.compare.force_events import (PHASES, Puncture, detect_contact,
                                                  detect_punctures, segment_phases)
from tissue_sim_ros.analysis.compare.force_metrics import (curve_errors, event_errors, peak_force,
                                                   per_phase_errors, retraction_minimum)

RATES = {'88-100 Hz': (88.0, 100.0), '1 kHz': (1000.0, 1000.0)}
FLOOR_N = 1e-3          # the contact rule's absolute floor (force_events module docstring)
SMOOTHING_M = 1e-4      # the puncture rule's running median span


def sample_times(rng, duration_s, rate_hz):
    """Times from 0 with steps drawn uniformly between 1/max and 1/min rate (jittered)."""
    steps = rng.uniform(1.0 / rate_hz[1], 1.0 / rate_hz[0], int(duration_s * rate_hz[1]) + 10)
    time = np.concatenate([[0.0], np.cumsum(steps)])
    return time[time <= duration_s]


def insertion(rng, *, rate_hz=(88.0, 100.0), speed=2e-3, gap=5e-3, depth=25e-3, rest_s=1.0,
              hold_s=2.0, tail_s=1.0, force_noise=0.01, travel_noise=0.0, onset='quadratic',
              stiffness=4e4, punctures=(), pull_n=-1.0):
    """Rest, advance at ``speed`` to ``depth`` of travel, hold, retract to 0, rest. The needle
    touches at travel ``gap``; beyond it the force is ``stiffness * d**2`` (quadratic onset, N/m²)
    or ``stiffness * d`` (ramp, N/m) at d = travel - gap, less every drop ``(d_puncture, drop_n)``
    already passed; at depth it relaxes by 30 %; on the way out the tissue pulls ``pull_n`` while
    the tip is below the surface. Returns the noisy record and its truth."""
    t_contact, t_depth = rest_s + gap / speed, rest_s + depth / speed
    t_out = t_depth + hold_s
    time = sample_times(rng, t_out + depth / speed + tail_s, rate_hz)
    travel = np.where(time <= t_out, np.clip(speed * (time - rest_s), 0, depth),
                      np.clip(depth - speed * (time - t_out), 0, depth))
    below = np.clip(travel - gap, 0, None)
    force = stiffness * (below ** 2 if onset == 'quadratic' else below)
    for puncture_depth, drop in punctures:
        force -= np.where(below > puncture_depth + 1e-12, drop, 0.0)
    at_depth = (time >= t_depth) & (time <= t_out)
    relaxed = 1 - np.exp(-(time[at_depth] - t_depth) / 0.5)
    force[at_depth] = force[at_depth][0] * (1 - 0.3 * relaxed)
    force[time > t_out] = np.where(below[time > t_out] > 0, pull_n, 0.0)
    boundaries = {'loading': t_contact, 'hold': t_depth, 'retraction': t_out}
    if punctures:
        boundaries['inserted'] = rest_s + (gap + punctures[0][0]) / speed
    return {'time_s': time, 'travel_m': travel + rng.normal(0, travel_noise, len(time)),
            'force_n': force + rng.normal(0, force_noise, len(time)), 'true_force_n': force,
            'true_travel_m': travel, 'contact_s': t_contact, 'boundaries': boundaries}


def true_phases(record):
    """The phase of each sample from the boundary times the record was built with."""
    time, bounds = record['time_s'], record['boundaries']
    phases = np.full(len(time), 'approach', dtype='<U10')
    phases[time >= bounds['loading']] = 'loading'
    if 'inserted' in bounds:
        phases[time > bounds['inserted']] = 'inserted'
    phases[time >= bounds['hold']] = 'hold'
    phases[time > bounds['retraction']] = 'retraction'
    return phases


# --- contact -------------------------------------------------------------------------------

@pytest.mark.parametrize('rate', RATES.values(), ids=RATES.keys())
@pytest.mark.parametrize('seed', range(3))
def test_contact_on_a_ramp_is_found_before_the_force_is_five_noise_up(rate, seed):
    noise, slope, speed = 0.01, 300.0, 2e-3          # 0.3 N/mm at 2 mm/s: 0.6 N/s
    record = insertion(np.random.default_rng(seed), rate_hz=rate, onset='ramp', stiffness=slope,
                       speed=speed, force_noise=noise)
    contact = detect_contact(record['time_s'], record['force_n'], record['travel_m'])
    # the onset is where the force averaged over sustain_s / 2 = 50 ms (w samples, noise
    # sigma / sqrt(w)) last sat at or below 2 sigma / sqrt(w) + floor: within 3 sigma / sqrt(w)
    # of that, and the centred average lets the ramp show up to half a window (and a sample) early
    averaged_noise = noise / np.sqrt(round(0.05 * np.mean(rate)))
    latest = record['contact_s'] + (5 * averaged_noise + FLOOR_N) / (slope * speed) + 1 / rate[0]
    earliest = record['contact_s'] - 0.025 - 1.0 / rate[0]
    assert earliest <= record['time_s'][contact] <= latest
    # and always before the raw force is 5 noise up, where the detection sets in
    detection_s = (5 * noise + FLOOR_N) / (slope * speed)
    assert record['time_s'][contact] <= record['contact_s'] + detection_s


@pytest.mark.parametrize('rate', RATES.values(), ids=RATES.keys())
def test_contact_on_a_quadratic_rise_lies_between_touching_and_the_detection_level(rate):
    noise, stiffness, speed = 0.01, 4e4, 2e-3
    record = insertion(np.random.default_rng(5), rate_hz=rate, force_noise=noise,
                       stiffness=stiffness, speed=speed)
    contact = detect_contact(record['time_s'], record['force_n'], record['travel_m'])
    latest = record['contact_s'] + np.sqrt((5 * noise + FLOOR_N) / stiffness) / speed
    assert record['contact_s'] - 0.025 - 1.0 / rate[0] <= record['time_s'][contact] <= latest


def test_a_spike_and_a_rise_while_the_needle_stands_still_are_not_contact():
    rng = np.random.default_rng(11)
    record = insertion(rng, onset='ramp', stiffness=300.0, rest_s=2.0)
    time, force = record['time_s'], record['force_n'].copy()
    force[(time > 0.5) & (time < 0.53)] += 1.0       # a 30 ms spike: shorter than sustain_s
    tug = (time > 1.2) & (time < 1.6)                # 0.4 s of pull on the cable, stage at rest
    force[tug] += 0.3
    contact = detect_contact(time, force, record['travel_m'])
    assert abs(time[contact] - record['contact_s']) < 0.1
    # without the travel the tug is the first sustained rise: the travel check is what skips it
    without_travel = detect_contact(time, force)
    assert abs(time[without_travel] - time[tug][0]) < 0.03


def test_noise_alone_has_no_contact():
    rng = np.random.default_rng(3)
    time = sample_times(rng, 20.0, (88.0, 100.0))
    force = rng.normal(0.0, 0.02, len(time))
    assert detect_contact(time, force) is None
    assert detect_contact(time, force, np.linspace(0, 0.02, len(time))) is None


def test_contact_refuses_a_force_of_another_length():
    with pytest.raises(ValueError, match='force_n has 3 samples; expected 4'):
        detect_contact([0.0, 0.1, 0.2, 0.3], [0.0, 0.0, 1.0])


# --- punctures -----------------------------------------------------------------------------

@pytest.mark.parametrize('rate', RATES.values(), ids=RATES.keys())
@pytest.mark.parametrize('seed', range(3))
def test_punctures_are_found_at_their_travel_with_their_force_and_drop(rate, seed):
    noise, stiffness, gap = 0.02, 4e4, 5e-3
    layers = ((6e-3, 0.5), (14e-3, 2.0))              # 35 % and 27 % of their peaks
    record = insertion(np.random.default_rng(seed), rate_hz=rate, force_noise=noise,
                       stiffness=stiffness, gap=gap, punctures=layers)
    found = detect_punctures(record['travel_m'], record['force_n'])
    assert len(found) == 2
    passed = 0.0
    for puncture, (where, drop) in zip(found, layers):
        peak = stiffness * where ** 2 - passed
        slope = 2 * stiffness * where                  # N/m at the peak, both sides
        # a running median over 0.1 mm moves each end of the fall by at most the curve's change
        # over that span; 3 noise for what the median leaves of the noise
        assert abs(puncture.travel_m - (gap + where)) <= SMOOTHING_M
        assert abs(puncture.force_n - peak) <= slope * SMOOTHING_M + 3 * noise
        assert abs(puncture.drop_n - drop) <= 2 * slope * SMOOTHING_M + 3 * noise
        assert abs(record['force_n'][puncture.index] - peak) < 5 * noise + slope * SMOOTHING_M
        passed += drop


def test_a_noiseless_simulated_curve_gives_the_sample_before_the_drop():
    tick, speed, stiffness, where, drop = 0.02, 2e-3, 4e4, 6e-3, 0.5
    record = insertion(np.random.default_rng(0), rate_hz=(1 / tick, 1 / tick), force_noise=0.0,
                       stiffness=stiffness, punctures=((where, drop),), speed=speed)
    (puncture,) = detect_punctures(record['travel_m'], record['force_n'])
    below = record['true_travel_m'] - 5e-3
    assert puncture.index == np.flatnonzero(below > where + 1e-12)[0] - 1
    slope_span = 2 * stiffness * where * 2 * speed * tick      # the curve over two ticks
    assert abs(puncture.force_n - stiffness * where ** 2) <= slope_span
    assert abs(puncture.drop_n - drop) <= 2 * slope_span


@pytest.mark.parametrize('rate', RATES.values(), ids=RATES.keys())
def test_a_smooth_noisy_curve_with_relaxation_has_no_puncture(rate):
    for seed in range(4):
        record = insertion(np.random.default_rng(seed), rate_hz=rate, force_noise=0.02,
                           travel_noise=5e-6)
        # the hold relaxes by 30 % and the retraction pulls at -1 N: neither is an insertion
        assert detect_punctures(record['travel_m'], record['force_n']) == []


def test_single_sample_spikes_are_not_punctures():
    record = insertion(np.random.default_rng(8), force_noise=0.01)
    force, time = record['force_n'].copy(), record['time_s']
    for spike_s in (4.0, 6.0, 8.0, 10.0):           # 0.5 N glitches while the force is 0.2-4 N
        force[np.searchsorted(time, spike_s)] += 0.5
    assert detect_punctures(record['travel_m'], force) == []


def test_a_double_top_before_one_fall_is_one_puncture_at_the_higher_top():
    # piecewise linear in depth below the surface [mm -> N]: up to 1.5 N, a dip, a second top
    # 0.02 N lower, then the fall to 1.0 N, and on
    below_mm = np.array([0.0, 5.0, 5.3, 5.6, 5.62, 9.0])
    force_n = np.array([0.0, 1.5, 1.42, 1.48, 1.0, 2.0])
    travel = np.arange(0.0, 10e-3, 4e-5)               # 2 mm/s at 50 Hz, noiseless
    force = np.interp((travel - 1e-3) * 1e3, below_mm, force_n, left=0.0)
    (puncture,) = detect_punctures(travel, force)
    assert abs(puncture.travel_m - 6e-3) <= 4e-5
    assert puncture.force_n == pytest.approx(1.5, abs=0.02)


def test_a_drop_smaller_than_the_fraction_is_not_a_puncture():
    stiffness, where = 4e4, 8e-3
    peak = stiffness * where ** 2                      # 2.56 N
    record = insertion(np.random.default_rng(2), force_noise=0.005, stiffness=stiffness,
                       punctures=((where, 0.1 * peak),))
    assert detect_punctures(record['travel_m'], record['force_n']) == []
    # a lower fraction makes it an event; the same loading regains its peak within 0.4 mm of the
    # 7 mm that built it, so it is a pre-drop, not a puncture
    from tissue_sim_ros.analysis.compare.force_events import detect_drops
    (found,) = detect_drops(record['travel_m'], record['force_n'], min_drop_fraction=0.05)
    assert abs(found.travel_m - (5e-3 + where)) <= SMOOTHING_M and found.kind == 'pre-drop'


def test_punctures_refuse_bad_arguments():
    travel, force = np.linspace(0, 0.01, 50), np.linspace(0, 1, 50)
    with pytest.raises(ValueError, match='min_drop_fraction = 1.5'):
        detect_punctures(travel, force, min_drop_fraction=1.5)
    with pytest.raises(ValueError, match=r'inserting has shape \(3,\)'):
        detect_punctures(travel, force, inserting=[True, True, False])


# --- phases --------------------------------------------------------------------------------

@pytest.mark.parametrize('rate', RATES.values(), ids=RATES.keys())
def test_phases_of_a_jittered_noisy_insertion_match_its_motion(rate):
    record = insertion(np.random.default_rng(4), rate_hz=rate, onset='ramp', stiffness=300.0,
                       force_noise=0.01, travel_noise=5e-6, punctures=((6e-3, 0.6),))
    phases = segment_phases(record['time_s'], record['travel_m'], record['force_n'])
    truth = true_phases(record)
    margin_s = 0.1            # 0.2 mm at 2 mm/s: the contact, depth and puncture tolerances
    far = np.ones(len(phases), dtype=bool)
    for boundary in record['boundaries'].values():
        far &= np.abs(record['time_s'] - boundary) > margin_s
    np.testing.assert_array_equal(phases[far], truth[far])
    runs = [phases[0]] + [b for a, b in zip(phases[:-1], phases[1:]) if a != b]
    assert runs == list(PHASES)


def test_a_travel_glitch_does_not_move_the_hold():
    record = insertion(np.random.default_rng(9), onset='ramp', stiffness=300.0, travel_noise=5e-6)
    travel = record['travel_m'].copy()
    time = record['time_s']
    travel[np.searchsorted(time, 5.0)] += 2e-2      # one encoder glitch of 20 mm mid-insertion
    phases = segment_phases(time, travel, record['force_n'])
    hold = time[phases == 'hold']
    assert abs(hold[0] - record['boundaries']['hold']) < 0.05
    assert abs(hold[-1] - record['boundaries']['retraction']) < 0.05


def test_given_contact_and_puncture_set_the_boundaries_exactly():
    record = insertion(np.random.default_rng(6), onset='ramp', stiffness=300.0)
    phases = segment_phases(record['time_s'], record['travel_m'], record['force_n'],
                            contact=400, first_puncture=700)
    assert phases[399] == 'approach' and phases[400] == 'loading'
    assert phases[700] == 'loading' and phases[701] == 'inserted'
    with pytest.raises(ValueError, match='first_puncture = 300 is before contact = 400'):
        segment_phases(record['time_s'], record['travel_m'], record['force_n'], contact=400,
                       first_puncture=300)


# --- curve and event errors ----------------------------------------------------------------

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


# --- alignment -----------------------------------------------------------------------------

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


def test_a_recording_that_starts_just_above_the_tissue_keeps_its_noise_and_its_puncture():
    """The first 10 % of such a recording holds the loading's rise; taken as noise, it set the
    puncture threshold (8 noise) above a 0.4 N drop. Truth: the noise added and the drop made."""
    from tissue_sim_ros.analysis.compare.force_events import baseline_and_noise, detect_contact, detect_punctures
    rng = np.random.default_rng(3)
    inserting = np.arange(0.0, 0.019, 3e-5)                   # 3 mm/s at 100 Hz, 1 mm gap
    travel = np.concatenate([inserting, np.full(50, 0.019), inserting[::-1]])   # hold, retract
    depth = np.clip(travel - 0.001, 0.0, None)
    force = np.where(depth < 0.010, 0.048e3 * depth + 9.2e3 * depth ** 2, 1.0 + 10.0 * (depth - 0.010))
    force[inserting.size:] = 0.5 * force[inserting.size:] - 0.3                  # the way out
    noisy = force + rng.normal(0.0, 0.005, travel.size)
    baseline, noise = baseline_and_noise(noisy)
    punctures = detect_punctures(travel, noisy)
    contact = detect_contact(np.arange(travel.size) * 0.01, noisy, travel)
    print(f'baseline {baseline * 1e3:.2f} mN, noise {noise * 1e3:.2f} mN (added 0 and 5); contact at '
          f'{travel[contact] * 1e3:.2f} mm (made at 1.0); punctures at '
          f'{[round(p.travel_m * 1e3, 2) for p in punctures]} mm (made at 11.0)')
    assert abs(baseline) < 0.003 and 0.003 < noise < 0.010
    assert abs(travel[contact] - 0.001) < 3e-4
    assert len(punctures) == 1 and abs(punctures[0].travel_m - 0.011) < 2e-4
