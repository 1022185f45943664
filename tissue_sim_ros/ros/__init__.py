"""The ROS 2 node: a thin rclpy shell over parts that import no rclpy.

Sub-packages:

- :mod:`~tissue_sim_ros.ros.messages`: engine arrays <-> messages, their CDR bytes, topics;
- :mod:`~tissue_sim_ros.ros.loop`: the engine thread, the tick thread, pacing, the pose input and
  the trace that makes a run replayable;
- :mod:`~tissue_sim_ros.ros.clients`: programs that talk to a node from outside (the scripted
  driver, a listener, the node as a child process).

Modules here:

- :mod:`.parameters`, :mod:`.parameter_declaration`: every node parameter and its checks;
  declaring them with rclpy;
- :mod:`.diagnostics`, :mod:`.recording`, :mod:`.targets`, :mod:`.predictions`: what the node
  reports, records, tracks and predicts;
- :mod:`.needle_shape`: the needle's shape (``needle/shape``) and the tip's frame for TF;
- :mod:`.node`, :mod:`.node_main`: the node itself and its process.
"""
__all__ = ['clients', 'diagnostics', 'loop', 'messages', 'needle_shape', 'node', 'node_main',
           'parameter_declaration', 'parameters', 'predictions', 'recording', 'targets']
