"""A scene's substeps in compiled slices while the needle is outside, at the membrane or inside.

A substep of :meth:`~tissue_sim_ros.engine.scene.scene.Scene.advance` is the needle's pose for
the step, the force kernel (the element pass, then the node update), the watchdog, and the
needle's step after the tissue's: as Python around compiled calls (``NeedleTissue.set_pose``,
``Simulation.step``, ``NeedleTissue.after_step``) it runs cold, after an element pass has been
through the caches. Here :func:`run_slice` runs the substeps of an advance in one ``nogil``
call, as many as run the same way in a row, each the force kernel, timed on the thread's CPU
clock into ``Simulation.kernel_s`` as Python timed it (:mod:`.clock`), and then

- the needle outside (phase ``approach``): :func:`after_approach_step`, the needle moved, the
  watchdog, the needle's kinematics and the test for the surface (``kernels.approach_hit``);
  a step that meets the surface goes on in ``NeedleTissue.after_kinematics``;
- a sharp tip bonded to the outer membrane (phase ``contact``, before the first puncture):
  :func:`after_contact_step`, the needle moved, the watchdog, the bonds solved and applied, the
  tip's samples tried against the surface, the work and the wrench; a step where the contact may
  end or the membrane may rupture goes on in ``NeedleTissue.after_kinematics``, one where samples
  touched in ``NeedleTissue.after_engaging``;
- the needle inside (``inserted``, ``retracting``, no membrane): :func:`after_inside_step`, the
  needle moved, the watchdog, the compiled inside step (``step.inserted_step``) and the outcome
  the Python would otherwise decide on (the apex still in its layer, no shaft point to add, none
  to release); a step that needs more goes on in ``NeedleTissue.after_inserted_step``. A flexible
  needle's is :func:`.rod_substeps.after_rod_inside_step`, the same with its shaft's step.

The slice calls the element pass, the node update and the step after them by the addresses of
their compiled code (:mod:`.call`, each with a check of its types): the machine code a Python
call runs, the element pass as the compile cache had it compiled (not optimized again inside
another function), one machine code of :func:`run_slice` for every model, cached, and a
dispatch that types arrays and integers only (numba's first-class function values cost
microseconds of Python a slice). It stops at the target time, ``max_steps``, the deadline (by
its last substep's wall time, on the monotonic clock, as ``Scene.advance`` does), after a
watchdog energy-check step (every ``check_interval``-th: the strain energy's element pass before
it, called the same way, the test after the tissue's step as ``Simulation.step`` makes it) and
at any outcome but DONE. The work of the needle's forces (``kernels.applied_work``) and the
3-vector dots a contact step decides on (``kernels.dot3``) are one function for both paths:
numpy's went through BLAS, whose kernels may sum in another order. Figures: docs/performance.md.

The same kernels in the same order: a scene advanced this way gives the same state, to the last
bit, as one advanced through the Python calls (``Scene.compiled_substeps = False``; tested), and
the watchdog checks the energy at the same steps. It runs where that holds simply: one needle,
translating (a turning needle's slerp stays in Python), the explicit integrator with no
prescribed DOFs and no relaxation, the needle at no membrane but a sharp tip at the outer one,
on Linux (where compiled code reads the clocks); every other step is the general one.
"""
import math

import numpy as np
from numba import njit, types

from tissue_sim_ros.engine.compiled.call import call_compiled, compiled_address, signature_check
from tissue_sim_ros.engine.compiled.clock import MONOTONIC, THREAD_CPU, clock_ns
from tissue_sim_ros.engine.compiled.outcomes import (CHECK, DIVERGED, DONE, ENGAGED, REFUSED, TAIL, energy_limit,
                                                     inside_outcome, move_and_watch)
from tissue_sim_ros.engine.compiled.rod_substeps import after_rod_inside_step
from tissue_sim_ros.engine.needle.kernels import (applied_work, approach_hit, dot3, needle_kinematics, patch_apply,
                                                  patch_solve, put_rigid_points, put_rows, wrench_about)
from tissue_sim_ros.engine.needle.parameters import rupture_force_at
from tissue_sim_ros.engine.needle.step import inserted_step
from tissue_sim_ros.engine.needle.tip import engage_samples
from tissue_sim_ros.engine.solver.explicit import _advance_free

__all__ = ['after_approach_step', 'after_inside_step', 'after_contact_step', 'run_slice',
           'CompiledSubsteps', 'DONE', 'TAIL', 'DIVERGED', 'ENGAGED', 'REFUSED', 'CHECK']

