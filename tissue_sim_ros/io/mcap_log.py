"""Recording ROS 2 messages to MCAP and reading them back, without rclpy.

Files follow the MCAP ``ros2`` profile so that rosbag2 (``ros2 bag play x.mcap``), Foxglove /
Lichtblick (``@mcap/core``), ``rosbags`` and ``mcap_ros2`` open them:

- schema name ``pkg/msg/Type``, encoding ``ros2msg``, text = the type's ``.msg`` followed, for
  each dependency (depth first, field order, each once), by a line of 80 ``=``, ``MSG: pkg/Type``
  and that type's ``.msg`` (:func:`message_definition`);
- channel message encoding ``cdr``; the payload is the wire bytes (``serialize_message`` or a
  ``raw=True`` subscription), never re-encoded here;
- channel metadata ``offered_qos_profiles``: the YAML list rosbag2 (Jazzy, bag metadata version
  9) writes, policies as strings (``reliable``, ``transient_local``, ``keep_last``,
  ``automatic``), durations as ``{sec, nsec}`` (:func:`qos_profiles_yaml`);
- zstd-compressed chunks with message indexes, chunk indexes, a summary with Statistics, summary
  offsets, CRCs of every chunk and of the data section;
- one MCAP Metadata record (name ``tissue_sim``) with the scene, the parameters and the package
  version, written at the start of the file so that it survives a hard kill.

Durability (what a reader sees if the process dies):

- ``close()`` (also on ``with`` exit, SIGINT handled by the caller, or interpreter exit through
  ``atexit``) writes the summary: the file is complete and every reader opens it.
- After SIGKILL (or, with ``fsync=True``, a power cut) the file under its final name holds the
  header, the metadata record and every chunk closed so far; the open chunk (at most
  ``chunk_interval_s`` of log time or wall time, or ``chunk_size`` bytes), the writer queue and
  the summary are missing. Readers that need the footer refuse it (``rosbags``,
  ``mcap.reader.SeekingReader``, ``McapIndexedReader`` of ``@mcap/core``; rosbag2's C++ reader
  has a fallback scan, not tried here); stream readers read every closed chunk:
  :func:`recover_truncated` reports what is intact and can write a repaired copy, and
  :func:`read_log` takes ``allow_truncated=True``. Closed chunks are handed to the OS at once
  (the file is unbuffered); ``fsync=True`` also forces them to the disk.

Chunk ending: ``mcap.writer.Writer`` (1.6) ends a chunk only when it outgrows ``chunk_size``, or
in the public ``Writer.flush()`` of mcap 1.6 ("finishes the chunk in progress ... flushes the
stream"); :func:`end_chunk` wraps that in one place, with a fallback for older versions.
"""
from __future__ import annotations

import atexit
import datetime as _dt
import importlib.util
import math
import os
import queue
import re
import struct
import sys
import threading
import time
import weakref
import zlib
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, NamedTuple

import yaml
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Channel, Footer, Message, Metadata, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import LIBRARY_IDENTIFIER, CompressionType, IndexType, Writer
from mcap_ros2.decoder import DecoderFactory

from tissue_sim_ros import __version__ as _PACKAGE_VERSION

