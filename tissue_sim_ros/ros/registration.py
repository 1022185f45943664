"""Registration: where the tissue is in the robot's world, and where the needle starts.

Two facts a robot study measures before it inserts, held here without rclpy (the node's services
``~/set_tissue_pose`` and ``~/register_needle`` call these and answer with their words):

- **the tissue's pose** in the robot's frame (``registration.parent_frame_id``; a tracked marker, a
  touched fiducial): the transform of the tissue frame (the mesh frame, ``frame_id``) in it, from
  the parameters ``registration.tissue_position_m`` / ``_orientation_xyzw`` at start and
  :meth:`Registration.set_tissue_pose` at run time. The node broadcasts it on /tf_static (so the
  robot's TF relates to the mesh) and records it (the /tf_static message and the service call).
  It does not move the engine: the engine works in the tissue frame.
- **the needle's start**: the engine's needle starts at the scene's ``needle.initial_position_m``;
  a robot that starts elsewhere would be refused (a jump) or joined at the re-synchronisation
  speed. Registering the needle (:func:`needle_start_rule`) makes the robot's current pose, in the
  tissue frame, the needle's start from now on (``~/reset`` included): allowed only while the
  simulated needle is out of the tissue and the new pose is outside it too (the engine checks:
  ``NeedleTissue.set_start``). With ``registration.needle_at_first_pose`` the first pose received
  does it. The engine trace records the placement (a ``PLACE`` row), so ``tissue-sim replay`` does
  it again at the same point of the run.
"""

from __future__ import annotations

import numpy as np

from tissue_sim_ros.engine.needle.pose import unit_quaternion
from tissue_sim_ros.errors import PoseError

__all__ = ['Registration', 'needle_start_rule']


class Registration:
    """The tissue frame's pose in ``parent`` (empty: none published)."""

    def __init__(self, tissue_frame: str, parent: str, position, orientation, tolerance: float = 0.01):
        self.tissue_frame, self.parent, self.tolerance = tissue_frame, parent, tolerance
        self.position, self.orientation = np.asarray(position, dtype=np.float64), np.asarray(
            orientation, dtype=np.float64
        )
        self.changes = 0

    @property
    def transform(self):
        """(parent frame, position, orientation), or None while no parent frame is set."""
        return (self.parent, self.position, self.orientation) if self.parent else None

    def set_tissue_pose(self, frame_id: str, position, orientation) -> str:
        """Take a new registration (``frame_id`` empty: the current parent frame); the sentence
        the service answers with. PoseError, naming the field, for a non-finite value, a quaternion
        that is not unit, or a frame that is the tissue's own."""
        parent = frame_id or self.parent
        p = np.asarray(position, dtype=np.float64)
        if not parent or parent == self.tissue_frame:
            raise PoseError(
                'pose.header.frame_id',
                frame_id,
                f'the robot frame the tissue frame '
                f'{self.tissue_frame!r} is registered in (registration.parent_frame_id is '
                f'{self.parent!r})',
            )
        if p.shape != (3,) or not np.isfinite(p).all():
            raise PoseError('pose.pose.position', p.tolist(), 'three finite numbers [m]')
        q, norm = unit_quaternion(np.asarray(orientation, dtype=np.float64), self.tolerance)
        if q is None:
            raise PoseError(
                'pose.pose.orientation',
                np.asarray(orientation).tolist(),
                f'a unit quaternion (norm {norm:.6g}, tolerance {self.tolerance})',
            )
        self.parent, self.position, self.orientation = parent, p, q
        self.changes += 1
        return (
            f'tissue frame {self.tissue_frame!r} registered in {parent!r} at {np.round(p, 6).tolist()} m, '
            f'orientation {np.round(q, 6).tolist()}'
        )


def needle_start_rule(seen, frame_id: str):
    """The pose a needle registration takes: ``seen`` is the input's newest pose that passed the
    value checks, (stamp ns, position, orientation) in the tissue frame, or None. PoseError when
    there is none (nothing received from the robot yet)."""
    if seen is None:
        raise PoseError(
            'needle pose',
            None,
            f'no needle pose received yet (in {frame_id!r} or through TF): '
            'the needle is registered where the robot holds it, so it must publish first',
        )
    return seen[1].copy(), seen[2].copy()
