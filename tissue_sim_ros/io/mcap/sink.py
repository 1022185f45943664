"""Where the MCAP writer's bytes go: a fresh log name, an unbuffered file, ending a chunk now.

These three decide what a hard kill leaves on disk: a closed chunk reaches the OS (page cache)
when it is written, since nothing between ``mcap.writer.Writer`` and the file buffers it.
"""
from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path

from mcap.writer import Writer

__all__ = ['new_log_path', 'UnbufferedSink', 'end_chunk']


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


class UnbufferedSink:
    """The writer's output: every write goes to the OS at once.

    ``mcap.writer.Writer`` wraps a raw file (``RawIOBase``) in a ``BufferedWriter``; this object
    is not one, so the writer uses it as it is. With chunking the writer only writes at a chunk's
    end (chunk, message indexes) and for metadata, so this costs a few system calls per chunk and
    guarantees that a closed chunk is in the OS (page cache) when ``add_message`` returns.
    ``fsync=True`` also forces it to the disk at each ``flush()`` (against a power cut).
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

    ``mcap.writer.Writer`` (1.6) ends a chunk by itself only when it outgrows ``chunk_size``;
    mcap 1.6 has the public ``Writer.flush()`` ("finishes the chunk in progress ... flushes the
    stream"), older versions only the private ``__finalize_chunk`` (name-mangled), used as a
    fallback. A chunk without messages stays open (schemas and channels registered since the
    last chunk wait for the next message).
    """
    public = getattr(writer, 'flush', None)
    if public is not None:
        public()
        return
    writer._Writer__finalize_chunk()  # mcap < 1.6