__all__ = [
    'DEFAULT_METADATA_NAME',
    'LogMessage',
    'McapRecorder',
    'RecorderStats',
    'TruncatedLogError',
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

DEFAULT_METADATA_NAME = 'tissue_sim'
PROFILE = 'ros2'
SCHEMA_ENCODING = 'ros2msg'
MESSAGE_ENCODING = 'cdr'
_SEPARATOR = '=' * 80
_NS_PER_S = 1_000_000_000

# --------------------------------------------------------------------------------------------
# message definitions from the installed .msg files

_PRIMITIVES = frozenset(
    'bool byte char float32 float64 int8 uint8 int16 uint16 int32 uint32 int64 uint64 '
    'string wstring'.split())
_TYPE_PART = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


def _split_type(type_name: str) -> tuple[str, str]:
    """('geometry_msgs', 'Wrench') from 'geometry_msgs/msg/Wrench' or 'geometry_msgs/Wrench';
    ('std_srvs', 'Trigger_Event') from 'std_srvs/srv/Trigger_Event'."""
    parts = str(type_name).split('/')
    if len(parts) == 3 and parts[1] in ('msg', 'srv'):
        parts = [parts[0], parts[2]]
    if len(parts) != 2 or not all(_TYPE_PART.match(p) for p in parts):
        raise ValueError(
            f'type_name: {type_name!r}; expected "pkg/msg/Type" (or "pkg/Type", "pkg/srv/Type_Event")')
    return parts[0], parts[1]


def schema_name(type_name: str) -> str:
    """The MCAP schema name of a type: 'pkg/msg/Type', or 'pkg/srv/Type_Event' (and _Request,
    _Response) for the messages rosidl generates from a service, as rosbag2 names them."""
    pkg, name = _split_type(type_name)
    return f'{pkg}/{"srv" if _service_part(pkg, name) is not None else "msg"}/{name}'


def _share_dirs(pkg: str) -> list[Path]:
    """Candidate ``share`` directories for a package, most specific first.

    1. the install prefix of the importable Python package ``pkg`` (located with
       ``importlib.util.find_spec``, which does not import it): the .msg that matches the module
       rclpy serializes with, in a virtual environment (``<venv>/share``) as in
       ``/opt/ros/<distro>`` or a colcon ``install/<pkg>`` tree;
    2. every prefix of ``AMENT_PREFIX_PATH`` (a sourced ROS installation or workspace);
    3. ``sys.prefix/share`` (the environment this interpreter runs in).
    """
    dirs: list[Path] = []
    try:
        spec = importlib.util.find_spec(pkg)
    except (ImportError, ValueError):
        spec = None
    if spec is not None:
        locations = list(spec.submodule_search_locations or [])
        if not locations and spec.origin:
            locations = [str(Path(spec.origin).parent)]
        for loc in locations:
            # <prefix>/lib/pythonX.Y/site-packages/<pkg> (or local/lib/..., dist-packages)
            for parent in list(Path(loc).resolve().parents)[:6]:
                dirs.append(parent / 'share')
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep):
        if prefix:
            dirs.append(Path(prefix) / 'share')
    dirs.append(Path(sys.prefix) / 'share')
    seen: set[Path] = set()
    unique = []
    for d in dirs:
        if d not in seen:
            seen.add(d)
            unique.append(d)
    return unique


def msg_file(type_name: str) -> Path:
    """Path of the installed ``share/<pkg>/msg/<Type>.msg`` of a message type."""
    pkg, name = _split_type(type_name)
    tried = []
    for share in _share_dirs(pkg):
        candidate = share / pkg / 'msg' / f'{name}.msg'
        if candidate.is_file():
            return candidate
        tried.append(str(candidate.parent))
    raise FileNotFoundError(
        f'{pkg}/msg/{name}.msg not found; looked in {tried[:8]} (install the message package '
        'or source its workspace so that AMENT_PREFIX_PATH names it)')


def _dependencies(pkg: str, text: str) -> list[tuple[str, str]]:
    """Non-primitive field types of a .msg, in field order, each once."""
    out: list[tuple[str, str]] = []
    for line in text.splitlines():
        code = line.split('#', 1)[0].strip()
        if not code:
            continue
        type_token = code.split()[0]
        base = type_token.split('[', 1)[0].split('<=', 1)[0]
        if base in _PRIMITIVES:
            continue
        parts = base.split('/')
        if len(parts) == 1:
            dep = (pkg, parts[0])  # a bare name is a type of the same package
        else:
            dep = _split_type(base)
        if dep not in out:
            out.append(dep)
    return out


@lru_cache(maxsize=None)
def _service_part(pkg: str, name: str) -> str | None:
    """The .msg text of ``<Service>_Request``, ``_Response`` or ``_Event``, as rosidl generates
    them from ``share/<pkg>/srv/<Service>.srv`` (request above the ``---`` line, response below;
    a part without fields gets rosidl's placeholder field); None for other names."""
    suffix = next((s for s in ('_Request', '_Response', '_Event') if name.endswith(s)), None)
    if suffix is None:
        return None
    service = name[:-len(suffix)]
    path = next((d / pkg / 'srv' / f'{service}.srv' for d in _share_dirs(pkg)
                 if (d / pkg / 'srv' / f'{service}.srv').is_file()), None)
    if path is None:
        return None
    if suffix == '_Event':
        return (f'service_msgs/ServiceEventInfo info\n{pkg}/{service}_Request[<=1] request\n'
                f'{pkg}/{service}_Response[<=1] response\n')
    request, _, response = _split_service(path.read_text(encoding='utf-8'))
    text = (request if suffix == '_Request' else response).strip('\n')
    has_fields = any(line.split('#', 1)[0].strip() for line in text.splitlines())
    return (text if has_fields else 'uint8 structure_needs_at_least_one_member') + '\n'


