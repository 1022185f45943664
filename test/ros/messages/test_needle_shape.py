"""needle/shape's topics and the tip's frame a TF broadcaster takes (ros/needle_shape.py)."""
import numpy as np
import pytest

pytest.importorskip('rclpy')

from tissue_sim_ros.ros.messages.needle_shape import shape_topics, tip_transform  # noqa: E402


def test_the_shape_topics_and_the_tip_frame():
    assert shape_topics(['needle']) == ['needle/shape']
    assert shape_topics(['a', 'b']) == ['needle/a/shape', 'needle/b/shape']
    positions, quaternions = np.arange(9.0).reshape(3, 3), np.tile([0.0, 0.0, 0.0, 1.0], (3, 1))
    translation, rotation = tip_transform(positions, quaternions)
    assert np.array_equal(translation, [6.0, 7.0, 8.0]) and np.array_equal(rotation, [0.0, 0.0, 0.0, 1.0])
