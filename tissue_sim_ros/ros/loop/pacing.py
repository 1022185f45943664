"""How much the node's engine works, how far it may fall behind, and when the ladder steps.

Pure arithmetic on nanoseconds and seconds (no rclpy, no threads), so it is tested without a
ROS graph. The engine thread (:mod:`~tissue_sim_ros.ros.loop.engine_thread`) asks:

- where to advance to: the newest received pose's stamp, never past now and never more than one
  period behind it (with no pose for longer the needle is held at the newest), by the node-clock
  time since the previous advance, at most max(2 periods, ``max_lag_s``) (2 periods with sim
  time): a longer jump of the clock is skipped and counted (``target_ns``, ``advance_s``);
- until when it may work: each tick gives it ``budget_fraction`` x period of working time (the
  engine's budget per tick), spent by its advances until the next tick, whenever in the period
  they come; an advance stops starting substeps when the budget is spent (``deadline``). With
  ``use_sim_time`` there is no wall-clock budget: the node is lock-step;
- the cost measured online: wall seconds per simulated second, averaged over about a second;
  ``demand`` = that cost / budget_fraction is the budget use (above 1 the engine cannot keep
  real time within its budget);
- whether to wait for more poses before advancing (``wait_for_poses_s``): a pose stream faster
  than the ticks (a robot's state at 500 Hz or 1 kHz) would make a cycle of the engine's Python
  per pose, while only the state at each tick is published; waiting costs no pose its tick as long
  as, by the measured cost, the advance of what is then owed still ends before the tick, with
  ``COALESCE_SAFETY`` times the cost and ``COALESCE_MARGIN_S`` to spare, and within the budget;
  and for at most ``COALESCE_MAX_SPAN_S`` of poses, as the needle goes on a straight line over an
  advance (the poses between its ends are not followed).

When the engine cannot keep up, what it was asked for and has not simulated is its lag; it is
held at most ``max_lag_s`` (the engine thread drops the excess: the needle then reaches its
pose in less simulated time), so the published state is never more than that behind the
received poses.

:class:`LadderControl` decides when the degradation ladder steps down (the demand above 1, or
the lag above half its bound, for ``DOWN_AFTER_S``) and back up (the demand the level above
would have, the demand now times that rung's cost ratio, below ``UP_BELOW`` for ``UP_AFTER_S``);
after a change it waits ``SETTLE_S`` and measures the rung's real cost ratio (kept within
``RATIO_TRUST`` of the a-priori one); nothing is decided in the first ``START_GRACE_S``.
"""
from __future__ import annotations

from tissue_sim_ros.units import NS_PER_S

__all__ = ['EnginePacing', 'LadderControl', 'COST_TIME_CONSTANT_S', 'DOWN_AFTER_S', 'UP_AFTER_S',
           'UP_BELOW', 'SETTLE_S', 'RATIO_TRUST', 'START_GRACE_S', 'COALESCE_SAFETY', 'COALESCE_MARGIN_S',
           'COALESCE_MIN_WAIT_S', 'COALESCE_MAX_SPAN_S']

COST_TIME_CONSTANT_S = 1.0
DOWN_AFTER_S = 1.0
UP_AFTER_S = 3.0
UP_BELOW = 0.7
SETTLE_S = 1.0
#: a measured cost ratio is kept within this factor of the rung's a-priori one
RATIO_TRUST = 1.5
#: no ladder decision this long after the engine starts (imports, first page faults, a cold cache)
START_GRACE_S = 3.0
#: waiting for more poses: the advance's predicted wall time is this times the measured cost per
#: simulated second, and ends this long before the tick (a thread woken late on a busy machine)
COALESCE_SAFETY = 2.0
COALESCE_MARGIN_S = 0.002
#: shorter waits are not worth a sleep: the engine advances at once
COALESCE_MIN_WAIT_S = 0.0005
#: at most this much of the pose stream in one advance: the needle moves on the chord between its
#: ends, about 1 % of the amplitude off a 10 Hz tremor's path (A (omega T)^2 / 8)
COALESCE_MAX_SPAN_S = 0.005


