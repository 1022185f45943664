"""Scene (engine/scene/scene.py), the engine's whole-step API: advances add up to the time asked
for, deadlines leave steps to the next call, the start gap, and several needles in one tissue."""

import time

import numpy as np
import pytest

from support.needles import MESH, TWO, _run
from support.scenes import small_scene
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import PoseError, SceneError

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


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


def test_needle_starting_inside_the_tissue_is_refused():
    with pytest.raises(PoseError, match='needle.initial_pose = .*starts inside the tissue'):
        small_scene(gap=-0.003)


def test_advance_calls_add_up_to_the_time_asked_for():
    """Whole steps toward a running target: 100 calls of 20 ms end within one step before 2 s,
    never past it (dropping each call's remainder ran 20.6 ms per call on the default scene)."""
    scene = small_scene()
    p, q = scene.needle_pose
    for _ in range(100):
        scene.advance(0.02, p, q)
    assert 2.0 - scene.dt < scene.time <= 2.0 + 1e-12
    scene.reset()
    assert scene.time == 0.0
    scene.advance(0.02, p, q)
    assert 0.02 - scene.dt < scene.time <= 0.02 + 1e-12


def test_a_deadline_leaves_steps_to_the_next_call_without_changing_the_result():
    """An advance stopped by its deadline (or max_steps) leaves the rest of its steps to the next
    call, even one of duration 0, and the needle and tissue end exactly where one uninterrupted
    advance puts them; a deadline already past runs no step and does not move the needle."""
    p0, q = small_scene().needle_pose
    target = p0 + np.array([0.0, 0.0, -0.004])

    def run(split):
        scene = small_scene(gap=0.001)
        counts = []
        for k in range(1, 6):
            pose = p0 + (target - p0) * k / 5
            if split:
                counts.append(scene.advance(0.02, pose, q, max_steps=3))
                counts.append(scene.advance(0.0, pose, q))
            else:
                counts.append(scene.advance(0.02, pose, q))
        return scene, counts

    whole, whole_counts = run(False)
    parts, part_counts = run(True)
    assert sum(part_counts) == sum(whole_counts) and max(part_counts[::2]) == 3
    assert min(part_counts[1::2]) > 0                        # the duration-0 calls ran the rest
    assert parts.time == whole.time
    assert np.allclose(parts.needle.position, whole.needle.position, rtol=0, atol=1e-15)
    # the same steps; the split calls interpolate the needle from another start, equal to round-off
    assert np.abs(whole.displacement).max() > 1e-4
    assert np.abs(parts.displacement - whole.displacement).max() < 1e-12 * np.abs(whole.displacement).max()
    before = parts.needle.position.copy()
    assert parts.advance(0.02, target + [0.0, 0.0, -0.001], q, deadline=time.perf_counter() - 1.0) == 0
    assert np.array_equal(parts.needle.position, before)
    assert parts.advance(0.0, target, q) > 0                 # the next call runs those steps


def test_advance_moves_the_needle_at_the_commanded_speed_in_every_step():
    """Calls of 10 ms at 10 mm/s (not a whole number of steps): every step, the last of each call
    included, moves the needle by v dt, and after each call it lies on the line at the
    simulation's time. Clamping each call's last step at the target made steps of 0.53 to 1.17 v dt."""
    scene = small_scene(gap=0.005)
    # every step through after_step, which records it here (the compiled substeps place the needle
    # the same way, bit for bit: engine/compiled/test_substeps.py)
    scene.compiled_substeps = False
    sim, needle = scene.simulation, scene.needle
    p0, q = scene.needle_pose
    speed, travels = 0.01, []
    original = needle.after_step

    def record(dt):
        travels.append(float(np.linalg.norm(needle.position - needle._previous_position)))
        original(dt)

    needle.after_step = record
    for k in range(1, 21):
        scene.advance(0.01, p0 + np.array([0.0, 0.0, -speed * 0.01 * k]), q)
        assert needle.position[2] == pytest.approx(p0[2] - speed * sim.time, abs=1e-12)
    assert scene.phase == 'approach' and len(travels) > 20 * 0.01 / sim.dt - 2
    assert np.allclose(travels, speed * sim.dt, rtol=1e-9)


def test_a_scene_file_that_is_not_a_mapping_is_refused_by_name(tmp_path):
    path = tmp_path / 'list.yaml'
    path.write_text('- 1\n- 2\n')
    with pytest.raises(SceneError, match=r"list.yaml': expected a mapping of scene keys .* found a list"):
        Scene.from_file(path)


@pytest.mark.parametrize('gap', [0.0005, 0.004, 0.02])
def test_start_gap_puts_the_tip_that_far_above_the_surface(gap):
    """needle.start_gap_m: the tip moves along the axis to that distance from the surface; the
    distance is measured by the tip itself: driving it gap + 1 mm makes contact, gap - 0.2 mm
    does not."""
    from tissue_sim_ros.engine.driver import SimulationDriver
    scene = Scene.from_file(None, mesh=COARSE, needle={'start_gap_m': gap})
    assert scene.start_gap_m == pytest.approx(gap, abs=1e-12)
    position, orientation = scene.needle_pose
    axis = scene.needle.axis.copy()
    driver = SimulationDriver(scene)
    for travel, touches in ((gap - 0.0002, False), (gap + 0.001, True)):
        driver.reset()
        pushed = 0.0                      # the largest axial force the tissue put on the needle
        steps = max(1, int(max(travel, 0.0) / 0.002) + 1)
        for k in range(1, steps + 1):
            driver.advance(0.02, position + max(travel, 0.0) * k / steps * axis, orientation)
            pushed = max(pushed, -float(driver.force @ axis))
        assert (pushed > 1e-6) == touches, (travel, pushed)


@pytest.mark.parametrize('text', ['', '# only a comment\n', '{}\n'])
def test_an_empty_scene_file_is_refused_saying_what_it_would_run(tmp_path, text):
    path = tmp_path / 'empty.yaml'
    path.write_text(text)
    with pytest.raises(SceneError, match=r"scene_file = '.*empty.yaml': no scene keys .*force stays 0 N"):
        Scene.from_file(path)