_OUTSIDE, _INSIDE, _CONTACT = 'approach', 'inside', 'contact'
_ADVANCE_RETURNS = types.Tuple((types.float64, types.float64, types.int64))     # solver._advance_free's
_ENERGY_RETURNS = types.Tuple((types.float64, types.int64))                     # model._strain_energy's


@njit(cache=True, nogil=True)
def after_approach_step(s, work, kinetic, bad, start, move, energy, watch, rest, displacement, triangles, boxes,
                        surface_nodes, position, axis, previous_position, previous_axis, length, diameter, dt, tip,
                        travel, base_velocity, axis_rate, ray_origin, applied_points, applied_point_forces,
                        wrench_force, wrench_torque):
    """The substep after the force kernel with the needle outside (module docstring): DONE (no
    contact, the wrench zero), TAIL (the tip met the surface: ``after_kinematics`` goes on) or
    DIVERGED."""
    if not move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
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
                      results, needle):
    """The substep after the force kernel with the needle inside (module docstring).

    The needle's pose arrays, ``length`` and ``apex_rest`` are those in ``needle``, named.
    ``state``: (the apex's element, whether the applied forces need clearing first), updated.
    ``decide``: (release_beyond, needle length, shaft point spacing, the layer's region index);
    ``kinds``, ``params``, ``tags``: the region selectors (``region_selectors.region_of_point``;
    no kinds: each element's own region, ``element_region``). ``needle``:
    ``NeedleTissue.inserted_arguments``. Returns the outcome; ``results`` gets the inside step's
    nine values (friction, cutting, samples found, points of action, work, apex element, travel
    and deepest point along the axis, speed along it)."""
    if not move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                          previous_axis, length, tip):
        return DIVERGED
    return inside_outcome(inserted_step(*needle, state[0], state[1] != 0), state, energy, results, decide, kinds, params,
                          tags, element_region, apex_rest)


@njit(cache=True, nogil=True)
def after_contact_step(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                       previous_axis, length, dt, tip, travel, base_velocity, axis_rate, contact_force, rest,
                       displacement, velocity, inverse_mass, force_scale, rotation, patch_offsets, targets, nodes,
                       weights, pseudo_inverse, residual, multipliers, sample_scale, sample_forces, total,
                       patch_work, rupture, triangles, surface_boxes, surface_nodes, sample_offsets, engaged, new,
                       reach, diameter, candidates, near_boxes, boxes, subset, subset_cells, sample_nodes,
                       sample_weights, applied_forces, applied_points, applied_point_forces, wrench_force,
                       wrench_torque):
    """The substep after the force kernel with a sharp tip bonded to the outer membrane (phase
    ``contact``, on the surface, no shaft points yet): ``NeedleTissue._after_step`` for the step
    that holds the bonds, does not rupture the membrane and takes no new sample. DONE; TAIL
    before the bonds are applied when the contact may end or the membrane may rupture (within
    1e-6 of its criterion: the Python decides, from ``after_kinematics``); ENGAGED after the tip's
    samples were tried when some touched (``after_engaging`` goes on); DIVERGED.

    ``rupture``: (0 for the force criterion, 1 for energy; rupture force [N], its rate exponent,
    reference speed [m/s]; the work that ruptures it under the energy criterion [J]):
    ``Membrane``'s, through the functions the Python uses. The patch's arrays are ContactPatch's (its work in
    ``patch_work``), the samples' the SharpTipContact's; the rest NeedleTissue's."""
    if not move_and_watch(s, work, kinetic, bad, start, move, energy, watch, position, axis, previous_position,
                          previous_axis, length, tip):
        return DIVERGED
    for r in range(3):
        contact_force[r] = 0.0
    applied_forces[:] = 0.0
    needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel, base_velocity,
                      axis_rate)
    n = patch_offsets.shape[0]
    put_rigid_points(tip, rotation, patch_offsets, n, targets, 0)
    patch_solve(rest, displacement, nodes, weights, pseudo_inverse, targets, residual, multipliers, sample_scale,
                1.0 / (dt * dt), sample_forces, total)
    axial = dot3(total, axis)
    if axial < 1e-9 and not dot3(travel, axis) > 1e-15:        # it may pull back: the Python decides
        return TAIL
    speed = dot3(base_velocity, axis)
    if rupture[0] == 0.0:
        if axial >= rupture_force_at(rupture[1], rupture[2], rupture[3], speed) * (1.0 - 1e-6):
            return TAIL
    elif patch_work[0] + dot3(total, travel) >= rupture[4] * (1.0 - 1e-6):
        return TAIL
    patch_apply(displacement, velocity, inverse_mass, force_scale, nodes, weights, multipliers, dt, applied_forces)
    for r in range(3):
        contact_force[r] = total[r]
    patch_work[0] += dot3(total, travel)
    put_rows(targets, n, applied_points, 0)
    put_rows(sample_forces, n, applied_point_forces, 0)
    back = math.sqrt(dot3(travel, travel)) + diameter
    if engage_samples(rest, displacement, triangles, surface_boxes, surface_nodes, tip, rotation, axis,
                      sample_offsets, engaged, new, back, reach + back, candidates, near_boxes, boxes, subset,
                      subset_cells, sample_nodes, sample_weights):
        return ENGAGED
    energy[0] += applied_work(applied_forces, velocity) * dt
    wrench_about(applied_points, applied_point_forces, n, position, wrench_force, wrench_torque)
    return DONE


