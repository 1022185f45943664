"""The names of the MCAP ``ros2`` profile this package writes, shared by writer, reader and repair.

Files follow the profile so that rosbag2 (``ros2 bag play x.mcap``), Foxglove / Lichtblick
(``@mcap/core``), ``rosbags`` and ``mcap_ros2`` open them: schema encoding ``ros2msg``, message
encoding ``cdr`` (the payload is the wire bytes, never re-encoded here), and one Metadata record
``tissue_sim`` with the scene, the parameters and the package version.
"""
from __future__ import annotations

from tissue_sim_ros.io.mcap.message_definitions import SCHEMA_ENCODING

__all__ = ['PROFILE', 'SCHEMA_ENCODING', 'MESSAGE_ENCODING', 'DEFAULT_METADATA_NAME',
           'package_version', 'library_name']

PROFILE = 'ros2'
MESSAGE_ENCODING = 'cdr'
DEFAULT_METADATA_NAME = 'tissue_sim'


def package_version() -> str:
    """This package's version (from its installed metadata; no engine import)."""
    from tissue_sim_ros import __version__
    return __version__


def library_name(role: str) -> str:
    """The MCAP header's ``library`` field: 'tissue_sim_ros/<version> <role>'."""
    return f'tissue_sim_ros/{package_version()} {role}'
