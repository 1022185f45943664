"""Repairing a log cut short (a hard kill, a full disk, a copy cut off): what is intact, and a copy.

A stream read (:class:`~tissue_sim_ros.io.mcap.reader.TolerantScan`) keeps every whole chunk
(decompressed and CRC-checked) up to the first torn record; the repaired copy holds those
schemas, channels (with their metadata), metadata records and messages, with the payloads as
they were, in a new complete file (zstd chunks, summary) that every reader opens.
``tissue-sim recover`` is the command around :func:`recover_truncated`.
"""
from __future__ import annotations

import datetime as _dt
import struct
from pathlib import Path

from mcap.opcode import Opcode
from mcap.records import DataEnd, Message, Metadata
from mcap.writer import CompressionType, Writer

from tissue_sim_ros.io.mcap.profile import PROFILE, library_name
from tissue_sim_ros.io.mcap.reader import TolerantScan, has_summary
from tissue_sim_ros.units import NS_PER_S
from tissue_sim_ros.errors import NotAnMcapError, RecoverError

__all__ = ['MCAP_MAGIC', 'check_mcap_magic', 'recover_log',
           'recover_truncated', 'recovery_summary']

MCAP_MAGIC = b'\x89MCAP0\r\n'


def check_mcap_magic(path) -> None:
    """Raise NotAnMcapError unless ``path`` starts with the MCAP magic (OSError if unreadable)."""
    with open(path, 'rb') as f:
        head = f.read(len(MCAP_MAGIC))
    if head != MCAP_MAGIC:
        raise NotAnMcapError(f'{path}: not an MCAP file (it starts with {head[:8]!r}, '
                             f'expected {MCAP_MAGIC!r})')


def _torn_chunk_times(path, offset: int) -> tuple[int, int] | None:
    """(message_start_time, message_end_time) of a chunk cut short at ``offset``, if its record
    header survived there (opcode, length, the two times); None otherwise."""
    with open(path, 'rb') as f:
        f.seek(offset)
        head = f.read(1 + 8 + 16)
    if len(head) < 25 or head[0] != Opcode.CHUNK:
        return None
    return struct.unpack_from('<QQ', head, 9)


class _RepairedCopy:
    """The repaired file: intact records written again into a new complete MCAP."""

    def __init__(self, path):
        self._file = open(path, 'xb')  # noqa: SIM115  (never overwrite)
        self._writer = Writer(self._file, compression=CompressionType.ZSTD, enable_data_crcs=True)
        self._writer.start(profile=PROFILE, library=library_name('recover'))
        self._schemas: dict[int, int] = {}
        self._channels: dict[int, int] = {}

    def add_metadata(self, record: Metadata) -> None:
        self._writer.add_metadata(record.name, dict(record.metadata))

    def add_message(self, scan: TolerantScan, record: Message) -> None:
        channel = scan.channels[record.channel_id]
        if channel.schema_id and channel.schema_id not in self._schemas:
            s = scan.schemas[channel.schema_id]
            self._schemas[s.id] = self._writer.register_schema(s.name, s.encoding, s.data)
        if channel.id not in self._channels:
            self._channels[channel.id] = self._writer.register_channel(
                channel.topic, channel.message_encoding, self._schemas.get(channel.schema_id, 0),
                dict(channel.metadata))
        self._writer.add_message(self._channels[channel.id], record.log_time, record.data,
                                 record.publish_time, record.sequence)

    def finish(self) -> None:
        self._writer.finish()

    def close(self) -> None:
        self._file.close()