@njit(cache=True, inline='always')
def _energy_check_fails(kinetic, strain, inverted, bad, work, energy, watch):
    """Whether an energy-check step diverged, as ``Simulation.watch(bad, None)`` and
    ``Simulation._check_energy`` decide after the step's tissue work is put in: bad components,
    kinetic + strain energy not finite or past the limit (``watch``: growth factor times swing,
    initial energy, floor; ``energy[0]``: the work put in before the step), inverted elements
    where refused (``watch[3]`` 1)."""
    total = kinetic + strain
    return (bad != 0 or not math.isfinite(total) or total > energy_limit(watch, energy[0] + work)
            or (inverted != 0 and watch[3] != 0.0))


@njit(cache=True, nogil=True)
def run_slice(addresses, checks, kernel_args, advance_args, after_args, energy_args, energy, watch, clock,
              counters):
    """Substeps in one call, each the force kernel (``kernel(*kernel_args)``, then the node update
    ``advance(*advance_args)``) and ``after(s, work, kinetic, bad, *after_args)``, the functions
    called by the addresses of their compiled code (``addresses``, with ``checks`` of their types:
    :mod:`.compiled_call`; one machine code of this function for every model and mode, and numba's
    cache keeps it), as ``Scene.advance`` runs them: the needle at ``s`` of its move, toward the
    running target time. The first substep runs (the caller checked it may); the next ones while
    they end by the target time, before ``max_steps``, within the deadline (its last substep's wall
    time ahead) and while ``after`` says DONE. The watchdog's energy-check step (every
    ``check_interval``-th) is the slice's last: the strain energy before it
    (``strain_energy(*energy_args)``, the fourth function), the test after the tissue's step
    (:func:`_energy_check_fails`; ``energy`` and ``watch`` are ``after``'s); a step that fails
    it ends the slice before ``after`` (outcome CHECK). None runs (outcome REFUSED) if a check
    of types is not that of the arguments passed here.

    ``clock``: (time, dt, start time, target time, deadline (perf_counter s; inf: none), the last
    substep's wall time, then, after a check step, its strain energy, ``s`` and tissue work) [s,
    J]; ``counters``: (step count, check_interval, max_steps (< 0: none), then, after a check
    step, its inverted elements and 1). Returns (substeps run, the last one's outcome, its kinetic
    energy and bad components (the watchdog's), thread CPU ns in the force kernel)."""
    if (checks[0] != signature_check((), kernel_args, None)
            or checks[1] != signature_check((), advance_args, (0.0, 0.0, 0))
            or checks[2] != signature_check((0.5, 0.0, 0.0, 0), after_args, 0)
            or checks[3] != signature_check((), energy_args, (0.0, 0))):
        return 0, REFUSED, 0.0, 0, 0
    time, dt, start_t, end_t, deadline, step_wall = clock[0], clock[1], clock[2], clock[3], clock[4], clock[5]
    step_count, check_interval, max_steps = counters[0], counters[1], counters[2]
    timed = deadline < np.inf
    steps, outcome, kinetic, bad, kernel_ns = 0, DONE, 0.0, 0, 0
    checking = False
    while outcome == DONE and not checking:
        if steps:
            if not time + dt <= end_t + 1e-9 * dt or steps == max_steps:
                break
            if timed and clock_ns(MONOTONIC) / 1e9 + step_wall > deadline:
                break
        wall0 = clock_ns(MONOTONIC) if timed else 0
        s = min(1.0, (time + dt - start_t) / (end_t - start_t))
        checking = (step_count + 1) % check_interval == 0
        if checking:         # energy at u_n, matched with the velocity at t_n from the advance
            strain, inverted = call_compiled(addresses[3], (), energy_args, (0.0, 0))
        cpu0 = clock_ns(THREAD_CPU)
        call_compiled(addresses[0], (), kernel_args, None)
        work, kinetic, bad = call_compiled(addresses[1], (), advance_args, (0.0, 0.0, 0))
        kernel_ns += clock_ns(THREAD_CPU) - cpu0
        if checking:
            clock[6], clock[7], clock[8], counters[3], counters[4] = strain, s, work, inverted, 1
            if _energy_check_fails(kinetic, strain, inverted, bad, work, energy, watch):
                outcome = CHECK
        if outcome == DONE:
            outcome = call_compiled(addresses[2], (s, work, kinetic, bad), after_args, 0)
        time = time + dt
        step_count += 1
        steps += 1
        if timed:
            step_wall = (clock_ns(MONOTONIC) - wall0) / 1e9
    clock[0], clock[5], counters[0] = time, step_wall, step_count
    return steps, outcome, kinetic, bad, kernel_ns


