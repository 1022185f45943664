"""Repairing a log cut short (a hard kill, a full disk, a copy cut off): what is intact, and a copy.

:func:`~tissue_sim_ros.io.mcap.salvage.salvage` keeps every whole chunk (decompressed and
CRC-checked), before and after any damaged stretch, and says what each stretch held; the
repaired copy holds those schemas, channels (with their metadata), metadata records and
messages, with the payloads as they were, in a new complete file (zstd chunks, summary) that
every reader opens.
``tissue-sim recover`` is the command around :func:`recover_truncated`.
"""
from __future__ import annotations

import datetime as _dt
from pathlib import Path

from mcap.records import Message, Metadata
from mcap.writer import CompressionType, Writer

from tissue_sim_ros.io.mcap.profile import PROFILE, library_name
from tissue_sim_ros.io.mcap.salvage import Salvage, salvage
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

    def add_message(self, found: Salvage, record: Message) -> None:
        channel = found.channels[record.channel_id]
        if channel.schema_id and channel.schema_id not in self._schemas:
            s = found.schemas[channel.schema_id]
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


def recover_truncated(path, repaired_path=None, found: Salvage | None = None) -> dict:
    """Read every readable record of a (possibly) damaged or truncated log; report it.

    Returns ``complete`` (footer and summary read back, nothing skipped), ``messages``,
    ``per_topic`` counts, first/last log time, the metadata records, ``data_intact`` (the data
    section read to its end with nothing skipped: only the summary may be gone), ``file_bytes``
    and ``intact_bytes``, and what was lost: ``damage``, one entry per stretch of the file no
    record could be read from (``start``, ``end`` byte offsets; the log times and the messages per
    topic of what it held where the summary or a surviving header says, ``known`` whether those
    counts are exact), ``lost_messages`` (exact when the summary's statistics or the chunks'
    message indexes survived, else None), ``orphaned`` (messages kept on channels whose
    definition was lost: left out of the copy) and ``lost_s``: 0.0 when nothing was lost, the log
    time the damaged stretches held where known (a chunk cut short by a hard kill: from the last
    kept message to the chunk's end), or None when the file does not say (a hard kill ends the
    file at a chunk boundary; the open chunk never reached it: ``chunk_age.ChunkAge`` has the
    bound). With ``repaired_path`` (must not exist) it also writes every intact schema, channel,
    metadata record and message to a new complete MCAP file (same payloads, same channel
    metadata, zstd chunks, summary). ``found``: the file's :func:`salvage`, when already read.
    """
    found = salvage(path) if found is None else found
    per_topic: dict[str, int] = {}
    metadata: dict[str, dict[str, str]] = {}
    first = last = None
    orphaned = 0
    copy = None if repaired_path is None else _RepairedCopy(repaired_path)
    try:
        for record in found.records:
            if isinstance(record, Metadata):
                metadata.setdefault(record.name, {}).update(record.metadata)
                if copy is not None:
                    copy.add_metadata(record)
            elif isinstance(record, Message):
                channel = found.channels.get(record.channel_id)
                if channel is None:
                    orphaned += 1
                    continue
                per_topic[channel.topic] = per_topic.get(channel.topic, 0) + 1
                first = record.log_time if first is None else min(first, record.log_time)
                last = record.log_time if last is None else max(last, record.log_time)
                if copy is not None:
                    copy.add_message(found, record)
        if copy is not None:
            copy.finish()
    finally:
        if copy is not None:
            copy.close()
    kept = sum(per_topic.values())
    damage = [_damage_entry(d, found, last) for d in found.damage]
    return {
        'path': str(path),
        'complete': found.complete,
        'messages': kept,
        'per_topic': per_topic,
        'first_log_time_ns': first,
        'last_log_time_ns': last,
        'metadata': metadata,
        'error': _why_incomplete(found),
        'data_intact': found.data_end and not found.damage,
        'file_bytes': found.file_bytes,
        'intact_bytes': found.file_bytes - sum(d.end - d.start for d in found.damage),
        'damage': damage,
        'lost_messages': _lost_messages(found, kept + orphaned, damage),
        'orphaned': orphaned,
        'torn_chunk_end_time_ns': next((d['last_log_time_ns'] for d in reversed(damage)
                                        if d['end'] == found.file_bytes), None),
        'lost_s': _lost_s(found, damage),
        'repaired_path': None if repaired_path is None else str(repaired_path),
    }


def _why_incomplete(found: Salvage) -> str | None:
    """Why the log is not complete (None when it is)."""
    if found.damage:
        return f'{len(found.damage)} damaged stretch(es) skipped'
    if not found.data_end:
        return 'the file ends before its data section does (cut short)'
    return None if found.complete else 'the summary is missing or damaged'


def _damage_entry(damage, found: Salvage, last_kept) -> dict:
    topics = {}
    for channel_id, count in damage.messages.items():
        channel = found.channels.get(channel_id)
        topic = channel.topic if channel is not None else f'channel {channel_id}'
        topics[topic] = topics.get(topic, 0) + count
    first = damage.first_log_time_ns
    if damage.end == found.file_bytes and last_kept is not None and first is not None:
        first = last_kept                      # a torn last chunk: lost from the last kept message on
    return {'start': damage.start, 'end': damage.end, 'bytes': damage.end - damage.start,
            'first_log_time_ns': first, 'last_log_time_ns': damage.last_log_time_ns,
            'messages': topics if damage.known else None}


