"""The compiled substep after the force kernel with a flexible needle inside.

:func:`after_rod_inside_step` is :func:`~.substeps.after_inside_step` for a needle with an elastic
shaft: the needle moved, the watchdog, the compiled inside step
(:func:`~tissue_sim_ros.engine.needle.rod_step.rod_inserted_step`) and the outcome the Python
would otherwise decide on, the same decisions on the same floats (shaft points' places are arc
lengths along the rod, the tip's travel is along the tip's axis). The needle's move writes the
straight needle's tip, which the rod's step replaces with the rod's.
"""
from numba import njit

from tissue_sim_ros.engine.compiled.outcomes import DIVERGED, inside_outcome, move_and_watch
from tissue_sim_ros.engine.needle.rod_step import rod_inserted_step

__all__ = ['after_rod_inside_step']


@njit(cache=True, nogil=True)
def after_rod_inside_step(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                          previous_axis, length, tip, apex_rest, state, decide, kinds, params, tags, element_region,
                          results, needle):
    """``after_inside_step`` with the flexible needle's inside step (module docstring); its
    arguments, ``needle`` the flexible needle's ``NeedleTissue.inserted_arguments``."""
    if not move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                          previous_axis, length, tip):
        return DIVERGED
    return inside_outcome(rod_inserted_step(*needle, state[0], state[1] != 0), state, energy, results, decide,
                          kinds, params, tags, element_region, apex_rest)
