"""Several needles in one tissue (scene key ``needles``).

Truths: the one-needle scene (a list of one needle, or a second needle that never touches the
tissue, changes nothing, bit for bit); the run without the other needle's push (each wrench
changes when the other needle pushes nearby, and only through the tissue); the schema's rules.
"""
import numpy as np
import pytest

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import InputError

MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
DOWN = np.array([0.0, 0.0, -1.0])
SPEED, TICK = 0.005, 0.02


def _run(needles, moves, seconds):
    """Drive each needle down at SPEED during its (start, end) window of ``moves`` [s]; per tick
    the forces of every needle (k, n, 3)."""
    scene = Scene.from_file(None, mesh=MESH, needles=needles)
    driver = SimulationDriver(scene)
    starts = [needle.position.copy() for needle in scene.needles]
    q = scene.needle.orientation.copy()
    forces = []
    for k in range(1, int(round(seconds / TICK)) + 1):
        t = k * TICK
        poses = [(p + DOWN * SPEED * min(max(t - a, 0.0), b - a), q) for p, (a, b) in zip(starts, moves)]
        driver.advance(TICK, *poses[0], others=poses[1:])
        forces.append(driver.forces.copy())
    return scene, np.array(forces)


TWO = [{'name': 'biopsy', 'initial_position_m': [0.0, 0.0, 0.159]},
       {'name': 'fixation', 'initial_position_m': [0.005, 0.0, 0.159]}]


@pytest.mark.parametrize('pusher', [0, 1])
def test_each_wrench_changes_when_the_other_needle_pushes_nearby(pusher):
    """The held needle goes 6 mm into the tissue (15 mm from 9 mm above it) and stays; the other,
    5 mm beside it, then goes in as far or stays out. The held needle's force changes only in the first case."""
    held = 1 - pusher
    moves = [None, None]
    moves[held] = (0.0, 3.0)
    pushed = list(moves)
    pushed[pusher] = (3.0, 6.0)
    still = list(moves)
    still[pusher] = (0.0, 0.0)
    scene, with_push = _run(TWO, pushed, 6.0)
    _, without = _run(TWO, still, 6.0)
    assert [n.phase for n in scene.needles][held] == 'contact'
    before = slice(0, 150)           # until the pusher starts: the two runs are the same run
    np.testing.assert_array_equal(with_push[before, held], without[before, held])
    change = np.abs(with_push[-1, held] - without[-1, held])
    assert change[2] > 0.05, f'the held needle felt {change} N of the push beside it'
    assert abs(with_push[-1, pusher, 2]) > 0.2                          # the pusher carries a load
    np.testing.assert_array_equal(without[:, pusher], 0.0)              # the one left out: none


def test_a_list_of_one_needle_and_a_needle_that_never_touches_change_nothing():
    one, alone = _run([{'name': 'only', 'initial_position_m': [0.0, 0.0, 0.159]}], [(0.0, 3.0)], 3.0)
    default = Scene.from_file(None, mesh=MESH)
    assert default.needle_names == ['needle'] and one.needle_names == ['only']
    far = [TWO[0], {'name': 'spare', 'initial_position_m': [0.02, 0.02, 0.3]}]
    _, beside = _run(far, [(0.0, 3.0), (0.0, 0.0)], 3.0)
    np.testing.assert_array_equal(beside[:, 0], alone[:, 0])
    assert np.abs(alone[-1, 0, 2]) > 0.2


def test_a_reset_puts_every_needle_back():
    scene, _ = _run(TWO, [(0.0, 2.0), (0.0, 2.0)], 2.0)
    scene.reset()
    np.testing.assert_array_equal([n.position for n in scene.needles], [[0.0, 0.0, 0.159], [0.005, 0.0, 0.159]])
    assert [n.phase for n in scene.needles] == ['approach', 'approach']


@pytest.mark.parametrize('needles, words', [
    ([{'name': 'a'}, {'name': 'a', 'initial_position_m': [0.01, 0, 0.159]}], r'needles\[1\].name .*unique'),
    ([{'name': 'with space'}], r'needles\[0\].name'),
    ([{'initial_position_m': [0, 0, 0.159]}], r'needles\[0\] = .*non-empty name'),
    ([{'name': 'a', 'diameter': 0.001}], r'unknown scene key needles\[0\].diameter'),
    ([{'name': 'a', 'length_m': -1.0}], r'needles\[0\].length_m = -1.0'),
    ([{'name': 'a'}, {'name': 'b', 'initial_position_m': [0.0, 0.0, -0.01]}],
     r'needles\[1\].initial_pose = .*starts inside the tissue'),
])
def test_bad_needle_lists_are_refused_by_name(needles, words):
    """Refused as input (a SceneError for the keys, a PoseError for where the needle starts)."""
    with pytest.raises(InputError, match=words):
        Scene.from_file(None, mesh={'generator': 'box', 'divisions': [4, 4, 3]}, needles=needles)


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
