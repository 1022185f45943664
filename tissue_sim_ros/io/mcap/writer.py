"""Recording ROS 2 messages (CDR bytes) to an MCAP file without rclpy: :class:`McapRecorder`.

File layout: the ``ros2`` profile (:mod:`tissue_sim_ros.io.mcap.profile`), zstd-compressed chunks
with message indexes, chunk indexes, a summary with Statistics, summary offsets, CRCs of every
chunk and of the data section; channel metadata ``offered_qos_profiles``
(:mod:`tissue_sim_ros.io.mcap.rosbag2_qos`); one Metadata record written at the start of the file so
that it survives a hard kill.

Durability (what a reader sees if the process dies):

- ``close()`` (also on ``with`` exit, SIGINT handled by the caller, or interpreter exit through
  ``atexit``) writes the summary: the file is complete and every reader opens it.
- After SIGKILL (or, with ``fsync=True``, a power cut) the file holds the header, the metadata
  record and every chunk closed so far; the open chunk, the writer queue and the summary are
  missing. The loss bound is in :class:`ChunkAge`. Readers that need the footer refuse such a
  file (``rosbags``, ``mcap.reader.SeekingReader``, ``McapIndexedReader`` of ``@mcap/core``);
  stream readers read every closed chunk: ``tissue-sim recover`` /
  :func:`tissue_sim_ros.io.mcap.recovery.recover_truncated` report what is intact and write a
  repaired copy, and ``read_log(..., allow_truncated=True)`` reads it as it is.
"""
from __future__ import annotations

import atexit
import math
import queue
import sys
import threading
import time
import weakref
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer

from tissue_sim_ros.io.mcap.chunk_age import ChunkAge
from tissue_sim_ros.io.mcap.profile import (DEFAULT_METADATA_NAME, MESSAGE_ENCODING, PROFILE,
                                            SCHEMA_ENCODING, library_name, package_version)
from tissue_sim_ros.io.mcap.sink import UnbufferedSink, end_chunk, new_log_path
from tissue_sim_ros.io.mcap.message_definitions import message_definition, schema_name
from tissue_sim_ros.io.mcap.rosbag2_qos import qos_profiles_yaml
from tissue_sim_ros.system.thread_names import name_os_thread

__all__ = ['ChunkAge', 'McapRecorder', 'RecorderStats']

_COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}
_STOP = object()
_WRITER_BATCH_S = 0.05   # the longest the writer thread lets messages gather before it writes them
_open_recorders: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:  # interpreter exit (also after KeyboardInterrupt)
    for recorder in list(_open_recorders):
        try:
            recorder.close()
        except Exception as exc:  # noqa: BLE001  (no logger left at exit: say it on stderr)
            print(f'tissue_sim_ros: could not close the MCAP log {recorder.path}: {exc}; '
                  f'`tissue-sim recover {recorder.path}` can repair it', file=sys.stderr)


@dataclass
class _TopicInfo:
    channel_id: int
    type_name: str
    count: int = 0


@dataclass
class RecorderStats:
    """Counters of a recorder (a snapshot)."""

    messages_written: int = 0  # handed to the MCAP writer
    messages_dropped: int = 0
    messages_unsaved: int = 0  # queued or in the open chunk: what a hard kill now would lose
    chunks_closed: int = 0
    bytes_written: int = 0
    queued_bytes: int = 0
    writer_wakeups: int = 0    # batches: times the writer thread found the queue empty and let messages gather
    per_topic: dict = field(default_factory=dict)


def _checked_interval(chunk_interval_s, chunk_size, compression) -> float:
    """The chunk interval as a float; ValueError naming a bad option."""
    interval = float(chunk_interval_s)
    if not (math.isfinite(interval) and interval > 0):
        raise ValueError(f'chunk_interval_s: {chunk_interval_s}; expected a time > 0 s')
    if int(chunk_size) < 1024:
        raise ValueError(f'chunk_size: {chunk_size}; expected >= 1024 bytes')
    if compression not in _COMPRESSION:
        raise ValueError(f'compression: {compression!r}; expected one of {list(_COMPRESSION)}')
    return interval


def _metadata_record(metadata: Mapping[str, str]) -> dict[str, str]:
    """The first Metadata record: strings only, with ``package_version`` added if absent."""
    record = {}
    for key, value in dict(metadata).items():
        if not isinstance(key, str) or not isinstance(value, str):
            raise TypeError(
                f'metadata[{key!r}]: {type(value).__name__}; MCAP metadata holds strings '
                '(serialize the scene and parameters to text first)')
        record[key] = value
    record.setdefault('package_version', package_version())
    return record


