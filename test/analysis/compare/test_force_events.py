"""Contact, punctures and phases in a force curve (analysis/compare/force_events.py), each checked
on synthetic insertions whose truth the test builds: contact time, puncture travel and size,
phase boundaries."""

import numpy as np
import pytest

from support.force_curves import FLOOR_N, RATES, SMOOTHING_M, insertion, sample_times, true_phases
from tissue_sim_ros.analysis.compare.force_events import (PHASES, detect_contact, detect_punctures,
                                                          segment_phases)


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


def test_a_short_approach_in_a_long_record_keeps_the_baseline_the_noise_and_the_contact():
    """0.5 s before contact in a 36 s record at 100 Hz: the first tenth of the record (and its
    first third) reaches 0.2 mm into a loading of 0.1 N/mm. Truth: the noise added (5 mN), the
    baseline 0, the contact made at 1 mm of travel."""
    from tissue_sim_ros.analysis.compare.force_events import baseline_and_noise
    record = insertion(np.random.default_rng(7), rate_hz=(100.0, 100.0), gap=1e-3, rest_s=0.0, hold_s=10.0,
                       onset='ramp', stiffness=100.0, force_noise=0.005)
    baseline, noise = baseline_and_noise(record['force_n'])
    contact = detect_contact(record['time_s'], record['force_n'], record['travel_m'])
    print(f'baseline {baseline * 1e3:.2f} mN, noise {noise * 1e3:.2f} mN (made 0 and 5); contact at '
          f'{record["travel_m"][contact] * 1e3:.3f} mm (made at 1)')
    assert abs(baseline) < 0.002 and 0.004 < noise < 0.006
    # the walk back's level sits 2 noise / sqrt(5) + 1 mN up: 0.055 mm of this loading, 0.1 mm with noise
    assert 0.0 <= record['travel_m'][contact] - 1e-3 < 1e-4


def test_a_noiseless_curve_s_contact_in_the_data_s_noise_lags_as_the_data_s_does():
    """A slow quadratic onset under 20 mN of noise at 100 Hz: the detector finds contact in a noisy
    record well after it finds it on the noiseless curve. Truth: the mean contact over 40 noisy
    records of the same curve (independent noise); ``contact_in_noise`` must land on it within
    3 standard errors, where the noiseless detection misses it by several."""
    from tissue_sim_ros.analysis.compare.force_events import baseline_and_noise, contact_in_noise
    clean = insertion(np.random.default_rng(0), rate_hz=(100.0, 100.0), gap=1e-3, rest_s=0.5,
                      stiffness=1e4, force_noise=0.0)
    time, force, travel = clean['time_s'], clean['true_force_n'], clean['true_travel_m']
    rng = np.random.default_rng(1)
    records = [force + rng.normal(0.0, 0.02, force.size) for _ in range(40)]
    found = np.array([time[detect_contact(time, noisy, travel)] for noisy in records])
    noise = baseline_and_noise(records[0])[1]
    in_noise = time[contact_in_noise(time, force, travel, noise_n=noise, record_time_s=time)]
    noiseless = time[detect_contact(time, force, travel, noise_n=noise)]
    error = found.std(ddof=1) / np.sqrt(found.size)
    print(f'noisy records {found.mean():.3f} +- {error:.3f} s; in noise {in_noise:.3f} s; noiseless '
          f'{noiseless:.3f} s (touched at {clean["contact_s"]:.3f} s)')
    assert abs(in_noise - found.mean()) < 3 * error
    assert found.mean() - noiseless > 6 * error
    # no noise: the noiseless curve's own contact
    assert contact_in_noise(time, force, travel, noise_n=0.0, record_time_s=time) == \
        detect_contact(time, force, travel, noise_n=0.0)