def _split_service(text: str) -> tuple[str, str, str]:
    """(request, '---', response) of a .srv file."""
    parts = re.split(r'^---[ \t]*$', text, maxsplit=1, flags=re.MULTILINE)
    return parts[0], '---', parts[1] if len(parts) > 1 else ''


@lru_cache(maxsize=None)
def _msg_text(pkg: str, name: str) -> str:
    service = _service_part(pkg, name)
    if service is not None:
        return service
    return msg_file(f'{pkg}/{name}').read_text(encoding='utf-8').rstrip() + '\n'


@lru_cache(maxsize=None)
def message_definition(type_name: str) -> str:
    """The ``ros2msg`` schema text of a type: its .msg, then each dependency once.

    Dependencies are visited depth first in field order (as rosbag2's message definition cache
    does); each is introduced by a line of 80 '=' and ``MSG: pkg/Type``.
    """
    root = _split_type(type_name)
    parts = [_msg_text(*root)]
    seen = {root}

    def visit(pkg: str, text: str) -> None:
        for dep in _dependencies(pkg, text):
            if dep in seen:
                continue
            seen.add(dep)
            dep_text = _msg_text(*dep)
            parts.append(f'{_SEPARATOR}\nMSG: {dep[0]}/{dep[1]}\n{dep_text}')
            visit(dep[0], dep_text)

    visit(root[0], parts[0])
    return ''.join(parts)


# --------------------------------------------------------------------------------------------
# QoS in rosbag2's offered_qos_profiles form

_QOS_POLICIES = {
    'history': ('keep_last', 'keep_all', 'system_default'),
    'reliability': ('reliable', 'best_effort', 'system_default', 'best_available'),
    'durability': ('volatile', 'transient_local', 'system_default', 'best_available'),
    'liveliness': ('automatic', 'manual_by_topic', 'system_default', 'best_available'),
}
_QOS_DURATIONS = ('deadline', 'lifespan', 'liveliness_lease_duration')
_QOS_DEFAULTS = {
    'history': 'keep_last', 'depth': 10, 'reliability': 'reliable', 'durability': 'volatile',
    'liveliness': 'automatic', 'avoid_ros_namespace_conventions': False,
}


def _duration(key: str, value) -> dict[str, int]:
    if isinstance(value, Mapping):
        sec, nsec = int(value['sec']), int(value['nsec'])
    else:
        ns = int(value)
        if ns < 0:
            raise ValueError(f'qos.{key}: {ns} ns; expected >= 0 (0 = unspecified)')
        sec, nsec = divmod(ns, _NS_PER_S)
    return {'sec': sec, 'nsec': nsec}


