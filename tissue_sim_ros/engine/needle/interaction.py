"""A rigid needle against the tissue: contact, puncture, cutting, friction, reaction wrench.

The needle is a straight rigid cylinder given by the pose of its base frame (position, unit
quaternion x y z w); its axis is the frame's +z and the tip is at +z * length
(docs/scene-guide.md, "Needle and tip shapes"). The
tissue is a :class:`~tissue_sim_ros.engine.solver.explicit.Simulation`. Each time step the scene moves the needle
(:meth:`NeedleTissue.set_pose`), calls ``Simulation.step`` and then
:meth:`NeedleTissue.after_step`, which applies the needle's constraints and forces as follows
(or, in the common cases, runs the same kernels in one compiled call after the force kernel:
:mod:`~tissue_sim_ros.engine.compiled.substeps`).

Material points. The needle acts on *material points* of the tissue: a point inside an element
(barycentric weights over its 4 nodes) or on a surface triangle (3 nodes), located once in the
deformed mesh and then carried by the tissue. A force on a point goes to its nodes by the same
weights, so elements larger than the needle are handled, and the needle's footprint is resolved
as soon as the mesh is finer than it.

Contact and puncture (phase ``contact``): :mod:`~tissue_sim_ros.engine.needle.membrane`. The
end touches the surface (or, inside, a layer with a membrane) and holds it until the membrane
ruptures by the region's criterion; then the needle is inside.

Inside (phases ``inserted``, ``retracting``): :mod:`~tissue_sim_ros.engine.needle.inside`.
Shaft points carried by the tissue hold it on the axis and drag it by friction; the end cuts its
way in; the tip's apex meets the layers, which are surfaces.

Reaction wrench. Every force the needle puts on the tissue is recorded with its point of action
on the needle; the wrench on the needle is their negative sum, and the torque about the base
origin is sum (r - p) x (-f). Both are available in the world or the needle frame.

The other needle modules: :mod:`~tissue_sim_ros.engine.needle.pose` (pose maths, pose rules),
:mod:`~tissue_sim_ros.engine.needle.parameters` (geometry, membrane, friction),
:mod:`~tissue_sim_ros.engine.needle.kernels` (numba kernels),
:mod:`~tissue_sim_ros.engine.needle.membrane` (contact and puncture),
:mod:`~tissue_sim_ros.engine.needle.inside` (shaft points, friction, cutting, layers),
:mod:`~tissue_sim_ros.engine.needle.contact` (a flat end's bonded contact) and
:mod:`~tissue_sim_ros.engine.needle.tip` (sharp tips). Their public names are re-exported here.
"""
import math

import numpy as np

from tissue_sim_ros.engine.solver.implicit_bonds import BondRows
from tissue_sim_ros.engine.mesh.tetmesh import element_neighbours, face_elements
from tissue_sim_ros.engine.needle.contact import disc_offsets
from tissue_sim_ros.engine.needle.kernels import (applied_work, cell_boxes, first_surface_hit, locate_point,
                                                  needle_kinematics, put_axis_points, put_rigid_points, put_rows,
                                                  shaft_solve, wrench_about)
from tissue_sim_ros.engine.needle.inside import InsideTissue
from tissue_sim_ros.engine.needle.membrane import MembraneContact
from tissue_sim_ros.engine.needle.rod_coupling import RodState, add_tip_loads
from tissue_sim_ros.engine.needle.shaft import NeedleShaft
from tissue_sim_ros.engine.needle.parameters import (Friction, Membrane, NeedleGeometry, RegionInteraction,
                                                     TipShape)
from tissue_sim_ros.engine.needle.tip import SharpTipContact, tip_length, tip_samples
from tissue_sim_ros.engine.needle.pose import (QUATERNION_NORM_TOLERANCE, needle_axis, pose_jump,
                                               rotation_matrix, slerp, validate_pose)
from tissue_sim_ros.errors import PoseError

