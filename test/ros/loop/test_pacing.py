"""The node engine's pacing (ros/loop/pacing.py): its arithmetic against the rules it states."""

import pytest

from tissue_sim_ros.ros.loop.pacing import (COALESCE_MARGIN_S, COALESCE_MAX_SPAN_S, COALESCE_MIN_WAIT_S,
                                            COALESCE_SAFETY, EnginePacing, LadderControl, RATIO_TRUST)

MS = 1_000_000


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
