"""The node's loop, without rclpy: poses in, the engine on its own thread, the tick out.

- :mod:`.pose_input`: validation of received poses, bad-input accounting, the pose at tick time;
- :mod:`.pose_receiver`: received poses as bytes, decoded a bounded number per slice;
- :mod:`.pacing`: how much the engine works, how far it may fall behind, the ladder's steps;
- :mod:`.trace`: what the engine did, in order: the record that makes a run replayable;
- :mod:`.engine_thread`: the engine on its own thread, never waited for;
- :mod:`.tick_thread`: the 50 Hz tick on the monotonic clock;
- :mod:`.transforms`: rigid transforms and a TF buffer (interpolation, chains), as tf2 does them.
"""
__all__ = ['engine_thread', 'pacing', 'pose_input', 'pose_receiver', 'tick_thread', 'trace', 'transforms']
