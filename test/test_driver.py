"""The one simulation driver and the node engine's pacing, checked against a second formulation
(the scene stepped by hand), the policy's stated outcomes and the pacing's arithmetic."""
import numpy as np
import pytest

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.errors import PoseError, SimulationDiverged
from tissue_sim_ros.ros.loop.pacing import (COALESCE_MARGIN_S, COALESCE_MAX_SPAN_S, COALESCE_MIN_WAIT_S, COALESCE_SAFETY,
                                             RATIO_TRUST, EnginePacing, LadderControl)

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}
MS = 1_000_000


def make_scene():
    from tissue_sim_ros.engine.scene.scene import Scene
    return Scene.from_file(None, mesh=COARSE)


def descent(scene, speed=0.02, ticks=60, tick=0.02):
    start, _ = scene.needle_pose
    axis = scene.needle.axis.copy()
    times = tick * np.arange(1, ticks + 1)
    return times, start + speed * times[:, None] * axis


def test_follow_equals_the_scene_stepped_by_hand():
    """A schedule followed by the driver gives bit for bit what Scene.advance + reaction_wrench
    give when called by hand with the same durations (the insert command's old loop)."""
    scene_a, scene_b = make_scene(), make_scene()
    times, positions = descent(scene_a)
    samples = SimulationDriver(scene_a).follow(times, positions)
    orientation = scene_b.needle_pose[1]
    previous, forces, steps = 0.0, [], 0
    for t, p in zip(times, positions):
        steps += scene_b.advance(t - previous, p, orientation)
        previous = t
        forces.append(scene_b.reaction_wrench('world')[0])
    np.testing.assert_array_equal(samples.force, np.array(forces))
    assert samples.substeps == steps and samples.time[-1] == scene_b.time
    assert np.abs(samples.force[:, 2]).max() > 0.05  # it did touch the tissue
    assert samples.tip_depth[-1] > 0 and samples.phase[-1] != 'approach'


def test_a_refused_pose_holds_the_needle_and_time_goes_on():
    scene = make_scene()
    driver = SimulationDriver(scene)
    position, orientation = scene.needle_pose
    outcome = driver.advance(0.02, position + [0.0, 0.0, -0.02], orientation)  # 20 mm > 5 mm limit
    assert isinstance(outcome.refused, PoseError) and driver.refusals == 1
    np.testing.assert_array_equal(scene.needle_pose[0], position)
    assert outcome.substeps == int(0.02 / scene.dt + 1e-9) and driver.simulated_s == 0.02
    with pytest.raises(PoseError):  # a schedule is the caller's: follow raises it
        driver.follow([0.04], [position + [0.0, 0.0, -0.02]])


def _diverging(scene, on_call, nan=False):
    real_advance, real_wrench, calls = scene.advance, scene.reaction_wrench, {'n': 0}

    def advance(*args):
        calls['n'] += 1
        steps = real_advance(*args)
        if calls['n'] == on_call and not nan:
            raise SimulationDiverged('injected', 1, scene.time, scene.dt, scene.dt)
        return steps

    def wrench(frame='world', needle=0):
        force, torque = real_wrench(frame, needle)
        return (force * np.nan if nan and calls['n'] >= on_call else force), torque
    scene.advance, scene.reaction_wrench = advance, wrench


@pytest.mark.parametrize('nan', [False, True])
def test_divergence_policy_reset_hold_raise(nan):
    times, positions = descent(make_scene(), ticks=5)
    # reset: back at rest at time 0, counted; the simulated clock keeps counting
    scene = make_scene()
    _diverging(scene, 3, nan)
    driver = SimulationDriver(scene, on_divergence='reset')
    for k in range(3):
        outcome = driver.advance(0.02, positions[k], scene.needle_pose[1])
    assert outcome.diverged is not None and driver.divergences == 1
    assert scene.time == 0.0 and driver.simulated_s == pytest.approx(0.04)
    assert np.all(np.isfinite(driver.force)) and not driver.held
    # hold: frozen, the last finite wrench kept, nothing advances until reset
    scene = make_scene()
    _diverging(scene, 3, nan)
    driver = SimulationDriver(scene, on_divergence='hold')
    for k in range(3):
        driver.advance(0.02, positions[k], scene.needle_pose[1])
    frozen = scene.time
    assert driver.held and driver.advance(0.02).substeps == 0 and scene.time == frozen
    assert np.all(np.isfinite(driver.force))
    driver.reset()
    assert not driver.held and scene.time == 0.0
    # raise: the offline commands' policy
    scene = make_scene()
    _diverging(scene, 1, nan)
    with pytest.raises(SimulationDiverged):
        SimulationDriver(scene).advance(0.02, positions[0], scene.needle_pose[1])