def recover_truncated(path, repaired_path=None) -> dict:
    """Read what a (possibly) truncated log holds with a stream read; report it.

    Returns ``complete`` (footer reached), ``messages``, ``per_topic`` counts, first/last log
    time, the metadata records and ``error`` (why the read stopped); and what was lost at the
    end: ``data_intact`` (the data section ended properly: only the summary was cut, nothing
    lost), ``file_bytes`` and ``intact_bytes`` (the bytes after it are dropped),
    ``torn_chunk_end_time_ns`` (the last log time of a chunk cut short, when its header
    survived) and ``lost_s``: 0.0 when nothing was lost, the log time from the last kept
    message to the end of a torn chunk (a lower bound: a file cut off may have lost later
    chunks too), or None when the file does not say (a hard kill ends the file at a chunk
    boundary; the open chunk never reached it: ``chunk_age.ChunkAge`` has the bound).
    With ``repaired_path`` (must not exist) it also
    writes every intact schema, channel, metadata record and message to a new complete MCAP
    file (same payloads, same channel metadata, zstd chunks, summary).
    """
    scan = TolerantScan(path)
    per_topic: dict[str, int] = {}
    metadata: dict[str, dict[str, str]] = {}
    first = last = None
    data_intact = False
    copy = None if repaired_path is None else _RepairedCopy(repaired_path)
    try:
        for record in scan:
            if isinstance(record, Metadata):
                metadata.setdefault(record.name, {}).update(record.metadata)
                if copy is not None:
                    copy.add_metadata(record)
            elif isinstance(record, Message):
                topic = scan.channels[record.channel_id].topic
                per_topic[topic] = per_topic.get(topic, 0) + 1
                first = record.log_time if first is None else min(first, record.log_time)
                last = record.log_time if last is None else max(last, record.log_time)
                if copy is not None:
                    copy.add_message(scan, record)
            elif isinstance(record, DataEnd):
                data_intact = True
        if copy is not None:
            copy.finish()
    finally:
        if copy is not None:
            copy.close()
    with open(path, 'rb') as f:
        file_bytes = f.seek(0, 2)
    torn = None if scan.complete or data_intact else _torn_chunk_times(path, scan.intact_bytes)
    if scan.complete or data_intact:
        lost_s = 0.0
    elif torn is not None:
        lost_s = max(0, torn[1] - (torn[0] if last is None else last)) / NS_PER_S
    else:
        lost_s = None
    return {
        'path': str(path),
        'complete': scan.complete,
        'messages': sum(per_topic.values()),
        'per_topic': per_topic,
        'first_log_time_ns': first,
        'last_log_time_ns': last,
        'metadata': metadata,
        'error': scan.error,
        'data_intact': data_intact,
        'file_bytes': file_bytes,
        'intact_bytes': scan.intact_bytes,
        'torn_chunk_end_time_ns': None if torn is None else torn[1],
        'lost_s': lost_s,
        'repaired_path': None if repaired_path is None else str(repaired_path),
    }


def _clock(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns / NS_PER_S, _dt.timezone.utc).isoformat(
        timespec='milliseconds').replace('+00:00', 'Z')


def recovery_summary(report: dict) -> str:
    """One line: messages kept, the log span, and how much time was lost at the end."""
    n, topics = report['messages'], len(report['per_topic'])
    kept = f'{n} messages on {topics} topic{"" if topics == 1 else "s"}'
    if n:
        span = (report['last_log_time_ns'] - report['first_log_time_ns']) / NS_PER_S
        kept += f' ({span:.3f} s of log, last at {_clock(report["last_log_time_ns"])})'
    dropped = report['file_bytes'] - report['intact_bytes']
    if report['complete']:
        end = 'complete: nothing lost'
    elif report['data_intact']:
        end = f'only the summary was cut ({dropped} bytes dropped): nothing lost'
    elif report['lost_s'] is not None:
        end = (f'lost at the end: at least {report["lost_s"]:.3f} s (a chunk cut short, '
               f'{dropped} bytes dropped; later chunks may be gone too)')
    else:
        end = ('lost at the end: not recorded in the file (after a hard kill, at most the '
               "recorder's chunk_interval_s, 1 s by default, after the last kept message"
               f'{f"; {dropped} bytes dropped" if dropped else ""})')
    out = report['repaired_path']
    return f'{report["path"]}: kept {kept}; {end}' + (f'; wrote {out}' if out else '')


def recover_log(path, out=None) -> tuple[dict, str]:
    """``tissue-sim recover``: check the input, write the repaired copy, and summarize.

    ``out`` defaults to ``<name>.recovered.mcap`` beside the input; a complete log is copied
    only when ``out`` is given. Returns (report of :func:`recover_truncated`, summary line);
    RecoverError for a missing or unreadable file, a file that is not an MCAP, or an ``out``
    that exists (never overwritten).
    """
    path = Path(path)
    try:
        check_mcap_magic(path)
        complete = has_summary(path)
    except (OSError, NotAnMcapError) as exc:
        raise RecoverError(_one_line(exc, path)) from None
    if out is None and not complete:
        out = path.with_name(f'{path.stem}.recovered.mcap')
    if out is not None and Path(out).exists():
        raise RecoverError(f'{out}: exists; give --out a new file name (logs are never '
                           'overwritten)')
    try:
        report = recover_truncated(path, out)
    except OSError as exc:
        if out is not None and not isinstance(exc, FileExistsError):
            Path(out).unlink(missing_ok=True)
        raise RecoverError(_one_line(exc, out)) from None
    return report, recovery_summary(report)


def _one_line(exc: BaseException, path) -> str:
    if isinstance(exc, NotAnMcapError):
        return str(exc)
    reason = getattr(exc, 'strerror', None) or str(exc) or type(exc).__name__
    return f'{getattr(exc, "filename", None) or path}: {reason}'
