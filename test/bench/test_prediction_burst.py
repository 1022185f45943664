"""A burst of planner requests (bench/prediction_burst.py): each request a path from where the
needle is, on along its axis at the burst's speed, a pose every 0.1 s, stamped 1 ms apart; the
engine's path rules accept it; the figures pair answers with their requests. Truth: the needle
axis of the pose (world -z for the default orientation), the path read back with the node's own
reader, the times made up here."""
import types

import numpy as np
import pytest

pytest.importorskip('rclpy')

from tissue_sim_ros.bench.prediction_burst import POSE_EVERY_S, PredictionBurst  # noqa: E402
from tissue_sim_ros.engine.prediction import check_path  # noqa: E402
from tissue_sim_ros.ros.predictions import path_arrays  # noqa: E402

DOWN = np.array([1.0, 0.0, 0.0, 0.0])            # the needle frame's +z along world -z


class _Client:
    def create_publisher(self, *args):
        return types.SimpleNamespace(publish=lambda msg: None)

    def create_subscription(self, *args):
        return None


def test_each_request_goes_on_along_the_needle_axis_from_the_current_pose():
    burst = PredictionBurst(_Client(), 3, path_s=2.0, speed_m_s=0.004)
    start = np.array([0.001, -0.002, 0.159])
    requests = burst.requests(start, DOWN, 'world', 5_000_000_000)
    assert len(requests) == 3
    for r, msg in enumerate(requests):
        stamps, positions, orientations = path_arrays(msg, 'world')
        offsets = np.arange(21) * POSE_EVERY_S
        first = msg.poses[0].header.stamp
        assert first.sec * 1_000_000_000 + first.nanosec == 5_000_000_000 + r * 1_000_000
        np.testing.assert_allclose(stamps, offsets, rtol=0, atol=1e-9)      # from the first pose
        np.testing.assert_allclose(positions, start + np.outer(0.004 * offsets, [0.0, 0.0, -1.0]), rtol=0,
                                   atol=1e-15)
        np.testing.assert_array_equal(orientations, np.tile(DOWN, (21, 1)))
        check_path(stamps, positions, orientations, max_jump_m=0.005, start_pose=(start, DOWN))


def test_the_figures_pair_each_answer_with_its_request():
    burst = PredictionBurst(_Client(), 3)
    burst.sent_at = {10: 100.0, 20: 100.001, 30: 100.002}
    burst.answers = {10: (100.5, 101), 30: (101.202, 0), 99: (100.1, 5)}      # 99: not this burst's
    figures = burst.figures()
    assert (figures['predictions_sent'], figures['predictions_answered'], figures['predictions_with_points']) \
        == (3, 2, 1)
    assert figures['prediction_first_answer_s'] == pytest.approx(0.5)
    assert figures['prediction_last_answer_s'] == pytest.approx(1.2)
