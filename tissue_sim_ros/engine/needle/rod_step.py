"""The step of a flexible needle inside the tissue in one compiled call.

:func:`rod_inserted_step` is :func:`~.step.inserted_step` with the elastic shaft
(:mod:`.rod_coupling`): the needle's kinematics at the base, the guide up to the entry, the rod
and the shaft's points solved together with friction along the rod, the tip's frame from the
rod, then the tip's kernels in that frame (cutting samples found again, a sharp tip's faces
pushing the tissue aside, the cutting law), the reaction wrench with the work the needle put in,
the tip's loads on the rod for the next step and the walk that finds the apex. It takes
``inserted_step``'s arguments with the rod's inserted before the last two and returns the same
floats, so :meth:`.interaction.NeedleTissue.after_inserted_step` and the compiled substeps
(:mod:`~tissue_sim_ros.engine.compiled.rod_substeps`) decide on it as on the rigid needle's.
"""
import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle.kernels import needle_kinematics, put_rows
from tissue_sim_ros.engine.needle.rod_coupling import (add_tip_loads, centreline_points, guide_nodes,
                                                       rod_shaft_solve, tip_frame)
from tissue_sim_ros.engine.needle.step import close_step, cut_at_tip

__all__ = ['ROD_SWEEPS', 'rod_shaft_step', 'rod_inserted_step']

#: Newton steps of the rod with the points' projection, per step (rod_coupling)
ROD_SWEEPS = 2


@njit(cache=True)
def rod_shaft_step(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights, n_points,
                   position, axis, previous_position, rotation, length, dt, tip, travel, friction_law, free_beyond,
                   closing_m, point_offsets, point_forces, point_depths, point_shares, applied_forces, applied_points,
                   applied_point_forces, start, nodes, previous, h, radius, bending, axial, loads, frames, gradient,
                   band, step, before, scratch, held, point_stiffness, point_pull, node_share, point_segments,
                   point_fractions, tip_rotation, tip_axis, virtual_base, tip_velocity):
    """The shaft's part of the step, after the base's kinematics: the guide up to the entry (the
    shallowest point), the rod and the points solved together with friction
    (:func:`~.rod_coupling.rod_shaft_solve`), the tip's frame from the rod (``tip``, ``travel``
    and the tip's arrays written) and the points' forces and points of action from row
    ``start`` of the applied lists. Returns the friction force."""
    previous[:] = nodes
    entry = np.inf
    for k in range(n_points):
        entry = min(entry, point_depths[k])
    first_free = guide_nodes(nodes, position, axis, previous_position, h, entry)
    friction = rod_shaft_solve(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights,
                               n_points, nodes, previous, first_free, position, rotation, axis, entry, radius, h,
                               bending, axial, loads, frames, gradient, band, step, before, scratch, held,
                               point_stiffness, point_pull, node_share, dt, length, friction_law, ROD_SWEEPS,
                               free_beyond, closing_m, point_offsets, point_forces, point_depths, point_shares,
                               point_segments, point_fractions, applied_forces)
    tip_frame(nodes, previous, frames, length, dt, tip, tip_rotation, tip_axis, virtual_base, tip_velocity, travel)
    centreline_points(nodes, point_segments, point_fractions, n_points, applied_points, start)
    put_rows(point_forces, n_points, applied_point_forces, start)
    return friction


@njit(cache=True)
def rod_inserted_step(rest, displacement, velocity, inverse_mass, force_scale, tetrahedra, neighbours,
                      element_boxes, mesh_nodes, position, axis, previous_position, previous_axis, rotation, length,
                      dt, tip, travel, base_velocity, axis_rate,
                      point_nodes, point_weights, n_points, friction_law, free_beyond, closing_m,
                      point_offsets, point_forces, point_depths, point_shares,
                      sample_offsets, sample_elements, tip_offsets, tip_nodes, tip_weights, walk_weights,
                      candidates, near_boxes, cutting_force_n, cutting_law, tip_forces, tip_depths, unit_shares,
                      no_offsets, faces_cut, engaged, new, face_nodes, face_weights, face_params, face_forces,
                      face_points, face_total,
                      applied_forces, applied_points, applied_point_forces, wrench_force, wrench_torque,
                      apex_weights, apex_rest, sparse,
                      nodes, previous, h, radius, bending, axial, loads, frames, gradient, band, step, before,
                      scratch, held, point_stiffness, point_pull, node_share, point_segments, point_fractions,
                      tip_rotation, tip_axis, virtual_base, tip_velocity, no_rate,
                      apex_start, clear_first):
    """One step of the inserted flexible needle (module docstring); the arguments are
    :func:`~.step.inserted_step`'s and, before the last two, the rod's
    (:meth:`.interaction.NeedleTissue.inserted_arguments`). Returns inserted_step's nine
    values, the travel along the tip's axis."""
    if clear_first:
        applied_forces[:] = 0.0
    needle_kinematics(position, axis, previous_position, previous_axis, length, dt, tip, travel,
                      base_velocity, axis_rate)
    friction = rod_shaft_step(rest, displacement, velocity, inverse_mass, force_scale, point_nodes, point_weights,
                              n_points, position, axis, previous_position, rotation, length, dt, tip, travel,
                              friction_law, free_beyond, closing_m, point_offsets, point_forces, point_depths,
                              point_shares, applied_forces, applied_points, applied_point_forces, 0, nodes, previous,
                              h, radius, bending, axial, loads, frames, gradient, band, step, before, scratch, held,
                              point_stiffness, point_pull, node_share, point_segments, point_fractions, tip_rotation,
                              tip_axis, virtual_base, tip_velocity)
    n_applied = n_points
    cutting, n_tip, n_applied = cut_at_tip(
        rest, displacement, velocity, inverse_mass, force_scale, tetrahedra, neighbours, element_boxes, mesh_nodes,
        tip, tip_rotation, virtual_base, tip_axis, tip_velocity, no_rate, dt, sample_offsets, sample_elements,
        tip_offsets, tip_nodes, tip_weights, walk_weights, candidates, near_boxes, cutting_force_n, cutting_law,
        tip_forces, tip_depths, unit_shares, no_offsets, faces_cut, engaged, new, face_nodes, face_weights,
        face_params, face_forces, face_points, face_total, applied_forces, applied_points, applied_point_forces,
        n_applied)
    add_tip_loads(nodes, loads, applied_points, applied_point_forces, n_points, n_applied, scratch)
    return (friction, cutting, n_tip, n_applied) + close_step(
        rest, displacement, velocity, tetrahedra, neighbours, position, axis, tip_axis, dt, tip, travel,
        base_velocity, point_nodes, n_points, point_depths, tip_nodes, n_tip, faces_cut, face_nodes, applied_forces,
        applied_points, applied_point_forces, n_applied, wrench_force, wrench_torque, apex_weights, apex_rest,
        sparse, apex_start)