def _lost_messages(found: Salvage, read: int, damage) -> int | None:
    """Messages lost: the summary's count less those read, else the damaged chunks' indexes."""
    if found.statistics is not None:
        return max(0, found.statistics.message_count - read)
    if all(d['messages'] is not None for d in damage):
        return sum(sum(d['messages'].values()) for d in damage)
    return None


def _lost_s(found: Salvage, damage) -> float | None:
    if not damage:
        return 0.0
    spans = [d['last_log_time_ns'] - d['first_log_time_ns'] for d in damage
             if d['first_log_time_ns'] is not None and d['last_log_time_ns'] is not None]
    return max(0, sum(spans)) / NS_PER_S if len(spans) == len(damage) else None


def _clock(ns: int) -> str:
    return _dt.datetime.fromtimestamp(ns / NS_PER_S, _dt.timezone.utc).isoformat(
        timespec='milliseconds').replace('+00:00', 'Z')


def recovery_summary(report: dict) -> str:
    """One line: messages kept, the log span, and what was lost where."""
    n, topics = report['messages'], len(report['per_topic'])
    kept = f'{n} messages on {topics} topic{"" if topics == 1 else "s"}'
    if n:
        span = (report['last_log_time_ns'] - report['first_log_time_ns']) / NS_PER_S
        kept += f' ({span:.3f} s of log, last at {_clock(report["last_log_time_ns"])})'
    inside = [d for d in report['damage'] if d['end'] != report['file_bytes']]
    at_end = [d for d in report['damage'] if d['end'] == report['file_bytes']]
    parts = [f'lost {_inside_text(d)}' for d in inside]
    if report['complete']:
        parts.append('complete: nothing lost')
    elif report['data_intact']:
        parts.append(f'only the summary was cut ({report["file_bytes"] - report["intact_bytes"]} bytes dropped): '
                     'nothing lost')
    elif at_end and at_end[0]['first_log_time_ns'] is not None and at_end[0]['last_log_time_ns'] is not None:
        lost = max(0, at_end[0]['last_log_time_ns'] - at_end[0]['first_log_time_ns']) / NS_PER_S
        parts.append(f'lost at the end: at least {lost:.3f} s (a chunk cut short, {at_end[0]["bytes"]} bytes '
                     'dropped; later chunks may be gone too)')
    elif not report['data_intact'] and not report['complete'] and not inside:
        dropped = at_end[0]['bytes'] if at_end else 0
        parts.append('lost at the end: not recorded in the file (after a hard kill, at most the '
                     "recorder's chunk_interval_s, 1 s by default, after the last kept message"
                     f'{f"; {dropped} bytes dropped" if dropped else ""})')
    if inside and report['lost_messages'] is not None:
        parts[-1] += f' ({report["lost_messages"]} messages lost in all)'
    if report['orphaned']:
        parts.append(f'{report["orphaned"]} messages left out: their channel was defined only in a lost chunk')
    out = report['repaired_path']
    return f'{report["path"]}: kept {kept}; {"; ".join(parts)}' + (f'; wrote {out}' if out else '')


def _inside_text(damage: dict) -> str:
    """A damaged stretch inside the file: where, which log times, which messages."""
    what = []
    if damage['first_log_time_ns'] is not None and damage['last_log_time_ns'] is not None:
        what.append(f'log time {_clock(damage["first_log_time_ns"])} to {_clock(damage["last_log_time_ns"])}')
    if damage['messages']:
        what.append(', '.join(f'{count} on {topic}' for topic, count in sorted(damage['messages'].items())))
    return (f'bytes {damage["start"]}-{damage["end"]} (a damaged stretch, skipped; every readable chunk after '
            f'it kept{"; " + "; ".join(what) if what else ""})')


def recover_log(path, out=None) -> tuple[dict, str]:
    """``tissue-sim recover``: check the input, write the repaired copy, and summarize.

    ``out`` defaults to ``<name>.recovered.mcap`` beside the input; a complete log is copied
    only when ``out`` is given. Returns (report of :func:`recover_truncated`, summary line);
    RecoverError for a missing or unreadable file, a file that is not an MCAP, or an ``out``
    that exists (never overwritten). A log whose summary reads back but that has a damaged chunk
    is not complete: it is repaired too.
    """
    path = Path(path)
    try:
        check_mcap_magic(path)
        found = salvage(path)
    except (OSError, NotAnMcapError) as exc:
        raise RecoverError(_one_line(exc, path)) from None
    if out is None and not found.complete:
        out = path.with_name(f'{path.stem}.recovered.mcap')
    if out is not None and Path(out).exists():
        raise RecoverError(f'{out}: exists; give --out a new file name (logs are never '
                           'overwritten)')
    try:
        report = recover_truncated(path, out, found)
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
