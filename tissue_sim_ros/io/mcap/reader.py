"""Reading MCAP logs back without rclpy: messages, metadata and a summary of what a log holds.

Messages are decoded by ``mcap_ros2`` from the schemas in the file. A payload that does not
decode with its schema (a malformed message the node received and recorded as it came) is
skipped and reported, never raised: see :class:`LogReading`. A file without a valid summary (a
hard kill) raises :class:`TruncatedLogError` unless the caller allows it; then every readable
record is read (:func:`~tissue_sim_ros.io.mcap.salvage.salvage`, which :mod:`.recovery` shares).
"""
from __future__ import annotations

import logging
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import yaml
from mcap.exceptions import DecoderNotFoundError, McapError
from mcap.reader import make_reader
from mcap.records import Message, Metadata
from mcap_ros2.decoder import DecoderFactory

from tissue_sim_ros.io.mcap.profile import DEFAULT_METADATA_NAME
from tissue_sim_ros.io.mcap.salvage import salvage
from tissue_sim_ros.units import NS_PER_S
from tissue_sim_ros.errors import TruncatedLogError

__all__ = ['LogMessage', 'LogReading', 'UndecodableMessages', 'has_summary', 'read_log', 'read_metadata', 'summarize_log']

_log = logging.getLogger(__name__)

#: How many log times of undecodable messages :class:`UndecodableMessages` keeps per topic.
FIRST_LOG_TIMES_KEPT = 5


class LogMessage(NamedTuple):
    topic: str
    type_name: str
    log_time_ns: int
    message: Any  # a types.SimpleNamespace decoded by mcap_ros2 (no rclpy)


@dataclass
class UndecodableMessages:
    """The messages of one topic that did not decode with their schema and were skipped."""

    count: int = 0
    first_log_times_ns: list[int] = field(default_factory=list)  # up to FIRST_LOG_TIMES_KEPT
    first_error: str = ''


# What a torn file can raise while being read: end of data, a record cut short, a bad CRC in the
# last chunk, a chunk that does not decompress.
_TORN_ERRORS: tuple[type[BaseException], ...] = (McapError, struct.error, ValueError, EOFError,
                                                 zlib.error)
try:
    import zstandard as _zstd
    _TORN_ERRORS += (_zstd.ZstdError,)
except ImportError:  # pragma: no cover  (zstandard comes with mcap's zstd support; without it
    _zstd = None     # no zstd chunk can be read, so there is no zstd error to expect)


def _check_complete(reader, path) -> None:
    try:
        reader.get_summary()
    except _TORN_ERRORS as exc:
        raise TruncatedLogError(
            f'{path}: no valid footer/summary ({exc}); the recording was cut short. '
            'Use `tissue-sim recover`, recover_truncated() or '
            'read_log(..., allow_truncated=True).') from exc


def has_summary(path) -> bool:
    """Whether the file's footer and summary read back (a log closed properly)."""
    with open(path, 'rb') as f:
        try:
            _check_complete(make_reader(f), path)
        except TruncatedLogError:
            return False
    return True


class LogReading(Iterator[LogMessage]):
    """What :func:`read_log` returns: an iterator of :class:`LogMessage` that also reports.

    ``undecodable``: {topic: :class:`UndecodableMessages`} of the messages skipped so far because
    their payload did not decode with the channel's schema (count, first log times, first
    error); complete once the iteration has ended. ``skipped`` is the total.
    """

    def __init__(self, path, topics, allow_truncated: bool):
        self.undecodable: dict[str, UndecodableMessages] = {}
        self._factory = DecoderFactory()
        self._decoders: dict[int, Any] = {}  # channel id -> decoder, or the exception it raised
        self._messages = self._read(path, topics, allow_truncated)

    @property
    def skipped(self) -> int:
        return sum(u.count for u in self.undecodable.values())

    def __next__(self) -> LogMessage:
        return next(self._messages)

    def close(self) -> None:
        """Stop early and close the file."""
        self._messages.close()

    def _read(self, path, topics, allow_truncated) -> Iterator[LogMessage]:
        with open(path, 'rb') as f:
            reader = make_reader(f)
            try:
                _check_complete(reader, path)
            except TruncatedLogError:
                if not allow_truncated:
                    raise
                yield from self._read_truncated(path, topics)
                return
            for schema, channel, message in reader.iter_messages(topics=topics,
                                                                  log_time_order=True):
                yield from self._decoded(schema, channel, message, raw_if_no_decoder=False)

    def _read_truncated(self, path, topics) -> Iterator[LogMessage]:
        wanted = None if topics is None else {topics} if isinstance(topics, str) else set(topics)
        found = salvage(path)
        for record in found.records:
            if isinstance(record, Message):
                channel = found.channels.get(record.channel_id)
                if channel is not None and (wanted is None or channel.topic in wanted):
                    yield from self._decoded(found.schemas.get(channel.schema_id), channel, record,
                                             raw_if_no_decoder=True)

    def _decoded(self, schema, channel, message, raw_if_no_decoder) -> Iterator[LogMessage]:
        """The decoded message, or nothing (counted) when its payload does not decode."""
        type_name = schema.name if schema else ''
        decoder = self._decoders.get(channel.id)
        if decoder is None:
            try:
                decoder = self._factory.decoder_for(channel.message_encoding, schema)
            except Exception as exc:  # noqa: BLE001  (a schema mcap_ros2 cannot parse)
                decoder = exc
            if decoder is None:
                if raw_if_no_decoder:
                    yield LogMessage(channel.topic, type_name, message.log_time, message.data)
                    return
                raise DecoderNotFoundError(
                    f'no decoder for message encoding {channel.message_encoding!r}, schema '
                    f'{type_name!r} (topic {channel.topic})')
            self._decoders[channel.id] = decoder
        try:
            if isinstance(decoder, Exception):
                raise decoder
            value = decoder(message.data)
        except Exception as exc:  # noqa: BLE001  (any failure of one payload: skip, count it)
            self._count_undecodable(channel.topic, message, exc)
            return
        yield LogMessage(channel.topic, type_name, message.log_time, value)

    def _count_undecodable(self, topic: str, message, exc: Exception) -> None:
        entry = self.undecodable.setdefault(topic, UndecodableMessages())
        entry.count += 1
        if len(entry.first_log_times_ns) < FIRST_LOG_TIMES_KEPT:
            entry.first_log_times_ns.append(message.log_time)
        if entry.count == 1:
            entry.first_error = f'{type(exc).__name__}: {exc}'[:200]
            _log.warning('%s: skipped an undecodable message (%d bytes) at log time %.9f s: %s',
                         topic, len(message.data), message.log_time / NS_PER_S,
                         entry.first_error)


