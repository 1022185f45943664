"""Files in and out, without rclpy and without numba.

- :mod:`~tissue_sim_ros.io.mcap`: recording ROS 2 messages to MCAP, reading them back,
  repairing a log cut short;
- :mod:`~tissue_sim_ros.io.trials`: load-cell recordings (CSV, TSV, MCAP) as trials in SI, and
  the data description of a study.
"""
__all__ = ['mcap', 'trials']
