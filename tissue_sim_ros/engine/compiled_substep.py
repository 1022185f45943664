"""A scene's substep as the force kernel and one compiled call, while the needle is outside or inside.

A substep of :meth:`.scene.Scene.advance` is the needle's pose for the step, the force kernel (the
element pass, then the node update), the watchdog, and the needle's step after the tissue's,
as Python around compiled calls (``NeedleTissue.set_pose``, ``Simulation.step``,
``NeedleTissue.after_step``): Python that runs cold, after an element pass has been through the
caches (issue 19 item 3: one call into compiled code per slice, the needle's bookkeeping inside
it). Here the force kernel runs as before and is timed as before (``Simulation.kernel_s``), and
the rest of the substep is one compiled call:

- the needle outside (phase ``approach``): :func:`after_approach_step`, the needle moved, the
  watchdog, the needle's kinematics and the test for the surface (``needle_kernels.approach_hit``);
  a step that meets the surface goes on in ``NeedleTissue.after_kinematics``;
- the needle inside (``inserted``, ``retracting``, no membrane): :func:`after_inside_step`, the
  needle moved, the watchdog, the compiled inside step (``needle_step.inserted_step``) and the
  outcome the Python would otherwise decide on (the apex still in its layer, no shaft point to
  add, none to release); a step that needs more goes on in ``NeedleTissue.after_inserted_step``.

Both calls release the GIL, as the force kernel does: the node's executor thread publishes while
the needle's step runs (about 35 us of the inside substep on the default scene). On node-bench's
insertions (default scene, in-process, 100 advances a second) the work outside the force kernel
fell from 62-73 to 59-63 us a substep (alternating runs), the approach's surface test
(``needle_kernels.near_surface_hit``) included.

The same kernels in the same order: a scene advanced this way gives the same state, to the last
bit, as one advanced through the Python calls (``Scene.compiled_substeps = False``; tested). It
runs where that holds simply: one needle, translating (a turning needle's slerp stays in Python),
the explicit integrator with no prescribed DOFs and no relaxation, the needle not at a membrane,
and not on the watchdog's energy-check steps (every ``check_interval``-th, which need the strain
energy before the step); every other step is the general one.
"""
import time

import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle_kernels import approach_hit, needle_kinematics, wrench_about
from tissue_sim_ros.engine.needle_step import inserted_step
from tissue_sim_ros.engine.region_selectors import region_of_point
from tissue_sim_ros.engine.solver import _advance_free

__all__ = ['after_approach_step', 'after_inside_step', 'CompiledSubsteps', 'DONE', 'TAIL', 'DIVERGED']

#: a compiled step's outcome: complete; the needle's Python must decide the rest; the watchdog
#: tripped (the needle's step not run)
DONE, TAIL, DIVERGED = 0, 1, 2
_OUTSIDE, _INSIDE = 'approach', 'inside'


@njit(cache=True, inline='always')
def _move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
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
    return not bad and kinetic <= watch[0] * (watch[1] + max(energy[0], 0.0)) + watch[2]


@njit(cache=True, nogil=True)
def after_approach_step(s, work, kinetic, bad, start, move, energy, watch, rest, displacement, triangles, boxes,
                        surface_nodes, position, axis, previous_position, previous_axis, length, diameter, dt, tip,
                        travel, base_velocity, axis_rate, ray_origin, applied_points, applied_point_forces,
                        wrench_force, wrench_torque):
    """The substep after the force kernel with the needle outside (module docstring): DONE (no
    contact, the wrench zero), TAIL (the tip met the surface: ``after_kinematics`` goes on) or
    DIVERGED."""
    if not _move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                           previous_axis, length, tip):
        return DIVERGED
    needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel, base_velocity,
                      axis_rate)
    if approach_hit(rest, displacement, triangles, boxes, surface_nodes, tip, travel, axis, diameter,
                    ray_origin)[0] >= 0:
        return TAIL
    wrench_about(applied_points, applied_point_forces, 0, position, wrench_force, wrench_torque)
    return DONE


@njit(cache=True, nogil=True)
def after_inside_step(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                      previous_axis, length, tip, apex_rest, state, decide, kinds, params, tags, element_region,
                      needle):
    """The substep after the force kernel with the needle inside (module docstring).

    The needle's pose arrays, ``length`` and ``apex_rest`` are those in ``needle``, named.
    ``state``: (the apex's element, whether the applied forces need clearing first), updated.
    ``decide``: (release_beyond, needle length, shaft point spacing, the layer's region index);
    ``kinds``, ``params``, ``tags``: the region selectors (``region_selectors.region_of_point``;
    no kinds: each element's own region, ``element_region``). ``needle``:
    ``NeedleTissue.inserted_arguments``. Returns (outcome, and the inside step's nine values)."""
    if not _move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                           previous_axis, length, tip):
        return DIVERGED, 0.0, 0.0, 0, 0, 0.0, -2, 0.0, 0.0, 0.0
    (friction, cutting, n_tip, n_applied, needle_work, apex, travel_along, deepest,
     speed_along) = inserted_step(*needle, state[0], state[1] != 0)
    state[1] = 0                                   # explicit: the step zeroed what it applied
    energy[0] += needle_work
    outcome = TAIL
    if not (travel_along < 0.0 and deepest > decide[0]) and apex >= 0 and not decide[1] - deepest >= decide[2]:
        region = region_of_point(kinds, params, tags, apex_rest[0], apex_rest[1], apex_rest[2], apex)
        if region < 0:
            region = element_region[apex]
        if region == decide[3]:
            state[0] = apex
            outcome = DONE
    return outcome, friction, cutting, n_tip, n_applied, needle_work, apex, travel_along, deepest, speed_along


