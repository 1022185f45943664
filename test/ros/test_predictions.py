"""The node's predictions over ROS (ros/predictions.py): plan/candidate in, plan/prediction out.

Truths: the engine's own prediction of the same path from a scene at rest (the node's tissue is
at rest while no pose comes; the schedules of substeps differ only by where the node's clock
left the step grid, the tolerance stated below), the requests' own stamps and order, the path
rules of engine.prediction (a refusal names the pose), the msg_examples answer, recomputed."""

import os
import signal
import subprocess
import time

import numpy as np
import pytest

from tissue_sim_ros.engine.scene.scene import Scene

rclpy = pytest.importorskip('rclpy')

from nav_msgs.msg import Path  # noqa: E402
from trajectory_msgs.msg import JointTrajectory  # noqa: E402

from support.paths import ROOT  # noqa: E402
from support.processes import group_gone, wait_for  # noqa: E402
from support.ros_harness import DOWN, make_scene  # noqa: E402
from tissue_sim_ros.engine.prediction import check_path, predict  # noqa: E402
from tissue_sim_ros.ros.messages.topics import PLAN_QOS  # noqa: E402
from tissue_sim_ros.ros.predictions import path_msg  # noqa: E402

SPEED = 0.004
STEP_S = 0.05


def _candidate(start, seconds, stamp_s, *, nan_at=None, frame_id='world'):
    """A path straight down from ``start`` at SPEED, a pose every STEP_S, stamped from stamp_s."""
    t = np.arange(int(round(seconds / STEP_S)) + 1) * STEP_S
    positions = np.asarray(start, dtype=float) - np.outer(SPEED * t, [0.0, 0.0, 1.0])
    if nan_at is not None:
        positions[nan_at, 2] = np.nan
    return path_msg(int(stamp_s * 1e9) + np.round(t * 1e9).astype(np.int64), positions,
                    np.tile(DOWN, (t.size, 1)), frame_id)


def _listen(h):
    answers = []
    h.client.create_subscription(JointTrajectory, 'plan/prediction', answers.append, PLAN_QOS)
    publisher = h.client.create_publisher(Path, 'plan/candidate', PLAN_QOS)
    deadline = time.monotonic() + 10
    while not (publisher.get_subscription_count() and h.node.prediction_pub.get_subscription_count()):
        assert time.monotonic() < deadline, 'plan/candidate and plan/prediction did not match'
        time.sleep(0.01)
    return publisher, answers


def _wait(answers, count, timeout=60.0):
    deadline = time.monotonic() + timeout
    while len(answers) < count:
        assert time.monotonic() < deadline, f'{len(answers)} answers after {timeout} s; expected {count}'
        time.sleep(0.02)


def test_answers_in_order_with_the_request_stamps_and_the_engines_values(harness):
    h = harness(**{'prediction.workers': 1, 'prediction.threads': 1, 'prediction.max_error': 0.0})   # as live
    publisher, answers = _listen(h)
    start = h.scene.needle_pose[0]
    requests = [_candidate(start, 2.6, 100.0), _candidate(start, 1.0, 101.0, nan_at=3),
                Path(), _candidate(start, 1.0, 103.0, frame_id='elsewhere'), _candidate(start, 1.5, 104.0)]
    requests[2].header.stamp.sec = 102
    for msg in requests:
        publisher.publish(msg)
    _wait(answers, len(requests))
    assert [a.header.stamp.sec for a in answers] == [100, 101, 102, 103, 104]
    assert [len(a.points) for a in answers] == [53, 0, 0, 0, 31]
    assert answers[0].header.frame_id == h.node.config.wrench_frame_id
    first = answers[0]
    assert [p.time_from_start.sec + 1e-9 * p.time_from_start.nanosec for p in first.points] == \
        pytest.approx(np.arange(53) * STEP_S, abs=1e-9)
    # the engine's prediction of the same path from rest, in the node's wrench frame
    scene = make_scene()
    stamps = np.arange(53) * STEP_S
    positions = start - np.outer(SPEED * stamps, [0.0, 0.0, 1.0])
    expected = predict(scene, check_path(stamps, positions, np.tile(DOWN, (53, 1)), max_jump_m=0.005),
                       wrench_frame=h.node.config.wrench_frame)
    assert list(first.joint_names) == expected.columns
    values = np.array([list(p.positions) for p in first.points])
    force_scale = np.abs(expected.values[:, :3]).max()
    assert force_scale > 0.05, 'the path should load the tissue'
    # the node's clock left the step grid anywhere within a step: each waypoint may be reached up
    # to one step (dt = a few ms at SPEED: microns) earlier or later than from rest
    np.testing.assert_allclose(values[:, :3], expected.values[:, :3], rtol=0, atol=0.03 * force_scale)
    np.testing.assert_allclose(values[:, 6], expected.values[:, 6], rtol=0, atol=SPEED * scene.dt + 1e-9)
    status = h.diagnostics_now()['tissue_sim: predictions'][2]
    assert (status['requests'], status['answered'], status['refused']) == ('5', '2', '3')
    assert 'path.poses[0].header.frame_id' in status['last_refusal'] and 'elsewhere' in status['last_refusal']


