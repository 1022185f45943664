"""Pose maths and pose rules (engine/needle/pose.py) against independent truth: the Hamilton product
q v q* for rotations, closed-form angles and chords, and the rules' thresholds on either side."""

import math

import numpy as np
import pytest

from support.scenes import DOWN, small_scene
from tissue_sim_ros.engine.needle.parameters import NeedleGeometry
from tissue_sim_ros.engine.needle.pose import (DEFAULT_MAX_JUMP_M, DEFAULT_MAX_JUMP_RAD,
                                               QUATERNION_NORM_TOLERANCE, needle_axis, pose_jump,
                                               rotation_angle, rotation_matrix, slerp, unit_quaternion,
                                               validate_pose)
from tissue_sim_ros.errors import PoseError
from tissue_sim_ros.ros.clients.drive import _axis
from tissue_sim_ros.ros.loop.pose_input import PoseInputLimits


def hamilton(a, b):
    """Quaternion product a b, both (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz])


def rotate(q, v):
    """v rotated by the unit quaternion q: the vector part of q (v, 0) q*."""
    conjugate = np.array([-q[0], -q[1], -q[2], q[3]])
    return hamilton(hamilton(q, [*v, 0.0]), conjugate)[:3]


def about(axis, angle):
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return np.array([*(math.sin(angle / 2) * axis), math.cos(angle / 2)])


def random_quaternions(n, seed=3):
    q = np.random.default_rng(seed).normal(size=(n, 4))
    return q / np.linalg.norm(q, axis=1)[:, None]


def test_rotation_matrix_and_needle_axis_rotate_like_the_quaternion_product():
    for q in random_quaternions(20):
        R = rotation_matrix(q)
        for v in np.eye(3):
            np.testing.assert_allclose(R @ v, rotate(q, v), atol=1e-15)
        np.testing.assert_allclose(needle_axis(q), rotate(q, [0.0, 0.0, 1.0]), atol=1e-15)
        assert np.array_equal(needle_axis(q), R[:, 2])  # the same arithmetic: bit for bit
        assert np.array_equal(_axis(q), needle_axis(q))  # tissue-sim drive uses the engine's rule
    np.testing.assert_allclose(needle_axis([1.0, 0.0, 0.0, 0.0]), [0.0, 0.0, -1.0])  # base +z down


def test_rotation_angle_and_slerp_follow_the_axis_angle_form():
    axis = [0.3, -0.5, 0.8]
    for a, b in ((0.1, 0.4), (-1.0, 2.0), (0.0, 3.0)):
        assert rotation_angle(about(axis, a), about(axis, b)) == pytest.approx(abs(b - a), abs=1e-7)
    q = about([1.0, 2.0, 3.0], 0.7)
    assert rotation_angle(q, -q) == pytest.approx(0.0, abs=1e-7)  # q and -q: the same rotation
    middle = slerp(about(axis, 0.2), about(axis, 1.4), 0.5)
    np.testing.assert_allclose(middle, about(axis, 0.8), atol=1e-12)
    assert rotation_angle(slerp(q, -about([1.0, 2.0, 3.0], 1.3), 0.25), q) == pytest.approx(0.15, abs=1e-9)


def test_unit_quaternion_normalises_within_the_tolerance_and_refuses_beyond():
    q = np.array([0.0, 0.6, 0.0, 0.8])
    unit, norm = unit_quaternion(q)
    assert unit is q and norm == pytest.approx(1.0)  # unit: passed on unchanged, bit for bit
    unit, norm = unit_quaternion(1.009 * q)
    assert norm == pytest.approx(1.009) and np.linalg.norm(unit) == pytest.approx(1.0, abs=1e-15)
    assert unit_quaternion(1.011 * q)[0] is None and unit_quaternion(0.989 * q)[0] is None
    assert unit_quaternion(1.05 * q, tolerance=0.1)[0] is not None
    with pytest.raises(PoseError, match=f'norm 1.02, expected 1 within {QUATERNION_NORM_TOLERANCE}'):
        validate_pose([0, 0, 0], 1.02 * q)


def test_pose_jump_measures_the_base_the_tip_and_the_rotation():
    length = 0.15
    p0, q0 = np.array([0.01, 0.02, 0.2]), about([1.0, 0.0, 0.0], math.pi)  # pointing down
    moved = pose_jump(p0, q0, p0 + [0.003, 0.0, -0.004], q0, length)
    assert moved.distance_m == pytest.approx(0.005, abs=1e-15) and moved.angle_rad == 0.0
    # turning about the base by theta about an axis across the needle: the tip moves the chord
    # 2 L sin(theta / 2); the base does not move
    for theta in (0.01, 0.04):
        q1 = hamilton(about([0.0, 1.0, 0.0], theta), q0)
        turned = pose_jump(p0, q0, p0, q1, length)
        assert turned.distance_m == pytest.approx(2 * length * math.sin(theta / 2), rel=1e-9)
        assert turned.angle_rad == pytest.approx(theta, rel=1e-7)
        assert pose_jump(p0, q0, p0, q1).distance_m == 0.0  # base only
    # the limits are inclusive: a move of exactly the limit passes, a hair more does not
    origin = np.zeros(3)
    assert not pose_jump(origin, q0, np.array([0.0, 0.0, 0.004]), q0).exceeds(0.004)
    assert pose_jump(origin, q0, np.array([0.0, 0.0, 0.0040001]), q0).exceeds(0.004)
    assert pose_jump(p0, q0, p0, hamilton(about([0, 0, 1], 0.6), q0)).exceeds(1.0, max_jump_rad=0.5)
    assert not pose_jump(p0, q0, p0, hamilton(about([0, 0, 1], 0.6), q0)).exceeds(1.0)


def test_the_jump_defaults_have_one_home():
    assert NeedleGeometry().max_jump_m == DEFAULT_MAX_JUMP_M == 0.005
    assert PoseInputLimits().max_jump_m == DEFAULT_MAX_JUMP_M
    assert PoseInputLimits().max_jump_rad == DEFAULT_MAX_JUMP_RAD == 0.5


def test_bad_poses_are_refused_by_name_and_state_is_unchanged():
    scene = small_scene()
    p, q = scene.needle_pose
    for position, orientation, field in (([np.nan, 0, 0.2], DOWN, 'pose.position'),
                                         ([0, np.inf, 0.2], DOWN, 'pose.position'),
                                         (p, [1.0, 0.0, 0.0, np.nan], 'pose.orientation'),
                                         (p, [1.2, 0.0, 0.0, 0.0], 'pose.orientation'),
                                         (p + [0.0, 0.0, -0.02], DOWN, 'pose.position')):
        with pytest.raises(PoseError) as err:
            scene.advance(0.02, position, orientation)
        assert err.value.field == field and field in str(err.value)
    assert scene.time == 0.0 and np.array_equal(scene.needle_pose[0], p)
    position, orientation = validate_pose(p, [1.005, 0.0, 0.0, 0.0])          # close to unit: normalised
    assert np.linalg.norm(orientation) == pytest.approx(1.0, abs=1e-15)
