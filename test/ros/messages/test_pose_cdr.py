"""The node's PoseStamped decoder (ros/pose_cdr) against rclpy's own serialization: every frame
id length (each alignment of the doubles), stamps at their limits, NaN kept, both byte orders;
payloads it does not read are refused, and the node's decode then gives rclpy's answer."""

import struct

import numpy as np
import pytest
from geometry_msgs.msg import PoseStamped
from rclpy.serialization import deserialize_message, serialize_message

from tissue_sim_ros.ros.messages.conversions import pose_from_msg
from tissue_sim_ros.ros.messages.pose_cdr import decode_pose, pose_from_cdr


def _message(frame_id, sec, nanosec, values):
    msg = PoseStamped()
    msg.header.frame_id = frame_id
    msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
    p, q = msg.pose.position, msg.pose.orientation
    p.x, p.y, p.z, q.x, q.y, q.z, q.w = (float(v) for v in values)
    return msg


def _same(a, b):
    assert np.array_equal(a[0], b[0], equal_nan=True) and np.array_equal(a[1], b[1], equal_nan=True)
    assert a[2] == b[2] and a[3] == b[3] and type(a[3]) is int


@pytest.mark.parametrize('length', range(0, 18))
def test_every_frame_id_length_decodes_as_rclpy_does(length):
    rng = np.random.default_rng(length)
    values = rng.normal(size=7) * 10.0 ** rng.integers(-6, 6, size=7)
    if length % 5 == 0:
        values[length % 7] = np.nan
    frame_id = ''.join(chr(ord('a') + k % 26) for k in range(length - 1)) + ('é' if length else '')
    for sec, nanosec in ((0, 0), (1_700_000_000, 999_999_999), (-5, 7), (2**31 - 1, 1)):
        data = serialize_message(_message(frame_id, sec, nanosec, values))
        expected = pose_from_msg(deserialize_message(data, PoseStamped))
        _same(pose_from_cdr(data), expected)
        assert expected[3] == sec * 1_000_000_000 + nanosec


def test_big_endian_payload_reads_the_same_values():
    values = (0.1, -0.2, 0.3, 0.0, 0.0, 0.38268343236, 0.92387953251)
    frame = b'world\x00'
    body = struct.pack('>iII', 12, 345, len(frame)) + frame
    body += b'\x00' * ((-(len(body)) % 8))
    data = b'\x00\x00\x00\x00' + body + struct.pack('>7d', *values)
    position, quaternion, frame_id, stamp = pose_from_cdr(data)
    assert position.tolist() == list(values[:3]) and quaternion.tolist() == list(values[3:])
    assert frame_id == 'world' and stamp == 12_000_000_345


@pytest.mark.parametrize('damage', ['cut', 'longer', 'encapsulation', 'no_nul', 'huge_length'])
def test_payloads_it_does_not_read_are_refused_and_the_node_falls_back_to_rclpy(damage):
    data = bytearray(serialize_message(_message('world', 3, 4, range(7))))
    if damage == 'cut':
        data = data[:30]
    elif damage == 'longer':
        data += b'\x00' * 8                 # rclpy reads the message and ignores the rest
    elif damage == 'encapsulation':
        data[1] = 7
    elif damage == 'no_nul':
        data[16 + 5] = ord('x')             # the frame id's terminating NUL
    else:
        data[12:16] = struct.pack('<I', 2**31)
    with pytest.raises(ValueError):
        pose_from_cdr(bytes(data))
    try:
        expected = pose_from_msg(deserialize_message(bytes(data), PoseStamped))
    except Exception as exc:                # noqa: BLE001 - whatever rclpy raises, decode raises too
        with pytest.raises(type(exc)):
            decode_pose(bytes(data))
    else:
        _same(decode_pose(bytes(data)), expected)