class EnginePacing:
    """Targets, budget windows and the measured cost (see the module docstring)."""

    def __init__(self, period_s: float, budget_fraction: float, max_lag_s: float,
                 sim_time: bool = False):
        self.period_s = float(period_s)
        self.period_ns = int(round(self.period_s * NS_PER_S))
        self.budget_fraction = float(budget_fraction)
        self.budget_s = self.budget_fraction * self.period_s
        self.max_lag_s = float(max_lag_s)
        self.engine_clock_ns: int | None = None   # node-clock time the engine was advanced to
        self.sim_time = bool(sim_time)
        # with sim time the engine keeps up by construction (lock-step): jumps are skipped
        self.max_advance_s = 2.0 * self.period_s if sim_time else max(2.0 * self.period_s, self.max_lag_s)
        self.skipped_s = 0.0                       # clock jumps not simulated
        self._window_used = 0.0                    # working time spent since the last tick
        self.cost_per_sim_s: float | None = None   # wall s per simulated s, averaged
        self._wall_acc = 0.0
        self._sim_acc = 0.0
        self.busy_s = 0.0                           # engine wall time in advances, all ticks
        self.windows = 0
        self.windows_spent = 0                      # windows whose budget ran out while behind

    def target_ns(self, now_ns: int, newest_stamp_ns: int | None) -> int:
        if newest_stamp_ns is None:
            return now_ns
        return min(now_ns, max(int(newest_stamp_ns), now_ns - self.period_ns))

    def advance_s(self, to_ns: int) -> float:
        """Seconds to advance to ``to_ns`` (0 when not later than the engine clock); moves the
        engine clock there. The first advance is one period; an advance is at most
        ``max_advance_s`` (a jump of the clock, as when /clock starts, or a stall of the whole
        process, is skipped, not simulated: counted in ``skipped_s``)."""
        if self.engine_clock_ns is None:
            self.engine_clock_ns = to_ns
            return self.period_s
        advance = max(0.0, (to_ns - self.engine_clock_ns) / NS_PER_S)
        self.engine_clock_ns = max(self.engine_clock_ns, to_ns)
        if advance > self.max_advance_s:
            self.skipped_s += advance - self.max_advance_s
            advance = self.max_advance_s
        return advance

    def hold(self, now_ns: int) -> None:
        """Paused or held: the engine clock follows now, and that time is not simulated."""
        self.engine_clock_ns = now_ns

    def new_window(self, behind: bool) -> None:
        """A tick: a new budget of ``budget_s`` of working time, and the cost average updated
        with the previous window's work (``behind``: the engine ended it with work left)."""
        if behind and self.windows:
            self.windows_spent += 1
        self.windows += 1
        self._window_used = 0.0
        if self._sim_acc > 0.0:
            sample = self._wall_acc / self._sim_acc
            alpha = min(1.0, self.period_s / COST_TIME_CONSTANT_S)
            self.cost_per_sim_s = sample if self.cost_per_sim_s is None else \
                self.cost_per_sim_s + alpha * (sample - self.cost_per_sim_s)
            self._wall_acc = self._sim_acc = 0.0

    def deadline(self, wall_now: float) -> float | None:
        """perf_counter time after which an advance starting at ``wall_now`` starts no substep:
        now plus what is left of this tick's budget (None: no limit, sim time)."""
        if self.sim_time:
            return None
        return wall_now + max(0.0, self.budget_s - self._window_used)

    def spent(self, wall_s: float, simulated_s: float) -> None:
        self.busy_s += wall_s
        self._window_used += wall_s
        self._wall_acc += wall_s
        self._sim_acc += simulated_s

    def wait_for_poses_s(self, to_tick_s: float, owed_s: float) -> float:
        """How long the engine may wait for more poses [s] when it owes ``owed_s`` of simulated
        time and the coming tick is ``to_tick_s`` away: the longest wait w after which the
        advance of ``owed_s + w`` (the poses go on coming in real time), at ``COALESCE_SAFETY``
        times the measured cost, still ends ``COALESCE_MARGIN_S`` before the tick and within
        what is left of this tick's budget, and spans at most ``COALESCE_MAX_SPAN_S``. 0
        (advance now) with sim time (lock-step), before the cost is measured, or for less than
        ``COALESCE_MIN_WAIT_S``."""
        if self.sim_time or self.cost_per_sim_s is None:
            return 0.0
        k = COALESCE_SAFETY * self.cost_per_sim_s
        wait = min((to_tick_s - COALESCE_MARGIN_S - k * owed_s) / (1.0 + k), COALESCE_MAX_SPAN_S - owed_s)
        if k > 0.0:
            wait = min(wait, (self.budget_s - self._window_used) / k - owed_s)
        return wait if wait >= COALESCE_MIN_WAIT_S else 0.0

    def reset_cost(self) -> None:
        """Forget the measured cost (the engine's settings changed)."""
        self.cost_per_sim_s = None
        self._wall_acc = self._sim_acc = 0.0

    @property
    def demand(self) -> float | None:
        """Budget use: the share of its budget the engine needs to keep real time (None until
        measured)."""
        return None if self.cost_per_sim_s is None else self.cost_per_sim_s / self.budget_fraction


