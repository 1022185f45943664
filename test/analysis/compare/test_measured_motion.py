"""A trial's needle travel as a pose schedule (analysis/compare/measured_motion.py): the stage's
motion in closed form, the travel shifted so that contact happens at the same moment in the
simulation, a pre-roll from the start pose, and the schedule held past the last sample. Truth:
the motion evaluated here by hand, and straight lines (which the smoothing keeps exactly)."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.compare.measured_motion import (END_HOLD_S, PRE_ROLL_SPEED_M_S, MeasuredMotion,
                                                             schedule_for_scene, trial_travel, within_depth)
from tissue_sim_ros.io.trials.trial import Trial


def _stage_trial(**motion):
    time_s = 100.0 + np.arange(0, 2001) * 0.005                        # 10 s at 200 Hz, its own origin
    return Trial('stage.csv', time_s, np.zeros(time_s.size), motion={'hold_s': 0.0, 'retract': False, **motion})


def test_the_stage_motion_is_still_then_in_at_its_speed_held_and_back():
    trial = _stage_trial(speed_m_s=0.002, start_s=1.0, travel_m=0.01, hold_s=2.0, retract=True)
    travel = trial_travel(trial)
    t = trial.time_s - 100.0
    by_hand = np.piecewise(t, [t < 1.0, (t >= 1.0) & (t < 6.0), (t >= 6.0) & (t < 8.0), t >= 8.0],
                           [0.0, lambda s: 0.002 * (s - 1.0), 0.01, lambda s: np.maximum(0.01 - 0.002 * (s - 8.0), 0.0)])
    np.testing.assert_allclose(travel, by_hand, rtol=0, atol=1e-15)
    with pytest.raises(ValueError, match='stage.csv: no position column and no motion'):
        trial_travel(_stage_trial(start_s=0.0, travel_m=0.01))


def test_the_schedule_meets_the_tissue_when_the_trial_did_from_the_scenes_own_gap():
    """Measured: still for 0.5 s, then 4 mm/s, contact at 3 mm of travel; the scene's needle
    starts 9 mm above its tissue. The schedule rolls it 6 mm down at the pre-roll speed, then
    follows the measured line 6 mm further on: contact at the same trial time; held past the
    last sample."""
    time_s = np.linspace(0.0, 2.0, 401)
    travel = np.clip((time_s - 0.5) * 0.004, 0.0, None)
    motion = MeasuredMotion(time_s, travel, contact_index=int(np.searchsorted(travel, 0.003)), gap_m=0.003)
    start, axis = np.array([0.0, 0.0, 0.159]), np.array([0.0, 0.0, -1.0])
    schedule = schedule_for_scene(motion, start, axis, scene_gap_m=0.009, tick_s=0.01)
    pre = schedule.trial_time_s < 0
    assert pre.sum() == int(np.ceil(0.006 / (PRE_ROLL_SPEED_M_S * 0.01)))
    np.testing.assert_allclose(np.diff(schedule.travel_m[pre]), PRE_ROLL_SPEED_M_S * 0.01, rtol=1e-12)
    following = ~pre & (schedule.trial_time_s > 0.6) & (schedule.trial_time_s < 1.9)   # away from the kink
    expected = (schedule.trial_time_s[following] - 0.5) * 0.004 - 0.003 + 0.009
    np.testing.assert_allclose(schedule.travel_m[following], expected, rtol=0, atol=1e-12)
    at_contact = np.interp(0.5 + 0.003 / 0.004, schedule.trial_time_s, schedule.travel_m)
    assert at_contact == pytest.approx(0.009, abs=1e-12)            # the scene's gap, when the trial touched
    np.testing.assert_allclose(schedule.positions, start + schedule.travel_m[:, None] * axis, rtol=0, atol=1e-15)
    np.testing.assert_allclose(np.diff(schedule.times_s), 0.01, rtol=1e-12)
    assert schedule.trial_time_s[-1] >= time_s[-1] + END_HOLD_S - 0.01 - 1e-12
    assert schedule.travel_m[-1] == pytest.approx(travel[-1] - 0.003 + 0.009, abs=1e-9)


def test_a_trial_is_cut_where_its_travel_since_contact_passes_the_depth():
    time_s = np.linspace(0.0, 3.0, 301)
    travel = 0.004 * time_s
    force = np.where(travel > 0.002, 100.0 * (travel - 0.002), 0.0)
    trial = Trial('ramp.csv', time_s, force, travel_m=travel)
    cut = within_depth(trial, 0.005, gap_m=0.002)
    beyond = np.flatnonzero(travel - 0.002 > 0.005)[0]
    assert cut.n_samples == beyond + 1 and cut.travel_m[-1] == travel[beyond]
    np.testing.assert_array_equal(cut.axial_force_n, force[:beyond + 1])
    assert within_depth(trial, 1.0, gap_m=0.002).n_samples == trial.n_samples    # never that deep
    with pytest.raises(ValueError, match='max depth'):
        within_depth(trial, 0.0, gap_m=0.002)
