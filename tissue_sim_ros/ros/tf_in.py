"""TF in: the needle's pose from a robot's TF tree, and poses in other frames brought into the tissue frame.

Where tf2_ros is installed it would do this; the PyPI wheels of ROS 2 Jazzy have no tf2_ros, so the
node keeps its own buffer (:class:`~tissue_sim_ros.ros.loop.transforms.TransformBuffer`, fed from
/tf and /tf_static) and this module does the two lookups the node needs. No rclpy here: the node
hands over the received transforms as plain values.

- ``input.source: tf`` (:meth:`TfInput.receive`): every /tf message that moves a frame of the chain
  from the tissue frame (``frame_id``) to ``input.tf_frame`` gives one pose of the needle base,
  ``tissue_from_tf_frame * input.tf_offset``, at the latest time the whole chain has (tf2's
  ``Time(0)``): the robot's rate, the robot's stamps. Those poses go through the same checks,
  interpolation and diagnostics as ``needle/pose`` (:mod:`~tissue_sim_ros.ros.loop.pose_input`).
- a ``needle/pose`` (or a path pose) whose ``frame_id`` is another frame than the tissue's
  (:meth:`TfInput.to_tissue`) is transformed at its stamp, interpolated between the transforms that
  bracket it; a transform at most ``input.tf_timeout_s`` older than the stamp is used as it is (the
  robot's TF a little behind its pose stream); else it is refused as ``tf_unavailable``.

Frames the node itself broadcasts (:mod:`~tissue_sim_ros.ros.tf_out`) are ignored when they come
back on /tf: the buffer holds the robot's tree and the registration only.
"""

from __future__ import annotations

import numpy as np

from tissue_sim_ros.ros.loop.transforms import TransformBuffer, TransformUnavailable, compose
from tissue_sim_ros.units import NS_PER_S

__all__ = ['TfInput', 'TransformUnavailable', 'transforms_of']


def transforms_of(msg) -> list:
    """(parent, child, stamp ns, translation, rotation x y z w) of each transform of a
    tf2_msgs/TFMessage (any object with its fields: an rclpy message, a decoded log message)."""
    out = []
    for t in msg.transforms:
        s, r, q = t.header.stamp, t.transform.translation, t.transform.rotation
        out.append(
            (
                t.header.frame_id,
                t.child_frame_id,
                int(s.sec) * NS_PER_S + int(s.nanosec),
                (r.x, r.y, r.z),
                (q.x, q.y, q.z, q.w),
            )
        )
    return out


class TfInput:
    """The node's TF input (see the module docstring). ``tissue_frame``: the node's frame_id;
    ``tf_frame``: the frame followed with ``input.source: tf`` (None: poses come from the topic);
    ``offset``: (position, orientation) of the needle base in ``tf_frame``; ``own_frames``: the child
    frames the node broadcasts (ignored on the way in)."""

    def __init__(
        self,
        tissue_frame: str,
        *,
        tf_frame: str | None = None,
        offset=None,
        timeout_s: float = 0.1,
        own_frames=(),
        cache_s: float = 10.0,
    ):
        self.buffer = TransformBuffer(cache_s)
        self.tissue_frame, self.tf_frame = tissue_frame, tf_frame or None
        self.offset = offset if offset is not None else (np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))
        self.hold_ns = int(timeout_s * NS_PER_S)
        self.own_frames = frozenset(own_frames)
        self._chain: frozenset | None = None  # child frames of the tissue <- tf_frame chain
        self._last_stamp = -1
        self.poses = 0  # poses made from TF (input.source tf)

    def receive(self, transforms, static: bool = False):
        """Add the transforms of one /tf (or /tf_static) message; returns the needle base's pose
        ``(position, orientation, tissue frame, stamp ns)`` when they moved the followed chain to a
        newer time, a TransformUnavailable when the chain cannot be looked up yet, else None."""
        moved = False
        for parent, child, stamp_ns, translation, rotation in transforms:
            if child in self.own_frames:
                continue
            self.buffer.set_transform(parent, child, stamp_ns, translation, rotation, static)
            if self._chain is None or child in self._chain or static:
                moved = True
        if self.tf_frame is None or not moved:
            return None
        try:
            if self._chain is None or static:
                up_source, up_target = self.buffer.chain(self.tissue_frame, self.tf_frame)
                self._chain = frozenset(up_source[:-1] + up_target[:-1])
            tissue_from_tool, stamp_ns = self.buffer.lookup(self.tissue_frame, self.tf_frame, 0)
        except TransformUnavailable as exc:
            self._chain = None
            return exc
        if stamp_ns <= self._last_stamp:
            return None
        self._last_stamp = stamp_ns
        self.poses += 1
        position, orientation = compose(tissue_from_tool, self.offset)
        return position, orientation, self.tissue_frame, stamp_ns

    def to_tissue(self, position, orientation, frame_id: str, stamp_ns: int):
        """A pose given in ``frame_id`` at ``stamp_ns`` (0: the latest), in the tissue frame:
        (position, orientation, tissue frame, stamp ns). TransformUnavailable when TF cannot relate
        the frames at that time (within the timeout)."""
        if frame_id == self.tissue_frame:
            return position, orientation, frame_id, stamp_ns
        try:
            tissue_from_frame, _ = self.buffer.lookup(self.tissue_frame, frame_id, stamp_ns)
        except TransformUnavailable:
            newest, _ = self._newest_usable(frame_id, stamp_ns)
            if newest is None:
                raise
            tissue_from_frame = newest
        p, q = compose(
            tissue_from_frame,
            (np.asarray(position, dtype=np.float64), np.asarray(orientation, dtype=np.float64)),
        )
        return p, q, self.tissue_frame, stamp_ns

    def _newest_usable(self, frame_id: str, stamp_ns: int):
        """The chain's latest transform when it is at most the timeout older than ``stamp_ns``."""
        latest, latest_ns = self.buffer.lookup(self.tissue_frame, frame_id, 0)
        if latest_ns <= stamp_ns <= latest_ns + self.hold_ns:
            return latest, latest_ns
        raise TransformUnavailable(
            f'transform {self.tissue_frame} <- {frame_id} at {stamp_ns / NS_PER_S:.9f} s: '
            f'the newest is at {latest_ns / NS_PER_S:.9f} s, more than input.tf_timeout_s '
            f'= {self.hold_ns / NS_PER_S:g} s before (or the stamp is older than the buffer)'
        )