class LadderControl:
    """When the degradation ladder steps (see the module docstring). ``rung_cost_ratio(level)``:
    the a-priori cost ratio of a level against the one above it; ``started_s``: when the engine
    started (the decisions' clock, perf_counter s)."""

    def __init__(self, bottom: int, rung_cost_ratio, enabled: bool = True, started_s: float = 0.0):
        self.bottom = int(bottom)
        self.enabled = bool(enabled) and self.bottom > 0
        self._a_priori = rung_cost_ratio
        self.started_s = float(started_s)
        self.measured_ratio: dict[int, float] = {}
        self.level = 0
        self._over_since: float | None = None
        self._under_since: float | None = None
        self._changed_at: float | None = None
        self._cost_before: float | None = None

    def cost_ratio(self, level: int) -> float:
        return self.measured_ratio.get(level, self._a_priori(level))

    def decide(self, now_s: float, demand: float | None, lag_s: float, max_lag_s: float,
               cost: float | None = None) -> int | None:
        """The level to switch to now, or None; ``cost``: the measured cost per simulated second
        (after a change has settled it gives the rung's measured ratio)."""
        if not self.enabled or now_s < self.started_s + START_GRACE_S:
            return None
        if self._changed_at is not None and now_s - self._changed_at < SETTLE_S:
            return None
        self._settled(cost)
        if demand is None:
            return None
        over = demand > 1.0 or lag_s > 0.5 * max_lag_s
        self._over_since = (self._over_since if self._over_since is not None else now_s) if over else None
        if over and self.level < self.bottom and now_s - self._over_since >= DOWN_AFTER_S:
            return self.level + 1
        roomy = self.level > 0 and not over and demand * self.cost_ratio(self.level) < UP_BELOW
        self._under_since = (self._under_since if self._under_since is not None else now_s) if roomy else None
        if roomy and now_s - self._under_since >= UP_AFTER_S:
            return self.level - 1
        return None

    def changed(self, now_s: float, level: int, cost_before: float | None) -> None:
        """The ladder went to ``level`` at ``now_s``; ``cost_before``: the measured cost per
        simulated second just before (for the rung's measured cost ratio)."""
        self._cost_before = cost_before if level > self.level else None
        self.level = level
        self._changed_at = now_s
        self._over_since = self._under_since = None

    def _settled(self, cost_now: float | None) -> None:
        """The cost at the new level after settling: the rung's measured ratio, kept within
        RATIO_TRUST of the a-priori one (a step down in a passing slowdown, the machine busy for
        a moment, would otherwise measure a ratio that never lets the ladder back up)."""
        if self._cost_before is not None and cost_now:
            a_priori = self._a_priori(self.level)
            ratio = self._cost_before / cost_now
            self.measured_ratio[self.level] = min(max(ratio, a_priori / RATIO_TRUST), a_priori * RATIO_TRUST)
            self._cost_before = None
