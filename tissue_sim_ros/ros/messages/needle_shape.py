"""The needle's shape on ROS: ``needle/shape``, and the tip's frame for TF.

``needle/shape`` (nav_msgs/msg/Path, every tick, in ``frame_id``; ``needle/<name>/shape`` per
needle in a scene with several): the needle's centreline from the base to the tip, a pose per
point with the needle's frame there (its +z along the needle): a flexible needle's rod nodes, each
with the frame of the segment that starts there, a rigid needle's base and tip in the base frame
(engine: ``NeedleTissue.write_shape``). The last pose is the tip: its position is the tip's apex
(the ``tip_x_m``... values of the diagnostics), its orientation the tip's frame (the bevel's
direction turns with it).

TF: where the node broadcasts TF, the tip's frame is the last pose of the shape,
:func:`tip_transform` (parent ``frame_id``, child ``<needle frame>_tip``); this module gives it
and the node publishes the shape, so a TF broadcaster takes the tip from here.
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.ros.messages.cdr_bytes import NeedleShapeBytes

__all__ = ['shape_topics', 'NeedleShapes', 'tip_transform']


def shape_topics(names) -> list[str]:
    """The shape topic of each needle: needle/shape for one, needle/<name>/shape for several."""
    if len(names) == 1:
        return ['needle/shape']
    return [f'needle/{name}/shape' for name in names]


def tip_transform(positions: np.ndarray, quaternions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translation (3,) [m], rotation (4,) x y z w) of the tip's frame in the shape's frame: the
    shape's last pose (the transform a TF broadcaster sends for the tip)."""
    return np.array(positions[-1], dtype=float), np.array(quaternions[-1], dtype=float)


class NeedleShapes:
    """The needles' shape publishers and their bytes. ``create_publisher(type, topic)``: the
    node's (with the QoS it chooses); ``publish(publisher, bytes, stamp_ns)``: the node's (it
    records what it publishes)."""

    def __init__(self, names, sizes, frame_id: str, create_publisher, serialize):
        from nav_msgs.msg import Path
        self.topics = shape_topics(names)
        self.publishers = [create_publisher(Path, topic) for topic in self.topics]
        self._bytes = [NeedleShapeBytes(size, frame_id, serialize) for size in sizes]

    def publish(self, snapshot, stamp_ns: int, publish) -> None:
        """Each needle's shape of the engine's ``snapshot`` (engine_thread.Snapshot), stamped."""
        for k, publisher in enumerate(self.publishers):
            publish(publisher, self._bytes[k].serialized(snapshot.shape_positions[k], snapshot.shape_quaternions[k],
                                                         stamp_ns), stamp_ns)
