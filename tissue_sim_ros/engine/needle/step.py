"""The step of a needle inside the tissue in one compiled call.

Once the needle is in (phases ``inserted`` and ``retracting``, no membrane contact), every step
runs the same sequence, :meth:`.interaction.NeedleTissue.after_step` in order: the needle's
kinematics, the shaft's lateral hold and friction (:func:`~.kernels.shaft_solve`), the cutting
samples found again under the end (:func:`~.kernels.follow_rigid_samples`), a sharp tip's faces
pushing the displaced tissue aside (:func:`~.tip.tip_contact_solve`), the cutting law on the
samples, the reaction wrench with the work the needle put in, and the walk that finds the tip's
apex in the deformed mesh. As a dozen Python calls into numba, the calls and the Python between
them would cost about half as much again as the kernels themselves; here the sequence is one
call to the same kernels in the same order, so the forces are the same to the last bit. What
the Python after it decides on the outcome (shaft points released behind the tip, the layer of
the apex's material point, a new membrane met, a new shaft point) reads the floats returned;
:mod:`~tissue_sim_ros.engine.compiled.substeps` calls it from compiled code and decides the
common outcome (nothing to do) there, handing the other steps to that Python.
"""
import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle.kernels import (follow_rigid_samples, locate_walk, needle_kinematics,
                                                  put_axis_points, put_rigid_points, put_rows, shaft_solve,
                                                  wrench_about)
from tissue_sim_ros.engine.needle.tip import take_found, tip_contact_solve

__all__ = ['close_step', 'cut_at_tip', 'inserted_step', 'take_work']


@njit(cache=True)
def inserted_step(rest, displacement, velocity, inverse_mass, force_scale, tetrahedra, neighbours,
                  element_boxes, mesh_nodes, position, axis, previous_position, previous_axis, rotation, length, dt,
                  tip, travel, base_velocity, axis_rate,
                  point_nodes, point_weights, n_points, friction_law, free_beyond, closing_m,
                  point_offsets, point_forces, point_depths, point_shares,
                  sample_offsets, sample_elements, tip_offsets, tip_nodes, tip_weights, walk_weights, candidates,
                  near_boxes, cutting_force_n, cutting_law, tip_forces, tip_depths, unit_shares, no_offsets,
                  faces_cut, engaged, new, face_nodes, face_weights, face_params, face_forces, face_points,
                  face_total,
                  applied_forces, applied_points, applied_point_forces, wrench_force, wrench_torque,
                  apex_weights, apex_rest, sparse, apex_start, clear_first):
    """One step of the inserted needle (module docstring). The arrays are NeedleTissue's (shaft
    points, cutting samples, and with ``faces_cut`` a sharp tip's contact); ``applied_forces``
    is filled (cleared first with ``clear_first``, else it must hold zeros). With ``sparse`` the
    work is summed over the nodes the needle pushed, which are then zeroed again (the array
    holds zeros after the call: no pass over the whole mesh, 3 us a step on the default scene);
    without, it keeps the forces and the work is a dot product over the whole array. The tip's
    apex is walked to from element ``apex_start`` (< 0: not walked), its weights in
    ``apex_weights`` and its rest coordinates in ``apex_rest``. (The two arguments that change
    from step to step come last: the rest are :meth:`.interaction.NeedleTissue.inserted_arguments`.)
    Returns (friction force, cutting force, cutting samples found, points of action written, work
    of the needle's forces over the step [J], the apex's element (locate_walk: -1 outside, -2 not
    found), the tip's travel along the axis [m], the deepest shaft point's axial coordinate [m],
    the base's speed along the axis [m/s]): what the Python that follows decides on."""
    if clear_first:
        applied_forces[:] = 0.0
    needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel,
                      base_velocity, axis_rate)
    friction = shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights,
                           n_points, position, axis, rotation, base_velocity, axis_rate, dt, length, friction_law,
                           2, free_beyond, closing_m, point_offsets, point_forces, point_depths, point_shares,
                           applied_forces)
    put_axis_points(position, axis, point_depths, n_points, applied_points, 0)
    put_rows(point_forces, n_points, applied_point_forces, 0)
    n_applied = n_points
    cutting, n_tip, n_applied = cut_at_tip(
        rest, displacement, velocity, inverse_mass, force_scale, tetrahedra, neighbours, element_boxes, mesh_nodes,
        tip, rotation, position, axis, base_velocity, axis_rate, dt, sample_offsets, sample_elements, tip_offsets,
        tip_nodes, tip_weights, walk_weights, candidates, near_boxes, cutting_force_n, cutting_law, tip_forces,
        tip_depths, unit_shares, no_offsets, faces_cut, engaged, new, face_nodes, face_weights, face_params,
        face_forces, face_points, face_total, applied_forces, applied_points, applied_point_forces, n_applied)
    return (friction, cutting, n_tip, n_applied) + close_step(
        rest, displacement, velocity, tetrahedra, neighbours, position, axis, axis, dt, tip, travel, base_velocity,
        point_nodes, n_points, point_depths, tip_nodes, n_tip, faces_cut, face_nodes, applied_forces, applied_points,
        applied_point_forces, n_applied, wrench_force, wrench_torque, apex_weights, apex_rest, sparse, apex_start)