def read_log(path, topics=None, *, allow_truncated: bool = False) -> LogReading:
    """(topic, type_name, log_time_ns, decoded message) in log-time order, without rclpy.

    Messages are decoded by ``mcap_ros2`` from the schemas in the file. A message whose payload
    does not decode is skipped, never raised: the returned :class:`LogReading` counts them per
    topic in ``undecodable`` (with the first log times and the first error), and the first of
    each topic is logged as a warning. A file without a valid summary raises TruncatedLogError
    unless ``allow_truncated``: then the intact chunks are read in file order (stream read).
    """
    return LogReading(path, topics, allow_truncated)


def read_metadata(path, name: str | None = DEFAULT_METADATA_NAME) -> dict:
    """The MCAP Metadata record ``name`` as a dict of strings ({} if absent); later records of
    the same name update earlier ones. ``name=None``: {record name: dict} of all records.
    Reads truncated files too (the recorder writes the metadata first).
    """
    records: list[Metadata] = []
    with open(path, 'rb') as f:
        reader = make_reader(f)
        try:
            _check_complete(reader, path)
            records = list(reader.iter_metadata())
        except TruncatedLogError:
            records = [r for r in salvage(path).records if isinstance(r, Metadata)]
    if name is None:
        out: dict[str, dict[str, str]] = {}
        for r in records:
            out.setdefault(r.name, {}).update(r.metadata)
        return out
    merged: dict[str, str] = {}
    for r in records:
        if r.name == name:
            merged.update(r.metadata)
    return merged


def _topic_entry(schema, channel, first=None, last=None, count=0) -> dict[str, Any]:
    return {'type': schema.name if schema else '', 'count': count,
            'first_log_time_ns': first, 'last_log_time_ns': last,
            'qos': yaml.safe_load(channel.metadata.get('offered_qos_profiles', '') or '[]')}


def _statistics(summary) -> dict[str, Any] | None:
    """The file's Statistics record as a dict, channel counts by topic (None if absent)."""
    if summary is None or summary.statistics is None:
        return None
    st = summary.statistics
    by_id = {c.id: c.topic for c in summary.channels.values()}
    return {
        'message_count': st.message_count,
        'channel_message_counts': {by_id.get(k, str(k)): v
                                   for k, v in st.channel_message_counts.items()},
        'message_start_time': st.message_start_time,
        'message_end_time': st.message_end_time,
        'chunk_count': st.chunk_count,
        'metadata_count': st.metadata_count,
    }


def summarize_log(path) -> dict:
    """What a log holds: per topic its type, count, first/last log time and QoS; totals.

    Counts come from scanning the messages (no decoding); ``statistics`` repeats what the
    file's Statistics record says (None if it has none), so the two can be compared.
    """
    with open(path, 'rb') as f:
        reader = make_reader(f)
        _check_complete(reader, path)
        header = reader.get_header()
        summary = reader.get_summary()
        topics: dict[str, dict[str, Any]] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            entry = topics.get(channel.topic)
            if entry is None:
                entry = topics[channel.topic] = _topic_entry(
                    schema, channel, message.log_time, message.log_time)
            entry['count'] += 1
            entry['first_log_time_ns'] = min(entry['first_log_time_ns'], message.log_time)
            entry['last_log_time_ns'] = max(entry['last_log_time_ns'], message.log_time)
    if summary is not None:  # topics registered but never written
        for channel in summary.channels.values():
            if channel.topic not in topics:
                topics[channel.topic] = _topic_entry(summary.schemas.get(channel.schema_id),
                                                     channel)
    firsts = [t['first_log_time_ns'] for t in topics.values() if t['count']]
    lasts = [t['last_log_time_ns'] for t in topics.values() if t['count']]
    return {
        'path': str(path),
        'profile': header.profile,
        'library': header.library,
        'message_count': sum(t['count'] for t in topics.values()),
        'first_log_time_ns': min(firsts) if firsts else None,
        'last_log_time_ns': max(lasts) if lasts else None,
        'duration_s': (max(lasts) - min(firsts)) / NS_PER_S if firsts else 0.0,
        'topics': topics,
        'compression': sorted({c.compression for c in summary.chunk_indexes}) if summary else [],
        'statistics': _statistics(summary),
    }

