"""Every readable record of a damaged MCAP file, and exactly what lies between them.

A log can be cut short (a hard kill, a full disk) or damaged inside (a bad sector, a copy that
flipped bytes). :func:`salvage` walks the data section record by record; a chunk is kept only
whole (decompressed, its CRC checked). Where a record cannot be read, the walk skips to the next
readable chunk, found from the summary's chunk index where the file's summary survives, else by
scanning the bytes for the next chunk whose CRC checks, and every intact chunk after the damage
is kept. Each stretch it skips is a :class:`Damage`: where it lies in the file, the log times of
the chunks it held (from their index, or from a chunk header that survived) and, where the
summary or the chunk's message indexes say, how many messages it held on which channel.

The summary's schemas and channels stand in for those defined only inside a damaged chunk, so
later messages on those channels are kept.
"""
from __future__ import annotations

import mmap
import os
import struct
import zlib
from dataclasses import dataclass, field
from io import BytesIO

from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import (Channel, Chunk, ChunkIndex, DataEnd, Footer, Header, Message, MessageIndex, Metadata,
                          Schema, Statistics)
from mcap.stream_reader import breakup_chunk

__all__ = ['Damage', 'Salvage', 'salvage']

_MAGIC = b'\x89MCAP0\r\n'
_FOOTER_BYTES = 1 + 8 + 20 + len(_MAGIC)        # the footer record and the closing magic
_COMPRESSIONS = ('', 'zstd', 'lz4')


@dataclass
class Damage:
    """A stretch of the file no record could be read from."""
    start: int                       # byte offset
    end: int                         # byte offset of the next readable record (the file's size: none)
    first_log_time_ns: int | None = None   # of the messages it held, where known
    last_log_time_ns: int | None = None
    messages: dict = field(default_factory=dict)   # {channel id: messages it held}, where known
    known: bool = False              # whether ``messages`` comes from an index (else unknown)


@dataclass
class Salvage:
    """What :func:`salvage` found: the records in order, the damage, and the summary's view."""
    records: list                    # Header, Schema, Channel, Message, Metadata, DataEnd, Footer
    damage: list                     # [Damage]
    complete: bool                   # the footer was reached with nothing skipped
    data_end: bool                   # the data section ended properly (DataEnd read)
    schemas: dict                    # {id: Schema} from the data and the summary
    channels: dict                   # {id: Channel} from the data and the summary
    statistics: Statistics | None    # the summary's, when it survived
    file_bytes: int


def _parse(record_type, content: bytes, length: int | None = None):
    """A record parsed from exactly ``content`` (None when it does not fill it exactly)."""
    stream = ReadDataStream(BytesIO(content))
    try:
        record = record_type.read(stream, length) if length is not None else record_type.read(stream)
    except Exception:           # any malformed content: the record is not readable
        return None
    return record if stream.count <= len(content) else None


def _record_at(data, pos: int):
    """(opcode, content, next offset) of the record at ``pos``, or None when no record fits there."""
    if pos + 9 > len(data):
        return None
    opcode = data[pos]
    (length,) = struct.unpack_from('<Q', data, pos + 1)
    end = pos + 9 + length
    if end > len(data) or opcode == 0 or opcode > Opcode.DATA_END:
        return None
    return opcode, bytes(data[pos + 9:end]), end


def _chunk_records(content: bytes):
    """The records inside a chunk record's content, or None when it is not a whole chunk (its
    fields do not fit, an unknown compression, or the CRC of its records does not check)."""
    if len(content) < 8 * 3 + 4 + 4:
        return None
    (compression_length,) = struct.unpack_from('<I', content, 28)
    if compression_length > 16 or 32 + compression_length + 8 > len(content):
        return None
    chunk = _parse(Chunk, content)
    if chunk is None or chunk.compression not in _COMPRESSIONS:
        return None
    try:
        return chunk, breakup_chunk(chunk, validate_crc=True)
    except Exception:           # a decompression or CRC failure: the chunk is damaged
        return None


