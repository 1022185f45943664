"""A simulation on a trial's clock: what ``compare`` holds against the trial, and the scene's own
punctures where they happened (:class:`SimulatedCurve`)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['SimulatedCurve', 'simulated_curve']


@dataclass
class SimulatedCurve:
    """A simulation on a trial's clock: time since contact [s], travel since contact [m],
    axial force [N]; ``diverged``: the watchdog's reason, or ''; ``puncture_events``: the scene's
    own punctures as (travel since contact [m], layer) pairs (the layer: the region's place among
    those with a membrane)."""

    time_since_contact_s: np.ndarray
    travel_since_contact_m: np.ndarray
    axial_force_n: np.ndarray
    diverged: str = ''
    puncture_events: tuple = ()


def simulated_curve(result, schedule, motion, scene_gap_m: float) -> SimulatedCurve:
    """The simulation ``result`` of ``schedule`` (made from ``motion``) on the trial's clock."""
    contact_time = float(motion.time_s[motion.contact_index])
    keep = schedule.trial_time_s >= 0.0                       # not the pre-roll
    events = tuple((float(t) - scene_gap_m, int(layer)) for t, layer in
                   zip(result.puncture_travel_m, result.puncture_layer))
    return SimulatedCurve(schedule.trial_time_s[keep] - contact_time,
                          schedule.travel_m[keep] - scene_gap_m, np.asarray(result.axial_force_n)[keep],
                          result.diverged, events)
