"""Driving the simulation from a measured motion: a trial's needle travel as a pose schedule.

A recording says how far the needle travelled (a position column, or the stage's speed, start
time and travel when there is none) and, from the force, when the tip met the tissue. The
simulated needle starts where its scene puts it, at its own gap above the surface; the measured
travel is applied shifted so that contact happens at the same moment in both:

    simulated travel(t) = measured travel(t) - measured gap + scene gap

where the measured gap is the travel at contact (given, or found by ``detect_contact``: the first
sustained rise of the force above the pre-contact noise). A short pre-roll at
``PRE_ROLL_SPEED_M_S`` brings the simulated needle from its start pose to where the measured
motion begins (no contact happens there: it stays above the surface). The travel is resampled
onto the simulator's sampling interval ``tick_s`` and smoothed over ``SMOOTHING_S`` (a
Savitzky-Golay filter, order 2): a position sensor's noise, differentiated by the engine, would
otherwise become velocity noise the viscous friction feels. The schedule runs ``END_HOLD_S``
past the trial's last sample, the needle held where the data ends: a simulation is compared with
every repeat of its speed, each on its own contact's clock, and a sample the simulation does not
reach counts as a miss (the calibration's objective), so it must reach them all: ended at the
last whole tick before a jittered recording's last sample, it would leave that sample out, a
constant miss in every evaluation that stops the search's relative tests early.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['MeasuredMotion', 'PRE_ROLL_SPEED_M_S', 'SMOOTHING_S', 'END_HOLD_S', 'trial_travel', 'measured_motion',
           'within_depth', 'Schedule', 'schedule_for_scene']

PRE_ROLL_SPEED_M_S = 0.02
SMOOTHING_S = 0.05
#: how long the schedule holds the needle past the trial's last sample [s] (module docstring)
END_HOLD_S = 0.1


def trial_travel(trial) -> np.ndarray:
    """The needle travel [m] at each sample: the trial's position, or the stage motion it
    describes (``trial.motion``: still until ``start_s``, at ``speed_m_s`` to ``travel_m``, a
    hold of ``hold_s``, back at the same speed when ``retract``)."""
    if trial.travel_m is not None:
        return np.asarray(trial.travel_m, dtype=float)
    motion = trial.motion
    if not motion or motion.get('speed_m_s') is None or motion.get('travel_m') is None:
        raise ValueError(f'{trial.file}: no position column and no motion (speed and travel) in '
                         'the data description: the needle motion is unknown')
    t = trial.time_s - trial.time_s[0]
    start = motion.get('start_s')
    if start is None:
        start = _start_from_contact(trial, motion)
    speed, travel = float(motion['speed_m_s']), float(motion['travel_m'])
    ramp = travel / speed
    hold = float(motion.get('hold_s') or 0.0)
    inserting = np.clip((t - start) * speed, 0.0, travel)
    if not motion.get('retract'):
        return inserting
    back = np.clip((t - start - ramp - hold) * speed, 0.0, travel)
    return inserting - back


def _start_from_contact(trial, motion) -> float:
    """The stage's start time when not given: contact found in the force, reached at the stage
    speed from a gap of ``motion['gap_m']`` (0: the needle started at the surface)."""
    from tissue_sim_ros.analysis.compare.force_events import detect_contact
    contact = detect_contact(trial.time_s, trial.axial_force_n)
    if contact is None:
        raise ValueError(f'{trial.file}: motion.start_s not given and no contact found in the force')
    gap = float(motion.get('gap_m') or 0.0)
    return float(trial.time_s[contact] - trial.time_s[0]) - gap / float(motion['speed_m_s'])


@dataclass(frozen=True)
class MeasuredMotion:
    """A trial's travel [m] (from its first sample) at its sample times [s] (from its first
    sample), the sample where the tip met the tissue, and the travel then: the measured gap."""

    time_s: np.ndarray
    travel_m: np.ndarray
    contact_index: int
    gap_m: float


def measured_motion(trial, *, gap_m: float | None = None) -> MeasuredMotion:
    """The trial's motion; ``gap_m``: the travel at contact when known (else detected)."""
    from tissue_sim_ros.analysis.compare.force_events import detect_contact
    travel = trial_travel(trial)
    time = trial.time_s - trial.time_s[0]
    contact = detect_contact(trial.time_s, trial.axial_force_n, travel)
    if gap_m is None:
        if contact is None:
            raise ValueError(f'{trial.file}: no contact found in the force (no sustained rise above '
                             'the pre-contact noise); give the start gap')
        gap_m = float(travel[contact])
    elif contact is None:
        contact = int(np.argmax(travel >= gap_m)) if np.any(travel >= gap_m) else len(travel) - 1
    return MeasuredMotion(time, travel, int(contact), float(gap_m))