def _read_summary(data) -> tuple[list, dict, dict, Statistics | None]:
    """(chunk indexes, schemas, channels, statistics) of the summary, when the footer and the
    summary read back; empty otherwise."""
    empty = ([], {}, {}, None)
    if len(data) < len(_MAGIC) + _FOOTER_BYTES or bytes(data[-len(_MAGIC):]) != _MAGIC:
        return empty
    found = _record_at(data, len(data) - _FOOTER_BYTES)
    if found is None or found[0] != Opcode.FOOTER:
        return empty
    footer = _parse(Footer, found[1])
    if footer is None or not 0 < footer.summary_start < len(data) - _FOOTER_BYTES:
        return empty
    # the CRC covers the summary and the footer up to its own field
    covered = bytes(data[footer.summary_start:len(data) - len(_MAGIC) - 4])
    if footer.summary_crc and zlib.crc32(covered) != footer.summary_crc:
        return empty
    indexes, schemas, channels, statistics, pos = [], {}, {}, None, footer.summary_start
    readers = {Opcode.CHUNK_INDEX: ChunkIndex, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel,
               Opcode.STATISTICS: Statistics}
    while pos < len(data) - _FOOTER_BYTES:
        found = _record_at(data, pos)
        if found is None:
            return empty
        opcode, content, pos = found
        record = _parse(readers[opcode], content) if opcode in readers else None
        if isinstance(record, ChunkIndex):
            indexes.append(record)
        elif isinstance(record, Schema):
            schemas[record.id] = record
        elif isinstance(record, Channel):
            channels[record.id] = record
        elif isinstance(record, Statistics):
            statistics = record
    return sorted(indexes, key=lambda i: i.chunk_start_offset), schemas, channels, statistics


def _next_chunk(data, start: int, indexes) -> int:
    """The offset of the next readable chunk after ``start``: the chunk index's next entry where
    there is one, else the first chunk found by scanning whose CRC checks (the file's size: none)."""
    for index in indexes:
        if index.chunk_start_offset >= start and _chunk_at(data, index.chunk_start_offset):
            return index.chunk_start_offset
    pos = start
    while True:
        pos = data.find(bytes([Opcode.CHUNK]), pos)
        if pos < 0:
            return len(data)
        if _chunk_at(data, pos):
            return pos
        pos += 1


def _chunk_at(data, pos: int) -> bool:
    found = _record_at(data, pos)
    return found is not None and found[0] == Opcode.CHUNK and _chunk_records(found[1]) is not None


def _describe(damage: Damage, data, indexes) -> None:
    """Fill in what the damaged stretch held: from the chunk indexes of the chunks it covers, or
    from a chunk header at its start and the message indexes written after it."""
    covered = [i for i in indexes if damage.start <= i.chunk_start_offset < damage.end]
    if covered:
        damage.first_log_time_ns = min(i.message_start_time for i in covered)
        damage.last_log_time_ns = max(i.message_end_time for i in covered)
        messages, known = {}, True
        for index in covered:
            for channel, offset in index.message_index_offsets.items():
                found = _record_at(data, offset)
                record = _parse(MessageIndex, found[1]) if found and found[0] == Opcode.MESSAGE_INDEX else None
                if record is None:
                    known = False
                    continue
                messages[channel] = messages.get(channel, 0) + len(record.records)
        damage.messages, damage.known = messages, known
        return
    if damage.start + 25 <= len(data) and data[damage.start] == Opcode.CHUNK:
        first, last = struct.unpack_from('<QQ', data, damage.start + 9)
        if first <= last:
            damage.first_log_time_ns, damage.last_log_time_ns = first, last


def salvage(path) -> Salvage:
    """Walk ``path`` (which starts with the MCAP magic) and keep every readable record."""
    with open(path, 'rb') as f:
        if os.fstat(f.fileno()).st_size < 4096:          # small (or empty: mmap refuses those)
            return _walk(f.read())
        with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
            return _walk(data)


def _walk(data) -> Salvage:
    indexes, schemas, channels, statistics = _read_summary(data)
    records, damage = [], []
    complete = data_end = False
    pos = len(_MAGIC)
    readers = {Opcode.HEADER: Header, Opcode.SCHEMA: Schema, Opcode.CHANNEL: Channel, Opcode.METADATA: Metadata,
               Opcode.DATA_END: DataEnd}
    while pos < len(data) and not data_end:
        found = _record_at(data, pos)
        kept = None
        if found is not None:
            opcode, content, after = found
            if opcode == Opcode.CHUNK:
                kept = _chunk_records(content)
                kept = None if kept is None else kept[1]
            elif opcode == Opcode.MESSAGE:
                message = _parse(Message, content, len(content))
                kept = None if message is None else [message]
            elif opcode in readers:
                record = _parse(readers[opcode], content)
                kept = None if record is None else [record]
            else:                   # the footer, an index, an attachment: nothing to keep
                kept = []
        if kept is None:
            gap = Damage(pos, _next_chunk(data, pos + 1, indexes))
            _describe(gap, data, indexes)
            damage.append(gap)
            pos = gap.end
            continue
        for record in kept:
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, DataEnd):
                data_end = True
            records.append(record)
        if found[0] == Opcode.FOOTER:
            complete = not damage
            break
        pos = after
    if data_end and not damage:
        complete = complete or bool(indexes) or statistics is not None
    return Salvage(records, damage, complete, data_end, schemas, channels, statistics, len(data))