def qos_profile(qos: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """One rosbag2 QoS profile dict (key order as rosbag2 writes it) from a partial dict.

    Keys: history, depth, reliability, durability, liveliness (names as in rmw, any case),
    deadline / lifespan / liveliness_lease_duration (int ns or {'sec', 'nsec'}; also with a
    ``_ns`` suffix), avoid_ros_namespace_conventions. Missing keys take the defaults of a
    reliable volatile keep-last-10 publisher; unknown keys or values raise ValueError.
    """
    given = dict(qos or {})
    for key in list(given):
        if key.endswith('_ns') and key[:-3] in _QOS_DURATIONS:
            given[key[:-3]] = given.pop(key)
    allowed = (set(_QOS_POLICIES) | set(_QOS_DURATIONS)
               | {'depth', 'avoid_ros_namespace_conventions'})
    unknown = sorted(set(given) - allowed)
    if unknown:
        raise ValueError(f'qos: unknown keys {unknown}; expected some of {sorted(allowed)}')
    merged = {**_QOS_DEFAULTS, **given}
    policies = {}
    for key, choices in _QOS_POLICIES.items():
        value = str(getattr(merged[key], 'name', merged[key])).lower()
        if value not in choices:
            raise ValueError(f'qos.{key}: {merged[key]!r}; expected one of {list(choices)}')
        policies[key] = value
    depth = int(merged['depth'])
    if depth < 0:
        raise ValueError(f'qos.depth: {depth}; expected >= 0')
    durations = {key: _duration(key, merged.get(key, 0)) for key in _QOS_DURATIONS}
    return {  # a fresh dict per duration: no YAML anchors/aliases in the dump
        'history': policies['history'],
        'depth': depth,
        'reliability': policies['reliability'],
        'durability': policies['durability'],
        'deadline': durations['deadline'],
        'lifespan': durations['lifespan'],
        'liveliness': policies['liveliness'],
        'liveliness_lease_duration': durations['liveliness_lease_duration'],
        'avoid_ros_namespace_conventions': bool(merged['avoid_ros_namespace_conventions']),
    }


def qos_profiles_yaml(qos: Mapping[str, Any] | None) -> str:
    """``offered_qos_profiles`` channel metadata: a YAML list with one profile, or '' for None.

    The form is rosbag2 Jazzy's: policy names as strings. rosbag2 reads a bare .mcap (no
    ``rosbag2`` metadata record) with metadata version 9, where policies must be strings; an
    empty string makes ``ros2 bag play`` use its default QoS for the topic.
    """
    if qos is None:
        return ''
    return yaml.safe_dump([qos_profile(qos)], sort_keys=False, default_flow_style=False)


# --------------------------------------------------------------------------------------------
# writing


def new_log_path(directory, prefix: str = 'tissue_sim', now: _dt.datetime | None = None) -> Path:
    """``<directory>/<prefix>_YYYY-MM-DDTHH-MM-SSZ.mcap`` (UTC start time), never an existing file.

    Creates the directory. A name already taken gets ``_1``, ``_2``... The name is free when
    returned; :meth:`McapRecorder.create` opens it exclusively and retries on a race.
    """
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    now = now or _dt.datetime.now(_dt.timezone.utc)
    stamp = now.astimezone(_dt.timezone.utc).strftime('%Y-%m-%dT%H-%M-%SZ')
    path = directory / f'{prefix}_{stamp}.mcap'
    k = 0
    while path.exists():
        k += 1
        path = directory / f'{prefix}_{stamp}_{k}.mcap'
    return path


class _UnbufferedSink:
    """The writer's output: every write goes to the OS at once.

    ``mcap.writer.Writer`` wraps a raw file (``RawIOBase``) in a ``BufferedWriter``; this object
    is not one, so the writer uses it as it is. With chunking the writer only writes at a chunk's
    end (chunk, message indexes) and for metadata, so this costs a few system calls per chunk and
    guarantees that a closed chunk is in the OS (page cache) when ``add_message`` returns.
    """

    def __init__(self, raw, fsync: bool):
        self._raw = raw
        self._fsync = fsync
        self.position = raw.tell()

    def write(self, data) -> int:
        view = memoryview(data).cast('B')
        total = len(view)
        while view:
            n = self._raw.write(view)
            if n is None:  # non-blocking file: not ours, but do not spin silently
                raise OSError('MCAP sink: write would block')
            view = view[n:]
        self.position += total
        return total

    def tell(self) -> int:
        return self.position

    def flush(self) -> None:
        if self._fsync:
            os.fsync(self._raw.fileno())

    def close(self) -> None:
        self._raw.close()


def end_chunk(writer: Writer) -> None:
    """End the writer's open chunk now (if it holds a message) and flush its stream.

    mcap 1.6 has the public ``Writer.flush()`` for this; older versions only the private
    ``__finalize_chunk`` (name-mangled), used as a fallback. A chunk without messages stays open
    (schemas and channels registered since the last chunk wait for the next message).
    """
    public = getattr(writer, 'flush', None)
    if public is not None:
        public()
        return
    writer._Writer__finalize_chunk()  # mcap < 1.6


_COMPRESSION = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                'none': CompressionType.NONE}
_STOP = object()
_open_recorders: weakref.WeakSet = weakref.WeakSet()


