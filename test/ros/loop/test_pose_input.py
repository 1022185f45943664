"""PoseInput, the node's pose stream (pure, no ROS): interpolation between samples, each refusal
kind named and counted, floods, staleness; and re-synchronisation (so that a jump lock-out ends):
a robot that moved past the jump limit during a gap in its stream is followed again, the
needle joining it at a bounded speed that the engine accepts; a wild pose in a live stream is
still refused.

Truth: poses written here in closed form (interpolated values, the robot's trajectory), the
rule's thresholds, and the engine's own jump check (a scene advanced through the poses handed
out)."""

import math

import numpy as np
import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.ros.loop.pose_input import BAD_INPUT_KINDS, PoseInput, PoseInputLimits, RESYNC_STEP_MAX_S
from tissue_sim_ros.units import NS_PER_S

DOWN = np.array([1.0, 0.0, 0.0, 0.0])  # needle axis (base +z) along world -z
TICK_NS = 20_000_000  # the node's 50 Hz
POSE_NS = 10_000_000  # a 100 Hz robot
NS = NS_PER_S


def robot(t_ns, speed=0.0055, start=np.array([0.0, 0.0, 0.2])):
    """Where the robot holds the needle base at time t: straight down at ``speed`` [m/s] from 1 s."""
    return start + np.array([0.0, 0.0, -speed * max(0.0, t_ns / NS_PER_S - 1.0)])


def play(pose_input, stamps, pose_of, t_end_ns, ticks_from_ns=NS_PER_S):
    """The node's loop: each tick offers the poses stamped up to it (received at their stamp) and
    asks for the pose at the tick. Returns ({stamp: kind}, [(tick, handed pose)])."""
    kinds, handed = {}, []
    pending = list(stamps)
    for t in range(ticks_from_ns, t_end_ns + 1, TICK_NS):
        while pending and pending[0] <= t:
            s = pending.pop(0)
            p, q = pose_of(s)
            kinds[s] = pose_input.offer(p, q, 'world', s, s)[0]
        pose = pose_input.pose_at(t)
        if pose is not None:
            handed.append((t, pose[0].copy(), pose[1].copy()))
    return kinds, handed


def gap_stream(gap_from_ns=2 * NS_PER_S, gap_ns=1_100_000_000, n_after=200):
    """100 Hz stamps from 1 s to the gap, then ``n_after`` more after a ``gap_ns`` silence."""
    before = list(range(NS_PER_S, gap_from_ns + 1, POSE_NS))
    resume = before[-1] + gap_ns
    return before, [resume + k * POSE_NS for k in range(n_after)]


def test_after_a_gap_while_the_robot_moved_6_mm_the_stream_is_followed_again_within_the_limits():
    limits = PoseInputLimits()
    pose_input = PoseInput(limits, reference_pose=(robot(0), DOWN))
    before, after = gap_stream()
    assert np.linalg.norm(robot(after[0]) - robot(before[-1])) == pytest.approx(0.00605)  # > 5 mm
    kinds, handed = play(pose_input, before + after, lambda s: (robot(s), DOWN), after[-1] + 10 * TICK_NS)

    # what the issue saw: every pose after the gap refused. Now: the first one re-synchronises
    assert [kinds[s] for s in before] == [None] * len(before)
    assert kinds[after[0]] == 'resynchronised' and [kinds[s] for s in after[1:]] == [None] * 199
    assert pose_input.counts['resynchronised'] == 1 and pose_input.counts['jump'] == 0
    assert pose_input.bad_total == 0 and pose_input.accepted == len(before) + len(after)

    times = np.array([t for t, _, _ in handed])
    positions = np.array([p for _, p, _ in handed])
    steps = np.linalg.norm(np.diff(positions, axis=0), axis=1)
    # never more than the jump limit between ticks; in fact at most the catch-up speed
    assert steps.max() <= limits.resync_speed_m_s * TICK_NS / NS_PER_S * (1 + 1e-12)
    assert steps.max() < limits.max_jump_m / 10
    # the robot's pose where the stream is live and not being caught up: before the gap, and
    # from when the needle has joined (closing at 20 - 5.5 mm/s from 6.05 mm: 0.42 s)
    truth = np.array([robot(min(t, after[-1])) for t in times])
    live = (times <= before[-1]) | (times >= after[0] + 0.45 * NS_PER_S)
    np.testing.assert_allclose(positions[live], truth[live], atol=1e-12)
    joining = (times > after[0]) & (times < after[0] + 0.40 * NS_PER_S)
    assert (np.linalg.norm(positions[joining] - truth[joining], axis=1) > 1e-4).all()
    assert not pose_input.catching_up

    # the engine's own check takes every handed pose, one tick's advance each
    scene = Scene({'mesh': {'size_m': [0.01, 0.01, 0.005], 'origin_m': [-0.005, -0.005, 0.0],
                            'divisions': [2, 2, 1]},
                   'needle': {'initial_position_m': robot(0).tolist(), 'length_m': 0.15,
                              'initial_orientation_xyzw': DOWN.tolist()},
                   'solver': {'mass_scaling': 100.0}})
    assert scene.needle.geometry.max_jump_m == limits.max_jump_m
    for (t0, _, _), (t1, p, q) in zip(handed[:-1], handed[1:]):
        scene.advance((t1 - t0) / NS_PER_S, p, q)
    np.testing.assert_allclose(scene.needle_pose[0], robot(after[-1]), atol=1e-12)


