"""When the MCAP writer closes its open chunk: the rule behind the hard-kill loss bound.

What a SIGKILL loses is what the file does not hold yet: the open chunk and the writer queue.
This rule bounds how long a message can stay there; ``McapRecorder`` applies it.
"""
from __future__ import annotations

from tissue_sim_ros.units import NS_PER_S

__all__ = ['ChunkAge']


class ChunkAge:
    """When the open chunk must be closed: the rule behind the hard-kill loss bound.

    The chunk is closed as soon as its oldest message is ``chunk_interval_s / 2`` old, counted
    on the monotonic clock from the ``write()`` call that handed the message over, or in log time
    against a newer message (a faster-than-real-time writer), or when it outgrows ``chunk_size``.
    A closed chunk is in the OS once written (``sink.UnbufferedSink``).

    Bound: after SIGKILL the file holds every message handed to ``write()`` more than
    ``chunk_interval_s / 2 + d`` seconds before the kill, where d is the writer's delay: reaching
    the deadline (thread wake-up, the queue ahead of it) and compressing and writing the chunk,
    a few ms on an idle machine. The other half of the interval is the margin for d, so a hard
    kill loses at most the messages written in the last ``chunk_interval_s`` while the writer
    keeps up (d < chunk_interval_s / 2; a stalled disk breaks any bound:
    ``stats().queued_bytes`` shows it). Measured with a 50 Hz writer, interval 1 s (log time
    of the last message written minus that of the last one recovered): killed just before a
    chunk closes 0.48 s, at random moments 0.08-0.42 s, the same with a busy process on the two
    cores. Without the writer thread (``background=False``) the wall-clock rule is checked at
    each ``write()`` only.
    """

    def __init__(self, chunk_interval_s: float):
        self.close_after_s = chunk_interval_s / 2
        self._close_after_ns = int(round(self.close_after_s * NS_PER_S))
        self.first_log_ns: int | None = None
        self.oldest_written_at: float | None = None

    @property
    def is_open(self) -> bool:
        return self.first_log_ns is not None

    def add(self, log_ns: int, written_at: float) -> None:
        """A message went into the open chunk (``written_at``: ``time.monotonic()`` of write())."""
        if self.first_log_ns is None:
            self.first_log_ns, self.oldest_written_at = log_ns, written_at

    def due(self, log_ns: int, now: float, more_waiting: bool = False) -> bool:
        """Close now? (after adding a message with log time ``log_ns``). While ``more_waiting``
        (a backlog in the queue) the wall-clock rule waits until it is drained: one chunk per
        backlog, not one per message."""
        if not self.is_open:
            return False
        return (abs(log_ns - self.first_log_ns) >= self._close_after_ns
                or (self.expired(now) and not more_waiting))

    def expired(self, now: float) -> bool:
        return self.is_open and now - self.oldest_written_at >= self.close_after_s

    def wait_s(self, now: float) -> float | None:
        """Seconds until the open chunk expires (None: no open chunk)."""
        if not self.is_open:
            return None
        return max(0.0, self.oldest_written_at + self.close_after_s - now)

    def reset(self) -> None:
        self.first_log_ns = self.oldest_written_at = None
