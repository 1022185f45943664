"""The TF buffer's maths without rclpy (ros/loop/transforms.py: tf2's rules), against transforms
composed by hand with scipy's Rotation, scipy's Slerp, and round trips."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation, Slerp

from tissue_sim_ros.ros.loop.transforms import (
    TransformBuffer,
    TransformUnavailable,
    compose,
    invert,
    transform_point,
)

NS = 1_000_000_000
RNG = np.random.default_rng(11)


def random_transform():
    return RNG.uniform(-1, 1, 3), Rotation.random(random_state=RNG).as_quat()


def matrix(transform):
    """The 4x4 homogeneous matrix of a transform, by scipy."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(transform[1]).as_matrix()
    m[:3, 3] = transform[0]
    return m


def test_compose_invert_and_apply_agree_with_homogeneous_matrices():
    for _ in range(20):
        a, b = random_transform(), random_transform()
        np.testing.assert_allclose(matrix(compose(a, b)), matrix(a) @ matrix(b), atol=1e-12)
        np.testing.assert_allclose(matrix(invert(a)), np.linalg.inv(matrix(a)), atol=1e-12)
        point = RNG.uniform(-1, 1, 3)
        np.testing.assert_allclose(
            transform_point(a, point), (matrix(a) @ np.append(point, 1.0))[:3], atol=1e-12
        )
        there_and_back = compose(invert(a), a)
        np.testing.assert_allclose(there_and_back[0], 0.0, atol=1e-12)
        assert abs(abs(there_and_back[1][3]) - 1.0) < 1e-12


def test_a_chain_across_two_branches_equals_the_one_composed_by_hand():
    """base -> shoulder -> tool0 and base -> tissue: tissue_from_tool0 = inv(base_from_tissue)
    base_from_shoulder shoulder_from_tool0, and the reverse lookup is its inverse."""
    base_shoulder, shoulder_tool, base_tissue = random_transform(), random_transform(), random_transform()
    buffer = TransformBuffer()
    buffer.set_transform('base', 'shoulder', 5 * NS, *base_shoulder)
    buffer.set_transform('shoulder', 'tool0', 5 * NS, *shoulder_tool)
    buffer.set_transform('base', 'tissue', 0, *base_tissue, static=True)
    got, stamp = buffer.lookup('tissue', 'tool0', 0)
    expected = np.linalg.inv(matrix(base_tissue)) @ matrix(base_shoulder) @ matrix(shoulder_tool)
    assert stamp == 5 * NS
    np.testing.assert_allclose(matrix(got), expected, atol=1e-12)
    back, _ = buffer.lookup('tool0', 'tissue', 5 * NS)
    np.testing.assert_allclose(matrix(back), np.linalg.inv(expected), atol=1e-12)
    assert buffer.chain('tissue', 'tool0') == (['tool0', 'shoulder', 'base'], ['tissue', 'base'])


def test_interpolation_between_stamps_is_linear_and_slerp():
    buffer = TransformBuffer()
    (t0, q0), (t1, q1) = random_transform(), random_transform()
    buffer.set_transform('base', 'tool0', 1 * NS, t0, q0)
    buffer.set_transform('base', 'tool0', 3 * NS, t1, q1)
    slerp = Slerp([1.0, 3.0], Rotation.from_quat([q0, q1]))
    for s in (1.0, 1.25, 2.0, 2.9, 3.0):
        (t, q), _ = buffer.lookup('base', 'tool0', int(s * NS))
        w = (s - 1.0) / 2.0
        np.testing.assert_allclose(t, t0 + w * (t1 - t0), atol=1e-12)
        assert (Rotation.from_quat(q) * slerp([s]).inv()).magnitude()[0] < 1e-9
    with pytest.raises(TransformUnavailable, match='no extrapolation'):
        buffer.lookup('base', 'tool0', 4 * NS)
    with pytest.raises(TransformUnavailable, match='not on TF'):
        buffer.lookup('base', 'flange', 0)
    buffer.set_transform('map', 'odom', 0, *random_transform(), static=True)
    with pytest.raises(TransformUnavailable, match='different trees'):
        buffer.lookup('odom', 'tool0', 0)


def test_latest_common_time_and_out_of_order_stamps():
    buffer = TransformBuffer()
    for k, stamp in enumerate((1, 3, 2)):  # the third arrives late
        buffer.set_transform('base', 'link', stamp * NS, (float(stamp), 0.0, 0.0), (0, 0, 0, 1))
    buffer.set_transform('link', 'tool0', 2 * NS, (0.0, 1.0, 0.0), (0, 0, 0, 1))
    (t, _), stamp = buffer.lookup('base', 'tool0', 0)  # the chain's latest common time: 2 s
    assert stamp == 2 * NS
    np.testing.assert_allclose(t, [2.0, 1.0, 0.0])