@atexit.register
def _close_open_recorders() -> None:  # interpreter exit (also after KeyboardInterrupt)
    for recorder in list(_open_recorders):
        try:
            recorder.close()
        except Exception as exc:  # noqa: BLE001  (no logger left at exit: say it on stderr)
            print(f'tissue_sim_ros: could not close the MCAP log {recorder.path}: {exc}; '
                  f'tissue_sim_ros.io.mcap_log.recover_truncated() can repair it', file=sys.stderr)


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
    per_topic: dict = field(default_factory=dict)


class McapRecorder:
    """Writes ROS 2 messages (CDR bytes) to one MCAP file; thread-safe.

    ``McapRecorder(path, metadata={'scene': ..., 'parameters': ...})``, then ``add_topic`` once
    per topic and ``write`` per message, ``close()`` at the end (or use ``with``).

    - ``metadata``: str -> str, written as the MCAP Metadata record ``metadata_name`` at the
      start of the file; ``package_version`` is added if absent.
    - Chunks end when their messages span ``chunk_interval_s`` of log time, when the open chunk
      is ``chunk_interval_s`` old in wall time (checked by the writer thread even when no message
      comes), or when they outgrow ``chunk_size`` bytes; a hard kill loses at most that chunk.
    - ``background=True`` (default): ``write`` only queues the bytes; a writer thread builds,
      compresses (zstd releases the GIL) and writes chunks, so a publishing callback never waits
      for compression (about 18 ms per 4 MB chunk here). If more than ``max_queue_bytes`` are
      waiting (a stalled disk), new messages are dropped and counted, never blocking the caller.
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
        interval = float(chunk_interval_s)
        if not (math.isfinite(interval) and interval > 0):
            raise ValueError(f'chunk_interval_s: {chunk_interval_s}; expected a time > 0 s')
        if int(chunk_size) < 1024:
            raise ValueError(f'chunk_size: {chunk_size}; expected >= 1024 bytes')
        if compression not in _COMPRESSION:
            raise ValueError(f'compression: {compression!r}; expected one of {list(_COMPRESSION)}')
        record = {}
        for key, value in dict(metadata).items():
            if not isinstance(key, str) or not isinstance(value, str):
                raise TypeError(
                    f'metadata[{key!r}]: {type(value).__name__}; MCAP metadata holds strings '
                    '(serialize the scene and parameters to text first)')
            record[key] = value
        record.setdefault('package_version', _PACKAGE_VERSION)

        self.path = Path(path)
        self._interval_ns = int(round(interval * _NS_PER_S))
        self._interval_s = interval
        self._lock = threading.RLock()
        self._topics: dict[str, _TopicInfo] = {}
        self._schemas: dict[str, int] = {}
        self._closed = False
        self._error: BaseException | None = None
        self._stats = RecorderStats()
        self._chunk_first_log_ns: int | None = None
        self._chunk_opened_at: float | None = None
        self._max_queue_bytes = int(max_queue_bytes)
        self._queued_bytes = 0
        self._queued_count = 0
        self._chunk_messages = 0
        self._queue_lock = threading.Lock()

        raw = open(self.path, 'wb' if overwrite else 'xb', buffering=0)  # noqa: SIM115
        try:
            self._sink = _UnbufferedSink(raw, fsync)
            self._writer = Writer(
                self._sink,
                chunk_size=int(chunk_size),
                compression=_COMPRESSION[compression],
                index_types=IndexType.ALL,
                repeat_channels=True,
                repeat_schemas=True,
                use_chunking=True,
                use_statistics=True,
                use_summary_offsets=True,
                enable_crcs=True,
                enable_data_crcs=True,
            )
            self._writer.start(
                profile=PROFILE, library=f'tissue_sim_ros/{_PACKAGE_VERSION} {LIBRARY_IDENTIFIER}')
            self._writer.add_metadata(metadata_name, record)
            self._sink.flush()
        except BaseException:
            raw.close()
            self.path.unlink(missing_ok=True)
            raise

        self._queue: queue.Queue | None = None
        self._thread: threading.Thread | None = None
        if background:
            self._queue = queue.Queue()
            self._thread = threading.Thread(
                target=self._run, name=f'mcap-writer:{self.path.name}', daemon=True)
            self._thread.start()
        _open_recorders.add(self)

    # -- construction helpers ---------------------------------------------------------------

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
        ``tissue_sim_ros.ros.conversions.qos_to_dict``); None writes an empty profile list.
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

        ``cdr_bytes``: the serialized message (bytes-like, CDR with its 4-byte encapsulation
        header). ``log_time_ns``: receive/record time in ns; ``publish_time_ns`` defaults to it.
        ``sequence`` defaults to a per-topic counter from 1.
        """
        self._raise_error()
        if self._closed:
            raise RuntimeError(f'recorder for {self.path} is closed')
        info = self._topics.get(topic)
        if info is None:
            raise ValueError(f'topic {topic!r} was not added; call add_topic first')
        if isinstance(cdr_bytes, bytes):
            data = cdr_bytes
        elif isinstance(cdr_bytes, (bytearray, memoryview)):
            data = bytes(cdr_bytes)  # the caller may reuse its buffer
        else:
            raise TypeError(f'cdr_bytes: {type(cdr_bytes).__name__}; expected bytes')
        if len(data) < 4:
            raise ValueError(f'cdr_bytes: {len(data)} bytes; a CDR message has at least 4')
        log_time = int(log_time_ns)
        publish_time = log_time if publish_time_ns is None else int(publish_time_ns)
        for name, value in (('log_time_ns', log_time), ('publish_time_ns', publish_time)):
            if not 0 <= value < 2**64:
                raise ValueError(f'{name}: {value}; expected 0 <= ns < 2**64')
        if self._queue is None:
            with self._lock:
                self._check_open()
                self._add_locked(topic, data, log_time, publish_time, sequence)
            return True
        with self._queue_lock:
            if self._queued_bytes + len(data) > self._max_queue_bytes:
                self._stats.messages_dropped += 1
                return False
            self._queued_bytes += len(data)
            self._queued_count += 1
        self._queue.put((topic, data, log_time, publish_time, sequence))
        return True

    def _add_locked(self, topic, data, log_time, publish_time, sequence) -> None:
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
        if self._chunk_first_log_ns is None:
            self._chunk_first_log_ns = log_time
            self._chunk_opened_at = time.monotonic()
        elif (abs(log_time - self._chunk_first_log_ns) >= self._interval_ns
              or time.monotonic() - self._chunk_opened_at >= self._interval_s):
            self._end_chunk_locked()  # span of log time, or age in wall time (slow sim time)

    def _chunk_done(self) -> None:
        self._stats.chunks_closed += 1
        self._chunk_messages = 0
        self._chunk_first_log_ns = None
        self._chunk_opened_at = None
        self._sink.flush()

    def _end_chunk_locked(self) -> None:
        if self._chunk_first_log_ns is None:
            return
        end_chunk(self._writer)  # writes the chunk and its indexes; sink.flush() (fsync)
        self._chunk_done()

    def _run(self) -> None:
        """Writer thread: messages from the queue; ends chunks that are too old in wall time."""
        assert self._queue is not None
        while True:
            timeout = None
            if self._chunk_opened_at is not None:
                timeout = max(0.0, self._chunk_opened_at + self._interval_s - time.monotonic())
            try:
                item = self._queue.get(timeout=timeout)
            except queue.Empty:
                try:
                    with self._lock:
                        if (self._chunk_opened_at is not None and self._error is None
                                and time.monotonic() - self._chunk_opened_at >= self._interval_s):
                            self._end_chunk_locked()
                except BaseException as exc:  # noqa: BLE001  (reported by the caller's next call)
                    self._error = exc
                continue
            try:
                if item is _STOP:
                    return
                if callable(item):  # a flush request
                    item()
                    continue
                topic, data, log_time, publish_time, sequence = item
                with self._lock:  # then the queue lock: the order stats() takes them in
                    try:
                        if self._error is None:
                            self._add_locked(topic, data, log_time, publish_time, sequence)
                    finally:
                        with self._queue_lock:
                            self._queued_bytes -= len(data)
                            self._queued_count -= 1
            except BaseException as exc:  # noqa: BLE001
                self._error = exc
            finally:
                self._queue.task_done()

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
            self._queue.put(_STOP)
            self._thread.join()
            while True:  # messages queued by a write() that raced with close(): not recorded
                try:
                    item = self._queue.get_nowait()
                except queue.Empty:
                    break
                if isinstance(item, tuple):
                    self._stats.messages_dropped += 1
        error = self._error
        try:
            with self._lock:
                if error is None:
                    self._writer.finish()  # ends the chunk, writes DataEnd, summary, footer
                    self._stats.chunks_closed += int(self._chunk_first_log_ns is not None)
                    self._chunk_first_log_ns = None
                    self._chunk_messages = 0
                self._sink.flush()
        finally:
            self._stats.bytes_written = self._sink.position
            self._sink.close()
            _open_recorders.discard(self)
        if error is not None:
            self._error = None
            raise RuntimeError(f'MCAP recording to {self.path} failed: {error!r}') from error

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


