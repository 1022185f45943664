"""Programs that talk to a node from outside.

- :mod:`.node_process`: ``tissue_sim_node`` as a child process on a private ROS graph;
- :mod:`.drive`: ``tissue-sim drive``, a scripted insertion and retraction on ``needle/pose``;
- :mod:`.listener`: a client that only listens (the extra subscriber a lab has);
- :mod:`.predict_client`: a planner's client of the ``~/predict_path`` action (``tissue_sim_ros.client``).
"""
__all__ = ['drive', 'listener', 'node_process', 'predict_client']
