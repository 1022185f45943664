"""TF out: the frames the node's messages name, on /tf and /tf_static (tf2_msgs/msg/TFMessage).

- /tf_static (transient local, one message holding every static transform, as tf2's static
  broadcaster sends): the tissue frame (``frame_id``) in ``registration.parent_frame_id`` when a
  registration is set, and each rigid needle's tip frame ``<needle frame>_tip`` on its base frame
  (the needle's length along +z);
- /tf, every tick, stamped with the tick: each needle's base frame (``needle_frame_id``;
  ``needle_frame_id_<name>`` in a scene with several needles, as their wrenches name it) in the
  tissue frame, where the simulated needle is, and each target's frame ``target_<name>`` in the
  tissue frame, where the tissue carried it (identity orientation: a target is a point), and a
  flexible needle's tip frame in the tissue frame: the last pose of its shape, which the rod's
  bending moves relative to the base (:func:`~tissue_sim_ros.ros.messages.needle_shape.tip_transform`).

So the wrench (in the needle frame), the cloud, the marker, the targets and the mesh (in the tissue
frame) all name frames that exist on TF, and RViz or Foxglove place them in the robot's world.
The message type comes from the tf2_msgs package (a ROS install's, or the one the set-up builds);
no rclpy here: the node publishes what :class:`TfFrames` builds.
"""

from __future__ import annotations

import numpy as np

from tissue_sim_ros.ros.messages.conversions import header
from tissue_sim_ros.ros.messages.needle_shape import tip_transform

__all__ = ['TF_TYPE', 'TfFrames', 'needle_frames', 'target_frame']

TF_TYPE = 'tf2_msgs/msg/TFMessage'


def needle_frames(needle_frame_id: str, needle_names) -> list[tuple[str, str]]:
    """(base frame, tip frame) per needle: the wrench's frame names, each with ``_tip``."""
    names = list(needle_names)
    bases = [needle_frame_id] if len(names) == 1 else [f'{needle_frame_id}_{n}' for n in names]
    return [(base, f'{base}_tip') for base in bases]


def target_frame(name: str) -> str:
    """The TF frame of the scene's target ``name``."""
    return f'target_{name}'


def _transform(parent: str, child: str, stamp, position, orientation=(0.0, 0.0, 0.0, 1.0)):
    from geometry_msgs.msg import TransformStamped

    t = TransformStamped(header=header(parent, stamp), child_frame_id=child)
    tr, r = t.transform.translation, t.transform.rotation
    tr.x, tr.y, tr.z = (float(c) for c in position)
    r.x, r.y, r.z, r.w = (float(c) for c in orientation)
    return t


class TfFrames:
    """The node's frames: ``tissue_frame`` (frame_id), ``needles``: :func:`needle_frames`,
    ``lengths``: each needle's length [m], ``targets``: the target names, ``flexible``: per
    needle, whether its shaft bends (its tip then goes on /tf, not /tf_static)."""

    def __init__(self, tissue_frame: str, needles, lengths, targets=(), flexible=()):
        self.tissue_frame = tissue_frame
        self.needles, self.lengths = list(needles), [float(x) for x in lengths]
        self.flexible = [bool(f) for f in flexible] or [False] * len(self.needles)
        self.targets = [target_frame(name) for name in targets]

    @property
    def own_frames(self) -> set[str]:
        """The child frames this node broadcasts (not the tissue frame: a registration may come
        from elsewhere too)."""
        return {f for pair in self.needles for f in pair} | set(self.targets)

    def static_msg(self, stamp_ns: int, registration=None):
        """/tf_static: ``registration`` (parent frame, position, orientation) of the tissue frame
        or None, and each rigid needle's tip on its base."""
        from tf2_msgs.msg import TFMessage

        transforms = []
        if registration is not None:
            parent, position, orientation = registration
            transforms.append(_transform(parent, self.tissue_frame, stamp_ns, position, orientation))
        for (base, tip), length, flexible in zip(self.needles, self.lengths, self.flexible):
            if not flexible:
                transforms.append(_transform(base, tip, stamp_ns, (0.0, 0.0, length)))
        return TFMessage(transforms=transforms)

    def dynamic_msg(self, stamp_ns: int, needle_positions, needle_orientations, target_positions,
                    shapes=()):
        """/tf of one tick: each needle's base pose and each target's position in the tissue frame,
        and each flexible needle's tip from ``shapes`` (per needle, its shape's positions and
        quaternions in the tissue frame) (refuses non-finite values: never NaN on a topic)."""
        from tf2_msgs.msg import TFMessage

        tips = [(tip, tip_transform(*shape)) for (_, tip), shape, flexible
                in zip(self.needles, shapes, self.flexible) if flexible]
        values = [
            np.asarray(a, dtype=np.float64) for a in (needle_positions, needle_orientations, target_positions)
        ] + [np.concatenate(pose) for _, pose in tips]
        if not all(np.isfinite(v).all() for v in values):
            raise ValueError('TF: a needle pose or a target position is not finite; refusing to publish')
        transforms = [
            _transform(self.tissue_frame, base, stamp_ns, p, q)
            for (base, _), p, q in zip(self.needles, values[0], values[1])
        ]
        transforms += [
            _transform(self.tissue_frame, frame, stamp_ns, p) for frame, p in zip(self.targets, values[2])
        ]
        transforms += [_transform(self.tissue_frame, tip, stamp_ns, p, q) for tip, (p, q) in tips]
        return TFMessage(transforms=transforms)