def test_a_wild_pose_in_a_live_stream_is_still_refused_and_changes_nothing():
    pose_input = PoseInput(PoseInputLimits(), reference_pose=(robot(0), DOWN))
    stamps = list(range(NS_PER_S, 3 * NS_PER_S, POSE_NS))
    wild = stamps[100]

    def pose_of(s):
        return (robot(s) + [0.0, 0.02, 0.0] if s == wild else robot(s)), DOWN
    kinds, handed = play(pose_input, stamps, pose_of, stamps[-1] + TICK_NS)
    assert kinds[wild] == 'jump' and sum(k is not None for k in kinds.values()) == 1
    assert pose_input.counts['resynchronised'] == 0 and not pose_input.catching_up
    for t, p, _ in handed:  # the robot's pose; at the wild pose's tick, the one before it (held)
        np.testing.assert_allclose(p, robot(min(t, stamps[-1]) - (POSE_NS if t == wild else 0)), atol=1e-12)


def test_a_stream_that_jumps_without_a_gap_is_refused_for_stale_after_s_then_rejoined():
    """An offset stream (e.g. a re-calibrated robot frame) that keeps coming at 100 Hz: refused
    as jumps while the last accepted pose is at most stale_after_s old, then re-synchronised."""
    limits = PoseInputLimits(stale_after_s=0.5)
    pose_input = PoseInput(limits)
    switch = 2 * NS_PER_S
    stamps = list(range(NS_PER_S, 4 * NS_PER_S, POSE_NS))
    offset = np.array([0.008, 0.0, 0.0])
    kinds, handed = play(pose_input, stamps, lambda s: (robot(s) + (offset if s >= switch else 0), DOWN),
                         stamps[-1] + TICK_NS)
    last_good = switch - POSE_NS
    refused = [s for s in stamps if kinds[s] == 'jump']
    # ages 0.01 ... 0.50 s are not stale (stale means older than 0.5 s): 50 poses
    assert refused == list(range(switch, last_good + NS_PER_S // 2 + 1, POSE_NS))
    assert kinds[last_good + NS_PER_S // 2 + POSE_NS] == 'resynchronised'
    positions = np.array([p for _, p, _ in handed])
    assert np.linalg.norm(np.diff(positions, axis=0), axis=1).max() <= 0.02 * 0.02 * (1 + 1e-12)
    np.testing.assert_allclose(handed[-1][1], robot(stamps[-1]) + offset, atol=1e-12)  # joined: 8 mm at 20 mm/s < 1 s


def test_a_turn_during_a_gap_is_joined_at_the_rotation_speed():
    limits = PoseInputLimits(resync_speed_rad_s=0.25)
    pose_input = PoseInput(limits)
    before, after = gap_stream(n_after=400)
    turn = 0.8  # rad about x, more than max_jump_rad 0.5
    turned = np.array([math.cos(turn / 2) * 1.0, 0.0, 0.0, -math.sin(turn / 2)])  # about(x, turn) * DOWN
    kinds, handed = play(pose_input, before + after,
                         lambda s: (robot(0), DOWN if s < after[0] else turned), after[-1])
    assert kinds[after[0]] == 'resynchronised'
    quaternions = np.array([q for _, _, q in handed])
    turns = [2 * math.acos(min(1.0, abs(float(a @ b)))) for a, b in zip(quaternions[:-1], quaternions[1:])]
    # slerp turns by nlerp below 0.06 rad: a step then differs from 0.005 rad by ~0.1 %
    assert max(turns) <= 0.25 * 0.02 * (1 + 2e-3)
    assert sum(turns) == pytest.approx(turn, abs=1e-6)  # along the shortest arc, no detour
    np.testing.assert_allclose(quaternions[-1], turned, atol=1e-12)


def test_a_long_pause_between_ticks_moves_the_needle_no_farther_than_one_bounded_step():
    limits = PoseInputLimits()
    pose_input = PoseInput(limits)
    pose_input.offer(robot(0), DOWN, 'world', NS_PER_S, NS_PER_S)
    p0, _ = pose_input.pose_at(NS_PER_S)
    far = robot(0) + [0.0, 0.0, -0.03]
    assert pose_input.offer(far, DOWN, 'world', 3 * NS_PER_S, 3 * NS_PER_S)[0] == 'resynchronised'
    p1, _ = pose_input.pose_at(30 * NS_PER_S)  # 27 s later (a paused node)
    assert np.linalg.norm(p1 - p0) == pytest.approx(limits.resync_speed_m_s * RESYNC_STEP_MAX_S, rel=1e-12)
    np.testing.assert_allclose((p1 - p0) / np.linalg.norm(p1 - p0), [0.0, 0.0, -1.0], atol=1e-12)


def test_after_a_reset_a_jump_from_the_needle_is_refused_however_long_the_wait():
    pose_input = PoseInput(PoseInputLimits())
    pose_input.offer(robot(0), DOWN, 'world', NS_PER_S, NS_PER_S)
    pose_input.reset((robot(0), DOWN))
    far = robot(0) + [0.0, 0.0, -0.02]
    for k in range(2, 10):
        assert pose_input.offer(far, DOWN, 'world', k * NS_PER_S, k * NS_PER_S)[0] == 'jump'
    assert pose_input.pose_at(10 * NS_PER_S) is None and pose_input.counts['resynchronised'] == 0


def test_kinds_counted_by_the_node_add_up_with_the_refused_ones():
    pose_input = PoseInput(PoseInputLimits(), reference_pose=(robot(0), DOWN))
    pose_input.offer(robot(0) + [0.0, 0.0, 0.02], DOWN, 'world', NS_PER_S, NS_PER_S)  # a jump
    pose_input.count('engine_refused')
    pose_input.count('malformed')  # not one of the kinds PoseInput judges: a key of its own
    pose_input.count('malformed')
    assert pose_input.counts['malformed'] == 2 and pose_input.counts['engine_refused'] == 1
    assert pose_input.bad_total == 4


# interpolation, refusals, floods, staleness
def _limits(**kw):
    return PoseInputLimits(**{'expected_frame_id': 'world', **kw})


def test_pose_input_interpolates_between_samples_and_holds_after():
    pi = PoseInput(_limits(max_jump_m=0.01))
    q0 = np.array([0.0, 0.0, 0.0, 1.0])
    q1 = np.array([0.0, 0.0, math.sin(0.1), math.cos(0.1)])  # 0.2 rad about z
    assert pi.offer([0, 0, 0], q0, 'world', 1 * NS, 1 * NS) == (None, None)
    assert pi.offer([0.004, 0, 0], q1, 'world', 1 * NS + 10_000_000, 1 * NS)[0] is None
    p, q = pi.pose_at(1 * NS + 2_500_000)  # a quarter of the way
    np.testing.assert_allclose(p, [0.001, 0, 0], atol=1e-15)
    np.testing.assert_allclose(q, [0, 0, math.sin(0.025), math.cos(0.025)], atol=1e-12)
    p, q = pi.pose_at(5 * NS)  # after the newest: held
    np.testing.assert_allclose(p, [0.004, 0, 0])
    np.testing.assert_allclose(q, q1)
    assert pi.pose_at(0)[0].tolist() == [0.004, 0, 0]  # older samples were dropped meanwhile


def test_pose_input_refuses_each_kind_and_names_it():
    pi = PoseInput(_limits(max_jump_m=0.005, max_future_s=0.5), reference_pose=([0, 0, 0], DOWN))
    t = 10 * NS
    cases = [
        ([np.nan, 0, 0], DOWN, 'world', t, 'non_finite'),
        ([0, 0, 0], [1.0, 0, 0, np.inf], 'world', t, 'non_finite'),
        ([0, 0, 0], [1.1, 0, 0, 0], 'world', t, 'non_unit_quaternion'),
        ([0, 0, 0], DOWN, 'map', t, 'wrong_frame'),
        ([0, 0, 0], DOWN, 'world', t + 2 * NS, 'future_stamp'),
        ([0.006, 0, 0], DOWN, 'world', t, 'jump'),  # from the needle (reference)
        ([0, 0, 0], [0, 0, 0, 1.0], 'world', t, 'jump'),  # 180 degrees
    ]
    for p, q, frame, stamp, kind in cases:
        got, detail = pi.offer(p, q, frame, stamp, t)
        assert got == kind, (p, q, frame, got, detail)
        assert detail
    assert pi.accepted == 0 and pi.newest() is None
    assert pi.offer([0.001, 0, 0], [1.005, 0, 0, 0], 'world', t, t)[0] is None  # normalised
    np.testing.assert_allclose(pi.newest()[2], DOWN)
    assert pi.offer([0, 0, 0], DOWN, 'world', t - 1, t)[0] == 'time_backwards'
    assert pi.offer([0.001, 0, 0], DOWN, 'world', 0, t + NS)[0] == 'unstamped'
    assert pi.newest()[0] == t + NS  # stamped with the receipt time
    expected = {k: 0 for k in BAD_INPUT_KINDS}
    expected.update({'non_finite': 2, 'non_unit_quaternion': 1, 'wrong_frame': 1, 'future_stamp': 1,
                     'jump': 2, 'time_backwards': 1, 'unstamped': 1})
    assert pi.counts == expected
    assert set(pi.counts) == set(BAD_INPUT_KINDS)


def test_pose_input_flood_keeps_latest_and_one_sample_per_slot():
    pi = PoseInput(_limits(max_rate_hz=250.0))  # 4 ms slots
    t0 = 3 * NS
    for k in range(1000):  # 1 kHz for 1 s
        pi.offer([0, 0, -1e-6 * k], DOWN, 'world', t0 + k * 1_000_000, t0 + k * 1_000_000)
    # samples open at k = 0, 4, 8, ...: 250 of them; the other 750 replace the newest sample
    assert pi.counts['flood'] == 750 and pi.accepted == 1000
    assert pi.newest()[1][2] == pytest.approx(-1e-6 * 999)  # the latest pose is the one held
    # the last two samples hold k = 995 (slot opened at 992) and k = 999 (slot 996)
    assert len(pi._samples) == pi.limits.buffer_length  # bounded: the oldest were dropped
    p, _ = pi.pose_at(t0 + 997_000_000)
    assert p[2] == pytest.approx(-997e-6, abs=1e-15)


def test_pose_input_stale_and_reset():
    pi = PoseInput(_limits(stale_after_s=0.5))
    assert pi.pose_at(NS) is None and not pi.stale(NS) and pi.age_s(NS) is None
    pi.offer([0, 0, 0], DOWN, 'world', NS, NS)
    assert not pi.stale(NS + 400_000_000) and pi.stale(NS + 600_000_000)
    pi.reset(([0.0, 0.0, 0.0], DOWN))
    assert pi.pose_at(2 * NS) is None
    assert pi.offer([0.0, 0.0, 0.02], DOWN, 'world', 2 * NS, 2 * NS)[0] == 'jump'


MS = 1_000_000
Q = [0.0, 0.0, 0.0, 1.0]


def _feed(pose_input, stamps_ms, receipts_ms):
    for stamp, receipt in zip(stamps_ms, receipts_ms):
        pose_input.offer([0.0, 0.0, 0.1], Q, 'world', int(stamp * MS), int(receipt * MS))


def test_a_late_burst_is_a_stall_and_a_pause_is_not():
    pose_input = PoseInput(PoseInputLimits(stale_after_s=0.5))
    stamps = np.arange(0, 1000, 10.0)
    _feed(pose_input, stamps, stamps + 1.0)                       # on time
    assert pose_input.delivery_stalls == 0
    _feed(pose_input, stamps + 3000, stamps + 3001)               # a 2 s pause, then on time again
    assert pose_input.delivery_stalls == 0 and pose_input.last_stall_ns is None
    held = np.arange(4000, 5000, 10.0)                            # stamped on time, held up a second
    _feed(pose_input, held, np.full(held.size, 5020.0))
    assert pose_input.delivery_stalls == 1 and pose_input.last_stall_ns == 5020 * MS
    assert pose_input.delivery_stall_max_s == pytest.approx(1.02)
    _feed(pose_input, stamps + 6000, stamps + 6001)
    _feed(pose_input, [7100.0, 7110.0], [7800.0, 7800.0])        # a second stall
    assert pose_input.delivery_stalls == 2