def test_a_path_not_starting_at_the_needle_is_refused_and_the_live_ticks_go_on(harness):
    h = harness(**{'prediction.workers': 1, 'prediction.threads': 1})
    publisher, answers = _listen(h)
    start = h.scene.needle_pose[0]
    ticks0 = h.node.ticks
    t0 = time.monotonic()
    publisher.publish(_candidate(start + [0.0, 0.01, 0.0], 1.0, 200.0))
    for k in range(20):
        publisher.publish(_candidate(start, 1.0, 201.0 + k))
    _wait(answers, 21)
    elapsed = time.monotonic() - t0
    assert len(answers[0].points) == 0 and all(len(a.points) == 21 for a in answers[1:])
    assert [a.header.stamp.sec for a in answers] == list(range(200, 221))
    status = h.diagnostics_now()['tissue_sim: predictions'][2]
    assert "the needle's current pose" in status['last_refusal']
    # the tick never waits for the predictions (the rate itself: tissue-sim node-bench --predictions)
    assert h.node.ticks - ticks0 >= 0.8 * elapsed * h.node.config.publish_rate_hz


def test_the_documented_planner_gets_its_answer(harness, monkeypatch, capfd):
    """docs/node.md's ten-line planner, run as written against a node (its candidate: the
    msg_examples path, which starts at the default needle pose the test scene shares)."""
    root = ROOT
    page = (root / 'docs' / 'node.md').read_text()
    start = page.index('```python\nimport rclpy\n') + len('```python\n')
    code = page[start:page.index('```\n', start)]
    harness(**{'prediction.workers': 1, 'prediction.threads': 1})
    monkeypatch.chdir(root)
    try:
        exec(compile(code, 'docs/node.md planner', 'exec'), {})
    finally:
        rclpy.shutdown()
    import ast
    printed = ast.literal_eval(capfd.readouterr().out.strip().splitlines()[-1])
    # the path ends 16 mm below the start, whose tip is 9 mm above the surface: 7 mm deep
    assert printed['tip_depth_m'] == pytest.approx(0.007, abs=2e-5)
    assert abs(printed['force_z_n']) > 0.05


