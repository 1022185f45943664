"""MCAP logs of ROS 2 messages, without rclpy: recording, reading back, repairing.

- :mod:`.message_definitions`: ROS type names and ``ros2msg`` schema text;
- :mod:`.rosbag2_qos`: the ``offered_qos_profiles`` channel metadata rosbag2 replays with;
- :mod:`.profile`: the ``ros2`` profile's names and the package version;
- :mod:`.sink`, :mod:`.chunk_age`: log names, the unbuffered file, when a chunk is closed;
- :mod:`.writer`: :class:`McapRecorder` and its hard-kill loss bound;
- :mod:`.reader`: :func:`read_log` (skips and reports undecodable messages),
  :func:`read_metadata`, :func:`summarize_log`;
- :mod:`.salvage`: every readable record of a damaged file, and what lies between them;
- :mod:`.recovery`: :func:`recover_truncated` (``tissue-sim recover``).

The public names are here. Importing this package imports no numba (the engine is not loaded
to write a log).
"""
from tissue_sim_ros.io.mcap.profile import DEFAULT_METADATA_NAME, MESSAGE_ENCODING, PROFILE, SCHEMA_ENCODING
from tissue_sim_ros.io.mcap.reader import (LogMessage, LogReading, UndecodableMessages, read_log,
                                           read_metadata, summarize_log)
from tissue_sim_ros.errors import TruncatedLogError
from tissue_sim_ros.io.mcap.recovery import recover_truncated
from tissue_sim_ros.io.mcap.sink import end_chunk, new_log_path
from tissue_sim_ros.io.mcap.writer import McapRecorder, RecorderStats
from tissue_sim_ros.io.mcap.message_definitions import message_definition, msg_file, schema_name
from tissue_sim_ros.io.mcap.rosbag2_qos import qos_profile, qos_profiles_yaml

__all__ = [
    'DEFAULT_METADATA_NAME',
    'MESSAGE_ENCODING',
    'PROFILE',
    'SCHEMA_ENCODING',
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
