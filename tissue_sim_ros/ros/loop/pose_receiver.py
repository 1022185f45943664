"""Received needle poses as bytes, decoded a bounded number per slice (no rclpy).

The node's subscription hands over raw bytes (recorded as received); they wait here and each
slice decodes at most ``limit`` of the newest, so that no rate of input, good or bad, costs a tick
more than a bounded amount: older ones waiting count as ``backlog``. A payload that does not decode
counts as ``malformed`` and is skipped: one buggy bridge or a bag replayed with the wrong type
must not stop the simulation.
"""
from __future__ import annotations

from collections import deque

from tissue_sim_ros.ros.loop.pose_input import ACCEPTED_KINDS
from tissue_sim_ros.ros.loop.transforms import TransformUnavailable

__all__ = ['PoseReceiver']



class PoseReceiver:
    """Queue of (receipt ns, bytes); :meth:`decode_into` feeds a PoseInput."""

    def __init__(self, capacity: int = 1000, limit: int = 64):
        self.queue: deque = deque(maxlen=capacity)
        self.limit = limit

    def add(self, receipt_ns: int, data: bytes) -> None:
        self.queue.append((receipt_ns, data))

    def decode_into(self, pose_input, decode, log_once) -> list[int]:
        """Decode the newest ``limit`` waiting poses in order and offer them to ``pose_input``;
        ``decode(bytes) -> (position, orientation, frame_id, stamp_ns)`` may raise for a bad
        payload, or TransformUnavailable (counted as
        ``tf_unavailable``); ``log_once(kind, text)``. Returns the receipt times of the accepted poses."""
        accepted = []
        while len(self.queue) > self.limit:
            self.queue.popleft()
            pose_input.count('backlog')
        while self.queue:
            receipt_ns, data = self.queue.popleft()
            try:
                position, orientation, frame_id, stamp_ns = decode(data)
            except TransformUnavailable as exc:
                pose_input.count('tf_unavailable')
                log_once('tf_unavailable', f'needle pose: tf_unavailable: {exc}')
                continue
            except Exception as exc:  # noqa: BLE001 - any payload a bridge or a bag can send
                pose_input.count('malformed')
                log_once('malformed', f'needle/pose: a {len(data)}-byte payload that is not a '
                         f'PoseStamped was skipped ({type(exc).__name__}: {exc})')
                continue
            kind, detail = pose_input.offer(position, orientation, frame_id, stamp_ns, receipt_ns)
            if kind is not None:
                log_once(kind, f'needle/pose: {kind}: {detail}')
            if kind is None or kind in ACCEPTED_KINDS:
                accepted.append(receipt_ns)
        return accepted
