"""The node's 50 Hz tick on its own thread, on the monotonic clock, instead of a ROS timer.

Why: with rclpy's EventsExecutor each timer callback costs about 100 us of dispatch on the
executor thread, a third of the node's work outside the physics besides the tick itself; and a
timer callback waits behind whatever callback runs before it, which makes the tick period
uneven. A dedicated loop thread is also how ros2_control runs its controller manager's update.
Figures: docs/performance.md.

The ticks are on a fixed schedule, ``start + k period`` (no drift); a tick that comes more than a
period late (the process stalled) gives up the slots it missed rather than running them back to
back, and the node counts them as missed. ``tick()`` must be safe to call beside the executor's
callbacks (the node's tick reads the engine's latest state, publishes and records; rclpy's
publishers and the recorder are thread-safe). An exception from ``tick()`` does not stop the
ticks: it is handed to ``on_error``. The node keeps the ROS timer with ``use_sim_time`` (its
ticks then follow /clock).
"""
from __future__ import annotations

import threading
import time

from tissue_sim_ros.system.thread_names import name_os_thread

__all__ = ['TickThread']


class TickThread:
    """Call ``tick()`` every ``period_s`` from :meth:`start` until :meth:`stop`."""

    def __init__(self, period_s: float, tick, on_error, name: str = 'tissue_sim-tick'):
        if not period_s > 0.0:
            raise ValueError(f'period_s: {period_s!r}; expected a period > 0 s')
        self.period_s, self._tick, self._on_error = float(period_s), tick, on_error
        self.errors = 0
        self.slots_given_up = 0          # slots of the schedule a stall overran
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)

    def start(self) -> None:
        if not self._thread.is_alive() and not self._stop.is_set():
            self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        """No tick starts after this returns (it waits for one that runs)."""
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    def _run(self) -> None:
        name_os_thread()
        period = self.period_s
        start = time.monotonic()
        k = 1
        while not self._stop.wait(max(0.0, start + k * period - time.monotonic())):
            try:
                self._tick()
            except Exception as exc:  # noqa: BLE001 - reported; the next tick comes all the same
                self.errors += 1
                self._on_error(exc)
            # the next slot in the future: slots a stall overran are given up, not run late
            next_k = max(k + 1, int((time.monotonic() - start) / period) + 1)
            self.slots_given_up += next_k - k - 1
            k = next_k
