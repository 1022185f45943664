"""Predictions as an action: ``~/predict_path`` (tissue_sim_msgs/action/PredictPath).

The goal is a nav_msgs/Path and options; the node simulates it exactly as a ``plan/candidate``
(:class:`~tissue_sim_ros.ros.predictions.PredictionService`: a copy of the state, a worker process, the
same numbers), and:

- **feedback**: the worker writes each row as it computes it into shared memory
  (:class:`~tissue_sim_ros.ros.predictions.Progress`); at most every ``feedback_period_s`` (default
  0.1 s) the server sends the progress fraction and the rows since the previous feedback;
- **cancel**: accepted at once; the worker stops at its next row, and the goal ends canceled
  without waiting for it;
- **result**: typed arrays (time, force, torque, tip depth, each target's displacement), the
  settings it ran on; a refused path (the same rules as the topic pair) aborts the goal with the
  reason in ``message``.

The server lives on a node of its own, ``<node>_actions``, spun by a SingleThreadedExecutor on a
thread of its own, so that the node's executor (the EventsExecutor by default) never runs a goal:
rclpy's EventsExecutor spins without pause while a goal's coroutine awaits its answer (a core's
worth of thread time, measured), which would take the interpreter lock from the tick. Goals are
coroutines on that executor, each awaiting its prediction, so any number run at once.
"""

from __future__ import annotations

import array
import threading

import numpy as np

from tissue_sim_ros.engine.prediction import WRENCH_COLUMNS
from tissue_sim_ros.ros.messages.conversions import header
from tissue_sim_ros.ros.predictions import CANCELLED

__all__ = [
    'ACTION_NAME',
    'ACTION_TYPE',
    'DEFAULT_FEEDBACK_PERIOD_S',
    'PredictPathServer',
    'result_arrays',
    'start_predictions',
]

ACTION_NAME = '~/predict_path'
ACTION_TYPE = 'tissue_sim_msgs/action/PredictPath'
DEFAULT_FEEDBACK_PERIOD_S = 0.1
#: the result's and the feedback's columns: the prediction's, each a float64[] of the action
_FIELDS = WRENCH_COLUMNS


def _doubles(values) -> array.array:
    out = array.array('d')
    out.frombytes(np.ascontiguousarray(values, dtype=np.float64).tobytes())
    return out


def _fill_columns(msg, times, values) -> None:
    msg.time_from_start_s = _doubles(times)
    for k, name in enumerate(_FIELDS):
        setattr(msg, name, _doubles(values[:, k]))


def result_arrays(result) -> dict:
    """A PredictPath result (or feedback) as numpy arrays by column name, targets as
    ``target/<name>/displacement_m`` (the topic pair's column names)."""
    columns = {'time_from_start_s': np.asarray(result.time_from_start_s, dtype=np.float64)}
    columns.update({name: np.asarray(getattr(result, name), dtype=np.float64) for name in _FIELDS})
    for target in getattr(result, 'targets', []):
        columns[f'target/{target.name}/displacement_m'] = np.asarray(target.displacement_m, dtype=np.float64)
    return columns


