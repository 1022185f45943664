"""Predictions of a candidate path (engine/prediction.py).

Truths: the live scene itself, continued along the same poses (a prediction is that run, on a
copy); the live scene's arrays before and after (a prediction leaves them alone); the path rules
stated in engine.prediction."""

import numpy as np
import pytest

from support.needles import DOWN, SPEED, TWO, _run
from support.predictions import TICK, _down, _scene
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.prediction import (WRENCH_COLUMNS, check_path, predict, predict_snapshot,
                                              scene_snapshot, write_snapshot)
from tissue_sim_ros.errors import PoseError


def _state(scene):
    return (scene.displacement.copy(), scene.simulation.velocity.copy(), scene.needle.position.copy(),
            float(scene.time), float(scene.target_time), scene.phase, len(scene.puncture_events))


@pytest.fixture(scope='module')
def live_and_prediction():
    """A live run to past the capsule's puncture, a prediction of 1.5 s more from there, and the
    live run continued along the same poses."""
    scene = _scene()
    driver = SimulationDriver(scene)
    stamps, positions, orientations = _down(scene, 0.0, 3.0)
    for k in range(1, stamps.size):
        driver.advance(TICK, positions[k], orientations[k])
    before = _state(scene)
    stamps, positions, orientations = _down(scene, 3.0, 1.5, t0=1234.5)
    path = check_path(stamps, positions, orientations, max_jump_m=0.005, start_pose=scene.needle_pose,
                      length_m=scene.needle.geometry.length_m)
    prediction = predict(driver.scene, path, wrench_frame=driver.wrench_frame)
    after = _state(scene)
    live = [np.r_[driver.force, driver.torque, scene.tip_depth, scene.targets_relative_to_needle()[0]]]
    rest = scene.targets.rest
    displacement = [np.linalg.norm(scene.target_positions() - rest, axis=1)]
    for k in range(1, stamps.size):
        driver.advance(TICK, positions[k], orientations[k])
        live.append(np.r_[driver.force, driver.torque, scene.tip_depth, 0.0])
        displacement.append(np.linalg.norm(scene.target_positions() - rest, axis=1))
    return scene, before, after, prediction, np.array(live), np.array(displacement)


def test_a_prediction_is_the_live_run_continued(live_and_prediction):
    scene, _, _, prediction, live, displacement = live_and_prediction
    assert scene.puncture_events, 'the live run should have punctured the capsule before the prediction'
    assert prediction.columns == list(WRENCH_COLUMNS) + ['target/tumour/displacement_m']
    np.testing.assert_allclose(prediction.time_from_start_s, np.arange(76) * TICK, atol=1e-9)
    # the same schedule of substeps from the same state: equal to rounding
    np.testing.assert_allclose(prediction.values[:, :6], live[:, :6], rtol=0, atol=1e-9)
    np.testing.assert_allclose(prediction.column('tip_depth_m'), live[:, 6], rtol=0, atol=1e-12)
    np.testing.assert_allclose(prediction.column('target/tumour/displacement_m'), displacement[:, 0],
                               rtol=0, atol=1e-12)
    assert abs(prediction.values[-1, 2]) > 0.1, 'the prediction should carry a real load'
    assert prediction.column('tip_depth_m')[-1] > prediction.column('tip_depth_m')[0] + 0.007


def test_a_prediction_leaves_the_live_state_unchanged(live_and_prediction):
    _, before, after, _, _, _ = live_and_prediction
    for a, b in zip(before, after):
        if isinstance(a, np.ndarray):
            assert np.array_equal(a, b)
        else:
            assert a == b


def test_a_worker_snapshot_predicts_the_same_and_a_rung_changes_the_settings(tmp_path):
    scene = _scene()
    stamps, positions, orientations = _down(scene, 0.0, 2.4)
    path = check_path(stamps, positions, orientations, max_jump_m=0.005, start_pose=scene.needle_pose)
    direct = predict(scene, path)
    snapshot = scene_snapshot(scene)
    assert write_snapshot(scene, tmp_path / 'scene.snapshot') >= 0.9 * len(snapshot)
    for copy in (snapshot, str(tmp_path / 'scene.snapshot')):
        again = predict_snapshot(copy, path, threads=1)
        np.testing.assert_allclose(again.values, direct.values, rtol=0, atol=1e-12)
    cheaper = predict_snapshot(snapshot, path, threads=1, mass_scaling=4 * scene.simulation.mass_scaling)
    assert cheaper.substeps == pytest.approx(direct.substeps / 2, rel=0.02)      # dt x sqrt(4)
    assert not np.array_equal(cheaper.values, direct.values)


@pytest.mark.parametrize('change, field, words', [
    (lambda s, p, q: (s[:0], p[:0], q[:0]), 'path.poses', 'no poses'),
    (lambda s, p, q: (s, np.where(np.arange(len(p))[:, None] == 3, np.nan, p), q), r'path.poses\[3\].pose.position',
     'finite'),
    (lambda s, p, q: (np.r_[s[:4], s[2], s[5:]], p, q), r'path.poses\[4\].header.stamp', 'stamps must increase'),
    (lambda s, p, q: (s, p + np.where(np.arange(len(p))[:, None] == 5, 0.02, 0.0), q),
     r'path.poses\[5\].pose.position', 'jump limit'),
    (lambda s, p, q: (s, p, q * np.where(np.arange(len(p))[:, None] == 2, 1.5, 1.0)),
     r'path.poses\[2\].pose.orientation', 'quaternion norm'),
    (lambda s, p, q: (s * 100, p, q), r'path.poses\[9\].header.stamp', 'more than the limit'),
    (lambda s, p, q: (s, p + [0.0, 0.0, 0.01], q), r'path.poses\[0\].pose.position', "the needle's current pose"),
])
def test_a_bad_path_is_refused_naming_the_pose(change, field, words):
    scene = _scene()
    stamps, positions, orientations = change(*_down(scene, 0.0, 0.18))
    with pytest.raises(PoseError, match=field) as caught:
        check_path(stamps, positions, orientations, max_jump_m=0.005, max_duration_s=10.0,
                   start_pose=scene.needle_pose)
    assert words in str(caught.value)


def test_a_prediction_moves_the_first_needle_and_reports_the_others_held():
    """From a state with the fixation needle in the tissue, a path that takes the biopsy needle
    in beside it: the fixation's wrench is a column, equal to the live run continued."""
    from tissue_sim_ros.engine.prediction import check_path, predict
    scene, _ = _run(TWO, [(10.0, 10.0), (0.0, 3.0)], 3.0)
    driver = SimulationDriver(scene)
    start, q = scene.needle_pose
    times = np.arange(0.0, 3.0 + 1e-9, TICK)
    positions = start + (SPEED * times)[:, None] * DOWN
    path = check_path(times, positions, np.tile(q, (times.size, 1)), max_jump_m=0.005)
    prediction = predict(driver.scene, path, wrench_frame=driver.wrench_frame)
    assert prediction.columns[-6:] == [f'needle/fixation/{c}' for c in
                                       ('force_x_n', 'force_y_n', 'force_z_n', 'torque_x_nm', 'torque_y_nm', 'torque_z_nm')]
    live = [driver.forces[1].copy()]
    for k in range(1, times.size):
        driver.advance(TICK, positions[k], q)
        live.append(driver.forces[1].copy())
    np.testing.assert_allclose(prediction.values[:, -6:-3], live, rtol=0, atol=1e-9)
    assert abs(prediction.values[-1, -4] - prediction.values[0, -4]) > 0.05   # felt the push beside it
