"""Readiness: a signal a launch file, a supervisor or a client can wait on.

The node's first start compiles the engine's kernels (half a minute on a cold cache) before it can
tick. ``~/ready`` (std_msgs/msg/Bool, transient local, so a late subscriber reads the state at
once) is false from the moment the node exists and true from its first tick: every topic then
flows and every service answers. The engine status of ``/diagnostics`` says the same
(``ready``: ``starting`` or ``ready``). Prediction workers may still be warming up then (the
``predictions`` status says ``workers_state``). No rclpy here: the node hands a publish function.
"""

from __future__ import annotations

__all__ = ['Readiness']


class Readiness:
    """``publish(bool)`` sends ``~/ready``; :meth:`starting` once set up, :meth:`ticking` at the
    first tick (from the tick's thread)."""

    def __init__(self, publish):
        self._publish = publish
        self.state = 'starting'

    def starting(self) -> None:
        self.state = 'starting'
        self._publish(False)

    def ticking(self) -> None:
        if self.state != 'ready':
            self.state = 'ready'
            self._publish(True)
