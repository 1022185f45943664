"""When the node's engine advances and when a tick publishes: slices, ticks and engine time.

A timer on the node clock fires ``slices`` times per tick of ``period_s``. Each slice advances the
engine to the newest received pose's stamp (never past now, never more than one period behind it:
with no pose for longer the needle is held at the newest), so the wrench of a tick shows the engine
at most one period (with poses streaming, one pose interval) behind the tick time. Advancing to
now would hold the needle at the newest pose until the next arrived: with 100 Hz poses and 5 ms
slices a stop-go whose inertial force spikes punctured the capsule 0.7 mm early.

Each advance is by the node-clock time since the previous one, at most ``MAX_TICK_ADVANCE``
periods, and one period after a tick that overran (the excess is dropped and counted as
``dropped_time_s``). With poses streaming most of a tick's engine work is done before the tick
time, so the wrench follows it by the last slice's work only. A slice that does not publish
starts no substep that would run into the next slice's time (``SLICE_MARGIN_S``; on the wall
clock, so not with ``use_sim_time``): the publishing slice runs what it left. A tick whose slices
take longer than the period in all is a deadline overrun; a gap of more than 1.5 periods between
ticks is a missed tick.

Pure arithmetic on integer nanoseconds and perf_counter seconds: no rclpy, tested without a graph.
"""
from __future__ import annotations

from tissue_sim_ros.units import NS_PER_S

__all__ = ['MAX_TICK_ADVANCE', 'SLICE_MARGIN_S', 'TickSchedule']

#: An advance is by the node-clock time since the previous one, at most this many periods (a
#: slice late by more drops the excess instead of asking the engine for ever more). After a tick
#: that overran, one period at most: catching up the node's own overrun makes every following
#: tick longer still (default scene, one numba thread, one advance per tick: 29 Hz with the
#: catch-up, 43 Hz without it).
MAX_TICK_ADVANCE = 2.0
#: A slice that does not publish stops starting substeps this long before the next slice is due
#: (the executor's hop to the next call); without it a slice slowed by the machine ran into the
#: publishing slice and that tick went out 2-4 ms late.
SLICE_MARGIN_S = 0.5e-3


class TickSchedule:
    """Slices and ticks on the timer's own schedule (see the module docstring)."""

    def __init__(self, period_s: float, slices: int):
        self.period_s = float(period_s)
        self.period_ns = int(round(self.period_s * NS_PER_S))
        self.slices = int(slices)
        self.slice_s = self.period_s / self.slices
        self.engine_clock_ns: int | None = None  # node-clock time the engine was advanced to
        self.overran = False      # the previous tick's work took longer than a period
        self.dropped_time_s = 0.0  # time not simulated because a slice came too late
        self.missed_ticks = 0
        self.missed_for_input = 0  # missed ticks that input handling caused
        self.deadline_overruns = 0
        self._schedule0_ns: int | None = None  # scheduled time of the timer's first call
        self._published_tick = -1
        self._last_tick_wall: float | None = None

    def ends_tick(self, now_ns: int, until_next_ns: int | None, timer_period_ns: int) -> bool:
        """Whether this timer call ends a tick: the last slice of a tick on the timer's schedule,
        or the first call after a tick whose last slice the executor skipped (late)."""
        until_next = until_next_ns if until_next_ns is not None else timer_period_ns
        # rcl keeps the phase of its schedule when calls are missed: this call's scheduled time
        # is the next call's less one timer period
        scheduled = now_ns + until_next - timer_period_ns
        if self._schedule0_ns is None:
            self._schedule0_ns = scheduled
        index = int(round((scheduled - self._schedule0_ns) / timer_period_ns))
        tick, position = divmod(index, self.slices)
        if position == self.slices - 1 or tick > self._published_tick + 1:
            self._published_tick = tick if position == self.slices - 1 else tick - 1
            return True
        return False

    def tick_started(self, wall: float, input_s: float = 0.0) -> float | None:
        """A publishing slice began at ``wall`` (perf_counter s), ``input_s`` of the node's time
        since the previous one spent on input: the interval since that one (None for the first),
        counting missed ticks, and among them those input handling caused (it took more than
        half a period of the interval: with less, the tick would have been on time without it)."""
        last, self._last_tick_wall = self._last_tick_wall, wall
        if last is None:
            return None
        interval = wall - last
        if interval > 1.5 * self.period_s:
            missed = int(round(interval / self.period_s)) - 1
            self.missed_ticks += missed
            if input_s > 0.5 * self.period_s:
                self.missed_for_input += missed
        return interval

    def tick_done(self, work_s: float) -> bool:
        """A tick's slices took ``work_s`` in all; True (and counted) when that overran."""
        self.overran = work_s > self.period_s
        self.deadline_overruns += int(self.overran)
        return self.overran

    def slice_target_ns(self, now_ns: int, newest_stamp_ns: int | None) -> int:
        """The node-clock time a slice advances the engine to."""
        if newest_stamp_ns is None:
            return now_ns
        return min(now_ns, max(int(newest_stamp_ns), now_ns - self.period_ns))

    def slice_deadline(self, wall0: float, until_next_ns: int | None, publishes: bool,
                       sim_time: bool) -> float | None:
        """perf_counter time past which a slice starts no substep (None: no deadline)."""
        if publishes or sim_time or until_next_ns is None:
            return None
        return wall0 + until_next_ns / NS_PER_S - SLICE_MARGIN_S

    def advance_to(self, to_ns: int) -> float:
        """Seconds to advance the engine to ``to_ns`` (0 when it is not later than the engine
        clock), limited as the module docstring says; moves the engine clock there."""
        if self.engine_clock_ns is None:
            self.engine_clock_ns = to_ns
            return self.slice_s
        advance_s = max(0.0, (to_ns - self.engine_clock_ns) / NS_PER_S)
        limit = self.period_s if self.overran else MAX_TICK_ADVANCE * self.period_s
        if advance_s > limit:
            self.dropped_time_s += advance_s - limit
            advance_s = limit
        self.engine_clock_ns = max(self.engine_clock_ns, to_ns)
        return advance_s

    def hold(self, now_ns: int) -> None:
        """Paused or held: the engine clock follows now, and that time is not caught up."""
        self.engine_clock_ns = now_ns
