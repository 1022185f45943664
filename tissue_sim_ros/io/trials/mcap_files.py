"""A robot's insertion log in MCAP (any rosbag2 recording) as a Trial, without rclpy.

The force comes from geometry_msgs/WrenchStamped on one topic, the needle base pose from
geometry_msgs/PoseStamped or TransformStamped on another (both named by the user); messages are
decoded by :func:`tissue_sim_ros.io.mcap.reader.read_log`. Conventions (docs/data.md): the needle
axis is its base frame's +z (or ``needle_axis`` in that frame); the wrench is the force on the
needle, so the axial force ``sign x (F . axis)`` with ``sign = -1`` is positive while the tissue
resists insertion. Rows in errors are a message's 1-based index on its topic, in log order.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError

from tissue_sim_ros.io.mcap.reader import read_log, summarize_log
from tissue_sim_ros.errors import TruncatedLogError
from tissue_sim_ros.io.mcap.recovery import check_mcap_magic
from tissue_sim_ros.errors import NotAnMcapError
from tissue_sim_ros.io.trials.trial import Trial, check_increasing_time, drop_nonfinite_rows
from tissue_sim_ros.errors import DataError
from tissue_sim_ros.units import NS_PER_S

__all__ = ['read_mcap_trial']

_WRENCH_TYPES = ('WrenchStamped',)
_POSE_TYPES = ('PoseStamped', 'TransformStamped')


@dataclass
class _Samples:
    """The messages of one topic sorted by time: stamps [ns], 1-based message index in log
    order, values (k, n), and the frames the first message names."""

    stamps_ns: np.ndarray
    rows: np.ndarray
    values: np.ndarray
    frame_id: str
    child_frame_id: str | None


def _file_topics(path: Path) -> str:
    try:
        topics = summarize_log(path)['topics']
    except (McapError, ValueError):
        return 'unknown (the file has no summary)'
    return ', '.join(f'{name} ({entry["type"]}, {entry["count"]})'
                     for name, entry in sorted(topics.items())) or 'none'


def _read_topics(path: Path, topics: list[str], allow_truncated: bool) -> dict[str, list]:
    """topic -> its decoded messages in log order; a topic without any is a DataError."""
    try:
        check_mcap_magic(path)
        reading = read_log(path, topics, allow_truncated=allow_truncated)
        by_topic: dict[str, list] = {topic: [] for topic in topics}
        for message in reading:
            by_topic[message.topic].append(message)
    except NotAnMcapError as exc:
        raise DataError(path, str(exc).removeprefix(f'{path}: ')) from None
    except OSError as exc:
        raise DataError(path, f'cannot be read ({exc.strerror or exc})') from None
    except TruncatedLogError:
        raise DataError(path, 'the recording was cut short (no valid summary); read it with '
                              'allow_truncated=True or repair it with tissue-sim recover') from None
    except McapError as exc:
        raise DataError(path, f'not a readable MCAP log ({exc})') from None
    for topic, messages in by_topic.items():
        if not messages:
            skipped = reading.undecodable.get(topic)
            why = f' ({skipped.count} did not decode: {skipped.first_error})' if skipped else ''
            raise DataError(path, f'no messages on topic {topic!r}{why}; the file has: '
                                  f'{_file_topics(path)}', column=topic)
    return by_topic


def _checked_type(path: Path, topic: str, messages: list, allowed: tuple[str, ...]) -> str:
    type_name = messages[0].type_name
    if type_name.rsplit('/', 1)[-1] not in allowed:
        raise DataError(path, f'topic type {type_name}; expected geometry_msgs/msg/'
                              f'{" or ".join(allowed)}', column=topic)
    return type_name.rsplit('/', 1)[-1]


def _samples(path: Path, topic: str, messages: list, values: list, time_source: str) -> _Samples:
    """Sorted by time (header stamps can arrive out of order); repeated times refused."""
    if time_source == 'log':
        stamps = [m.log_time_ns for m in messages]
    else:
        stamps = [m.message.header.stamp.sec * NS_PER_S + m.message.header.stamp.nanosec
                  for m in messages]
    stamps_ns = np.array(stamps, dtype=np.int64)
    frames = [m.message.header.frame_id for m in messages]
    other = next((i for i, frame in enumerate(frames) if frame != frames[0]), None)
    if other is not None:
        raise DataError(path, f'header.frame_id changes from {frames[0]!r} to {frames[other]!r}',
                        column=topic, row=other + 1)
    order = np.argsort(stamps_ns, kind='stable')
    rows = order + 1
    check_increasing_time(path, stamps_ns[order] / NS_PER_S, rows, topic)
    return _Samples(stamps_ns[order], rows, np.array(values, dtype=np.float64)[order], frames[0],
                    getattr(messages[0].message, 'child_frame_id', None))


def _finite(path: Path, topic: str, samples: _Samples, drop: bool,
            at_least: int) -> tuple[_Samples, int]:
    """The samples without NaN or inf (refused unless ``drop``), and how many were left out."""
    keep = drop_nonfinite_rows(path, {topic: samples.values}, samples.rows, drop)
    kept = _Samples(samples.stamps_ns[keep], samples.rows[keep], samples.values[keep],
                    samples.frame_id, samples.child_frame_id)
    if len(kept.rows) < at_least:
        raise DataError(path, f'{len(kept.rows)} message(s) with finite values; a trial needs at '
                              f'least {at_least}', column=topic)
    return kept, int(np.count_nonzero(~keep))


def _wrench_samples(path, topic, messages, time_source) -> _Samples:
    _checked_type(path, topic, messages, _WRENCH_TYPES)
    values = [(w.force.x, w.force.y, w.force.z, w.torque.x, w.torque.y, w.torque.z)
              for w in (m.message.wrench for m in messages)]
    return _samples(path, topic, messages, values, time_source)


def _pose_samples(path, topic, messages, time_source) -> _Samples:
    """Values: position x y z, orientation x y z w."""
    kind = _checked_type(path, topic, messages, _POSE_TYPES)
    values = []
    for m in messages:
        if kind == 'PoseStamped':
            p, q = m.message.pose.position, m.message.pose.orientation
        else:
            p, q = m.message.transform.translation, m.message.transform.rotation
        values.append((p.x, p.y, p.z, q.x, q.y, q.z, q.w))
    return _samples(path, topic, messages, values, time_source)


def _rotated(path, topic, quaternion_xyzw: np.ndarray, vector: np.ndarray) -> np.ndarray:
    """``vector`` rotated by the (normalised) quaternion x y z w."""
    norm = np.linalg.norm(quaternion_xyzw)
    if not norm > 0:
        raise DataError(path, f'orientation {quaternion_xyzw.tolist()} is not a rotation',
                        column=topic, row=1)
    q, w = quaternion_xyzw[:3] / norm, quaternion_xyzw[3] / norm
    return vector + 2.0 * w * np.cross(q, vector) + 2.0 * np.cross(q, np.cross(q, vector))


def _travel_at(stamps_ns: np.ndarray, pose: _Samples, axis_parent: np.ndarray) -> np.ndarray:
    """The pose's displacement from the first pose along the axis, interpolated linearly onto
    ``stamps_ns`` (held before the first pose and after the last)."""
    travel_at_poses = (pose.values[:, :3] - pose.values[0, :3]) @ axis_parent
    origin_ns = stamps_ns[0]
    return np.interp((stamps_ns - origin_ns).astype(np.float64),
                     (pose.stamps_ns - origin_ns).astype(np.float64), travel_at_poses)


def _wrench_in_needle_frame(path, wrench: _Samples, pose: _Samples | None, wrench_frame: str,
                            needle_frame: str, topic: str) -> bool:
    """Whether the wrench is expressed in the needle's frame (else in the pose's parent)."""
    if wrench_frame != 'auto' or pose is None:
        return wrench_frame != 'parent'
    if wrench.frame_id in (needle_frame, pose.child_frame_id):
        return True
    if wrench.frame_id == pose.frame_id:
        return False
    needle_frames = ' or '.join(repr(f) for f in (needle_frame, pose.child_frame_id) if f)
    raise DataError(path, f'wrench frame_id {wrench.frame_id!r} is neither the needle frame '
                          f'({needle_frames}) nor the pose frame {pose.frame_id!r}; say which '
                          "with wrench_frame: 'needle' or 'parent'", column=topic)


def read_mcap_trial(path, wrench_topic: str, pose_topic: str | None = None, *,
                    needle_axis=(0.0, 0.0, 1.0), needle_frame: str = 'needle',
                    wrench_frame: str = 'auto', sign: int = -1, time_source: str = 'header',
                    drop_nan_rows: bool = False, allow_truncated: bool = False) -> Trial:
    """The wrench (and needle pose) of an MCAP log as a :class:`Trial` in SI.

    - Time: the wrench header stamps (``time_source='log'``: MCAP log times), sorted.
    - Travel: the pose's displacement from the first pose along the needle axis, the axis being
      ``needle_axis`` (in the needle frame) turned by the first pose's orientation; the pose is
      interpolated linearly onto the wrench times (held before the first, after the last).
    - Axial force: ``sign x (F . axis)``, with the axis in the wrench's frame: ``needle_axis``
      when the wrench frame_id is ``needle_frame`` or the transform's child frame, the turned
      axis when it is the pose's parent frame (``wrench_frame`` 'needle'/'parent' says so for
      other names). Without a pose topic, ``needle_axis`` is taken in the wrench's frame.
    - ``force_n``, ``torque_nm``: the wrench as recorded.
    - Messages with NaN or inf are refused, or left out with ``drop_nan_rows`` (wrenches and
      poses, counted together in ``nan_rows_dropped``).
    A missing topic raises :class:`DataError` naming the topics the file has.
    """
    path = Path(path)
    if sign not in (1, -1) or wrench_frame not in ('auto', 'needle', 'parent'):
        raise ValueError(f'sign={sign!r}, wrench_frame={wrench_frame!r}: expected +1 or -1, and '
                         "'auto', 'needle' or 'parent'")
    axis_needle = np.asarray(needle_axis, dtype=np.float64)
    if axis_needle.shape != (3,) or not np.linalg.norm(axis_needle) > 0:
        raise ValueError(f'needle_axis = {needle_axis!r}: expected 3 numbers, not all 0')
    axis_needle = axis_needle / np.linalg.norm(axis_needle)
    if time_source not in ('header', 'log'):
        raise ValueError(f"time_source = {time_source!r}: expected 'header' or 'log'")
    topics = [wrench_topic] + ([pose_topic] if pose_topic else [])
    messages = _read_topics(path, topics, allow_truncated)
    wrench = _wrench_samples(path, wrench_topic, messages[wrench_topic], time_source)
    wrench, nan_rows_dropped = _finite(path, wrench_topic, wrench, drop_nan_rows, 2)
    travel_m, axis_in_wrench_frame = None, axis_needle
    if pose_topic:
        pose = _pose_samples(path, pose_topic, messages[pose_topic], time_source)
        pose, nan_poses_dropped = _finite(path, pose_topic, pose, drop_nan_rows, 1)
        nan_rows_dropped += nan_poses_dropped
        axis_parent = _rotated(path, pose_topic, pose.values[0, 3:], axis_needle)
        travel_m = _travel_at(wrench.stamps_ns, pose, axis_parent)
        if not _wrench_in_needle_frame(path, wrench, pose, wrench_frame, needle_frame,
                                       wrench_topic):
            axis_in_wrench_frame = axis_parent
    force_n, torque_nm = wrench.values[:, :3], wrench.values[:, 3:]
    return Trial(file=str(path), time_s=wrench.stamps_ns / NS_PER_S,
                 axial_force_n=sign * (force_n @ axis_in_wrench_frame), travel_m=travel_m,
                 force_n=force_n, torque_nm=torque_nm, nan_rows_dropped=nan_rows_dropped)