class PredictPathServer:
    """The action server (see the module docstring) of ``node`` over its ``predictions``."""

    def __init__(self, node, predictions, target_names):
        import rclpy
        from rclpy.action import ActionServer, CancelResponse, GoalResponse
        from rclpy.executors import SingleThreadedExecutor
        from tissue_sim_msgs.action import PredictPath

        self.type, self.predictions, self.target_names = PredictPath, predictions, list(target_names)
        self.name = node.resolve_service_name(ACTION_NAME)  # '/<namespace>/<node>/predict_path'
        self.frame_id = predictions.wrench_frame_id
        self.node = rclpy.create_node(
            f'{node.get_name()}_actions',
            namespace=node.get_namespace(),
            context=node.context,
            start_parameter_services=False,
        )
        self._requests: dict = {}
        self.goals = self.succeeded = self.aborted = self.canceled = 0
        self.server = ActionServer(
            self.node,
            PredictPath,
            self.name,
            execute_callback=self._execute,
            goal_callback=lambda goal: GoalResponse.ACCEPT,
            cancel_callback=self._cancel_requested,
        )
        self._cancel_response = CancelResponse.ACCEPT
        self.executor = SingleThreadedExecutor(context=node.context)
        self.executor.add_node(self.node)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._spin, name='tissue_sim-actions', daemon=True)
        self._thread.start()

    def _spin(self) -> None:
        from tissue_sim_ros.system.thread_names import name_os_thread

        name_os_thread()
        while not self._stop.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except Exception:  # noqa: BLE001 - rclpy shut down from outside: the thread ends
                if self._stop.is_set() or not self.node.context.ok():
                    return
                raise

    def _cancel_requested(self, goal_handle):
        request = self._requests.get(id(goal_handle))
        if request is not None:
            self.predictions.cancel(request)
            self._wake(goal_handle)
        return self._cancel_response

    def _wake(self, goal_handle) -> None:
        waiter = self._requests.get(('waiter', id(goal_handle)))
        if waiter is not None and not waiter.done():
            waiter.set_result(True)
            self.executor.wake()        # else the goal's coroutine resumes at the executor's next timeout

    async def _execute(self, goal_handle):
        from rclpy.task import Future

        goal = goal_handle.request
        period = goal.feedback_period_s if goal.feedback_period_s > 0 else DEFAULT_FEEDBACK_PERIOD_S
        self.goals += 1
        request = self.predictions.on_candidate(
            goal.path, reply=lambda r: self._wake(goal_handle), live=goal.live_settings
        )
        self._requests[id(goal_handle)] = request
        sent = 0
        try:
            while not request.done and not goal_handle.is_cancel_requested:
                waiter = Future()
                self._requests[('waiter', id(goal_handle))] = waiter
                timer = threading.Timer(period, lambda: self._wake(goal_handle))
                timer.daemon = True
                timer.start()
                if not request.done and not goal_handle.is_cancel_requested:
                    await waiter
                timer.cancel()
                sent = self._feedback(goal_handle, request, sent)
            return self._finish(goal_handle, request)
        finally:
            self._requests.pop(id(goal_handle), None)
            self._requests.pop(('waiter', id(goal_handle)), None)
            if request.progress is not None:
                request.progress.close()

    def _feedback(self, goal_handle, request, sent: int) -> int:
        progress = request.progress
        if progress is None or request.cancelled:
            return sent
        done = progress.done()
        if done <= sent:
            return sent
        rows = progress.read(sent, done)
        feedback = self.type.Feedback(
            progress=float(done / progress.rows), first_pose=sent, poses_total=progress.rows
        )
        _fill_columns(feedback, request.times[sent:done], rows)
        goal_handle.publish_feedback(feedback)
        return done

    def _finish(self, goal_handle, request):
        result = self.type.Result(header=header(self.frame_id, request.stamp), settings=request.settings)
        if goal_handle.is_cancel_requested or request.reason == CANCELLED:
            self.predictions.cancel(request)
            goal_handle.canceled()
            self.canceled += 1
            result.message = CANCELLED
            return result
        prediction = request.prediction
        if prediction is None:
            goal_handle.abort()
            self.aborted += 1
            result.message = request.reason or 'not predicted'
            return result
        _fill_columns(result, prediction.time_from_start_s, prediction.values)
        from tissue_sim_msgs.msg import TargetDisplacement

        first = len(WRENCH_COLUMNS)
        result.targets = [
            TargetDisplacement(name=name, displacement_m=_doubles(prediction.values[:, first + k]))
            for k, name in enumerate(self.target_names)
        ]
        goal_handle.succeed()
        self.succeeded += 1
        return result

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.server.destroy()
        self.executor.remove_node(self.node)
        self.node.destroy_node()


def start_predictions(node, cfg) -> None:
    """The predictions of ``node`` (a TissueSimNode): the service, ``plan/candidate`` and
    ``plan/prediction``, and the action server; set as the node's ``predictions``,
    ``prediction_pub``, ``candidate_sub`` and ``action_server``."""
    from nav_msgs.msg import Path
    from rclpy.serialization import deserialize_message
    from trajectory_msgs.msg import JointTrajectory

    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.ros.messages.topics import PLAN_QOS
    from tissue_sim_ros.ros.predictions import PredictionService

    ladder = node.engine.ladder
    if cfg.prediction_max_error > 0 and ladder is None:
        ladder = DegradationLadder(node.scene)  # its rungs' settings, never switched
        node._measure_ladder(ladder)

    def rung():
        level = (
            None
            if ladder is None or cfg.prediction_max_error <= 0
            else ladder.cheapest_within(cfg.prediction_max_error)
        )
        if level is None:
            return None, None
        chosen = ladder.rungs[level]
        return chosen.threshold, ladder.base_mass_scaling * chosen.mass_factor

    node.prediction_pub = node.create_publisher(JointTrajectory, 'plan/prediction', PLAN_QOS)
    geometry = node.scene.needle.geometry
    node.predictions = PredictionService(
        node.engine,
        frame_id=cfg.frame_id,
        wrench_frame=cfg.wrench_frame,
        wrench_frame_id=cfg.wrench_frame_id,
        target_names=node.scene.targets.names,
        other_needles=node.scene.needle_names[1:],
        max_jump_m=min(cfg.input_limits.max_jump_m, geometry.max_jump_m),
        length_m=geometry.length_m,
        max_duration_s=cfg.prediction_max_duration_s,
        workers=cfg.prediction_workers,
        threads=cfg.prediction_threads,
        publish=lambda msg: node._publish(node.prediction_pub, msg),
        log_once=node._log_once,
        decode=lambda data: deserialize_message(data, Path),
        rung=rung,
        prestart=cfg.prediction_prestart,
        to_tissue=node.tf_input.to_tissue,
    )

    def on_candidate(data: bytes) -> None:
        """A candidate path as received: recorded as is, handed to the predictions' intake."""
        if node._recorder is not None:
            node._recorder.write(node.candidate_sub.topic_name, data, node._now_ns())
        node.predictions.receive(data)

    node.candidate_sub = node.create_subscription(Path, 'plan/candidate', on_candidate, PLAN_QOS, raw=True)
    node.action_server = PredictPathServer(node, node.predictions, node.scene.targets.names)
