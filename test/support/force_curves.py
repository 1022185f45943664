"""Synthetic insertions whose truth the test builds: sample times, a force curve with contact and
punctures, and its true phases."""

import numpy as np

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
