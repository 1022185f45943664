"""Recording ROS 2 messages to MCAP and reading them back, without rclpy: the public names.

A facade over the modules that do the work, kept so that ``from tissue_sim_ros.io.mcap_log
import ...`` goes on working:

- :mod:`~tissue_sim_ros.io.ros_message_definitions`: ROS type names, ``ros2msg`` schema text;
- :mod:`~tissue_sim_ros.io.rosbag2_qos`: the ``offered_qos_profiles`` channel metadata;
- :mod:`~tissue_sim_ros.io.mcap_profile`: the ``ros2`` profile's names, the package version;
- :mod:`~tissue_sim_ros.io.mcap_sink`: log names, the unbuffered file, ending a chunk;
- :mod:`~tissue_sim_ros.io.mcap_writer`: :class:`McapRecorder` and its hard-kill loss bound;
- :mod:`~tissue_sim_ros.io.mcap_reader`: :func:`read_log` (skips and reports undecodable
  messages), :func:`read_metadata`, :func:`summarize_log`;
- :mod:`~tissue_sim_ros.io.mcap_recovery`: :func:`recover_truncated` (``tissue-sim recover``).

Importing this module imports no numba (the engine is not loaded to write a log).
"""
from tissue_sim_ros.io.mcap_profile import (  # noqa: F401  (module names it has always had)
    DEFAULT_METADATA_NAME, MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING)
from tissue_sim_ros.io.mcap_reader import (LogMessage, LogReading, TruncatedLogError,
                                           UndecodableMessages, read_log, read_metadata,
                                           summarize_log)
from tissue_sim_ros.io.mcap_recovery import recover_truncated
from tissue_sim_ros.io.mcap_sink import end_chunk, new_log_path
from tissue_sim_ros.io.mcap_writer import McapRecorder, RecorderStats
from tissue_sim_ros.io.ros_message_definitions import message_definition, msg_file, schema_name
from tissue_sim_ros.io.rosbag2_qos import qos_profile, qos_profiles_yaml

__all__ = [
    'DEFAULT_METADATA_NAME',
    'LogMessage',
    'LogReading',
    'McapRecorder',
    'RecorderStats',
    'TruncatedLogError',
    'UndecodableMessages',
    'end_chunk',
    'message_definition',
    'msg_file',
    'new_log_path',
    'qos_profile',
    'qos_profiles_yaml',
    'read_log',
    'read_metadata',
    'recover_truncated',
    'schema_name',
    'summarize_log',
]
