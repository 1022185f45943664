"""A compiled substep's outcome, and the needle's move and the watchdog's test it starts with.

The functions here are shared by every compiled step after the force kernel
(:mod:`.substeps`, :mod:`.rod_substeps`), so the needle moves and the watchdog decides the same way
in each.
"""
from numba import njit

from tissue_sim_ros.engine.mesh.selectors import region_of_point

__all__ = ['DONE', 'TAIL', 'DIVERGED', 'ENGAGED', 'REFUSED', 'CHECK', 'energy_limit', 'inside_outcome',
           'move_and_watch']

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


@njit(cache=True, inline='always')
def inside_outcome(step, state, energy, results, decide, kinds, params, tags, element_region, apex_rest):
    """What the Python after an inside step would decide, from the step's nine values ``step``
    (rigid or flexible needle's, :mod:`~tissue_sim_ros.engine.needle.step`): the work added to
    ``energy[0]``, the values into ``results``, and DONE when nothing is left to decide (the
    apex still in the layer's region ``decide[3]``, no shaft point to release or add), else TAIL.
    ``state``: (the apex's element, whether the applied forces need clearing first), updated."""
    friction, cutting, n_tip, n_applied, needle_work, apex, travel_along, deepest, speed_along = step
    state[1] = 0                                   # explicit: the step zeroed what it applied
    energy[0] += needle_work
    results[0], results[1], results[2], results[3], results[4] = friction, cutting, n_tip, n_applied, needle_work
    results[5], results[6], results[7], results[8] = apex, travel_along, deepest, speed_along
    if not (travel_along < 0.0 and deepest > decide[0]) and apex >= 0 and not decide[1] - deepest >= decide[2]:
        region = region_of_point(kinds, params, tags, apex_rest[0], apex_rest[1], apex_rest[2], apex)
        if region < 0:
            region = element_region[apex]
        if region == decide[3]:
            state[0] = apex
            return DONE
    return TAIL
