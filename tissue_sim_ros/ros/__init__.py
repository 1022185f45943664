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
  reports, records, tracks and predicts; :mod:`.prediction_action`: predictions as an action;
- :mod:`.tf_out`, :mod:`.tf_in`: the frames the node broadcasts on TF, and what it reads from TF
  (the robot's frames; the maths and the buffer are in :mod:`.loop.transforms`);
- :mod:`.registration`: the tissue's pose in the robot's frame and the needle's start;
- :mod:`.readiness`: ``~/ready``; :mod:`.services`: the node's services;
- :mod:`.node`, :mod:`.node_main`: the node itself and its process.
"""
__all__ = ['clients', 'diagnostics', 'loop', 'messages', 'node', 'node_main', 'parameter_declaration',
           'parameters', 'prediction_action', 'predictions', 'readiness', 'recording', 'registration',
           'services', 'targets', 'tf_in', 'tf_out']