@njit(cache=True)
def cut_at_tip(rest, displacement, velocity, inverse_mass, force_scale, tetrahedra, neighbours, element_boxes,
               mesh_nodes, tip, frame, base, along, base_velocity, axis_rate, dt, sample_offsets, sample_elements,
               tip_offsets, tip_nodes, tip_weights, walk_weights, candidates, near_boxes, cutting_force_n,
               cutting_law, tip_forces, tip_depths, unit_shares, no_offsets, faces_cut, engaged, new, face_nodes,
               face_weights, face_params, face_forces, face_points, face_total, applied_forces, applied_points,
               applied_point_forces, n_applied):
    """The tip's part of an inside step, in the tip's ``frame`` (rotation) on the line ``base`` +
    s ``along`` moving at ``base_velocity`` and turning at ``axis_rate``: the cutting samples found
    again under the end, a sharp tip's faces pushing the displaced tissue aside, the cutting law on
    the samples, their points of action from row ``n_applied``. The rigid needle's frame is its
    own; a flexible one's the rod's tip (:mod:`.rod_step`). Returns (cutting force, cutting
    samples found, points of action written)."""
    n_tip = follow_rigid_samples(rest, displacement, tetrahedra, neighbours, element_boxes, mesh_nodes, tip,
                                 frame, sample_offsets, sample_elements, tip_offsets, tip_nodes, tip_weights,
                                 walk_weights, candidates, near_boxes)
    if faces_cut:
        n_faces = engaged.shape[0]
        take_found(sample_elements, tip_nodes, tip_weights, engaged, new, face_nodes, face_weights)
        tip_contact_solve(rest, displacement, velocity, inverse_mass, force_scale, face_nodes, face_weights,
                          engaged, cutting_force_n / n_faces, face_params, tip, frame, dt, 2, face_forces,
                          face_points, applied_forces, face_total)
        put_rows(face_points, n_faces, applied_points, n_applied)
        put_rows(face_forces, n_faces, applied_point_forces, n_applied)
        n_applied += n_faces
    cutting = 0.0
    if n_tip:
        cutting_law[0] = cutting_force_n / n_tip
        cutting = shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, tip_nodes, tip_weights,
                              n_tip, base, along, frame, base_velocity, axis_rate, dt, 0.0, cutting_law, 0,
                              np.inf, 0.0, no_offsets, tip_forces, tip_depths, unit_shares, applied_forces)
        put_rigid_points(tip, frame, tip_offsets, n_tip, applied_points, n_applied)
        put_rows(tip_forces, n_tip, applied_point_forces, n_applied)
        n_applied += n_tip
    return cutting, n_tip, n_applied


@njit(cache=True)
def close_step(rest, displacement, velocity, tetrahedra, neighbours, position, axis, along, dt, tip, travel,
               base_velocity, point_nodes, n_points, point_depths, tip_nodes, n_tip, faces_cut, face_nodes,
               applied_forces, applied_points, applied_point_forces, n_applied, wrench_force, wrench_torque,
               apex_weights, apex_rest, sparse, apex_start):
    """The end of an inside step: the work the needle's forces put in over it (module docstring of
    :func:`inserted_step` on ``sparse``), the reaction wrench about the base ``position``, the
    walk to the tip's apex, the tip's travel along ``along`` (the rigid needle's ``axis``, a
    flexible one's tip axis) and the base's speed along ``axis``, the deepest shaft point.
    Returns (work [J], apex element, travel along [m], deepest [m], speed along [m/s])."""
    if sparse:
        work = take_work(applied_forces, velocity, point_nodes, n_points)
        if faces_cut:
            work += take_work(applied_forces, velocity, face_nodes, face_nodes.shape[0])
        work += take_work(applied_forces, velocity, tip_nodes, n_tip)
    else:
        work = np.vdot(applied_forces.reshape(-1), velocity.reshape(-1))
    wrench_about(applied_points, applied_point_forces, n_applied, position, wrench_force, wrench_torque)
    apex = -2
    if apex_start >= 0:
        apex = locate_walk(rest, displacement, tetrahedra, neighbours, apex_start, tip, 64, apex_weights)
        if apex >= 0:
            for r in range(3):
                x = 0.0
                for k in range(4):
                    x += apex_weights[k] * rest[tetrahedra[apex, k], r]
                apex_rest[r] = x
    travel_along = 0.0
    speed_along = 0.0
    for r in range(3):
        travel_along += travel[r] * along[r]
        speed_along += base_velocity[r] * axis[r]
    deepest = -np.inf
    for k in range(n_points):
        deepest = max(deepest, point_depths[k])
    return work * dt, apex, travel_along, deepest, speed_along


@njit(cache=True)
def take_work(applied_forces, velocity, nodes, n_rows):
    """Sum of f . v over the nodes of ``nodes[:n_rows]``, each node's force zeroed once counted
    (a node in several rows counts once)."""
    work = 0.0
    for s in range(n_rows):
        for k in range(nodes.shape[1]):
            i = nodes[s, k]
            for r in range(3):
                work += applied_forces[i, r] * velocity[i, r]
                applied_forces[i, r] = 0.0
    return work