# --------------------------------------------------------------------------------------------
# reading


class TruncatedLogError(McapError):
    """The file has no valid footer/summary (a hard kill); see :func:`recover_truncated`."""


class LogMessage(NamedTuple):
    topic: str
    type_name: str
    log_time_ns: int
    message: Any  # a types.SimpleNamespace decoded by mcap_ros2 (no rclpy)


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
            'Use recover_truncated() or read_log(..., allow_truncated=True).') from exc


def read_log(path, topics=None, *, allow_truncated: bool = False) -> Iterator[LogMessage]:
    """(topic, type_name, log_time_ns, decoded message) in log-time order, without rclpy.

    Messages are decoded by ``mcap_ros2`` from the schemas in the file. A file without a valid
    summary raises TruncatedLogError unless ``allow_truncated``: then the intact chunks are read
    in file order (stream read).
    """
    with open(path, 'rb') as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        try:
            _check_complete(reader, path)
        except TruncatedLogError:
            if not allow_truncated:
                raise
            yield from _read_truncated(path, topics)
            return
        for schema, channel, message, decoded in reader.iter_decoded_messages(
                topics=topics, log_time_order=True):
            yield LogMessage(channel.topic, schema.name if schema else '', message.log_time,
                             decoded)


def _read_truncated(path, topics) -> Iterator[LogMessage]:
    factory = DecoderFactory()
    wanted = None if topics is None else {topics} if isinstance(topics, str) else set(topics)
    scan = _TolerantScan(path)
    for record in scan:
        if isinstance(record, Message):
            channel = scan.channels[record.channel_id]
            if wanted is not None and channel.topic not in wanted:
                continue
            schema = scan.schemas.get(channel.schema_id)
            decoder = factory.decoder_for(channel.message_encoding, schema)
            yield LogMessage(channel.topic, schema.name if schema else '', record.log_time,
                             decoder(record.data) if decoder else record.data)


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
            records = [r for r in _TolerantScan(path) if isinstance(r, Metadata)]
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
                entry = topics[channel.topic] = {
                    'type': schema.name if schema else '', 'count': 0,
                    'first_log_time_ns': message.log_time, 'last_log_time_ns': message.log_time,
                    'qos': yaml.safe_load(channel.metadata.get('offered_qos_profiles', '')
                                          or '[]'),
                }
            entry['count'] += 1
            entry['first_log_time_ns'] = min(entry['first_log_time_ns'], message.log_time)
            entry['last_log_time_ns'] = max(entry['last_log_time_ns'], message.log_time)
    if summary is not None:  # topics registered but never written
        for channel in summary.channels.values():
            if channel.topic not in topics:
                schema = summary.schemas.get(channel.schema_id)
                topics[channel.topic] = {
                    'type': schema.name if schema else '', 'count': 0,
                    'first_log_time_ns': None, 'last_log_time_ns': None,
                    'qos': yaml.safe_load(channel.metadata.get('offered_qos_profiles', '')
                                          or '[]')}
    firsts = [t['first_log_time_ns'] for t in topics.values() if t['count']]
    lasts = [t['last_log_time_ns'] for t in topics.values() if t['count']]
    statistics = None
    if summary is not None and summary.statistics is not None:
        st = summary.statistics
        by_id = {c.id: c.topic for c in summary.channels.values()}
        statistics = {
            'message_count': st.message_count,
            'channel_message_counts': {by_id.get(k, str(k)): v
                                       for k, v in st.channel_message_counts.items()},
            'message_start_time': st.message_start_time,
            'message_end_time': st.message_end_time,
            'chunk_count': st.chunk_count,
            'metadata_count': st.metadata_count,
        }
    return {
        'path': str(path),
        'profile': header.profile,
        'library': header.library,
        'message_count': sum(t['count'] for t in topics.values()),
        'first_log_time_ns': min(firsts) if firsts else None,
        'last_log_time_ns': max(lasts) if lasts else None,
        'duration_s': (max(lasts) - min(firsts)) / 1e9 if firsts else 0.0,
        'topics': topics,
        'compression': sorted({c.compression for c in summary.chunk_indexes}) if summary else [],
        'statistics': statistics,
    }


