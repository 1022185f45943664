"""Predictions as the ~/predict_path action, against the plan/candidate topic pair on the same node.

Truths: the topic pair's answer to the same path (the same numbers), the path's own length (the
feedback's rows and progress), the result itself (the feedback's partial columns are its rows),
the wrench the node keeps publishing meanwhile (counted by the client).
"""

import os
import threading
import time

import numpy as np
import pytest

rclpy = pytest.importorskip('rclpy')
pytest.importorskip('tissue_sim_msgs.action')

from geometry_msgs.msg import WrenchStamped  # noqa: E402
from nav_msgs.msg import Path  # noqa: E402
from rclpy.action import ActionClient  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402
from tissue_sim_msgs.action import PredictPath  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402

from tissue_sim_ros.ros import node as node_mod  # noqa: E402
from tissue_sim_ros.ros.predictions import path_msg  # noqa: E402

DOMAIN_ID = 20 + os.getpid() % 20
DOWN = np.array([1.0, 0.0, 0.0, 0.0])
RELIABLE = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)


@pytest.fixture(autouse=True)
def _private_ros(monkeypatch):
    monkeypatch.setenv('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    monkeypatch.setenv('ROS_DOMAIN_ID', str(DOMAIN_ID))


def candidate(start, seconds, stamp_s, step_s=0.05, speed=0.004):
    t = np.arange(int(round(seconds / step_s)) + 1) * step_s
    positions = np.asarray(start, dtype=float) - np.outer(speed * t, [0.0, 0.0, 1.0])
    return path_msg(
        int(stamp_s * 1e9) + np.round(t * 1e9).astype(np.int64),
        positions,
        np.tile(DOWN, (t.size, 1)),
        'world',
    )


@pytest.fixture(scope='module')
def node():
    """A node with one prediction worker on the live settings, its executor on a thread, and a
    client node on another."""
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.ros.node_main import make_executor

    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=DOMAIN_ID)
    scene = Scene.from_file(
        None,
        mesh={'generator': 'box', 'divisions': [6, 6, 4]},
        targets=[{'name': 'tumour', 'position_m': [0.002, 0.0, -0.012]}],
    )
    the_node = node_mod.TissueSimNode(
        scene=scene,
        context=ctx,
        parameter_overrides=[
            Parameter('prediction.workers', value=1),
            Parameter('prediction.threads', value=1),
            Parameter('prediction.max_error', value=0.0),
        ],
    )
    client = rclpy.create_node('planner', context=ctx)
    stop = threading.Event()
    threads = []
    for n, executor in (
        (the_node, make_executor(the_node.config.executor, context=ctx)),
        (client, SingleThreadedExecutor(context=ctx)),
    ):
        executor.add_node(n)
        threads.append(
            threading.Thread(
                target=lambda e=executor: [e.spin_once(timeout_sec=0.05) for _ in iter(stop.is_set, True)],
                daemon=True,
            )
        )
        threads[-1].start()
    wrenches = []
    client.create_subscription(
        WrenchStamped, 'needle/wrench', lambda m: wrenches.append(time.monotonic()), RELIABLE
    )
    answers = []
    client.create_subscription(JointTrajectory, 'plan/prediction', answers.append, RELIABLE)
    ask = client.create_publisher(Path, 'plan/candidate', RELIABLE)
    action = ActionClient(client, PredictPath, '/tissue_sim/predict_path')
    deadline = time.monotonic() + 60
    while not (
        action.server_is_ready()
        and ask.get_subscription_count()
        and wrenches
        and the_node.predictions.workers_state == 'warm'
    ):
        assert time.monotonic() < deadline, 'the node, its workers and the action did not come up'
        time.sleep(0.02)
    yield {
        'node': the_node,
        'client': client,
        'action': action,
        'ask': ask,
        'answers': answers,
        'wrenches': wrenches,
        'ctx': ctx,
    }
    stop.set()
    for t in threads:
        t.join(timeout=5)
    action.destroy()
    the_node.destroy_node()
    client.destroy_node()
    rclpy.shutdown(context=ctx)


def wait(future_or_condition, timeout=60.0):
    done = future_or_condition.done if hasattr(future_or_condition, 'done') else future_or_condition
    deadline = time.monotonic() + timeout
    while not done():
        assert time.monotonic() < deadline, 'not done in time'
        time.sleep(0.005)


def send(setup, path, **goal):
    feedback = []
    future = setup['action'].send_goal_async(
        PredictPath.Goal(path=path, **goal), feedback_callback=lambda m: feedback.append(m.feedback)
    )
    wait(future)
    handle = future.result()
    assert handle.accepted
    return handle, feedback


