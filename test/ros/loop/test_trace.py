"""The engine trace (ros/loop/trace.py): what the engine did, encoded per tick and decoded again
to the same rows, and run through a driver again to the state the tick published. Truth: the
rows written here, and a second driver advanced by hand with the same arguments."""
import math

import numpy as np
import pytest

from tissue_sim_ros.ros.loop.trace import (ADVANCE, COLUMNS, DROP, HEADER_SIZE, LEVEL, RESET, TraceReplayer,
                                           advance_row, decode, encode, event_row)

STAMP = 123_456_789_012          # node-clock stamps this small stay exact through clock_ns()
DOWN = (1.0, 0.0, 0.0, 0.0)


def test_a_tick_decodes_to_the_rows_it_was_encoded_from():
    rows = [advance_row(7, 0.0125, (0.001, -0.002, 0.158), DOWN, 3, STAMP - 13_000_001),
            advance_row(8, 0.0075, None, None, 2, STAMP + 2_999_999),
            event_row(LEVEL, 8, 2.0), event_row(DROP, 8, 0.25), event_row(RESET, 9)]
    data = encode(STAMP, 8, rows)
    assert len(data) == HEADER_SIZE + len(rows) * len(COLUMNS)
    tick = decode(data)
    assert tick.stamp_ns == STAMP and tick.published_index == 8
    np.testing.assert_array_equal(tick.rows[:, 0], [ADVANCE, ADVANCE, LEVEL, DROP, RESET])
    np.testing.assert_array_equal(tick.rows[0, 1:11], [7, 0.0125, 0.001, -0.002, 0.158, *DOWN, 3])
    assert np.isnan(tick.rows[1, 3:10]).all() and tick.rows[1, 10] == 2
    assert [tick.rows[2, 10], tick.rows[3, 10]] == [2.0, 0.25]
    np.testing.assert_array_equal(tick.clock_ns(), [STAMP - 13_000_001, STAMP + 2_999_999, -1, -1, -1])
    with pytest.raises(ValueError, match='engine trace: 5 values'):
        decode(data[:5])


def test_a_replayed_trace_is_the_run_it_records_and_returns_the_published_state():
    from tissue_sim_ros.engine.driver import SimulationDriver
    from tissue_sim_ros.engine.scene.scene import Scene

    def scene():
        return Scene.from_file(None, mesh={'generator': 'box', 'divisions': [6, 6, 4]})
    by_hand = SimulationDriver(scene())
    start, q = by_hand.scene.needle_pose
    moves = [(0.02, start + [0.0, 0.0, -0.004 * k]) for k in range(1, 4)]   # 4 mm a tick: to the tissue
    states = {0: by_hand.force.copy()}
    for k, (duration, position) in enumerate(moves, 1):
        by_hand.advance(duration, position, q)
        states[k] = by_hand.force.copy()
    replayer = TraceReplayer(SimulationDriver(scene()))
    substeps = math.ceil(0.02 / by_hand.dt) + 1                              # enough to finish each
    first = decode(encode(STAMP, 1, [advance_row(1, *moves[0], q, substeps, STAMP)]))
    np.testing.assert_array_equal(replayer.apply(first)[0], states[1])
    later = decode(encode(STAMP + 20_000_000, 2, [advance_row(k, *moves[k - 1], q, substeps, STAMP)
                                                  for k in (2, 3)]))
    force, _, displacement = replayer.apply(later)          # two advances; the tick shows the first
    np.testing.assert_array_equal(force, states[2])
    assert displacement is None and replayer.index == 3
    np.testing.assert_array_equal(replayer.driver.force, states[3])
    assert np.abs(states[3]).max() > np.abs(states[1]).max() >= 0.0
