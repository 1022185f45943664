"""Readiness (ros/readiness.py): ~/ready is false from the node's start and true from its first
tick, sent once each (the topic is latched: a late subscriber reads the last value)."""

from tissue_sim_ros.ros.readiness import Readiness


def test_ready_is_false_while_starting_and_true_once_from_the_first_tick():
    sent = []
    readiness = Readiness(sent.append)
    readiness.starting()
    assert sent == [False] and readiness.state == 'starting'
    for _ in range(3):             # every tick calls it; only the first one says so
        readiness.ticking()
    assert sent == [False, True] and readiness.state == 'ready'
