"""What the node's engine did, in the order it did it: the record that makes a run replayable.

The node's engine runs on its own thread and works within a budget of wall time, so how far it
got by each tick depends on the machine. Replaying a recorded run message for message therefore
needs the engine's own inputs, not only the poses the node received: every advance (its
duration, the needle pose it moved to, the substeps it ran before its deadline), every reset,
every change of the degradation ladder and every drop of lag, and for each tick which advance
the published wrench shows. The node records them on ``TRACE_TOPIC`` as
``std_msgs/msg/Float64MultiArray``, one message per tick:

    data = [tick stamp sec, tick stamp nanosec, index of the advance the wrench shows,
            row, row, ...]                              (``data_offset`` = HEADER_SIZE)

each row ``COLUMNS`` (``layout.dim[1].label`` names them): ``kind`` (ADVANCE, RESET, LEVEL,
DROP, PLACE), the state ``index`` (each advance, reset and placement makes a new state, counted
from 1; 0 is the state at start; a level or a drop keeps the index of the state it follows),
``duration_s``, the pose ``x y z qx qy qz qw`` (an advance's target, NaN: the needle held where it
was; a placement's: the needle's new start, a registration), and ``value``: the substeps an
advance ran (its ``max_steps`` in a replay), the ladder level, or the lag bound a drop kept;
``clock_s``: the node-clock time an advance went to, in seconds from the message's tick stamp
(negative: before it; NaN for the other rows).
Plain lists here, no rclpy: the node builds the message; :class:`TraceReplayer` runs a trace
through a driver again (``tissue-sim replay``, and the node's tests).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ['TRACE_TOPIC', 'TRACE_TYPE', 'COLUMNS', 'HEADER_SIZE', 'ADVANCE', 'RESET', 'LEVEL',
           'DROP', 'PLACE', 'TickTrace', 'TraceReplayer', 'advance_row', 'event_row', 'place_row', 'encode',
           'decode']

TRACE_TOPIC = '~/engine_trace'
TRACE_TYPE = 'std_msgs/msg/Float64MultiArray'
COLUMNS = ('kind', 'index', 'duration_s', 'x', 'y', 'z', 'qx', 'qy', 'qz', 'qw', 'value', 'clock_s')
HEADER_SIZE = 3
ADVANCE, RESET, LEVEL, DROP, PLACE = 0, 1, 2, 3, 4
_NO_POSE = (math.nan,) * 7


def advance_row(index: int, duration_s: float, position, orientation, substeps: int,
                clock_ns: int) -> tuple:
    """An advance to node-clock time ``clock_ns``; ``position``/``orientation`` None: the needle
    held where it was. (The clock stays in ns here; :func:`encode` makes it relative.)"""
    pose = _NO_POSE if position is None else (*map(float, position), *map(float, orientation))
    return (ADVANCE, index, float(duration_s), *pose, substeps, int(clock_ns))


def event_row(kind: int, index: int, value: float = 0.0) -> tuple:
    """A reset, a ladder level (``value``) or a drop of lag beyond ``value`` seconds, made after
    advance ``index``."""
    return (kind, index, 0.0, *_NO_POSE, float(value), None)


def place_row(index: int, position, orientation) -> tuple:
    """The first needle placed at a new start (a registration), making state ``index``."""
    return (PLACE, index, 0.0, *map(float, position), *map(float, orientation), 0.0, None)


@dataclass
class TickTrace:
    """One tick's record: its stamp [ns], the advance its wrench shows, the rows since the
    previous tick."""

    stamp_ns: int
    published_index: int
    rows: np.ndarray     # (k, len(COLUMNS))

    def clock_ns(self) -> np.ndarray:
        """(k,) the node-clock time [ns] of each advance row (-1 for the other rows)."""
        offsets = self.rows[:, COLUMNS.index('clock_s')]
        # in integers: a stamp of today's epoch as a float64 is only good to 256 ns
        clock = np.int64(self.stamp_ns) + np.round(np.nan_to_num(offsets) * 1e9).astype(np.int64)
        return np.where(np.isnan(offsets), np.int64(-1), clock)


def encode(stamp_ns: int, published_index: int, rows) -> list[float]:
    """The message's ``data``: header then rows, flat (every value exact in a float64)."""
    sec, nanosec = divmod(int(stamp_ns), 1_000_000_000)
    flat = [float(sec), float(nanosec), float(published_index)]
    for row in rows:
        flat.extend(row[:-1])
        flat.append(math.nan if row[-1] is None else (row[-1] - int(stamp_ns)) / 1e9)
    return flat


def decode(data) -> TickTrace:
    """A TickTrace from a message's ``data`` (any sequence of floats)."""
    values = np.asarray(data, dtype=np.float64)
    if values.size < HEADER_SIZE or (values.size - HEADER_SIZE) % len(COLUMNS):
        raise ValueError(f'engine trace: {values.size} values; expected {HEADER_SIZE} + a multiple '
                         f'of {len(COLUMNS)}')
    stamp_ns = int(values[0]) * 1_000_000_000 + int(values[1])
    return TickTrace(stamp_ns, int(values[2]), values[HEADER_SIZE:].reshape(-1, len(COLUMNS)))


class TraceReplayer:
    """A recorded engine trace run through a driver again: the same advances (each with the
    substeps the node ran), resets, placements, ladder levels and drops, in the same order, so the state
    after each is the node's, bit for bit with the same scene, threads and kernels.
    ``ladder``: the scene's DegradationLadder (needed when the trace changes levels);
    ``keep_displacement``: keep the displacement of the published states too."""

    def __init__(self, driver, ladder=None, keep_displacement=False):
        self.driver, self.ladder, self.keep_displacement = driver, ladder, keep_displacement
        self.index = 0
        self._states = {0: self._state()}

    def _state(self):
        driver = self.driver
        return (driver.force.copy(), driver.torque.copy(),
                driver.displacement.copy() if self.keep_displacement else None)

    def apply(self, tick: TickTrace):
        """Run one tick's rows; (force, torque, displacement or None) of the state that tick
        published."""
        driver = self.driver
        for row in tick.rows:
            kind, index = int(row[0]), int(row[1])
            if kind == ADVANCE:
                has_pose = not math.isnan(row[3])
                driver.advance(float(row[2]), row[3:6] if has_pose else None,
                               row[6:10] if has_pose else None, max_steps=int(row[10]))
            elif kind == RESET:
                driver.reset()
            elif kind == LEVEL:
                if self.ladder is None:
                    raise ValueError('the trace changes the degradation ladder\'s level: replay it '
                                     'with the scene\'s DegradationLadder')
                self.ladder.set_level(int(row[10]))
            elif kind == DROP:
                driver.drop_lag(float(row[10]))
            elif kind == PLACE:
                driver.place_needle(row[3:6].copy(), row[6:10].copy())
            if kind in (ADVANCE, RESET, PLACE):
                self.index = index
                self._states[index] = self._state()
        published = self._states[tick.published_index]
        for old in [k for k in self._states if k < tick.published_index]:
            del self._states[old]
        return published
