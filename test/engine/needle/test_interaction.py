"""NeedleTissue (engine/needle/interaction.py): Newton's third law from the momentum balance every
step, and the jump limit held for the tip."""

import math

import numpy as np
import pytest

from support.scenes import small_scene
from tissue_sim_ros.engine.needle.interaction import rotation_matrix
from tissue_sim_ros.errors import PoseError


def test_wrench_is_minus_the_force_on_the_tissue_from_momentum_balance_every_step():
    """Undamped, so m (v+ - v) / dt = f_int + f_ext + f_needle exactly (symplectic Euler): the
    needle's force on the free nodes is read off the momentum change, independently of the
    needle code, and must equal minus the wrench; the torque equals sum (r - p) x f."""
    scene = small_scene(solver={'damping_per_s': 0.0}, region={'cutting_force_n': 0.3, 'membrane': {
        'criterion': 'force', 'rupture_force_n': 0.05}, 'friction': {'insertion_coulomb_n_per_m': 5.0}})
    sim, needle = scene.simulation, scene.needle
    p0, q = scene.needle_pose
    free = sim.dof_kind == 0
    checked = 0
    for k in range(1, 500):
        target = p0 + np.array([0.0, 0.0, -3e-3 * k * sim.dt]) + (np.array([2e-4 * sim.dt * k, 0, 0]) if k > 300 else 0)
        needle.set_pose(target, q)
        v_before = sim.velocity.copy()
        sim.step(1)
        needle.after_step(sim.dt)
        momentum_rate = sim.mass[:, None] * (sim.velocity - v_before) / sim.dt
        needle_on_nodes = np.where(free, momentum_rate - sim.internal_force - sim.external_forces, 0.0)
        force, torque = needle.reaction_wrench('world')
        scale = max(1e-3, float(np.abs(force).max()))
        assert np.allclose(needle_on_nodes.sum(axis=0), -force, atol=1e-9 * scale), k
        r = needle.application_points - needle.position
        assert np.allclose(np.cross(r, -needle.application_forces).sum(axis=0), torque, atol=1e-12)
        assert np.allclose(needle.application_forces.sum(axis=0), needle_on_nodes.sum(axis=0), atol=1e-9 * scale)
        checked += bool(np.any(force))
    assert needle.puncture_events and checked > 300
    f_needle, t_needle = needle.reaction_wrench('needle')
    R = rotation_matrix(needle.orientation)
    assert np.allclose(R @ f_needle, needle.reaction_wrench('world')[0])
    assert np.allclose(R @ t_needle, needle.reaction_wrench('world')[1])


def test_a_turn_about_the_base_is_limited_by_how_far_the_tip_moves():
    """The engine's jump limit (5 mm) holds for the tip too: turning by theta about the base moves
    the tip by the chord 2 L sin(theta / 2) while the base stays put."""
    scene = small_scene()
    p, q = scene.needle_pose
    length = scene.needle.geometry.length_m

    def turned(chord):
        theta = 2 * math.asin(chord / (2 * length))
        s, c = math.sin(theta / 2), math.cos(theta / 2)  # (0, s, 0, c) q: a turn about world y
        return np.array([c * q[0] + s * q[2], c * q[1] + s * q[3], c * q[2] - s * q[0], c * q[3] - s * q[1]])
    with pytest.raises(PoseError, match='moves the needle by 6 mm') as err:
        scene.advance(0.02, p, turned(0.006))
    assert err.value.field == 'pose.position' and scene.time == 0.0
    scene.advance(0.02, p, turned(0.004))
    scene.advance(0.0, p, turned(0.004))  # the rest of the way: the needle at the pose asked for
    np.testing.assert_allclose(np.linalg.norm(scene.needle.tip - (p + length * np.array([0.0, 0.0, -1.0]))),
                               0.004, rtol=1e-9)