def within_depth(trial, max_depth_m: float, *, gap_m: float | None = None):
    """``trial`` up to the sample where its travel since contact first passes ``max_depth_m``
    (the first millimetres of the insertion: what a study compares when the deeper part, the
    hold and the retraction are left out), with its travel as a column. The trial as it is
    when it never gets that deep."""
    from dataclasses import replace
    if not (np.isfinite(max_depth_m) and max_depth_m > 0):
        raise ValueError(f'max depth = {max_depth_m!r} m: expected a finite depth > 0')
    motion = measured_motion(trial, gap_m=gap_m)
    beyond = np.flatnonzero(motion.travel_m - motion.gap_m > max_depth_m)
    end = int(beyond[0]) + 1 if beyond.size else trial.n_samples

    def cut(values):
        return None if values is None else np.asarray(values)[:end]
    return replace(trial, time_s=cut(trial.time_s), axial_force_n=cut(trial.axial_force_n),
                   travel_m=cut(motion.travel_m), force_n=cut(trial.force_n), torque_nm=cut(trial.torque_nm))


@dataclass(frozen=True)
class Schedule:
    """What the simulation follows: times [s] from its start, the needle base positions (k, 3),
    the tip travel from the needle's start pose [m], and each sample's time on the trial's clock
    [s] (negative during the pre-roll)."""

    times_s: np.ndarray
    positions: np.ndarray
    travel_m: np.ndarray
    trial_time_s: np.ndarray


def schedule_for_scene(motion: MeasuredMotion, start_position, axis, scene_gap_m: float,
                       tick_s: float = 0.01, hold_s: float = END_HOLD_S) -> Schedule:
    """The pose schedule that applies ``motion`` to a needle starting at ``start_position``
    (its axis ``axis``) ``scene_gap_m`` above the tissue, held ``hold_s`` past the motion's last
    sample (see the module docstring)."""
    from scipy.signal import savgol_filter
    if not (tick_s > 0 and np.isfinite(tick_s)):
        raise ValueError(f'tick_s = {tick_s!r}: expected a finite interval > 0 s')
    duration = float(motion.time_s[-1]) + hold_s
    n = max(2, int(np.ceil(duration / tick_s)) + 1)
    trial_time = np.arange(n) * tick_s
    travel = np.interp(trial_time, motion.time_s, motion.travel_m)
    window = int(round(SMOOTHING_S / tick_s)) | 1
    if window >= 5 and n > window:
        travel = savgol_filter(travel, window, 2, mode='interp')
    travel = travel - motion.gap_m + scene_gap_m
    offset = float(travel[0])
    n_pre = int(np.ceil(abs(offset) / (PRE_ROLL_SPEED_M_S * tick_s)))
    pre_travel = offset * np.arange(1, n_pre + 1) / n_pre if n_pre else np.zeros(0)
    all_travel = np.concatenate([pre_travel, travel])
    times = np.arange(1, len(all_travel) + 1) * tick_s
    axis = np.asarray(axis, dtype=float)
    positions = np.asarray(start_position, dtype=float) + all_travel[:, None] * axis
    return Schedule(times, positions, all_travel, times - (n_pre + 1) * tick_s)
