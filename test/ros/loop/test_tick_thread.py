"""The node's tick thread: on a fixed schedule (no drift, never early), a stall gives up the slots
it overran instead of running them back to back, an exception is reported and the ticks go on,
and no tick runs after stop()."""

import threading
import time

import numpy as np
import pytest

from tissue_sim_ros.ros.loop.tick_thread import TickThread

PERIOD = 0.01


def _run(tick, seconds, on_error=None):
    errors = []
    ticker = TickThread(PERIOD, tick, on_error or errors.append)
    start = time.monotonic()
    ticker.start()
    time.sleep(seconds)
    ticker.stop()
    return start, errors, ticker


def test_ticks_keep_to_the_schedule_and_never_come_early():
    times = []
    start, errors, _ = _run(lambda: times.append(time.monotonic()), 1.0)
    phase = (np.array(times) - start) / PERIOD
    # each tick's slot, up to a period late (a loaded machine delays a tick by more than half a
    # period now and then): counted from the phase of the least late tick, which an early tick
    # would make negative
    offset = np.min(phase - np.round(phase))
    slots = np.floor(phase - offset + 1e-9)
    late = (phase - slots) * PERIOD                   # after its slot [s] (the first slot is 1)
    assert errors == []
    assert np.all(np.diff(slots) >= 1)                            # one tick a slot at most
    assert late.min() > -1e-3                                     # not before its slot
    assert np.median(late) < 5e-3                                 # and on it, whatever the load
    assert len(times) >= 0.8 * 1.0 / PERIOD                        # slots are given up only in stalls
    # no drift: a schedule of "a period after the last tick" would be 60-100 us later a tick
    # (the sleep's overshoot), several ms after 90 ticks
    assert np.median(late[-20:]) - np.median(late[:20]) < 2e-3


def test_a_stall_gives_up_the_slots_it_overran():
    times = []

    def tick():
        times.append(time.monotonic())
        if len(times) == 5:
            time.sleep(3.5 * PERIOD)                 # a stall of three and a half periods
    start, _, ticker = _run(tick, 0.3)
    gaps = np.diff(times)
    assert gaps[4] >= 3.5 * PERIOD                 # after the stall
    assert gaps[5:].min() > 0.5 * PERIOD           # no burst of late ticks to catch up
    slots = (np.array(times) - start) / PERIOD
    assert np.round(slots[5]) - np.round(slots[4]) >= 4        # slots 6..8 given up
    # the count of slots given up: every slot of the schedule was run or counted, over the
    # stall and whatever stalls a loaded machine added
    assert len(times) + ticker.slots_given_up == pytest.approx(np.round(slots[-1]), abs=1)
    assert ticker.slots_given_up >= 3


def test_an_exception_is_reported_and_the_ticks_go_on():
    count = [0]

    def tick():
        count[0] += 1
        if count[0] == 3:
            raise ValueError('force: nan')
    start, errors, ticker = _run(tick, 0.2)
    assert [str(e) for e in errors] == ['force: nan'] and ticker.errors == 1
    assert count[0] >= 10


def test_no_tick_runs_after_stop_returns():
    count = [0]
    running = threading.Event()

    def tick():
        running.set()
        time.sleep(0.5 * PERIOD)
        count[0] += 1
    ticker = TickThread(PERIOD, tick, lambda exc: None)
    ticker.start()
    assert running.wait(2.0)
    ticker.stop()
    seen = count[0]
    time.sleep(5 * PERIOD)
    assert count[0] == seen and not ticker.running
    with pytest.raises(ValueError, match='period_s'):
        TickThread(0.0, tick, lambda exc: None)