def test_a_displacement_beyond_float32_is_a_divergence():
    scene = make_scene()
    driver = SimulationDriver(scene, on_divergence='hold')
    real = scene.advance

    def advance(*args):
        steps = real(*args)
        scene.displacement[0, 0] = 1e39
        return steps
    scene.advance = advance
    assert driver.advance(0.02).diverged is not None and driver.held


def test_a_deadline_leaves_steps_that_a_later_call_runs():
    """Stopped by a deadline in the past, the driver is behind; advance(0) runs what is left,
    and the state equals an undisturbed run's."""
    scene_a, scene_b = make_scene(), make_scene()
    times, positions = descent(scene_a, ticks=3)
    a, b = SimulationDriver(scene_a), SimulationDriver(scene_b)
    q = scene_a.needle_pose[1]
    assert a.advance(0.02, positions[0], q, deadline=0.0).substeps == 0 and a.behind
    left = a.advance(0.0, positions[0], q).substeps
    assert left == b.advance(0.02, positions[0], q).substeps and not a.behind
    np.testing.assert_array_equal(scene_a.displacement, scene_b.displacement)


def test_pacing_targets_the_newest_pose_and_skips_clock_jumps():
    p = EnginePacing(0.02, 0.8, 0.25)
    assert p.target_ns(100 * MS, None) == 100 * MS
    assert p.target_ns(100 * MS, 90 * MS) == 90 * MS
    assert p.target_ns(100 * MS, 10 * MS) == 80 * MS  # at most one period behind now
    assert p.target_ns(100 * MS, 120 * MS) == 100 * MS  # never past now
    assert p.advance_s(0) == 0.02  # the first advance: one period
    assert p.advance_s(5 * MS) == pytest.approx(0.005)
    assert p.advance_s(5 * MS) == 0.0  # not later than the engine clock
    assert p.advance_s(205 * MS) == pytest.approx(0.2)  # within max(2 periods, max lag): asked for
    assert p.advance_s(1205 * MS) == pytest.approx(0.25) and p.skipped_s == pytest.approx(0.75)
    lock_step = EnginePacing(0.02, 0.8, 0.25, sim_time=True)
    lock_step.advance_s(0)
    assert lock_step.advance_s(100 * MS) == pytest.approx(0.04)  # sim time: 2 periods at most
    assert lock_step.deadline(1.0) is None


def test_pacing_budget_per_tick_and_measured_cost():
    p = EnginePacing(0.02, 0.5, 0.25)
    assert p.deadline(10.0) == pytest.approx(10.01)  # a whole budget (10 ms of work) from now
    p.new_window(behind=False)
    p.spent(0.004, 0.01)  # a first advance: 4 ms of work for 10 ms simulated
    assert p.deadline(20.013) == pytest.approx(20.019)  # the rest of the tick's budget, from now
    assert p.demand is None
    p.spent(0.004, 0.01)
    p.new_window(behind=True)
    assert p.cost_per_sim_s == pytest.approx(0.4) and p.demand == pytest.approx(0.8)
    assert p.windows_spent == 1
    p.spent(0.012, 0.02)   # more than the budget: the next advance starts no substep
    assert p.deadline(30.0) == 30.0
    for _ in range(200):  # a second of ticks at twice the cost: the average follows
        p.new_window(behind=False)
        p.spent(0.016, 0.02)
    assert p.cost_per_sim_s == pytest.approx(0.8, rel=0.01)