def test_max_error_runs_predictions_on_the_cheapest_rung_within_it(harness):
    from tissue_sim_ros.engine.ladder import DegradationLadder
    h = harness(**{'prediction.workers': 1, 'prediction.threads': 1, 'prediction.max_error': 1.0})
    ladder = h.node.engine.ladder
    deadline = time.monotonic() + 60
    while ladder.predicted_errors is None or None in ladder.predicted_errors:
        assert time.monotonic() < deadline, "the ladder's errors were not measured"
        time.sleep(0.05)
    bottom = ladder.rungs[-1]
    status = h.diagnostics_now()['tissue_sim: predictions'][2]
    assert status['settings'] == (f'non-linearity threshold {bottom.threshold:g}, mass scaling '
                                  f'{ladder.base_mass_scaling * bottom.mass_factor:g}')
    publisher, answers = _listen(h)
    start = h.scene.needle_pose[0]
    publisher.publish(_candidate(start, 2.6, 300.0))
    _wait(answers, 1)
    # the engine's predictions from rest on the bottom rung's settings and as configured: the answer
    # is nearer the first (not pointwise: the node's clock may shift the puncture by a step, which
    # leaves the answer 0.1 from the bottom rung's, against 0.3 from the configured one's)
    values = np.array([list(p.positions) for p in answers[0].points])[:, :3]
    stamps = np.arange(53) * STEP_S
    positions = start - np.outer(SPEED * stamps, [0.0, 0.0, 1.0])
    distance = []
    for level in (len(ladder.rungs) - 1, 0):
        scene = make_scene()
        DegradationLadder(scene).set_level(level)
        expected = predict(scene, check_path(stamps, positions, np.tile(DOWN, (53, 1)), max_jump_m=0.005),
                           wrench_frame=h.node.config.wrench_frame).values[:, :3]
        distance.append(np.sqrt(np.mean((values - expected) ** 2)) / np.abs(expected).max())
    assert distance[0] < 0.6 * distance[1], distance


def test_the_prediction_example_is_what_the_engine_answers():
    """msg_examples/plan_prediction.yaml answers plan_candidate.yaml on the default scene."""
    rclpy = pytest.importorskip('rclpy')  # noqa: F841 - message_yaml needs the message types
    from tissue_sim_ros.ros.messages.from_yaml import load_example
    from tissue_sim_ros.ros.predictions import path_arrays
    request = load_example(ROOT / 'msg_examples' / 'plan_candidate.yaml')['messages']['message']
    answer = load_example(ROOT / 'msg_examples' / 'plan_prediction.yaml')['messages']['message']
    scene = Scene.from_file(None, targets=[{'name': 'tumour', 'position_m': [0.002, 0.0, -0.015]}])
    path = check_path(*path_arrays(request, 'world'), max_jump_m=0.005, start_pose=scene.needle_pose)
    prediction = predict(scene, path, wrench_frame='needle')
    assert answer.header.stamp == request.header.stamp
    assert list(answer.joint_names) == prediction.columns
    assert [p.time_from_start.sec for p in answer.points] == [round(t) for t in prediction.time_from_start_s]
    np.testing.assert_allclose([list(p.positions) for p in answer.points], prediction.values, atol=1e-5)


def test_ctrl_c_ends_the_node_and_its_prediction_workers_quietly(tmp_path):
    """Ctrl-C at a terminal (SIGINT to the node's whole process group) while its prediction
    workers start: the node ends within 5 s, no worker is left, nothing prints a traceback."""
    from tissue_sim_ros.ros.clients.node_process import console_script, private_ros_env
    log = tmp_path / 'node.log'
    command = console_script('tissue_sim_node', 'tissue_sim_ros.cli.node_script') + [
        '--ros-args', '-p', 'prediction.workers:=2', '-p', 'prediction.prestart:=true']
    with open(log, 'w') as out:
        node = subprocess.Popen(command, env=private_ros_env(170 + os.getpid() % 20), stdout=out,
                                stderr=subprocess.STDOUT, start_new_session=True)
    try:
        wait_for(lambda: 'ticking' in log.read_text() or node.poll() is not None, 300, 'the node ticking')
        time.sleep(0.3)                              # the workers in their start-up (spawned, warming up)
        sent = time.monotonic()
        os.killpg(node.pid, signal.SIGINT)           # as a terminal's Ctrl-C: the whole group
        node.wait(timeout=30)
        ended_s = time.monotonic() - sent
        assert group_gone(node.pid, 5.0), 'a worker outlived the node'
    finally:
        if node.poll() is None:
            os.killpg(node.pid, signal.SIGKILL)
    text = log.read_text()
    print(f'node and workers ended {ended_s:.2f} s after SIGINT')
    assert node.returncode == 0 and ended_s < 5.0, text[-2000:]
    assert 'Traceback' not in text and 'KeyboardInterrupt' not in text, text[-2000:]