class CompiledSubsteps:
    """A scene's substeps through :func:`after_approach_step` or :func:`after_inside_step` over
    one ``Scene.advance`` call, its needle translating from ``start`` by ``move`` (module
    docstring). :meth:`ready` says whether the coming step can be run so; :meth:`step` runs it;
    :meth:`invalidate` after any other step (the arguments are gathered again: they may have
    changed)."""

    def __init__(self, scene, start, move):
        self.sim, self.needle = scene.simulation, scene.needle
        self.start, self.move = start, move
        self.energy = np.zeros(1)
        self.state = np.zeros(2, dtype=np.int64)
        self._key, self._calls = None, None

    def invalidate(self):
        self._key = None

    def ready(self) -> bool:
        sim, needle = self.sim, self.needle
        if not ((sim.step_count + 1) % sim.check_interval and sim.reference_energy is not None
                and sim.model.topology_version == sim._topology_version and not needle._touching()):
            return False
        if needle.n_points:
            mode = _INSIDE if needle.compiled_inside else None
        else:
            mode = _OUTSIDE if needle.phase == 'approach' and not needle._forces_applied else None
        if mode is None:
            return False
        key = (mode, sim.mass_version, sim.dt, needle.region)
        if key != self._key:
            self._key, self._calls = key, self._gather(mode)
        return self._calls is not None

    def _gather(self, mode):
        sim, needle = self.sim, self.needle
        forces = sim.model.force_pass_call(sim.displacement, sim.velocity)
        if forces is None:
            return None
        inverse_mass = needle._inverse_mass()
        needle.contact_force[:] = 0.0
        geometry = needle.geometry
        watch = np.array([sim.energy_limit_factor(), sim.reference_energy, sim.energy_floor])
        advance = sim.advance_arguments()
        common = (self.start, self.move, self.energy, watch)
        if mode == _OUTSIDE:
            after = common + (needle.rest, sim.displacement, needle.surface_triangles, needle.surface_boxes,
                              needle.surface_nodes, needle.position, needle.axis, needle._previous_position,
                              needle._previous_axis, geometry.length_m, geometry.diameter_m, sim.dt, needle._tip,
                              needle._travel, needle._base_velocity, needle._axis_rate, needle._ray_origin,
                              needle._applied_points, needle._applied_point_forces, needle.wrench_force,
                              needle.wrench_torque)
            return forces[0], forces[1], advance, after_approach_step, after, inverse_mass
        selectors = needle.selectors
        kinds, params, tags = ((np.zeros(0, dtype=np.int64), np.zeros((0, 6)), np.zeros(0, dtype=np.int64))
                               if selectors is None else (selectors.kinds, selectors.params, selectors.tags))
        decide = np.array([needle._release_beyond, geometry.length_m, geometry.shaft_point_spacing_m,
                           float(needle.region)])
        after = common + (needle.position, needle.axis, needle._previous_position, needle._previous_axis,
                          geometry.length_m, needle._tip, needle._apex_rest, self.state, decide, kinds, params,
                          tags, needle.element_region, needle.inserted_arguments(inverse_mass, sim.dt))
        return forces[0], forces[1], advance, after_inside_step, after, inverse_mass

    def step(self, s):
        """One substep, the needle's base at ``start + s move`` (``ready()`` said it can)."""
        sim, needle = self.sim, self.needle
        kernel, kernel_args, advance_args, after_step, after_args, inverse_mass = self._calls
        self.energy[0] = sim.input_work
        kernel0 = time.thread_time()
        kernel(*kernel_args)
        work, kinetic, bad = _advance_free(*advance_args)
        sim.kernel_s += time.thread_time() - kernel0
        if after_step is after_approach_step:
            outcome = after_approach_step(s, work, kinetic, bad, *after_args)
        else:
            self.state[0], self.state[1] = needle.apex_element, needle._forces_applied
            (outcome, friction, cutting, n_tip, n_applied, _, apex, travel_along, deepest,
             speed_along) = after_inside_step(s, work, kinetic, bad, *after_args)
        sim.input_work = self.energy[0]
        sim.kinetic_energy = kinetic
        sim.time = sim.time + sim.dt
        sim.step_count += 1
        if outcome == DIVERGED:
            sim.watch(bad, kinetic)        # raises SimulationDiverged, as Simulation.step would
        if after_step is after_approach_step:
            needle.friction_force = needle.cutting_force = 0.0
            needle.n_applied = 0
            if outcome == TAIL:
                needle.after_kinematics(inverse_mass, sim.dt)
                self._key = None
            else:
                needle.surface_point = None
            return
        needle.friction_force, needle.cutting_force, needle.n_tip, needle.n_applied = friction, cutting, n_tip, n_applied
        needle._forces_applied = False
        if outcome == TAIL:
            needle.after_inserted_step(inverse_mass, sim.dt, apex, travel_along, deepest, speed_along)
            self._key = None
        else:
            needle.apex_element = apex
            needle.phase = 'retracting' if speed_along < -1e-9 else 'inserted'