class McapRecorder:
    """Writes ROS 2 messages (CDR bytes) to one MCAP file; thread-safe.

    ``McapRecorder(path, metadata={'scene': ..., 'parameters': ...})``, then ``add_topic`` once
    per topic and ``write`` per message, ``close()`` at the end (or use ``with``).

    - ``metadata``: str -> str, written as the MCAP Metadata record ``metadata_name`` at the
      start of the file; ``package_version`` is added if absent.
    - Chunks are closed by the rule of :class:`ChunkAge`: a hard kill loses at most the messages
      written in the last ``chunk_interval_s`` (the chunk is closed at half of it).
    - ``background=True`` (default): ``write`` only queues the bytes; a writer thread builds,
      compresses (zstd releases the GIL) and writes chunks, so a publishing callback never waits
      for compression (about 18 ms per 4 MB chunk here). The thread takes what is queued in
      batches at most every ``chunk_interval_s / 10`` (50 ms at most), not at each message: a
      wake costs both threads a GIL hand-off, which a batch pays once for all its messages. If
      more than ``max_queue_bytes`` are waiting (a stalled disk), new messages are dropped and
      counted, never blocking the caller.
      ``background=False`` writes in the caller's thread under the lock (offline tools, tests).
    - Errors of the writer thread (disk full...) are raised by the next ``write``/``flush``/
      ``close``.
    - The path must not exist unless ``overwrite=True``: a log is never overwritten by accident.

    In a node, serialize each outgoing message once and hand the same bytes to both:
    ``data = serialize_message(msg); publisher.publish(data); recorder.write(topic, data, t)``
    (rclpy publishes ``bytes`` as they are); record incoming messages from a second
    subscription with ``raw=True``, whose callback receives the wire bytes.
    """

    def __init__(
        self,
        path,
        *,
        metadata: Mapping[str, str],
        chunk_interval_s: float = 1.0,
        chunk_size: int = 4 * 1024 * 1024,
        compression: str = 'zstd',
        metadata_name: str = DEFAULT_METADATA_NAME,
        background: bool = True,
        max_queue_bytes: int = 256 * 1024 * 1024,
        fsync: bool = False,
        overwrite: bool = False,
    ):
        interval = _checked_interval(chunk_interval_s, chunk_size, compression)
        record = _metadata_record(metadata)
        self.path = Path(path)
        self._init_state(interval, max_queue_bytes)
        self._open_file(overwrite, fsync, int(chunk_size), _COMPRESSION[compression],
                        metadata_name, record)
        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        if background:
            self._start_writer_thread()
        _open_recorders.add(self)

    def _init_state(self, interval: float, max_queue_bytes) -> None:
        """Locks, counters and the open chunk's age (before the file exists)."""
        self._chunk_age = ChunkAge(interval)
        self._lock = threading.RLock()
        self._topics: dict[str, _TopicInfo] = {}
        self._schemas: dict[str, int] = {}
        self._closed = False
        self._error: BaseException | None = None
        self._stats = RecorderStats()
        self._max_queue_bytes = int(max_queue_bytes)
        self._queued_bytes = 0
        self._queued_count = 0
        self._chunk_messages = 0
        self._queue_lock = threading.Lock()
        self._batch_s = min(_WRITER_BATCH_S, interval / 10.0)

    def _open_file(self, overwrite, fsync, chunk_size, compression, metadata_name, record) -> None:
        """Create the file, write the header and the metadata record (removed again on error)."""
        raw = open(self.path, 'wb' if overwrite else 'xb', buffering=0)  # noqa: SIM115
        try:
            self._sink = UnbufferedSink(raw, fsync)
            self._writer = Writer(
                self._sink, chunk_size=chunk_size, compression=compression,
                index_types=IndexType.ALL, repeat_channels=True, repeat_schemas=True,
                use_chunking=True, use_statistics=True, use_summary_offsets=True,
                enable_crcs=True, enable_data_crcs=True)
            self._writer.start(profile=PROFILE, library=library_name(LIBRARY_IDENTIFIER))
            self._writer.add_metadata(metadata_name, record)
            self._sink.flush()
        except BaseException:
            raw.close()
            self.path.unlink(missing_ok=True)
            raise

    def _start_writer_thread(self) -> None:
        self._queue = queue.Queue()
        self._thread = threading.Thread(
            target=self._run, name=f'mcap-writer:{self.path.name}', daemon=True)
        self._thread.start()

    @classmethod
    def create(cls, directory, *, prefix: str = 'tissue_sim', **kwargs) -> 'McapRecorder':
        """A recorder on a new file named by the UTC start time in ``directory``."""
        for _ in range(100):
            try:
                return cls(new_log_path(directory, prefix), **kwargs)
            except FileExistsError:  # another process took the name in between
                continue
        raise FileExistsError(f'no free log name in {directory} after 100 tries')

    # -- topics ------------------------------------------------------------------------------

    def add_topic(self, topic: str, type_name: str, qos: Mapping[str, Any] | None = None) -> int:
        """Register a topic (schema once per type, channel once per topic); its channel id.

        ``qos`` is the publisher's offered QoS (see :func:`qos_profile`; from rclpy use
        ``tissue_sim_ros.ros.messages.conversions.qos_to_dict``); None writes an empty profile list.
        Adding a topic again with the same type returns the same id.
        """
        if not isinstance(topic, str) or not topic:
            raise ValueError(f'topic: {topic!r}; expected a non-empty string')
        name = schema_name(type_name)
        qos_text = qos_profiles_yaml(qos)  # validate before taking the lock
        with self._lock:
            self._check_open()
            known = self._topics.get(topic)
            if known is not None:
                if known.type_name != name:
                    raise ValueError(
                        f'topic {topic!r}: already recorded as {known.type_name}, not {name}')
                return known.channel_id
            schema_id = self._schemas.get(name)
            if schema_id is None:
                schema_id = self._writer.register_schema(
                    name=name, encoding=SCHEMA_ENCODING,
                    data=message_definition(name).encode('utf-8'))
                self._schemas[name] = schema_id
            channel_id = self._writer.register_channel(
                topic=topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id,
                metadata={'offered_qos_profiles': qos_text})
            self._topics[topic] = _TopicInfo(channel_id, name)
            self._stats.per_topic[topic] = 0
            return channel_id

    @property
    def topics(self) -> dict[str, str]:
        """topic -> schema name of the registered topics."""
        with self._lock:
            return {t: info.type_name for t, info in self._topics.items()}

    # -- messages ----------------------------------------------------------------------------

    def write(self, topic: str, cdr_bytes, log_time_ns: int, publish_time_ns: int | None = None,
              sequence: int | None = None) -> bool:
        """Record one message; False if it was dropped (writer queue over its limit).

        ``cdr_bytes``: the serialized message (bytes-like), recorded verbatim whether or not it
        is valid CDR: a malformed message received on a topic stays in the log as evidence, and
        ``read_log`` skips and reports it. ``log_time_ns``: receive/record time in ns;
        ``publish_time_ns`` defaults to it. ``sequence`` defaults to a per-topic counter from 1.
        """
        written_at = time.monotonic()
        self._raise_error()
        if self._closed:
            raise RuntimeError(f'recorder for {self.path} is closed')
        if topic not in self._topics:
            raise ValueError(f'topic {topic!r} was not added; call add_topic first')
        if isinstance(cdr_bytes, bytes):
            data = cdr_bytes
        elif isinstance(cdr_bytes, (bytearray, memoryview)):
            data = bytes(cdr_bytes)  # the caller may reuse its buffer
        else:
            raise TypeError(f'cdr_bytes: {type(cdr_bytes).__name__}; expected bytes')
        log_time = int(log_time_ns)
        publish_time = log_time if publish_time_ns is None else int(publish_time_ns)
        for name, value in (('log_time_ns', log_time), ('publish_time_ns', publish_time)):
            if not 0 <= value < 2**64:
                raise ValueError(f'{name}: {value}; expected 0 <= ns < 2**64')
        item = (topic, data, log_time, publish_time, sequence, written_at)
        if self._queue is None:
            with self._lock:
                self._check_open()
                self._add_locked(*item)
            return True
        with self._queue_lock:
            if self._queued_bytes + len(data) > self._max_queue_bytes:
                self._stats.messages_dropped += 1
                return False
            self._queued_bytes += len(data)
            self._queued_count += 1
        self._queue.put(item)
        return True

    def _add_locked(self, topic, data, log_time, publish_time, sequence, written_at,
                    more_waiting: bool = False) -> None:
        info = self._topics[topic]
        info.count += 1
        seq = info.count % 2**32 if sequence is None else int(sequence) % 2**32
        before = self._sink.position
        self._writer.add_message(
            channel_id=info.channel_id, log_time=log_time, data=data,
            publish_time=publish_time, sequence=seq)
        self._stats.messages_written += 1
        self._stats.per_topic[topic] += 1
        self._chunk_messages += 1
        if self._sink.position != before:  # the writer ended the chunk (size), this message in it
            self._chunk_done()
            return
        self._chunk_age.add(log_time, written_at)
        if self._chunk_age.due(log_time, time.monotonic(), more_waiting):
            self._end_chunk_locked()

    def _chunk_done(self) -> None:
        self._stats.chunks_closed += 1
        self._chunk_messages = 0
        self._chunk_age.reset()
        self._sink.flush()

    def _end_chunk_locked(self) -> None:
        if not self._chunk_age.is_open:
            return
        end_chunk(self._writer)  # writes the chunk and its indexes; sink.flush() (fsync)
        self._chunk_done()

    def _run(self) -> None:
        """Writer thread: messages from the queue; closes the open chunk when it expires."""
        assert self._queue is not None
        name_os_thread()
        while True:
            if self._queue.empty():   # let a batch gather: put() wakes nobody while this sleeps
                time.sleep(self._batch_s)
                self._stats.writer_wakeups += 1
            try:
                item = self._queue.get(timeout=self._chunk_age.wait_s(time.monotonic()))
            except queue.Empty:
                self._end_expired_chunk()
                continue
            try:
                if item is _STOP:
                    return
                if callable(item):  # a flush request
                    item()
                    continue
                with self._lock:  # then the queue lock: the order stats() takes them in
                    try:
                        if self._error is None:
                            self._add_locked(*item, more_waiting=not self._queue.empty())
                    finally:
                        with self._queue_lock:
                            self._queued_bytes -= len(item[1])
                            self._queued_count -= 1
            except BaseException as exc:  # noqa: BLE001  (reported by the caller's next call)
                self._error = exc
            finally:
                self._queue.task_done()

    def _end_expired_chunk(self) -> None:
        try:
            with self._lock:
                if self._error is None and self._chunk_age.expired(time.monotonic()):
                    self._end_chunk_locked()
        except BaseException as exc:  # noqa: BLE001  (reported by the caller's next call)
            self._error = exc

    # -- control -----------------------------------------------------------------------------

    def flush(self) -> None:
        """Write every queued message and end the open chunk: all of it is then in the OS."""
        self._raise_error()
        if self._closed:
            return
        if self._queue is not None and self._thread is not None and self._thread.is_alive():
            def request():
                with self._lock:
                    if self._error is None:
                        self._end_chunk_locked()
            self._queue.put(request)
            self._queue.join()
        else:
            with self._lock:
                self._end_chunk_locked()
        self._raise_error()

    def add_metadata(self, name: str, data: Mapping[str, str]) -> None:
        """Another MCAP Metadata record (strings only), written now between chunks."""
        record = {str(k): v for k, v in data.items()}
        bad = [k for k, v in record.items() if not isinstance(v, str)]
        if bad:
            raise TypeError(f'metadata values for {bad} are not strings')
        with self._lock:
            self._check_open()
            self._writer.add_metadata(name, record)

    def close(self) -> None:
        """Write the rest and the summary (statistics, indexes) and close the file. Idempotent.

        Raises the writer thread's error, if any, once (the file is closed all the same).
        """
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self._thread is not None:
            self._stop_writer_thread()
        error = self._error
        try:
            with self._lock:
                if error is None:
                    self._writer.finish()  # ends the chunk, writes DataEnd, summary, footer
                    self._stats.chunks_closed += int(self._chunk_age.is_open)
                    self._chunk_age.reset()
                    self._chunk_messages = 0
                self._sink.flush()
        finally:
            self._stats.bytes_written = self._sink.position
            self._sink.close()
            _open_recorders.discard(self)
        if error is not None:
            self._error = None
            raise RuntimeError(f'MCAP recording to {self.path} failed: {error!r}') from error

    def _stop_writer_thread(self) -> None:
        """Let the thread write what is queued, then count what a racing write() queued after."""
        self._queue.put(_STOP)
        self._thread.join()
        while True:
            try:
                item = self._queue.get_nowait()
            except queue.Empty:
                break
            if isinstance(item, tuple):
                self._stats.messages_dropped += 1

    @property
    def closed(self) -> bool:
        return self._closed

    def stats(self) -> RecorderStats:
        """A snapshot of the counters."""
        with self._lock:
            with self._queue_lock:
                queued, queued_count = self._queued_bytes, self._queued_count
            return RecorderStats(
                messages_written=self._stats.messages_written,
                messages_dropped=self._stats.messages_dropped,
                messages_unsaved=queued_count + self._chunk_messages,
                chunks_closed=self._stats.chunks_closed,
                bytes_written=self._sink.position,
                queued_bytes=queued,
                writer_wakeups=self._stats.writer_wakeups,
                per_topic=dict(self._stats.per_topic))

    def _check_open(self) -> None:
        if self._closed:
            raise RuntimeError(f'recorder for {self.path} is closed')

    def _raise_error(self) -> None:
        if self._error is not None:
            raise RuntimeError(f'MCAP recording to {self.path} failed: {self._error!r}') \
                from self._error

    def __enter__(self) -> 'McapRecorder':
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()
