"""A burst of planner requests for ``tissue-sim node-bench --predictions N``.

During the bench's measured window a client sends ``count`` candidate paths on ``plan/candidate``
at once, each starting from the pose the bench last sent (where the needle is) and going on along
the needle axis at ``speed_m_s`` for ``path_s`` seconds, a pose every ``POSE_EVERY_S``. The answers
on ``plan/prediction`` are paired with the requests by their stamps. Figures: how many were
answered (with points), the time from the burst to each answer, and, from the node's diagnostics,
the real-time factor of its predictions; the live wrench rate over the same window is the bench's.
"""
from __future__ import annotations

import threading
import time

import numpy as np
from nav_msgs.msg import Path
from trajectory_msgs.msg import JointTrajectory

from tissue_sim_ros.engine.needle.pose import needle_axis
from tissue_sim_ros.ros.messages.conversions import stamp_to_ns
from tissue_sim_ros.ros.predictions import path_msg
from tissue_sim_ros.ros.messages.topics import PLAN_QOS

__all__ = ['POSE_EVERY_S', 'PredictionBurst']

POSE_EVERY_S = 0.1


class PredictionBurst:
    """Send the burst from ``client`` (an rclpy node spun elsewhere) ``delay_s`` after
    :meth:`start`; ``current_pose()`` -> (position (3,), orientation (4,), frame_id)."""

    def __init__(self, client, count: int, *, path_s: float = 10.0, speed_m_s: float = 0.001):
        self.count, self.path_s, self.speed_m_s = int(count), float(path_s), float(speed_m_s)
        self.sent_at: dict[int, float] = {}          # request stamp (ns) -> send time
        self.answers: dict[int, tuple[float, int]] = {}  # request stamp -> (receive time, points)
        self._lock = threading.Lock()
        self.publisher = client.create_publisher(Path, 'plan/candidate', PLAN_QOS)
        client.create_subscription(JointTrajectory, 'plan/prediction', self._on_answer, PLAN_QOS)
        self._thread = None

    def _on_answer(self, msg) -> None:
        with self._lock:
            self.answers[stamp_to_ns(msg.header.stamp)] = (time.monotonic(), len(msg.points))

    def start(self, delay_s: float, current_pose) -> None:
        def send():
            time.sleep(delay_s)
            position, orientation, frame_id = current_pose()
            for msg in self.requests(position, orientation, frame_id, time.time_ns()):
                self.sent_at[stamp_to_ns(msg.header.stamp)] = time.monotonic()
                self.publisher.publish(msg)
        self._thread = threading.Thread(target=send, name='prediction-burst', daemon=True)
        self._thread.start()

    def requests(self, position, orientation, frame_id: str, now_ns: int) -> list:
        """The burst's Path messages, stamped 1 ms apart from ``now_ns``."""
        axis = needle_axis(np.asarray(orientation, dtype=float))
        offsets = np.arange(0.0, self.path_s + 1e-9, POSE_EVERY_S)
        positions = np.asarray(position, dtype=float) + np.outer(self.speed_m_s * offsets, axis)
        orientations = np.tile(np.asarray(orientation, dtype=float), (offsets.size, 1))
        return [path_msg(now_ns + r * 1_000_000 + np.round(offsets * 1e9).astype(np.int64), positions,
                         orientations, frame_id) for r in range(self.count)]

    def wait(self, timeout_s: float) -> None:
        """Until every request is answered, or ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            with self._lock:
                if self.sent_at and len(self.answers) >= self.count:
                    return
            time.sleep(0.05)

    def figures(self) -> dict:
        with self._lock:
            answered = {s: a for s, a in self.answers.items() if s in self.sent_at}
        delays = np.array([answered[s][0] - self.sent_at[s] for s in sorted(answered)])
        return {
            'predictions_sent': len(self.sent_at),
            'predictions_answered': len(answered),
            'predictions_with_points': sum(1 for _, points in answered.values() if points),
            'prediction_path_s': self.path_s,
            'prediction_first_answer_s': float(delays.min()) if delays.size else float('nan'),
            'prediction_last_answer_s': float(delays.max()) if delays.size else float('nan'),
        }
