"""Predictions of a candidate path (engine.prediction, tissue-sim predict).

Truths: the live scene itself, continued along the same poses (a prediction is that run, on a
copy); the live scene's arrays before and after (a prediction leaves them alone); the path rules
stated in engine.prediction; the msg_examples answer, recomputed.
"""
import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest

from tissue_sim_ros.analysis.predict import main as predict_main, read_path_csv
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.errors import PoseError
from tissue_sim_ros.engine.prediction import (WRENCH_COLUMNS, check_path, predict, predict_snapshot,
                                              scene_snapshot, write_snapshot)
from tissue_sim_ros.engine.scene.scene import Scene

ROOT = Path(__file__).resolve().parents[1]
COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}
TUMOUR = [{'name': 'tumour', 'position_m': [0.002, 0.0, -0.012]}]
TICK = 0.02
SPEED = 0.005


def _scene():
    return Scene.from_file(None, mesh=COARSE, targets=TUMOUR)


def _down(scene, start_s, seconds, t0=0.0):
    """A straight path down the needle axis at SPEED, a pose per tick, from the pose the needle
    reaches after ``start_s`` of the same motion."""
    p0, q = scene.initial_needle_pose
    axis = scene.needle.axis
    t = np.arange(0.0, seconds + 1e-9, TICK)
    positions = p0 + ((start_s + t) * SPEED)[:, None] * axis
    return t0 + t, positions, np.tile(q, (t.size, 1))


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


def test_predict_command_writes_its_four_files(tmp_path):
    scene = _scene()
    stamps, positions, orientations = _down(scene, 0.0, 2.4)
    path_csv = tmp_path / 'path.csv'
    rows = np.column_stack([stamps, positions, orientations])
    path_csv.write_text('# a comment line\nt_s,x_m,y_m,z_m,qx,qy,qz,qw,note\n' +
                        ''.join(','.join(f'{v:.9g}' for v in row) + ',x\n' for row in rows))
    sets = ['mesh.generator=box', 'mesh.divisions=[6, 6, 4]',
            'targets=[{name: tumour, position_m: [0.002, 0.0, -0.012]}]']
    out = tmp_path / 'out'
    prediction = predict_main(None, path_csv, out, sets=sets, stream=open(tmp_path / 'log.txt', 'w'))
    with open(out / 'prediction.csv') as f:
        table = list(csv.DictReader(f))
    assert len(table) == stamps.size
    direct = predict(scene, check_path(stamps, positions, orientations, max_jump_m=0.005), wrench_frame='needle')
    np.testing.assert_allclose([float(r['force_z_n']) for r in table], direct.column('force_z_n'), atol=1e-6)
    summary = json.loads((out / 'prediction.json').read_text())
    assert summary['points'] == stamps.size and summary['wrench_frame'] == 'needle'
    assert summary['peak_force_n'] == pytest.approx(np.linalg.norm(prediction.values[:, :3], axis=1).max())
    assert summary['real_time_factor'] > 0 and math.isfinite(summary['real_time_factor'])
    assert (out / 'prediction.png').stat().st_size > 10_000
    assert 'answered in' in (out / 'prediction.md').read_text()


def test_predict_with_a_max_error_runs_on_the_cheapest_rung_within_it(tmp_path, monkeypatch):
    """--max-error: the rung the ladder's probe measured within it (the probe's errors, cached in
    a directory of the test's; a mass rung here), fewer substeps for the same path, and the answer
    within about that error of the live settings' (the probe is another path: twice it)."""
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.engine.ladder_probe import probe_errors
    scene = _scene()
    stamps, positions, orientations = _down(scene, 0.0, 2.4)
    path_csv = tmp_path / 'path.csv'
    path_csv.write_text('t,x,y,z,qx,qy,qz,qw\n' + ''.join(','.join(f'{v:.9g}' for v in row) + '\n'
                                                        for row in np.column_stack([stamps, positions, orientations])))
    sets = ['mesh.generator=box', 'mesh.divisions=[10, 10, 8]']       # 4.6 ms: x4 within the rungs' cap
    log = open(tmp_path / 'log.txt', 'w')
    live = predict_main(None, path_csv, tmp_path / 'live', sets=sets, stream=log)
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'cache'))
    cheap = predict_main(None, path_csv, tmp_path / 'cheap', sets=sets, max_error=0.02, stream=log)
    summary = json.loads((tmp_path / 'cheap' / 'prediction.json').read_text())
    probed = Scene.from_file(None, sets=sets)
    ladder = DegradationLadder(probed)
    errors = probe_errors(probed, ladder)
    level = max(k for k, e in enumerate(errors) if e <= 0.02)
    assert summary['rung'] == ladder.rungs[level].name and summary['rung_error'] == pytest.approx(errors[level])
    assert ladder.rungs[level].mass_factor > 1 and cheap.substeps < 0.6 * live.substeps
    force = live.column('force_z_n')
    assert np.sqrt(np.mean((cheap.column('force_z_n') - force) ** 2)) < 2 * 0.02 * np.ptp(force)


def test_a_path_csv_without_a_column_or_with_a_word_is_refused_by_line(tmp_path):
    from tissue_sim_ros.errors import DataError
    bad = tmp_path / 'bad.csv'
    bad.write_text('t,x,y,z,qx,qy,qz\n0,0,0,0.159,1,0,0\n')
    with pytest.raises(DataError, match="no column 'qw'"):
        read_path_csv(bad)
    bad.write_text('t,x,y,z,qx,qy,qz,qw\n# rows follow\n0,0,0,0.159,1,0,0,0\n0.1,0,0,deep,1,0,0,0\n')
    with pytest.raises(DataError, match=r"column 'z', row 4: 'deep'"):
        read_path_csv(bad)


def test_the_shipped_candidate_path_starts_at_the_default_needle():
    stamps, positions, orientations = read_path_csv(ROOT / 'config' / 'candidate_path.csv')
    scene_start = [0.0, 0.0, 0.159]
    assert positions[0].tolist() == scene_start and stamps[-1] - stamps[0] == pytest.approx(10.0)
    check_path(stamps, positions, orientations, max_jump_m=0.005,
               start_pose=(np.array(scene_start), np.array([1.0, 0.0, 0.0, 0.0])))


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
