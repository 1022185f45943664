"""The scene's targets on ROS: ``tissue/targets`` and their diagnostics.

``tissue/targets`` (geometry_msgs/msg/PoseArray, every tick, in ``frame_id``): where each target
is now, in the scene's order (the names: the diagnostics status and the scene file); identity
orientations (a target is a point). The status ``<node>: targets`` gives the names, and per
target the needle tip's distance to it and the lateral miss of the needle's line [m], the two
figures a planner steers by (engine.scene.targets).
"""
from __future__ import annotations

import numpy as np
from geometry_msgs.msg import Pose, PoseArray

from tissue_sim_ros.ros.messages.conversions import header

__all__ = ['targets_msg', 'targets_status']


def targets_msg(positions: np.ndarray, frame_id: str, stamp) -> PoseArray:
    """PoseArray of the (k, 3) target positions [m]; refuses a non-finite one."""
    if not np.isfinite(positions).all():
        raise ValueError(f'target positions {np.asarray(positions).tolist()} are not finite; refusing to '
                         'publish NaN or inf')
    msg = PoseArray(header=header(frame_id, stamp))
    poses = []
    for x, y, z in positions:
        pose = Pose()
        pose.position.x, pose.position.y, pose.position.z = float(x), float(y), float(z)
        pose.orientation.w = 1.0
        poses.append(pose)
    msg.poses = poses
    return msg


def targets_status(name: str, names, figures) -> tuple:
    """The DiagnosticStatus tuple of the targets: ``figures`` (tip distance, lateral miss, ahead
    of the tip), each (k,) [m], as the last tick computed them (engine.scene.targets)."""
    values = {'targets': len(names), 'names': ', '.join(names)}
    for k, target in enumerate(names):
        values[f'{target}/tip_distance_m'] = float(figures[0][k])
        values[f'{target}/lateral_miss_m'] = float(figures[1][k])
        values[f'{target}/ahead_of_tip_m'] = float(figures[2][k])
    return f'{name}: targets', 'OK', f'{len(names)} target(s)', values