def test_the_action_answers_the_topic_pairs_numbers_with_feedback_and_the_ticks_go_on(node):
    from tissue_sim_ros.ros.prediction_action import result_arrays

    engine = node['node'].engine
    start = node['node'].scene.needle_pose[0]
    path = candidate(start, 40.0, 100.0, step_s=0.02, speed=0.0005)  # 20 mm: 11 mm into the tissue
    # paused, so that both start from one copy of the state (a copy a few advances later starts
    # from another offset of the step grid: a puncture a step earlier or later)
    engine.call(lambda: setattr(engine, 'paused', True))
    node['ask'].publish(path)
    wait(lambda: node['answers'])
    topic = node['answers'][0]
    handle, feedback = send(node, path, live_settings=True, feedback_period_s=0.05)
    result_future = handle.get_result_async()
    wait(result_future)
    engine.call(lambda: setattr(engine, 'paused', False))
    answer = result_future.result()
    print(f'\nthe goal: {len(feedback)} feedback messages for {len(topic.points)} poses')
    assert answer.status == 4, answer.result.message  # SUCCEEDED
    result = answer.result
    columns = result_arrays(result)
    values = np.array([list(p.positions) for p in topic.points])
    assert list(topic.joint_names) == list(columns)[1:]
    np.testing.assert_array_equal(np.column_stack([columns[name] for name in topic.joint_names]), values)
    np.testing.assert_allclose(
        columns['time_from_start_s'],  # the topic's Durations: whole ns
        [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in topic.points],
        rtol=0,
        atol=1e-9,
    )
    assert result.header.frame_id == 'needle' and result.settings == 'as the live scene'
    assert np.abs(columns['force_z_n']).max() > 0.05
    # feedback: in order, growing progress, its partial columns are the result's rows
    assert len(feedback) >= 2
    assert [f.first_pose for f in feedback] == list(
        np.cumsum([0] + [len(f.force_z_n) for f in feedback[:-1]])
    )
    assert all(f.poses_total == len(values) for f in feedback) and feedback[-1].progress == pytest.approx(1.0)
    assert np.all(np.diff([f.progress for f in feedback]) > 0)
    rows = np.concatenate([np.asarray(f.force_z_n) for f in feedback])
    np.testing.assert_array_equal(rows, columns['force_z_n'])
    # the live wrench goes on while a goal runs (its rate: tissue-sim node-bench; here at least 90 %
    # of the ticks arrive)
    ticks0, t0 = len(node['wrenches']), time.monotonic()
    handle, _ = send(node, path, live_settings=True)
    wait(handle.get_result_async())
    elapsed = time.monotonic() - t0
    arrived = np.array(node['wrenches'][ticks0:])
    intervals = np.diff(arrived[arrived <= t0 + elapsed])
    print(
        f'\naction: {elapsed:.2f} s for {len(values)} poses, {len(feedback)} feedback messages; wrench '
        f'interval p50 {1e3 * np.percentile(intervals, 50):.1f} ms, '
        f'p99 {1e3 * np.percentile(intervals, 99):.1f} ms'
    )
    assert len(intervals) >= 0.9 * elapsed * 50 - 2


def test_a_cancelled_goal_ends_promptly_and_a_refused_path_aborts_with_its_reason(node):
    start = node['node'].scene.needle_pose[0]
    handle, feedback = send(
        node, candidate(start, 40.0, 200.0, step_s=0.02, speed=0.0005), live_settings=True
    )
    wait(lambda: feedback, 30)
    t0 = time.monotonic()
    cancel = handle.cancel_goal_async()
    result_future = handle.get_result_async()
    wait(result_future, 10)
    assert result_future.result().status == 5  # CANCELED
    assert result_future.result().result.message == 'cancelled'
    cancelled_in = time.monotonic() - t0
    wait(cancel)
    # the worker is free again: a short path is answered at once, not after the 40 s one
    handle, _ = send(node, candidate(start, 0.5, 300.0), live_settings=True)
    quick = handle.get_result_async()
    wait(quick, 20)
    assert quick.result().status == 4
    print(f'\ncancel: the goal ended {1e3 * cancelled_in:.0f} ms after the request')
    handle, _ = send(node, candidate(start + [0.0, 0.01, 0.0], 0.5, 400.0))
    refused = handle.get_result_async()
    wait(refused, 20)
    assert refused.result().status == 6  # ABORTED
    assert "the needle's current pose" in refused.result().result.message


def test_the_python_client_returns_arrays_and_a_dataframe(node):
    from tissue_sim_ros.client import PredictionClient, PredictionRefused

    start = node['node'].scene.needle_pose[0]
    seen = []
    with PredictionClient(context=node['ctx']) as client:
        t = np.arange(21) * 0.05
        answer = client.predict(
            (t, start - np.outer(0.004 * t, [0, 0, 1]), np.tile(DOWN, (21, 1))),
            feedback=lambda progress, rows: seen.append(progress),
            live_settings=True,
        )
        with pytest.raises(PredictionRefused, match='jump limit'):
            client.predict((t, start + np.outer(0.1 * t, [1, 0, 0]), np.tile(DOWN, (21, 1))))
    assert answer.columns['time_from_start_s'].tolist() == pytest.approx(t.tolist(), abs=1e-9)
    assert set(answer.columns) >= {'force_z_n', 'tip_depth_m', 'target/tumour/displacement_m'}
    assert answer.target_names == ['tumour'] and seen and seen[-1] == pytest.approx(1.0)
    frame = answer.dataframe
    try:
        import pandas  # noqa: F401
    except ImportError:
        assert frame is None
    else:
        assert list(frame.index) == pytest.approx(t.tolist(), abs=1e-9)
        np.testing.assert_array_equal(frame['force_z_n'].to_numpy(), answer.columns['force_z_n'])
