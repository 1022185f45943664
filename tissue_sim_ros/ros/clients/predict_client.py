"""A planner's client of the node's ``~/predict_path`` action: a path in, the prediction as arrays out.

::

    from tissue_sim_ros.client import PredictionClient
    with PredictionClient() as client:    # rclpy started here if it is not yet
        answer = client.predict(path)     # a nav_msgs/Path, or (times, positions, orientations)
    answer.columns['force_z_n']           # numpy arrays by column name
    answer.dataframe                      # the same as a pandas DataFrame (None without pandas)

The columns are the topic pair's (``time_from_start_s``, ``force_x_n`` .. ``torque_z_nm``,
``tip_depth_m``, ``target/<name>/displacement_m``), from the action's typed result. Feedback, when
asked for, is called with (progress fraction, the rows so far as a dict of arrays). A goal the node
refuses raises PredictionRefused with its reason; a timeout cancels the goal and raises TimeoutError.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from tissue_sim_ros.errors import InputError

__all__ = ['PathPrediction', 'PredictionClient', 'PredictionRefused']

DEFAULT_ACTION = '/tissue_sim/predict_path'


class PredictionRefused(InputError):
    """The node answered the goal with no prediction (a refused path, a path the engine cannot
    follow); the message is the node's reason."""


@dataclass
class PathPrediction:
    """The answer: ``columns`` (numpy arrays by name, one value per pose), the ``settings`` it ran
    on, the wrench's ``frame_id``, the path's ``stamp_ns``, the feedback messages received."""

    columns: dict
    settings: str
    frame_id: str
    stamp_ns: int
    feedback_messages: int = 0
    wall_s: float = 0.0
    target_names: list = field(default_factory=list)

    @property
    def dataframe(self):
        """The columns as a pandas DataFrame indexed by ``time_from_start_s``; None without pandas
        (not a dependency of the package)."""
        try:
            import pandas
        except ImportError:
            return None
        frame = pandas.DataFrame(self.columns)
        return frame.set_index('time_from_start_s')


def _path_msg(path, frame_id: str):
    if hasattr(path, 'poses'):
        return path
    from tissue_sim_ros.ros.predictions import path_msg

    times, positions, orientations = path
    stamps = (np.asarray(times, dtype=np.float64) * 1e9).round().astype(np.int64) + time.time_ns()
    return path_msg(stamps, positions, orientations, frame_id)


class PredictionClient:
    """An action client of ``action`` on ``node`` (None: a node of its own, ``tissue_sim_planner``,
    on ``context`` or rclpy's default one, which is started if it is not)."""

    def __init__(self, node=None, action: str = DEFAULT_ACTION, context=None):
        import rclpy
        from rclpy.action import ActionClient
        from rclpy.executors import SingleThreadedExecutor
        from tissue_sim_msgs.action import PredictPath

        self._started = False
        if node is None:
            if not rclpy.ok(context=context):
                rclpy.init(context=context)
                self._started = True
            node = rclpy.create_node('tissue_sim_planner', context=context)
            self._own_node = node
        else:
            self._own_node = None
        self.node, self.type = node, PredictPath
        self.client = ActionClient(node, PredictPath, action)
        self._executor = SingleThreadedExecutor(context=node.context)
        self._executor.add_node(node)

    def _spin_until(self, future, deadline: float) -> None:
        while not future.done():
            if time.monotonic() > deadline:
                raise TimeoutError('no answer from the tissue_sim node in time')
            self._executor.spin_once(timeout_sec=0.05)

    def predict(
        self,
        path,
        *,
        frame_id: str = 'world',
        live_settings: bool = False,
        feedback=None,
        feedback_period_s: float = 0.0,
        timeout_s: float = 120.0,
    ) -> PathPrediction:
        """Predict ``path`` (a nav_msgs/Path, or (times [s], positions (k, 3), orientations (k, 4))
        in ``frame_id``); see the module docstring."""
        from tissue_sim_ros.ros.prediction_action import result_arrays

        deadline = time.monotonic() + timeout_s
        if not self.client.wait_for_server(timeout_sec=max(0.0, min(timeout_s, 30.0))):
            raise TimeoutError(
                f'no {self.client._action_name} action server (is tissue_sim_node running, '
                'predictions on, the same ROS_DOMAIN_ID?)'
            )
        received = []

        def on_feedback(message):
            fb = message.feedback
            received.append(fb)
            if feedback is not None:
                feedback(float(fb.progress), result_arrays(fb))

        goal = self.type.Goal(
            path=_path_msg(path, frame_id),
            live_settings=bool(live_settings),
            feedback_period_s=float(feedback_period_s),
        )
        started = time.monotonic()
        sent = self.client.send_goal_async(goal, feedback_callback=on_feedback)
        self._spin_until(sent, deadline)
        handle = sent.result()
        if not handle.accepted:
            raise PredictionRefused('the node rejected the goal')
        answer = handle.get_result_async()
        try:
            self._spin_until(answer, deadline)
        except TimeoutError:
            self._spin_until(handle.cancel_goal_async(), time.monotonic() + 5.0)
            raise
        result = answer.result().result
        if answer.result().status != 4:  # action_msgs/GoalStatus.STATUS_SUCCEEDED
            raise PredictionRefused(f'path: {result.message}')
        stamp = result.header.stamp
        return PathPrediction(
            result_arrays(result),
            result.settings,
            result.header.frame_id,
            int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec),
            len(received),
            time.monotonic() - started,
            [t.name for t in result.targets],
        )

    def close(self) -> None:
        self.client.destroy()
        self._executor.remove_node(self.node)
        if self._own_node is not None:
            self._own_node.destroy_node()
        if self._started:
            import rclpy

            rclpy.try_shutdown(context=self.node.context)

    def __enter__(self) -> PredictionClient:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
