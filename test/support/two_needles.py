"""A node whose scene has two needles, and the poses that drive them."""

import os

import pytest

rclpy = pytest.importorskip('rclpy')

from builtin_interfaces.msg import Time as TimeMsg  # noqa: E402
from geometry_msgs.msg import PoseStamped  # noqa: E402

DOMAIN_ID = 10 + os.getpid() % 40
MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
NEEDLES = [{'name': 'biopsy', 'initial_position_m': [0.0, 0.0, 0.159]},
           {'name': 'fixation', 'initial_position_m': [0.006, 0.0, 0.159]}]
DOWN = (1.0, 0.0, 0.0, 0.0)
NS = 1_000_000_000


def _pose(position, stamp_ns):
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = TimeMsg(sec=int(stamp_ns // NS), nanosec=int(stamp_ns % NS))
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(c) for c in position)
    q = msg.pose.orientation
    q.x, q.y, q.z, q.w = DOWN
    return msg