class _TolerantScan:
    """Iterates the records of an MCAP stream until its end or the first torn record.

    Chunks are yielded only whole (decompressed and CRC-checked first); ``error`` says why the
    scan stopped (None when the footer was reached), ``complete`` whether it was.
    """

    def __init__(self, path):
        self.path = Path(path)
        self.schemas: dict[int, Schema] = {}
        self.channels: dict[int, Channel] = {}
        self.error: str | None = None
        self.complete = False

    def __iter__(self) -> Iterator[Any]:
        with open(self.path, 'rb') as f:
            reader = StreamReader(f, validate_crcs=True)
            try:
                for record in reader.records:
                    if isinstance(record, Schema):
                        self.schemas[record.id] = record
                    elif isinstance(record, Channel):
                        self.channels[record.id] = record
                    elif isinstance(record, Footer):
                        self.complete = True
                    yield record
            except _TORN_ERRORS as exc:
                self.error = f'{type(exc).__name__}: {exc}' if str(exc) else type(exc).__name__


def recover_truncated(path, repaired_path=None) -> dict:
    """Read what a (possibly) truncated log holds with a stream read; report it.

    Returns ``complete`` (footer reached), ``messages``, ``per_topic`` counts, first/last log
    time, the metadata records and ``error`` (why the read stopped). With ``repaired_path``
    (must not exist) it also writes every intact schema, channel, metadata record and message
    to a new complete MCAP file (same payloads, same channel metadata, zstd chunks, summary).
    """
    scan = _TolerantScan(path)
    per_topic: dict[str, int] = {}
    metadata: dict[str, dict[str, str]] = {}
    first = last = None
    writer = out = None
    written_schemas: dict[int, int] = {}
    written_channels: dict[int, int] = {}
    if repaired_path is not None:
        out = open(repaired_path, 'xb')  # noqa: SIM115
        writer = Writer(out, compression=CompressionType.ZSTD, enable_data_crcs=True)
        writer.start(profile=PROFILE, library=f'tissue_sim_ros/{_PACKAGE_VERSION} recover')
    n = 0
    try:
        for record in scan:
            if isinstance(record, Metadata):
                metadata.setdefault(record.name, {}).update(record.metadata)
                if writer is not None:
                    writer.add_metadata(record.name, dict(record.metadata))
            elif isinstance(record, Message):
                channel = scan.channels[record.channel_id]
                per_topic[channel.topic] = per_topic.get(channel.topic, 0) + 1
                n += 1
                first = record.log_time if first is None else min(first, record.log_time)
                last = record.log_time if last is None else max(last, record.log_time)
                if writer is not None:
                    if channel.schema_id and channel.schema_id not in written_schemas:
                        s = scan.schemas[channel.schema_id]
                        written_schemas[s.id] = writer.register_schema(s.name, s.encoding, s.data)
                    if channel.id not in written_channels:
                        written_channels[channel.id] = writer.register_channel(
                            channel.topic, channel.message_encoding,
                            written_schemas.get(channel.schema_id, 0), dict(channel.metadata))
                    writer.add_message(written_channels[channel.id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
        if writer is not None:
            writer.finish()
    finally:
        if out is not None:
            out.close()
    return {
        'path': str(path),
        'complete': scan.complete,
        'messages': n,
        'per_topic': per_topic,
        'first_log_time_ns': first,
        'last_log_time_ns': last,
        'metadata': metadata,
        'error': scan.error,
        'repaired_path': None if repaired_path is None else str(repaired_path),
    }