class CompiledSubsteps:
    """A scene's substeps through :func:`run_slice` with :func:`after_approach_step` or
    :func:`after_inside_step` (module docstring); one per scene. Each ``Scene.advance`` call
    :meth:`begin` s with its needle's move (from ``start`` by ``move``); :meth:`ready` says whether
    the coming substep can run so, :meth:`run` runs it and the next ones it can, and
    :meth:`invalidate` follows any other substep (the arguments are gathered again: they may have
    changed). ``counts``: substeps run so by (mode, outcome), for tests and profiles."""

    def __init__(self, scene):
        self.sim, self.needle = scene.simulation, scene.needle
        self.start, self.move = np.zeros(3), np.zeros(3)
        self.energy = np.zeros(1)
        self.state = np.zeros(2, dtype=np.int64)
        self.results = np.zeros(9)
        self.patch_work = np.zeros(1)
        self.clock = np.zeros(9)
        self.counters = np.zeros(5, dtype=np.int64)
        self.counts: dict = {}
        self._key, self._calls = None, None
        self._functions: dict = {}          # (kernel, step after, energy) -> (addresses, checks) (_functions_for)

    def __getstate__(self):
        """Pickled (a scene copied to a prediction worker) without what holds addresses of
        compiled code: they are this process's; the copy finds its own at its first gather."""
        state = dict(self.__dict__)
        state.update(_key=None, _calls=None, _functions={})
        return state

    def begin(self, start, move):
        self.start[:], self.move[:] = start, move
        self._key = None

    def invalidate(self):
        self._key = None

    def ready(self) -> bool:
        sim, needle = self.sim, self.needle
        if not (sim.reference_energy is not None and sim.model.topology_version == sim._topology_version):
            return False
        if needle._touching():
            contact, patch = needle.tip_contact, needle.patch
            needle._inverse_mass()                     # (new masses: a new generation, set below)
            mode = (_CONTACT if patch is not None and contact is not None and contact.active and contact.on_surface
                    and not needle.n_points and needle.phase == 'contact'
                    and patch.scale_generation == needle._mass_generation else None)
        elif needle.n_points:
            mode = _INSIDE if needle.compiled_inside else None
        else:
            mode = _OUTSIDE if needle.phase == 'approach' and not needle._forces_applied else None
        if mode is None:
            return False
        key = (mode, sim.mass_version, sim.dt, needle.region, id(needle.patch))
        if key != self._key:
            self._key, self._calls = key, self._gather(mode)
        return self._calls is not None

    def _functions_for(self, kernel, kernel_args, advance_args, after_step, after_args, energy, energy_args):
        """(addresses, checks) of the kernel's, the node update's, the step after's and the strain
        energy's code (compiled_call.compiled_address), found at the first gather with them: typing
        the arguments again at each advance cost 300-650 us. A scene's arguments keep their types
        (its arrays keep their dtypes and shapes' ranks when reallocated); were one to change,
        run_slice refuses the call and :meth:`run` finds the code for the new types."""
        value = self._functions.get((kernel, after_step, energy))
        if value is None:
            found = (compiled_address(kernel, kernel_args, types.none),
                     compiled_address(_advance_free, advance_args, _ADVANCE_RETURNS),
                     compiled_address(after_step, (0.5, 0.0, 0.0, 0) + after_args, types.int64),
                     compiled_address(energy, energy_args, _ENERGY_RETURNS))
            value = self._functions[(kernel, after_step, energy)] = (
                np.array([f[0] for f in found], dtype=np.int64), np.array([f[1] for f in found], dtype=np.int64))
        return value

    def _gather(self, mode):
        sim, needle = self.sim, self.needle
        forces = sim.model.force_pass_call(sim.displacement, sim.velocity)
        energy = sim.model.strain_energy_call(sim.displacement)
        if forces is None or energy is None:
            return None
        inverse_mass = needle._inverse_mass()
        needle.contact_force[:] = 0.0
        geometry = needle.geometry
        watch = np.array([sim.energy_limit_factor(), sim.reference_energy, sim.energy_floor,
                          float(sim.refuses_inverted())])
        advance = sim.advance_arguments()
        common = (self.start, self.move, self.energy, watch)
        if mode == _CONTACT:
            after_step = after_contact_step
            patch, contact = needle.patch, needle.tip_contact
            membrane = needle.regions[patch.region].membrane
            rupture = np.array([0.0 if membrane.criterion == 'force' else 1.0, membrane.rupture_force_n,
                                membrane.rate_exponent, membrane.reference_speed_m_s,
                                membrane.rupture_work_j(geometry.diameter_m)])
            after = common + (needle.position, needle.axis, needle._previous_position, needle._previous_axis,
                              geometry.length_m, sim.dt, needle._tip, needle._travel, needle._base_velocity,
                              needle._axis_rate, needle.contact_force, needle.rest, sim.displacement, sim.velocity,
                              inverse_mass, needle._force_scale, needle.rotation, patch.offsets, patch.targets,
                              patch.nodes, patch.weights, patch.pseudo_inverse, patch.residual, patch.multipliers,
                              patch.sample_scale, patch.sample_forces, patch.total, self.patch_work, rupture,
                              needle.surface_triangles, needle.surface_boxes, needle.surface_nodes, contact.offsets,
                              contact.engaged, contact.new, contact.reach, geometry.diameter_m,
                              *contact.surface_scratch(needle.surface_triangles), contact.nodes, contact.weights,
                              needle.applied_forces, needle._applied_points, needle._applied_point_forces,
                              needle.wrench_force, needle.wrench_torque)
        elif mode == _OUTSIDE:
            after_step = after_approach_step
            after = common + (needle.rest, sim.displacement, needle.surface_triangles, needle.surface_boxes,
                              needle.surface_nodes, needle.position, needle.axis, needle._previous_position,
                              needle._previous_axis, geometry.length_m, geometry.diameter_m, sim.dt, needle._tip,
                              needle._travel, needle._base_velocity, needle._axis_rate, needle._ray_origin,
                              needle._applied_points, needle._applied_point_forces, needle.wrench_force,
                              needle.wrench_torque)
        else:
            after_step = after_inside_step if needle.rod is None else after_rod_inside_step
            selectors = needle.selectors
            kinds, params, tags = ((np.zeros(0, dtype=np.int64), np.zeros((0, 6)), np.zeros(0, dtype=np.int64))
                                   if selectors is None else (selectors.kinds, selectors.params, selectors.tags))
            decide = np.array([needle._release_beyond, geometry.length_m, geometry.shaft_point_spacing_m,
                               float(needle.region)])
            after = common + (needle.position, needle.axis, needle._previous_position, needle._previous_axis,
                              geometry.length_m, needle._tip, needle._apex_rest, self.state, decide, kinds, params,
                              tags, needle.element_region, self.results,
                              needle.inserted_arguments(inverse_mass, sim.dt))
        return (*self._functions_for(forces[0], forces[1], advance, after_step, after, *energy), forces[1], advance,
                after_step, after, energy[1], watch, inverse_mass)

    def run(self, start_t, end_t, max_steps, deadline, step_wall, found_again=False):
        """The coming substep (``ready()`` said it can run) and the next ones :func:`run_slice`
        can run, toward target time ``end_t`` from ``start_t`` (``Scene.advance``'s), at most
        ``max_steps`` (None: no limit), none to start past ``deadline`` (None: none) by the last
        one's wall time ``step_wall``. Returns (substeps run, the last one's wall time [s])."""
        sim, needle = self.sim, self.needle
        (addresses, checks, kernel_args, advance_args, after_step, after_args, energy_args, watch,
         inverse_mass) = self._calls
        clock, counters = self.clock, self.counters
        clock[:6] = (sim.time, sim.dt, start_t, end_t, np.inf if deadline is None else deadline, step_wall)
        counters[:] = (sim.step_count, sim.check_interval, -1 if max_steps is None else max_steps, 0, 0)
        self.energy[0] = sim.input_work
        inside = after_step is after_inside_step or after_step is after_rod_inside_step
        if inside:
            self.state[0], self.state[1] = needle.apex_element, needle._forces_applied
        elif after_step is after_contact_step:
            self.patch_work[0] = needle.patch.work
        steps, outcome, kinetic, bad, kernel_ns = run_slice(addresses, checks, kernel_args, advance_args, after_args,
                                                            energy_args, self.energy, watch, clock, counters)
        if outcome == REFUSED:        # an argument's type changed: the functions' code for the new ones
            if found_again:
                raise RuntimeError('compiled substeps: the functions found for the arguments do not take them')
            self._functions.clear()
            self._calls = self._gather(self._key[0])
            return self.run(start_t, end_t, max_steps, deadline, step_wall, found_again=True)
        sim.input_work = self.energy[0]
        sim.kinetic_energy = kinetic
        sim.time = float(clock[0])
        sim.step_count = int(counters[0])
        sim.kernel_s += kernel_ns * 1e-9
        mode = self._key[0]
        self.counts[(mode, DONE)] = self.counts.get((mode, DONE), 0) + steps - (outcome != DONE)
        if outcome != DONE:
            self.counts[(mode, outcome)] = self.counts.get((mode, outcome), 0) + 1
        if outcome == DIVERGED:
            sim.watch(bad, kinetic)        # raises SimulationDiverged, as Simulation.step would
        if outcome == CHECK:
            self._failed_check(bad)
        if counters[4]:                    # the last step was an energy-check step, passed
            sim.note_safeguarded()
            self.counts[(mode, 'checked')] = self.counts.get((mode, 'checked'), 0) + 1
        if after_step is after_contact_step:
            self._after_contact_slice(outcome, inverse_mass)
            return steps, float(clock[5])
        if not inside:
            needle.friction_force = needle.cutting_force = 0.0
            needle.n_applied = 0
            if outcome == DONE or steps > 1:
                needle.surface_point = None
            if outcome == TAIL:
                needle.after_kinematics(inverse_mass, sim.dt)
                self._key = None
            return steps, float(clock[5])
        results = self.results
        needle.friction_force, needle.cutting_force = float(results[0]), float(results[1])
        needle.n_tip, needle.n_applied = int(results[2]), int(results[3])
        needle._forces_applied = False
        needle.apex_element = int(self.state[0])
        if outcome == TAIL:
            needle.after_inserted_step(inverse_mass, sim.dt, int(results[5]), float(results[6]), float(results[7]),
                                       float(results[8]))
            self._key = None
        else:
            needle.phase = 'retracting' if results[8] < -1e-9 else 'inserted'
        return steps, float(clock[5])

    def _failed_check(self, bad):
        """A slice's energy-check step that failed: the needle moved for it (not stepped) and the
        step's tissue work put in, as before Simulation.step's check, which then raises."""
        sim, clock = self.sim, self.clock
        position = np.multiply(self.move, clock[7])
        position += self.start
        self.needle.set_pose(position)
        sim.input_work += clock[8]
        sim.watch(bad, None)
        sim._check_energy(float(clock[6]), int(self.counters[3]))
        raise RuntimeError('compiled substeps: an energy check failed that Simulation passes')

    def _after_contact_slice(self, outcome, inverse_mass):
        """The needle's Python state after a slice of contact steps, and the Python's part of its
        last step (TAIL: from the kinematics on; ENGAGED: from the samples' engaging on)."""
        sim, needle = self.sim, self.needle
        needle.friction_force = needle.cutting_force = 0.0
        needle.patch.work = float(self.patch_work[0])
        if outcome == TAIL:
            needle.n_applied = 0
            needle.after_kinematics(inverse_mass, sim.dt)
            self._key = None
            return
        needle.n_applied = len(needle.patch.offsets)
        if outcome == ENGAGED:
            needle.after_engaging(inverse_mass, sim.dt)
            self._key = None
        else:
            needle._forces_applied = True
