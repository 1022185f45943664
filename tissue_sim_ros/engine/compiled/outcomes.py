"""A compiled substep's outcome, and the needle's move and the watchdog's test it starts with.

The functions here are shared by every compiled step after the force kernel
(:mod:`.substeps`, :mod:`.rod_substeps`), so the needle moves and the watchdog decides the same way
in each.
"""
from numba import njit

__all__ = ['DONE', 'TAIL', 'DIVERGED', 'ENGAGED', 'REFUSED', 'CHECK', 'energy_limit', 'move_and_watch']

#: a compiled step's outcome: complete; the needle's Python must decide the rest; the watchdog
#: tripped (the needle's step not run); (a contact step) samples touched: the Python takes them;
#: (run_slice) no step run: a function's check is not that of its arguments' types; an
#: energy-check step failed (the needle neither moved nor stepped)
DONE, TAIL, DIVERGED, ENGAGED, REFUSED, CHECK = 0, 1, 2, 3, 4, 5


@njit(cache=True, inline='always')
def energy_limit(watch, work_put_in):
    """``Simulation._energy_limit`` from ``watch`` (growth factor times swing, initial energy,
    floor) and the work put in so far [J]."""
    return watch[0] * (watch[1] + max(work_put_in, 0.0)) + watch[2]


@njit(cache=True, inline='always')
def move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                   previous_axis, length, tip):
    """The needle's base to ``start + s move`` (``NeedleTissue.set_pose`` with no rotation), the
    step's work added to ``energy[0]``; whether the watchdog passes the step (``watch``: growth
    factor times swing, initial energy, floor: ``Simulation._energy_limit``)."""
    for r in range(3):
        previous_position[r] = position[r]
        previous_axis[r] = axis[r]
        position[r] = move[r] * s
        position[r] += start[r]
        tip[r] = axis[r] * length
        tip[r] += position[r]
    energy[0] += work
    return not bad and kinetic <= energy_limit(watch, energy[0])
