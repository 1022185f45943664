"""Needle pose maths and the rules a pose must meet, shared by the engine and the node's input.

A pose is the position of the needle's base frame and its orientation as a unit quaternion
(x, y, z, w); the needle axis is that frame's +z (docs/scene-guide.md, "Needle and tip shapes").
Pure numpy, no numba and no ROS, so :mod:`tissue_sim_ros.ros.loop.pose_input` and
``tissue-sim drive`` import it cheaply.

Each rule has one home here:

- a quaternion whose norm is within :data:`QUATERNION_NORM_TOLERANCE` of 1 is normalised,
  farther from 1 it is refused (:func:`unit_quaternion`);
- a pose may not move farther than a jump limit from the previous one in one go
  (:func:`pose_jump`; defaults :data:`DEFAULT_MAX_JUMP_M` and :data:`DEFAULT_MAX_JUMP_RAD`):
  the engine measures the base and the tip against ``needle.max_jump_m`` per ``advance`` call,
  the node's input measures the base and the rotation against ``input.max_jump_m`` and
  ``input.max_jump_rad`` per received pose.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np

from tissue_sim_ros.errors import PoseError

__all__ = ['QUATERNION_NORM_TOLERANCE', 'DEFAULT_MAX_JUMP_M', 'DEFAULT_MAX_JUMP_RAD',
           'rotation_matrix', 'needle_axis', 'slerp', 'rotation_angle',
           'unit_quaternion', 'validate_pose', 'PoseJump', 'pose_jump']

_log = logging.getLogger('tissue_sim_ros.needle')

#: |‖q‖ - 1| above this is an error, below it q is normalised.
QUATERNION_NORM_TOLERANCE = 0.01
#: Largest move [m] of the needle (base, and tip in the engine) accepted in one go by default.
DEFAULT_MAX_JUMP_M = 0.005
#: Largest rotation [rad] between successive received poses accepted by default (node input).
DEFAULT_MAX_JUMP_RAD = 0.5


def rotation_matrix(quaternion):
    """3x3 rotation of a unit quaternion (x, y, z, w)."""
    x, y, z, w = quaternion
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def needle_axis(quaternion):
    """The needle axis in the world: +z of the base frame, the third column of
    :func:`rotation_matrix` (the same arithmetic, so the two agree bit for bit)."""
    return np.array(_axis_floats(quaternion))


def slerp(q0, q1, s):
    """Spherical linear interpolation between unit quaternions (x, y, z, w), shortest arc."""
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + s * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(d)
    return (math.sin((1 - s) * theta) * q0 + math.sin(s * theta) * q1) / math.sin(theta)


def rotation_angle(q0, q1) -> float:
    """Angle [rad] of the rotation between two unit quaternions: 2 acos |q0 . q1|."""
    x0, y0, z0, w0 = _floats(q0)
    x1, y1, z1, w1 = _floats(q1)
    return 2.0 * math.acos(min(1.0, abs(x0 * x1 + y0 * y1 + z0 * z1 + w0 * w1)))


def unit_quaternion(quaternion, tolerance=QUATERNION_NORM_TOLERANCE):
    """(unit quaternion or None, norm) of a finite (4,) float array.

    None when |‖q‖ - 1| > ``tolerance`` (refused); q itself when the norm is 1 within 1e-9
    (so a unit quaternion passes unchanged, bit for bit); else q / ‖q‖.
    """
    norm = math.sqrt(float(quaternion @ quaternion))      # np.linalg.norm's arithmetic, without its overhead
    if not abs(norm - 1.0) <= tolerance:
        return None, norm
    if abs(norm - 1.0) > 1e-9:
        return quaternion / norm, norm
    return quaternion, norm


_normalised_once = False


def validate_pose(position, orientation, field_name='pose'):
    """(position (3,), unit quaternion (4,)) as float arrays, or PoseError naming the field.

    A quaternion whose norm is within QUATERNION_NORM_TOLERANCE of 1 is normalised (said once in
    the log); farther from unit it is refused.
    """
    global _normalised_once
    try:
        p = np.array(position, dtype=np.float64).reshape(-1)
        q = np.array(orientation, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError):
        raise PoseError(field_name, (position, orientation), 'expected numbers') from None
    if p.shape != (3,) or not all(map(math.isfinite, p.tolist())):
        raise PoseError(f'{field_name}.position', p.tolist(), 'expected 3 finite numbers [m]')
    if q.shape != (4,) or not all(map(math.isfinite, q.tolist())):
        raise PoseError(f'{field_name}.orientation', q.tolist(),
                               'expected 4 finite numbers (quaternion x, y, z, w)')
    unit, norm = unit_quaternion(q)
    if unit is None:
        raise PoseError(f'{field_name}.orientation', q.tolist(),
                               f'quaternion norm {norm:.6g}, expected 1 within {QUATERNION_NORM_TOLERANCE}')
    if unit is not q and not _normalised_once:
        _log.warning('%s.orientation: quaternion norm %.9g normalised to 1 (said once)', field_name, norm)
        _normalised_once = True
    return p, unit


@dataclass(frozen=True)
class PoseJump:
    """How far one pose is from another: the largest move of the checked points [m] and the
    rotation angle [rad]."""

    distance_m: float
    angle_rad: float

    def exceeds(self, max_jump_m=DEFAULT_MAX_JUMP_M, max_jump_rad=math.inf) -> bool:
        """True when the move is over ``max_jump_m`` or the rotation over ``max_jump_rad``."""
        return self.distance_m > max_jump_m or self.angle_rad > max_jump_rad


def pose_jump(position0, orientation0, position1, orientation1, length_m=0.0) -> PoseJump:
    """The jump from pose 0 to pose 1 (validated arrays): the larger of the base's move and, for
    ``length_m`` > 0, the move of the point at +z * length_m (the tip), and the rotation angle."""
    # plain floats: this runs on every advance of every caller, and numpy's per-call cost on
    # 3-vectors would make it three times dearer
    x0, y0, z0 = _floats(position0)
    x1, y1, z1 = _floats(position1)
    dx, dy, dz = x1 - x0, y1 - y0, z1 - z0
    distance = math.sqrt(dx * dx + dy * dy + dz * dz)
    if length_m > 0.0:
        (u0, v0, w0), (u1, v1, w1) = _axis_floats(orientation0), _axis_floats(orientation1)
        tip_x = (x1 + length_m * u1) - (x0 + length_m * u0)
        tip_y = (y1 + length_m * v1) - (y0 + length_m * v0)
        tip_z = (z1 + length_m * w1) - (z0 + length_m * w0)
        distance = max(distance, math.sqrt(tip_x * tip_x + tip_y * tip_y + tip_z * tip_z))
    return PoseJump(distance, rotation_angle(orientation0, orientation1))


def _axis_floats(quaternion):
    """:func:`needle_axis` as a tuple of floats (the same arithmetic)."""
    x, y, z, w = _floats(quaternion)
    return 2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y)


def _floats(vector) -> list:
    """A short vector (array or sequence) as a list of Python floats."""
    return vector.tolist() if isinstance(vector, np.ndarray) else [float(v) for v in vector]
