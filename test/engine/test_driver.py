"""The one simulation driver (engine/driver.py), checked against a second formulation (the scene
stepped by hand) and the policy's stated outcomes."""

import numpy as np
import pytest

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.errors import PoseError, SimulationDiverged

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}


def make_scene():
    from tissue_sim_ros.engine.scene.scene import Scene
    return Scene.from_file(None, mesh=COARSE)


def descent(scene, speed=0.02, ticks=60, tick=0.02):
    start, _ = scene.needle_pose
    axis = scene.needle.axis.copy()
    times = tick * np.arange(1, ticks + 1)
    return times, start + speed * times[:, None] * axis


def test_follow_equals_the_scene_stepped_by_hand():
    """A schedule followed by the driver gives bit for bit what Scene.advance + reaction_wrench
    give when called by hand with the same durations (the insert command's old loop)."""
    scene_a, scene_b = make_scene(), make_scene()
    times, positions = descent(scene_a)
    samples = SimulationDriver(scene_a).follow(times, positions)
    orientation = scene_b.needle_pose[1]
    previous, forces, steps = 0.0, [], 0
    for t, p in zip(times, positions):
        steps += scene_b.advance(t - previous, p, orientation)
        previous = t
        forces.append(scene_b.reaction_wrench('world')[0])
    np.testing.assert_array_equal(samples.force, np.array(forces))
    assert samples.substeps == steps and samples.time[-1] == scene_b.time
    assert np.abs(samples.force[:, 2]).max() > 0.05  # it did touch the tissue
    assert samples.tip_depth[-1] > 0 and samples.phase[-1] != 'approach'


def test_a_refused_pose_holds_the_needle_and_time_goes_on():
    scene = make_scene()
    driver = SimulationDriver(scene)
    position, orientation = scene.needle_pose
    outcome = driver.advance(0.02, position + [0.0, 0.0, -0.02], orientation)  # 20 mm > 5 mm limit
    assert isinstance(outcome.refused, PoseError) and driver.refusals == 1
    np.testing.assert_array_equal(scene.needle_pose[0], position)
    assert outcome.substeps == int(0.02 / scene.dt + 1e-9) and driver.simulated_s == 0.02
    with pytest.raises(PoseError):  # a schedule is the caller's: follow raises it
        driver.follow([0.04], [position + [0.0, 0.0, -0.02]])


def _diverging(scene, on_call, nan=False):
    real_advance, real_wrench, calls = scene.advance, scene.reaction_wrench, {'n': 0}

    def advance(*args):
        calls['n'] += 1
        steps = real_advance(*args)
        if calls['n'] == on_call and not nan:
            raise SimulationDiverged('injected', 1, scene.time, scene.dt, scene.dt)
        return steps

    def wrench(frame='world', needle=0):
        force, torque = real_wrench(frame, needle)
        return (force * np.nan if nan and calls['n'] >= on_call else force), torque
    scene.advance, scene.reaction_wrench = advance, wrench


@pytest.mark.parametrize('nan', [False, True])
def test_divergence_policy_reset_hold_raise(nan):
    times, positions = descent(make_scene(), ticks=5)
    # reset: back at rest at time 0, counted; the simulated clock keeps counting
    scene = make_scene()
    _diverging(scene, 3, nan)
    driver = SimulationDriver(scene, on_divergence='reset')
    for k in range(3):
        outcome = driver.advance(0.02, positions[k], scene.needle_pose[1])
    assert outcome.diverged is not None and driver.divergences == 1
    assert scene.time == 0.0 and driver.simulated_s == pytest.approx(0.04)
    assert np.all(np.isfinite(driver.force)) and not driver.held
    # hold: frozen, the last finite wrench kept, nothing advances until reset
    scene = make_scene()
    _diverging(scene, 3, nan)
    driver = SimulationDriver(scene, on_divergence='hold')
    for k in range(3):
        driver.advance(0.02, positions[k], scene.needle_pose[1])
    frozen = scene.time
    assert driver.held and driver.advance(0.02).substeps == 0 and scene.time == frozen
    assert np.all(np.isfinite(driver.force))
    driver.reset()
    assert not driver.held and scene.time == 0.0
    # raise: the offline commands' policy
    scene = make_scene()
    _diverging(scene, 1, nan)
    with pytest.raises(SimulationDiverged):
        SimulationDriver(scene).advance(0.02, positions[0], scene.needle_pose[1])


def test_a_displacement_beyond_float32_is_a_divergence():
    scene = make_scene()
    driver = SimulationDriver(scene, on_divergence='hold')
    real = scene.advance

    def advance(*args):
        steps = real(*args)
        scene.displacement[0, 0] = 1e39
        return steps
    scene.advance = advance
    assert driver.advance(0.02).diverged is not None and driver.held


def test_a_deadline_leaves_steps_that_a_later_call_runs():
    """Stopped by a deadline in the past, the driver is behind; advance(0) runs what is left,
    and the state equals an undisturbed run's."""
    scene_a, scene_b = make_scene(), make_scene()
    times, positions = descent(scene_a, ticks=3)
    a, b = SimulationDriver(scene_a), SimulationDriver(scene_b)
    q = scene_a.needle_pose[1]
    assert a.advance(0.02, positions[0], q, deadline=0.0).substeps == 0 and a.behind
    left = a.advance(0.0, positions[0], q).substeps
    assert left == b.advance(0.02, positions[0], q).substeps and not a.behind
    np.testing.assert_array_equal(scene_a.displacement, scene_b.displacement)