__all__ = ['PHASES', 'NeedleTissue', 'PoseError', 'Friction', 'Membrane', 'RegionInteraction',
           'NeedleGeometry', 'TipShape', 'QUATERNION_NORM_TOLERANCE', 'rotation_matrix', 'slerp', 'validate_pose',
           'first_surface_hit', 'locate_point']

PHASES = ('approach', 'contact', 'inserted', 'retracting')


class NeedleTissue(NeedleShaft, InsideTissue, MembraneContact):
    """The needle-tissue interaction state of one scene (see the module docstring).

    simulation: the tissue's Simulation. element_region: (m,) region index of each element.
    regions: list of RegionInteraction, by region index. geometry: NeedleGeometry. selectors: the
    scene's RegionSelectors (where the layers are; None: each element's region is its own).
    """

    def __init__(self, simulation, element_region, regions, geometry, position, orientation, selectors=None,
                 name='needle'):
        self.simulation = simulation
        self.selectors = selectors
        self.mesh = simulation.model.mesh
        self.element_region = np.asarray(element_region, dtype=np.int64)
        self.regions = list(regions)
        self.geometry = geometry
        self.tetrahedra = np.ascontiguousarray(simulation.model.tetrahedra, dtype=np.int64)
        self.rest = self.mesh.rest_positions
        self._surface_owner()
        self.sharp = geometry.tip.shape != 'flat'
        # the cutting samples: the end's disc, or points over a sharp tip's surface
        self.disc_offsets = (tip_samples(0.5 * geometry.diameter_m, geometry.tip)[0] if self.sharp
                             else disc_offsets(0.5 * geometry.diameter_m))
        self.tip_contact = SharpTipContact(0.5 * geometry.diameter_m, geometry.tip) if self.sharp else None
        capacity = int(math.ceil(geometry.length_m / geometry.shaft_point_spacing_m)) + 16
        self.point_nodes = np.zeros((capacity, 4), dtype=np.int64)
        self.point_weights = np.zeros((capacity, 4))
        self.point_forces = np.zeros((capacity, 3))
        self.point_depths = np.zeros(capacity)
        self.point_offsets = np.zeros((capacity, 3))   # lateral, needle frame (shaft_solve)
        self.point_shares = np.zeros(capacity)
        #: the elastic shaft (engine.needle.rod_coupling), or None: rigid and straight
        self.rod = None if geometry.shaft is None else RodState(geometry.diameter_m, geometry.length_m,
                                                                geometry.shaft, capacity, self.mesh.n_nodes)
        self._rod_rows = 0                     # the shaft points' rows of the applied lists this step
        self.applied_forces = np.zeros((self.mesh.n_nodes, 3))
        n_disc = len(self.disc_offsets)
        self.tip_nodes = np.zeros((n_disc, 4), dtype=np.int64)     # cutting: material points at the tip
        self.tip_weights = np.zeros((n_disc, 4))
        self.tip_offsets = np.zeros((n_disc, 3))
        self.tip_forces = np.zeros((n_disc, 3))
        self.tip_depths = np.zeros(n_disc)
        self._unit_shares = np.ones(n_disc)
        self._no_offsets = np.zeros((n_disc, 3))
        # shaft points further than this from the base lie along a sharp tip's faces (not held)
        # and the tissue they pushed aside closes around the shaft over one tip length behind it
        self._closing_m = tip_length(0.5 * geometry.diameter_m, geometry.tip)
        self._free_beyond = geometry.length_m - self._closing_m if self.sharp else math.inf
        self.tip_elements = np.full(n_disc, -1, dtype=np.int64)   # where each sample was last found
        self._candidates = np.zeros(len(self.tetrahedra), dtype=np.int64)   # elements near the tip
        self._near_boxes = np.zeros((len(self.tetrahedra), 6))              # and their deformed boxes
        self._weights = np.zeros(4)
        self._apex_weights = np.zeros(4)
        self._apex_rest = np.zeros(3)
        # a shaft point deeper than this (from the base) is behind the tip, released going back
        self._release_beyond = geometry.length_m + 0.5 * geometry.shaft_point_spacing_m
        # the cutting law in shaft_solve's terms: static limit per sample (set per step), push only
        self._cutting_law = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, np.inf, 0.0, 0.0])
        self._friction_laws = [r.friction.as_array() for r in self.regions]
        # per-step work arrays (no allocation in the step loop)
        self._tip = np.zeros(3)
        self._travel = np.zeros(3)              # tip travel over the last step
        self._base_velocity = np.zeros(3)
        self._axis_rate = np.zeros(3)
        self._ray_origin = np.zeros(3)
        self.contact_force = np.zeros(3)
        self.wrench_force = np.zeros(3)         # world frame, on the needle, about the base origin
        self.wrench_torque = np.zeros(3)
        self._reserve_applied(capacity + 2 * n_disc)
        # the arrays the compiled inside step takes for a sharp tip's faces (a flat end's: unused ones)
        self._faces = self.tip_contact if self.sharp else SharpTipContact(0.5 * geometry.diameter_m,
                                                                          TipShape('conical', 30.0))
        #: run the inside step as one compiled call (False: the general path, the same kernels)
        self.compiled_inside = True
        self._mass_generation = 0
        self._initial_pose = validate_pose(position, orientation, f'{name}.initial_pose')
        self._bonds_in_solve = None         # the patch an implicit step held this step (implicit_bonds)
        self._patch_rows_of = None
        # the tissue's velocity before the needle's corrections (after_step, implicit integrators)
        self._velocity_before = np.zeros((self.mesh.n_nodes, 3)) if simulation.integrator != 'explicit' else None
        simulation.couplings.append(self)
        self.reset()
        self._check_outside(*self._initial_pose, f'{name}.initial_pose')

    def set_start(self, position, orientation, field_name='start'):
        """Make (position, orientation) the pose the needle starts from and resets to, and put it
        there (a registration: the needle starts where the robot holds it). PoseError unless the
        needle is out of the tissue now (phase ``approach``, touching nothing) and the new pose lies
        outside the (deformed) tissue: a needle cannot be put into or taken out of tissue."""
        position, orientation = validate_pose(position, orientation, field_name)
        if self.phase != 'approach' or self.n_points or self.patch is not None:
            raise PoseError(field_name, {'position': position.tolist(), 'orientation': orientation.tolist()},
                            f'the needle is in contact with the tissue (phase {self.phase}); a needle is '
                            'placed only while it is out of the tissue: ~/reset first')
        self._check_outside(position, orientation, field_name)
        self._initial_pose = (position, orientation)
        self.reset()

    # -- set-up --------------------------------------------------------------------------------
    def _surface_owner(self):
        """Surface triangles and the element each belongs to (for the membrane of the region hit)."""
        triangles = self.mesh.surface_triangles()
        self.surface_triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self.surface_nodes = np.unique(self.surface_triangles)
        self.surface_boxes = cell_boxes(self.rest, self.surface_triangles)
        self.element_boxes = cell_boxes(self.rest, self.tetrahedra)      # the searches near the tip
        self.mesh_nodes = np.arange(self.mesh.n_nodes)
        self.surface_owner = face_elements(self.tetrahedra, triangles, self.mesh.n_nodes)
        self._neighbours = element_neighbours(self.tetrahedra, self.mesh.n_nodes)

    def reset(self):
        """Needle back at its initial pose, out of the tissue, no forces."""
        self.position, self.orientation = (a.copy() for a in self._initial_pose)
        self.rotation = rotation_matrix(self.orientation)
        self.axis = self.rotation[:, 2].copy()
        self._previous_position = self.position.copy()
        self._previous_axis = self.axis.copy()
        if self.rod is not None:
            self.rod.straighten(self.position, self.rotation)
        self.phase = 'approach'
        self.patch = None
        if self.tip_contact is not None:
            self.tip_contact.release()
        self.apex_element = -1             # where the tip's apex was found last (inserted)
        self.n_points = 0
        self.region = -1
        self.n_tip = 0
        self.surface_point = None          # where the tip first touched the surface (world)
        self.puncture_events = []
        self.punctured_regions = set()     # membranes the needle has gone through (cleared once out)
        self.contact_force[:] = 0.0
        self.cutting_force = 0.0
        self.friction_force = 0.0
        self.wrench_force[:] = 0.0
        self.wrench_torque[:] = 0.0
        self.applied_forces[:] = 0.0
        self._forces_applied = False
        self.n_applied = 0
        self._bonds_in_solve = None
        self._mass_version = None
        self._update_tip()

    def _reserve_applied(self, capacity):
        """Room for ``capacity`` points of action (patch samples, shaft points, tip samples)."""
        old = getattr(self, '_applied_points', None)
        if old is None or len(old) < capacity:
            points, forces = np.zeros((capacity, 3)), np.zeros((capacity, 3))
            if old is not None:                    # keep what this step has written so far
                points[:len(old)] = old
                forces[:len(old)] = self._applied_point_forces
            self._applied_points, self._applied_point_forces = points, forces

    @property
    def application_points(self):
        """(k, 3) points of action [m] of the forces the needle applied in the last step (world)."""
        return self._applied_points[:self.n_applied]

    @property
    def application_forces(self):
        """(k, 3) forces [N] the needle applied to the tissue at ``application_points``."""
        return self._applied_point_forces[:self.n_applied]

    def _add_applied(self, n):
        """Start index for ``n`` more points of action."""
        start = self.n_applied
        self.n_applied += n
        return start

    def _update_tip(self):
        if self.rod is not None and self.n_points:
            return                              # the rod's tip, until its next step
        np.multiply(self.axis, self.geometry.length_m, out=self._tip)
        self._tip += self.position
        if self.rod is not None:
            self.rod.straighten(self.position, self.rotation)

    @property
    def tip(self):
        """Tip position (3,) [m], world frame (read only: the needle updates it in place)."""
        return self._tip

    def _check_outside(self, position, orientation, field_name):
        """Refuse a needle whose shaft or tip lies inside the (deformed) tissue."""
        axis = needle_axis(orientation)
        disp = self.simulation.displacement
        size = float(np.ptp(self.rest, axis=0).max())
        for s in np.linspace(0.0, 1.0, 33):
            point = position + s * self.geometry.length_m * axis
            element, _ = locate_point(self.rest, disp, self.tetrahedra, point, 1e-9 * size)
            if element >= 0:
                raise PoseError(field_name, {'position': position.tolist(), 'orientation': orientation.tolist()},
                                       f'the needle starts inside the tissue (point {np.round(point, 6).tolist()} m '
                                       f'lies in element {element}); start it outside')

    # -- pose -----------------------------------------------------------------------------------
    def check_pose(self, position, orientation, field_name='pose'):
        """Validate a new pose against the current one (values, unit quaternion, jump): neither the
        base nor the tip may move more than ``geometry.max_jump_m`` (engine.pose.pose_jump)."""
        position, orientation = validate_pose(position, orientation, field_name)
        jump = pose_jump(self.position, self.orientation, position, orientation, self.geometry.length_m)
        if jump.exceeds(self.geometry.max_jump_m):
            raise PoseError(f'{field_name}.position', position.tolist(),
                                   f'moves the needle by {jump.distance_m * 1e3:.4g} mm in one call, more than '
                                   f'max_jump_m = {self.geometry.max_jump_m * 1e3:.4g} mm')
        return position, orientation

    def set_pose(self, position, orientation=None):
        """Move the needle (already validated) for the coming step; ``orientation`` None: the
        same orientation (a translation: the rotation is not recomputed)."""
        self._previous_position[:] = self.position
        self._previous_axis[:] = self.axis
        self.position[:] = position
        if orientation is not None:
            self.orientation[:] = orientation
            self.rotation[:] = rotation_matrix(orientation)
            self.axis[:] = self.rotation[:, 2]
        self._update_tip()

    # -- stepping ---------------------------------------------------------------------------------
    def after_step(self, dt):
        """Contact, shaft constraints and friction after the tissue's step; puncture; wrench.

        Allocates no arrays on the way (work arrays are made in the constructor and at contact).
        After an implicit step the work the needle's corrections put in is counted over the moves
        they make, f . Delta u: counted as f . v dt (the explicit solver's count), it took in the
        step's own motion, and the tissue springing back in one step when a membrane ruptures
        (quasi-static: no inertia to slow it) made the work put in negative and tripped the
        energy watchdog.
        """
        sim = self.simulation
        if sim.integrator == 'explicit':
            self._after_step(dt)
            return
        work = sim.input_work
        self._velocity_before[:] = sim.velocity
        self._after_step(dt)
        if self._forces_applied:
            np.subtract(sim.velocity, self._velocity_before, out=self._velocity_before)
            work += float(np.vdot(self.applied_forces, self._velocity_before)) * dt
        sim.input_work = work

    def _after_step(self, dt):
        self.contact_force[:] = 0.0
        inverse_mass = self._inverse_mass()
        if self.compiled_inside and self.n_points and not self._touching():
            self._inserted_step(inverse_mass, dt)
            return
        if self._forces_applied:
            self.applied_forces[:] = 0.0
        self.friction_force = 0.0
        self.cutting_force = 0.0
        self.n_applied = 0
        needle_kinematics(self.position, self.axis, self._previous_position, self._previous_axis,
                           self.geometry.length_m, dt, self._tip, self._travel, self._base_velocity, self._axis_rate)
        if self.rod is not None:
            self._rod_shaft(inverse_mass, dt)
        self.after_kinematics(inverse_mass, dt)

    def after_kinematics(self, inverse_mass, dt):
        """The general step after the needle's kinematics (``after_step`` but the inside step's
        path): contact, the shaft and cutting, the phase, the wrench. Also where a compiled
        approach or contact step (engine.compiled_substep) goes on when the tip has met the
        surface, or the contact may end."""
        if self.phase == 'approach':
            self._detect_surface_contact(inverse_mass)
        if self.patch is not None:
            self._enforce_patch(inverse_mass, dt)
        if self.tip_contact is not None and self.tip_contact.active:
            self._engage_tip()
            self.after_engaging(inverse_mass, dt)
        else:
            self.after_contact(inverse_mass, dt)

    def after_engaging(self, inverse_mass, dt):
        """After a sharp tip's samples were tried against the membrane: new bonds (the first
        hold from the step they touch), then :meth:`after_contact`. Also where a compiled contact
        step goes on when samples touched."""
        if self._take_engaged(inverse_mass):
            self._enforce_patch(inverse_mass, dt)
        self.after_contact(inverse_mass, dt)

    def after_contact(self, inverse_mass, dt):
        """The step after the membrane contact: the shaft and cutting, the work of the needle's
        forces, the phase, the wrench."""
        sim = self.simulation
        if self.n_points and self.rod is None:        # (a flexible shaft's points: _rod_shaft)
            n = self.n_points
            self.friction_force = shaft_solve(
                self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.point_nodes,
                self.point_weights, n, self.position, self.axis, self.rotation, self._base_velocity,
                self._axis_rate, dt, self.geometry.length_m, self._friction_laws[self.region], 2,
                self._free_beyond, self._closing_m, self.point_offsets, self.point_forces, self.point_depths,
                self.point_shares, self.applied_forces)
            start = self._add_applied(n)
            put_axis_points(self.position, self.axis, self.point_depths, n, self._applied_points, start)
            put_rows(self.point_forces, n, self._applied_point_forces, start)
        if self.n_points:
            touching = self._touching()
            if not touching:
                self._follow_tip_samples()
                if self.sharp and self.tip_contact.cutting:
                    self._push_with_tip_faces(inverse_mass, dt)
            if not touching and self.n_tip:
                self._cutting_law[0] = self.regions[self.region].cutting_force_n / self.n_tip
                self.cutting_force = shaft_solve(
                    self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.tip_nodes,
                    self.tip_weights, self.n_tip, *self._cutting_frame(), dt, 0.0, self._cutting_law, 0, math.inf,
                    0.0, self._no_offsets, self.tip_forces, self.tip_depths, self._unit_shares, self.applied_forces)
                start = self._add_applied(self.n_tip)
                put_rigid_points(self._tip, self.tip_rotation, self.tip_offsets, self.n_tip, self._applied_points,
                                 start)
                put_rows(self.tip_forces, self.n_tip, self._applied_point_forces, start)
            self._release_passed_points()
            if not self._touching() and self.n_points:
                self._track_apex(inverse_mass)
        if self.rod is not None and self._rod_rows:     # the tip's loads on the rod, for its next step
            rod = self.rod
            add_tip_loads(rod.nodes, rod.loads, self._applied_points, self._applied_point_forces, self._rod_rows,
                          self.n_applied, rod.scratch)
            self._rod_rows = 0
        self._forces_applied = self.n_applied > 0
        if self._forces_applied:         # work of the needle's forces, for the energy watchdog
            sim.input_work += applied_work(self.applied_forces, sim.velocity) * dt
        self._update_phase(dt)
        wrench_about(self._applied_points, self._applied_point_forces, self.n_applied, self.position,
                self.wrench_force, self.wrench_torque)

    def implicit_bonds(self):
        """The bonds an implicit step holds inside its solve (engine.implicit_bonds): the bonded
        contact's samples at their targets on the needle end after this step, as BondRows along
        x, y and z, or none. Called by the step, after this step's pose is set. The shaft's
        points are not held this way: several in one element ask its affine field for lateral
        positions that disagree (0.3 mm of least-squares gap left on the coarse scene, and the
        quasi-static run stalled after the puncture); they stay with shaft_solve, after the step."""
        patch = self._bonds_in_solve = self.patch
        if patch is None:
            return ()
        put_rigid_points(self._tip, self.tip_rotation, patch.offsets, len(patch.offsets), patch.targets, 0)
        if self._patch_rows_of is not patch:          # made once a patch, its targets set each step
            self._patch_rows = BondRows.along_axes(np.broadcast_to(patch.nodes, patch.weights.shape),
                                                   patch.weights, patch.targets)
            self._patch_rows_of = patch
        self._patch_rows.targets[:] = patch.targets.reshape(-1)
        return (self._patch_rows,)

    def _inverse_mass(self):
        """(n, 3) inverse mass of each free DOF, 0 for held ones (the solver's compliance over a
        step, Simulation.constraint_compliance); rebuilt when the masses or the step change."""
        sim = self.simulation
        if self._mass_version != (sim.mass_version, sim.dt):
            self._inverse_mass_dofs, self._force_scale = sim.constraint_compliance()
            self._mass_version = (sim.mass_version, sim.dt)
            self._mass_generation += 1
        return self._inverse_mass_dofs

    def _update_phase(self, dt, speed=None):
        if self._touching():
            self.phase = 'contact'
        elif self.n_points:
            speed = float(self._base_velocity @ self.axis) if speed is None else speed
            self.phase = 'retracting' if speed < -1e-9 else 'inserted'
        else:
            self.phase = 'approach'
            self.surface_point = None

    # -- outputs ------------------------------------------------------------------------------------
    def tip_depth(self):
        """Travel [m] of the tip along the axis past the point where it first touched the surface
        (0 before contact and once the needle is out)."""
        if self.surface_point is None:
            return 0.0
        return max(0.0, float(np.dot(self.tip - self.surface_point, self.axis)))

    def reaction_wrench(self, frame='world'):
        """(force, torque) [N, N m] the tissue exerts on the needle, about the base origin, in the
        'world' frame or the 'needle' base frame."""
        if frame == 'world':
            return self.wrench_force.copy(), self.wrench_torque.copy()
        if frame == 'needle':
            return self.rotation.T @ self.wrench_force, self.rotation.T @ self.wrench_torque
        raise PoseError('frame', frame, "expected 'world' or 'needle'")
