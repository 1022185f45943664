"""A ``geometry_msgs/PoseStamped`` read straight from its CDR bytes.

The node receives poses as serialized bytes (it records them as received) and decodes them on
the engine thread, 100 times a second or more. ``rclpy.serialization.deserialize_message`` builds
the message object field by field through its checked setters: 38 us a pose on a quiet core,
about 200 us in the running node (4.6 % of the engine thread's time outside the physics kernels,
measured by thread time around the decode), while the layout is fixed. Here the layout is read
with ``struct`` (OMG CDR, XCDR1 as ROS 2's rmw layers write it: a 4-byte encapsulation header
(0x0000 big endian, 0x0001 little endian), then ``int32 sec, uint32 nanosec``, the frame id as a
``uint32`` length (with its terminating NUL) and its bytes, then seven ``float64`` aligned to 8
bytes from the end of the header: position x, y, z, orientation x, y, z, w; up to 3 bytes of
final padding). Anything else (an unknown encapsulation, a short or longer payload, a frame id
that is not NUL-terminated UTF-8) raises ValueError; the node then asks rclpy, so what it accepts
is what rclpy accepts (:func:`decode_pose`).
"""
from __future__ import annotations

import struct

import numpy as np

__all__ = ['pose_from_cdr', 'decode_pose']

_HEADER = {b'\x00\x00': '>', b'\x00\x01': '<'}
_STAMP = {'>': struct.Struct('>iII'), '<': struct.Struct('<iII')}
_POSE = {'>': struct.Struct('>7d'), '<': struct.Struct('<7d')}
_NS_PER_S = 1_000_000_000


def pose_from_cdr(data: bytes) -> tuple[np.ndarray, np.ndarray, str, int]:
    """(position (3,) m, quaternion (4,) x y z w, frame_id, stamp in ns) of a serialized
    PoseStamped, as ``conversions.pose_from_msg(deserialize_message(data, PoseStamped))``."""
    order = _HEADER.get(bytes(data[:2]))
    if order is None:
        raise ValueError(f'encapsulation {bytes(data[:4])!r}: expected plain CDR (00 00 or 00 01)')
    try:
        sec, nanosec, length = _STAMP[order].unpack_from(data, 4)
    except struct.error as exc:
        raise ValueError(f'{len(data)} bytes: too short for a PoseStamped header') from exc
    text_end = 16 + length
    pose_at = 4 + ((text_end - 4 + 7) & ~7)          # float64 aligned to 8 from the payload start
    if length < 1 or not 0 <= len(data) - (pose_at + 56) <= 3 or data[text_end - 1] != 0:
        raise ValueError(f'{len(data)} bytes with a frame id of {length} bytes: not a PoseStamped')
    frame_id = bytes(data[16:text_end - 1]).decode('utf-8')
    values = _POSE[order].unpack_from(data, pose_at)
    return (np.array(values[:3], dtype=np.float64), np.array(values[3:], dtype=np.float64), frame_id,
            sec * _NS_PER_S + nanosec)


def decode_pose(data: bytes) -> tuple[np.ndarray, np.ndarray, str, int]:
    """:func:`pose_from_cdr`, or rclpy's deserialization for a payload it does not read (which
    raises for one that is not a PoseStamped)."""
    try:
        return pose_from_cdr(data)
    except ValueError:
        from geometry_msgs.msg import PoseStamped
        from rclpy.serialization import deserialize_message

        from tissue_sim_ros.ros.messages.conversions import pose_from_msg
        return pose_from_msg(deserialize_message(data, PoseStamped))