def test_the_wait_for_more_poses_still_ends_the_advance_before_the_tick_within_the_budget():
    """The wait w solves w + safety * cost * (owed + w) + margin = time to the tick where the tick
    limits it, safety * cost * (owed + w) = the budget left where the budget does, owed + w = the
    longest span of poses where that does; none with sim time, before the cost is measured, or
    when too short."""
    p = EnginePacing(0.02, 0.8, 0.25)
    assert p.wait_for_poses_s(0.019, 0.001) == 0.0            # no cost measured yet
    p.spent(0.004, 0.02)
    p.new_window(behind=False)                                  # cost 0.2 s a simulated second
    k = COALESCE_SAFETY * 0.2
    for to_tick, owed in ((0.006, 0.001), (0.007, 0.0), (0.005, 0.002)):
        w = p.wait_for_poses_s(to_tick, owed)
        assert w > 0.0 and w + k * (owed + w) + COALESCE_MARGIN_S == pytest.approx(to_tick)
    assert p.wait_for_poses_s(0.019, 0.001) == pytest.approx(COALESCE_MAX_SPAN_S - 0.001)   # the span
    assert p.wait_for_poses_s(0.004, 0.005) == 0.0             # the advance alone needs the time left
    assert p.wait_for_poses_s(COALESCE_MARGIN_S + 0.0001, 0.0) == 0.0    # too short to be worth it
    p.spent(0.0148, 0.0)                                        # 1.2 ms of the tick's 16 ms budget left
    w = p.wait_for_poses_s(0.019, 0.001)
    assert w > COALESCE_MIN_WAIT_S and k * (0.001 + w) == pytest.approx(0.0012)
    lock_step = EnginePacing(0.02, 0.8, 0.25, sim_time=True)
    lock_step.spent(0.004, 0.02)
    lock_step.new_window(behind=False)
    assert lock_step.wait_for_poses_s(0.019, 0.001) == 0.0


def test_ladder_control_steps_down_after_a_second_over_and_up_after_three_with_room():
    control = LadderControl(2, lambda level: 2.0 if level == 2 else 1.25, started_s=-10.0)
    assert control.decide(0.0, 1.5, 0.0, 0.25) is None  # over, not yet for a second
    assert control.decide(0.99, 1.5, 0.0, 0.25) is None
    assert control.decide(1.0, 1.5, 0.0, 0.25) == 1
    control.changed(1.0, 1, cost_before=0.8)
    assert control.decide(1.5, 1.5, 0.0, 0.25, cost=0.7) is None  # settling
    assert control.decide(2.1, 0.5, 0.2, 0.25, cost=0.7) is None  # settled: the ratio measured
    assert control.measured_ratio[1] == pytest.approx(0.8 / 0.7)
    # the lag above half its bound is over too
    assert control.decide(3.1, 0.5, 0.2, 0.25) == 2
    control.changed(3.1, 2, cost_before=0.5)
    assert control.decide(4.2, 0.3, 0.0, 0.25, cost=0.1) is None
    assert control.measured_ratio[2] == pytest.approx(2.0 * RATIO_TRUST)  # 5x measured: held to 1.5x
    assert control.cost_ratio(2) == 3.0
    # room: the level above would need 0.2 x 3 = 0.6 < 0.7 of the budget, for 3 s
    assert control.decide(4.3, 0.2, 0.0, 0.25) is None
    assert control.decide(7.2, 0.2, 0.0, 0.25) is None
    assert control.decide(7.3, 0.2, 0.0, 0.25) == 1
    control.changed(7.3, 1, cost_before=None)
    # 0.6 x 1.14 = 0.69: room again; 0.62 x 1.14 = 0.71: not
    assert control.decide(8.4, 0.62, 0.0, 0.25) is None and control.decide(11.5, 0.62, 0.0, 0.25) is None
    assert LadderControl(0, lambda level: 1.0).decide(5.0, 9.0, 1.0, 0.25) is None  # no rung
    fresh = LadderControl(2, lambda level: 2.0, started_s=100.0)   # the start-up's grace
    assert fresh.decide(100.0, 5.0, 0.0, 0.25) is None and fresh.decide(102.9, 5.0, 0.0, 0.25) is None
    assert fresh.decide(103.0, 5.0, 0.0, 0.25) is None and fresh.decide(104.0, 5.0, 0.0, 0.25) == 1
