"""Messages without a node: engine arrays <-> ROS 2 messages, and the topics they travel on.

- :mod:`.topics`: every topic's name, type and QoS, in one place;
- :mod:`.conversions`: engine arrays <-> messages, pure functions;
- :mod:`.cdr_bytes`: the per-tick messages written straight into their CDR bytes;
- :mod:`.pose_cdr`: a PoseStamped read straight from its CDR bytes;
- :mod:`.from_yaml`: messages from YAML (the ``msg_examples/`` files);
- :mod:`.needle_shape`: ``needle/shape`` and the tip's frame.
"""
__all__ = ['cdr_bytes', 'conversions', 'from_yaml', 'needle_shape', 'pose_cdr', 'topics']
