"""The node's rolling statistics and its /diagnostics values (ros/diagnostics.py), without ROS:
a ring's percentiles are numpy's over the last n values, missed ticks follow the stated rule,
and the input status says what a PoseInput counted. Truth: numpy, the rule's arithmetic, and the
poses offered here."""
import time

import numpy as np
import pytest

from tissue_sim_ros.ros.diagnostics import NodeStats, Ring, _input_status
from tissue_sim_ros.ros.loop.pose_input import PoseInput, PoseInputLimits

NS = 1_000_000_000
DOWN = [1.0, 0.0, 0.0, 0.0]


def test_a_ring_keeps_the_last_n_values_and_their_percentiles():
    ring = Ring(10)
    assert np.isnan(ring.percentile(50))
    values = np.random.default_rng(5).normal(size=25)
    for k, value in enumerate(values, 1):
        ring.add(value)
        last = values[max(0, k - 10):k]
        assert sorted(ring.array()) == sorted(last)
        assert ring.percentile(99) == pytest.approx(np.percentile(last, 99), rel=1e-15)


def test_a_gap_of_more_than_one_and_a_half_periods_is_missed_ticks_and_input_caused_them():
    stats = NodeStats(50.0)                                  # 20 ms ticks
    for wall in (0.0, 0.02, 0.04, 0.069):                     # a 29 ms gap: within 1.5 periods
        stats.tick_started(wall)
    assert stats.missed_ticks == 0
    stats.tick_started(0.129)                                 # 60 ms: two ticks missed
    stats.input_done(0.004)
    stats.input_done(0.008)                                   # 12 ms of pose callbacks...
    stats.tick_started(0.209)                                 # ...in an 80 ms gap: three more
    assert (stats.missed_ticks, stats.missed_for_input) == (5, 3)
    np.testing.assert_allclose(stats.rings['tick_interval_s'].array(), [0.02, 0.02, 0.029, 0.06, 0.08])
    np.testing.assert_allclose(stats.rings['input_s'].array(), [0, 0, 0, 0, 0, 0.012])


def test_the_input_status_counts_what_the_pose_input_judged():
    stats = NodeStats(50.0)
    stats.window = {'bad0': 0, 'wall0': time.perf_counter()}
    poses = PoseInput(PoseInputLimits(expected_frame_id='world', stale_after_s=0.5))
    name, level, message, values = _input_status('tissue_sim', NS, stats, poses)
    assert (name, level, values['poses_received']) == ('tissue_sim: input', 'OK', 0) and 'no pose yet' in message
    poses.offer([0.0, 0.0, 0.16], DOWN, 'world', NS, NS)
    poses.offer([0.0, 0.0, 0.16], DOWN, 'map', NS + 10_000_000, NS + 10_000_000)
    poses.offer([np.nan, 0.0, 0.16], DOWN, 'world', NS + 20_000_000, NS + 20_000_000)
    name, level, message, values = _input_status('tissue_sim', NS + 30_000_000, stats, poses)
    assert (level, values['poses_received'], values['poses_accepted']) == ('WARN', 3, 1)
    assert (values['bad_input.wrong_frame'], values['bad_input.non_finite'], values['bad_input.jump']) == (1, 1, 0)
    assert message.startswith('2 bad poses in the last')
    assert values['last_pose_age_s'] == pytest.approx(0.03) and not values['stale']
    stats.window['bad0'] = poses.bad_total                    # a new window: no new bad pose
    level, message = _input_status('tissue_sim', 2 * NS, stats, poses)[1:3]
    assert level == 'WARN' and message.startswith('no pose for 1 s')
