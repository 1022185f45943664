"""Clocks read from compiled code (engine/compiled/clock.py): the monotonic clock is the one
time.perf_counter reads and the thread clock the one time.thread_time reads. Truth: Python's own
clocks read just before and after the compiled call."""
import time

import numpy as np
import pytest
from numba import njit

from tissue_sim_ros.engine.compiled.clock import AVAILABLE, MONOTONIC, THREAD_CPU, clock_ns

pytestmark = pytest.mark.skipif(not AVAILABLE, reason="Linux's clock ids only")


@njit(cache=False)
def _read(clock_id, spin):
    first = clock_ns(clock_id)
    total = 0.0
    for k in range(spin):                 # some work between the two readings
        total += np.sqrt(k)
    return first, clock_ns(clock_id), total


@pytest.mark.parametrize('clock_id, python_clock', [(MONOTONIC, time.perf_counter_ns),
                                                    (THREAD_CPU, time.thread_time_ns)])
def test_a_compiled_reading_lies_between_python_readings_of_the_same_clock(clock_id, python_clock):
    _read(clock_id, 1)                                        # compiled before the readings
    before = python_clock()
    first, second, _ = _read(clock_id, 2_000_000)
    after = python_clock()
    assert before <= first <= second <= after
    assert second - first > 0                                 # the work between them took time
