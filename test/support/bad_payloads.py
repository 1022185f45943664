"""Payloads that are not a PoseStamped, beside good ones, for the MCAP reading tests."""

import numpy as np
import pytest

pytest.importorskip('rclpy')

from rclpy.serialization import serialize_message  # noqa: E402

from support.mcap_samples import PERIOD, T0  # noqa: E402
from tissue_sim_ros.ros.messages import conversions as cv  # noqa: E402


def _pose(i):
    from geometry_msgs.msg import PoseStamped
    msg = PoseStamped()
    msg.header.frame_id = 'world'
    msg.header.stamp = cv.ns_to_stamp(T0 + i * PERIOD)
    msg.pose.position.x = 0.001 * i
    msg.pose.position.z = -0.002 * i
    msg.pose.orientation.w = 1.0
    return msg


def _bad_payloads():
    """Payloads a buggy bridge or a bag replayed with the wrong type can put on needle/pose."""
    rng = np.random.default_rng(13)
    good = serialize_message(_pose(1))
    return {
        'empty': b'',
        '1 byte': b'\x00',
        '7 random bytes': rng.bytes(7),
        '64 random bytes': rng.bytes(64),
        'CDR header then garbage': b'\x00\x01\x00\x00' + rng.bytes(40),
        'CDR header only': b'\x00\x01\x00\x00',
        'valid pose cut in half': good[:len(good) // 2],
        'valid pose less its last byte': good[:-1],
    }
