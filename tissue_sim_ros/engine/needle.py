"""A rigid needle against the tissue: contact, puncture, cutting, friction, reaction wrench.

The needle is a straight rigid cylinder given by the pose of its base frame (position, unit
quaternion x y z w); its axis is the frame's +z and the tip is at +z * length (DESIGN.md). The
tissue is a :class:`~tissue_sim_ros.engine.solver.Simulation`. Each time step the scene moves the needle
(:meth:`NeedleTissue.set_pose`), calls ``Simulation.step`` and then
:meth:`NeedleTissue.after_step`, which applies the needle's constraints and forces as follows.

Material points. The needle acts on *material points* of the tissue: a point inside an element
(barycentric weights over its 4 nodes) or on a surface triangle (3 nodes), located once in the
deformed mesh and then carried by the tissue. A force on a point goes to its nodes by the same
weights, so elements larger than the needle are handled, and the needle's footprint is resolved
as soon as the mesh is finer than it.

Contact (phase ``contact``). When the tip crosses the deformed surface, the needle's flat end is
bonded to the surface under it as a hard constraint solved exactly each step
(:mod:`~tissue_sim_ros.engine.needle_contact`). The contact lets go when the needle, not
advancing, would pull the tissue (while it advances, a momentary pull from the tissue's rebound
keeps the bond: letting go there made the contact chatter on visco-elastic tissue).

Puncture (the region's membrane). Criterion ``force``: the axial contact force reaches
``rupture_force_n`` (checked every step, so puncture happens within one step of the crossing).
Criterion ``energy``: the work the needle has done on the tissue since contact reaches
``toughness_j_per_m2`` times the needle's cross-section area (fracture-mechanics view of
Mahvash and Dupont 2010); viscous work counts, so a faster insertion ruptures earlier. With
F = f(d) + v beta(d), dF_rupture/dv = beta(d) - F'(d) B(d) / F (B the integral of beta): the rupture
force falls with speed where the curve stiffens faster than the viscous force grows (a stiffening
law; a flat punch on a linear material is about neutral). At puncture the contact is released and the tissue relaxes.

Inside (phases ``inserted``, ``retracting``). Shaft points are material points created at the
tip each ``shaft_point_spacing_m`` of advance. Each is held on the needle axis (lateral
constraint, so the tissue follows the needle sideways) and dragged along it by friction: a
modified Karnopp law per unit length (Okamura et al. 2004) with the inserted length shared
equally between the points. Relative velocity v (needle minus tissue, along the axis): inside
the stick band |v| <= stick_band / 2 the impulse that stops the relative motion is applied, up
to the static limit D; outside, the slip force (C + b |v|) opposes v. The slip force is solved
implicitly (the tissue point's velocity after the impulse enters b |v|), so it is stable for any
step. Insertion uses the ``insertion`` coefficients, retraction the ``retraction`` ones
(magnitudes). A shaft point the tip has passed back over is released; the needle is out when
none is left.

Cutting. The material points under the needle end (the disc samples, relocated at each new
shaft point) are pushed along the axis by the same velocity-level solve with a one-sided limit:
the tip carries the tissue in front of it at its own speed until that takes more than the
region's ``cutting_force_n`` (shared between the samples); then the tissue is cut and the force
is the cutting force. It never pulls, so retraction has no cutting force, and a needle stopped
inside still feels the compressed tissue push back (up to the cutting force).

Layers. When a new shaft point lies in another region that has a membrane, the needle end is
bonded to the material points in front of it and that membrane must be punctured in turn.

Reaction wrench. Every force the needle puts on the tissue is recorded with its point of action
on the needle; the wrench on the needle is their negative sum, and the torque about the base
origin is sum (r - p) x (-f). Both are available in the world or the needle frame.

The other needle modules: :mod:`~tissue_sim_ros.engine.pose` (pose maths, pose rules),
:mod:`~tissue_sim_ros.engine.needle_parameters` (geometry, membrane, friction),
:mod:`~tissue_sim_ros.engine.needle_kernels` (numba kernels) and
:mod:`~tissue_sim_ros.engine.needle_contact` (the bonded contact). Their public names are
re-exported here.
"""
import math

import numpy as np

from tissue_sim_ros.engine.mesh import element_neighbours, face_elements
from tissue_sim_ros.engine.needle_contact import ContactPatch, disc_offsets, end_samples
from tissue_sim_ros.engine.needle_kernels import (first_surface_hit, follow_rigid_samples, locate_point, needle_kinematics,
                                                  put_axis_points, put_rigid_points, put_rows, shaft_solve,
                                                  wrench_about)
from tissue_sim_ros.engine.needle_parameters import Friction, Membrane, NeedleGeometry, RegionInteraction
from tissue_sim_ros.engine.pose import (QUATERNION_NORM_TOLERANCE, NeedleInputError, needle_axis, pose_jump,
                                        rotation_matrix, slerp, validate_pose)

__all__ = ['PHASES', 'NeedleTissue', 'NeedleInputError', 'Friction', 'Membrane', 'RegionInteraction',
           'NeedleGeometry', 'QUATERNION_NORM_TOLERANCE', 'rotation_matrix', 'slerp', 'validate_pose',
           'first_surface_hit', 'locate_point']

PHASES = ('approach', 'contact', 'inserted', 'retracting')


class NeedleTissue:
    """The needle-tissue interaction state of one scene (see the module docstring).

    simulation: the tissue's Simulation. element_region: (m,) region index of each element.
    regions: list of RegionInteraction, by region index. geometry: NeedleGeometry.
    """

    def __init__(self, simulation, element_region, regions, geometry, position, orientation):
        self.simulation = simulation
        self.mesh = simulation.model.mesh
        self.element_region = np.asarray(element_region, dtype=np.int64)
        self.regions = list(regions)
        self.geometry = geometry
        self.tetrahedra = np.ascontiguousarray(simulation.model.tetrahedra, dtype=np.int64)
        self.rest = self.mesh.rest_positions
        self._surface_owner()
        self.disc_offsets = disc_offsets(0.5 * geometry.diameter_m)
        capacity = int(math.ceil(geometry.length_m / geometry.shaft_point_spacing_m)) + 16
        self.point_nodes = np.zeros((capacity, 4), dtype=np.int64)
        self.point_weights = np.zeros((capacity, 4))
        self.point_forces = np.zeros((capacity, 3))
        self.point_depths = np.zeros(capacity)
        self.point_shares = np.zeros(capacity)
        self.applied_forces = np.zeros((self.mesh.n_nodes, 3))
        n_disc = len(self.disc_offsets)
        self.tip_nodes = np.zeros((n_disc, 4), dtype=np.int64)     # cutting: material points at the tip
        self.tip_weights = np.zeros((n_disc, 4))
        self.tip_offsets = np.zeros((n_disc, 3))
        self.tip_forces = np.zeros((n_disc, 3))
        self.tip_depths = np.zeros(n_disc)
        self._unit_shares = np.ones(n_disc)
        self.tip_elements = np.full(n_disc, -1, dtype=np.int64)   # where each sample was last found
        self._weights = np.zeros(4)
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
        self._reserve_applied(capacity + n_disc + len(self.disc_offsets))
        self._mass_generation = 0
        self._initial_pose = validate_pose(position, orientation, 'needle.initial_pose')
        self.reset()
        self._check_outside(*self._initial_pose, 'needle.initial_pose')

    # -- set-up --------------------------------------------------------------------------------
    def _surface_owner(self):
        """Surface triangles and the element each belongs to (for the membrane of the region hit)."""
        triangles = self.mesh.surface_triangles()
        self.surface_triangles = np.ascontiguousarray(triangles, dtype=np.int64)
        self.surface_nodes = np.unique(self.surface_triangles)
        self.surface_owner = face_elements(self.tetrahedra, triangles, self.mesh.n_nodes)
        self._neighbours = element_neighbours(self.tetrahedra, self.mesh.n_nodes)

    def reset(self):
        """Needle back at its initial pose, out of the tissue, no forces."""
        self.position, self.orientation = (a.copy() for a in self._initial_pose)
        self.rotation = rotation_matrix(self.orientation)
        self.axis = self.rotation[:, 2].copy()
        self._previous_position = self.position.copy()
        self._previous_axis = self.axis.copy()
        self.phase = 'approach'
        self.patch = None
        self.n_points = 0
        self.region = -1
        self.n_tip = 0
        self.surface_point = None          # where the tip first touched the surface (world)
        self.puncture_events = []
        self.contact_force[:] = 0.0
        self.cutting_force = 0.0
        self.friction_force = 0.0
        self.wrench_force[:] = 0.0
        self.wrench_torque[:] = 0.0
        self.applied_forces[:] = 0.0
        self._forces_applied = False
        self.n_applied = 0
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
        np.multiply(self.axis, self.geometry.length_m, out=self._tip)
        self._tip += self.position

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
                raise NeedleInputError(field_name, {'position': position.tolist(), 'orientation': orientation.tolist()},
                                       f'the needle starts inside the tissue (point {point.tolist()} m '
                                       f'lies in element {element}); start it outside')

    # -- pose -----------------------------------------------------------------------------------
    def check_pose(self, position, orientation, field_name='pose'):
        """Validate a new pose against the current one (values, unit quaternion, jump): neither the
        base nor the tip may move more than ``geometry.max_jump_m`` (engine.pose.pose_jump)."""
        position, orientation = validate_pose(position, orientation, field_name)
        jump = pose_jump(self.position, self.orientation, position, orientation, self.geometry.length_m)
        if jump.exceeds(self.geometry.max_jump_m):
            raise NeedleInputError(f'{field_name}.position', position.tolist(),
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
        """
        sim = self.simulation
        if self._forces_applied:
            self.applied_forces[:] = 0.0
        self.contact_force[:] = 0.0
        self.friction_force = 0.0
        self.cutting_force = 0.0
        self.n_applied = 0
        inverse_mass = self._inverse_mass()
        needle_kinematics(self.position, self.axis, self._previous_position, self._previous_axis,
                           self.geometry.length_m, dt, self._tip, self._travel, self._base_velocity, self._axis_rate)
        if self.phase == 'approach':
            self._detect_surface_contact(inverse_mass)
        if self.patch is not None:
            self._enforce_patch(inverse_mass, dt)
        if self.n_points:
            n = self.n_points
            self.friction_force = shaft_solve(
                self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.point_nodes,
                self.point_weights, n, self.position, self.axis, self._base_velocity, self._axis_rate,
                dt, self.geometry.length_m, self._friction_laws[self.region], 2, self.point_forces,
                self.point_depths, self.point_shares, self.applied_forces)
            start = self._add_applied(n)
            put_axis_points(self.position, self.axis, self.point_depths, n, self._applied_points, start)
            put_rows(self.point_forces, n, self._applied_point_forces, start)
            if self.patch is None:
                self._follow_tip_samples()
            if self.patch is None and self.n_tip:
                self._cutting_law[0] = self.regions[self.region].cutting_force_n / self.n_tip
                self.cutting_force = shaft_solve(
                    self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.tip_nodes,
                    self.tip_weights, self.n_tip, self.position, self.axis, self._base_velocity, self._axis_rate,
                    dt, 0.0, self._cutting_law, 0, self.tip_forces, self.tip_depths, self._unit_shares,
                    self.applied_forces)
                start = self._add_applied(self.n_tip)
                put_rigid_points(self._tip, self.rotation, self.tip_offsets, self.n_tip, self._applied_points, start)
                put_rows(self.tip_forces, self.n_tip, self._applied_point_forces, start)
            self._release_passed_points()
            if self.patch is None and self.n_points:
                self._grow_shaft(inverse_mass)
        self._forces_applied = self.n_applied > 0
        if self._forces_applied:         # work of the needle's forces, for the energy watchdog
            sim.input_work += float(np.vdot(self.applied_forces, sim.velocity)) * dt
        self._update_phase(dt)
        wrench_about(self._applied_points, self._applied_point_forces, self.n_applied, self.position,
                self.wrench_force, self.wrench_torque)

    def _inverse_mass(self):
        """(n, 3) inverse mass of each free DOF, 0 for held ones; rebuilt when the masses change."""
        sim = self.simulation
        if self._mass_version != (sim.mass_version, sim.dt):
            self._inverse_mass_dofs = np.where(sim.dof_kind == 0, sim.inverse_mass[:, None], 0.0)
            self._force_scale = 1.0 + sim.dt * sim.damping_rate
            self._mass_version = (sim.mass_version, sim.dt)
            self._mass_generation += 1
        return self._inverse_mass_dofs

    # -- contact and puncture ---------------------------------------------------------------------
    def _detect_surface_contact(self, inverse_mass):
        """Start a contact when the tip has crossed the deformed surface."""
        # the tip is past the surface if the surface lies within the last step's travel or one
        # diameter behind the tip (the surface may have come up to a needle at rest)
        back = math.sqrt(float(self._travel @ self._travel)) + self.geometry.diameter_m
        disp = self.simulation.displacement
        np.multiply(self.axis, -back, out=self._ray_origin)
        self._ray_origin += self._tip
        hit, t, _, _, _ = first_surface_hit(self.rest, disp, self.surface_triangles, self._ray_origin,
                                            self.axis, 0.0, back)
        if hit < 0:
            return
        self.surface_point = self.tip - (back - t) * self.axis
        region = int(self.element_region[self.surface_owner[hit]])
        found = end_samples(self.rest, disp, self.surface_triangles, self.surface_nodes, self.tip, self.rotation,
                            self.axis, self.geometry.diameter_m, self.disc_offsets)
        if found is not None:
            self._begin_patch(*found, region, inverse_mass)

    def _begin_patch(self, offsets, sample_nodes, sample_weights, region, inverse_mass):
        membrane = self.regions[region].membrane
        if membrane is None:                       # no membrane: the needle enters at once
            self._enter(region, sample_nodes[0], sample_weights[0])
            return
        self.patch = ContactPatch.from_samples(offsets, sample_nodes, sample_weights, inverse_mass, region)
        self._reserve_applied(len(offsets) + len(self.point_nodes) + len(self.disc_offsets))
        self.phase = 'contact'

    def _enforce_patch(self, inverse_mass, dt):
        """The bonded contact's step: release when it would pull back, else hold; puncture."""
        patch, sim = self.patch, self.simulation
        if patch.scale_generation != self._mass_generation:
            patch.set_masses(inverse_mass, self._force_scale, self._mass_generation)
        n = len(patch.offsets)
        total = patch.solve(self.rest, sim.displacement, self._tip, self.rotation, dt)
        advancing = float(self._travel @ self.axis) > 0.0
        if float(total @ self.axis) < 0.0 and not advancing:   # it would pull back: contact lost
            self.patch = None
            if self.n_points == 0:
                self.phase = 'approach'
            return
        patch.apply(sim.displacement, sim.velocity, inverse_mass, self._force_scale, dt, self.applied_forces)
        self.contact_force[:] = total
        patch.work += float(total @ self._travel)
        start = self._add_applied(n)
        put_rows(patch.targets, n, self._applied_points, start)
        put_rows(patch.sample_forces, n, self._applied_point_forces, start)
        axial = float(total @ self.axis)
        if patch.ruptured(self.regions[patch.region].membrane, axial, self.geometry.diameter_m):
            self.puncture_events.append({'time_s': self.simulation.time, 'tip_depth_m': self.tip_depth(),
                                         'axial_force_n': axial, 'work_j': patch.work,
                                         'region': self.regions[patch.region].name})
            self.patch = None
            self._enter(patch.region, *patch.entry_point())

    def _enter(self, region, nodes, weights):
        """Puncture done (or no membrane): the needle is inside ``region``; first shaft point."""
        self.region = region
        self._add_point(nodes, weights)
        self._locate_tip_samples()
        self.phase = 'inserted'

    def _add_point(self, nodes, weights):
        if self.n_points == len(self.point_nodes):
            return
        k = self.n_points
        self.point_nodes[k] = 0
        self.point_weights[k] = 0.0
        self.point_nodes[k, :len(nodes)] = nodes
        self.point_weights[k, :len(weights)] = weights
        self.point_depths[k] = self.geometry.length_m
        self.n_points += 1

    def _grow_shaft(self, inverse_mass):
        """A new shaft point at the tip each spacing of advance; a new region's membrane."""
        deepest = float(self.point_depths[:self.n_points].max())
        if self.geometry.length_m - deepest < self.geometry.shaft_point_spacing_m:
            return
        disp = self.simulation.displacement
        element, weights = locate_point(self.rest, disp, self.tetrahedra, self.tip, 0.0)
        if element < 0:                     # the tip has left the mesh
            self.n_tip = 0
            return
        region = int(self.element_region[element])
        self._locate_tip_samples()
        if region != self.region and self.regions[region].membrane is not None:
            n = self.n_tip
            self.n_tip = 0
            self._begin_patch(self.tip_offsets[:n].copy(), self.tip_nodes[:n].copy(),
                              self.tip_weights[:n].copy(), region, inverse_mass)
            return
        self.region = region
        self._add_point(self.tetrahedra[element], weights)

    def _follow_tip_samples(self):
        """The cutting samples are the material under the needle end now: found again every step
        (walking from where each was found last), so the cutting force moves with the tip from
        element to element continuously (barycentric weights agree across a shared face). Found
        only at each new shaft point, they stayed with the tissue in between and the force built
        up again after each: a dip of up to 9 % every shaft point spacing."""
        self.n_tip = follow_rigid_samples(self.rest, self.simulation.displacement, self.tetrahedra,
                                          self._neighbours, self._tip, self.rotation, self.disc_offsets,
                                          self.tip_elements, self.tip_offsets, self.tip_nodes,
                                          self.tip_weights, self._weights)

    def _locate_tip_samples(self):
        """The material points under the needle end (disc samples) that take the cutting force."""
        disp = self.simulation.displacement
        n = 0
        for offset in self.disc_offsets:
            e, w = locate_point(self.rest, disp, self.tetrahedra, self.tip + self.rotation @ offset, 0.0)
            if e >= 0:
                self.tip_offsets[n] = offset
                self.tip_nodes[n] = self.tetrahedra[e]
                self.tip_weights[n] = w
                n += 1
        self.n_tip = n

    def _release_passed_points(self):
        """Shaft points the tip has gone back over leave the needle (retraction). Only while it
        goes back: advancing, the cutting push can carry the first point (a surface node of a
        coarse element) ahead of the tip, and releasing it took the needle out, so the same
        membrane was punctured again at once (three times in 1 mm at 10 mm/s on 2 mm cells)."""
        limit = self.geometry.length_m + 0.5 * self.geometry.shaft_point_spacing_m
        if float(self._travel @ self.axis) >= 0.0 or self.point_depths[:self.n_points].max() <= limit:
            return
        keep = self.point_depths[:self.n_points] <= limit
        n = int(keep.sum())
        for arr in (self.point_nodes, self.point_weights, self.point_depths):
            arr[:n] = arr[:self.n_points][keep]
        self.n_points = n
        if n == 0:
            self.region = -1
            self.n_tip = 0

    def _update_phase(self, dt):
        if self.patch is not None:
            self.phase = 'contact'
        elif self.n_points:
            speed = float(self._base_velocity @ self.axis)
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
        raise NeedleInputError('frame', frame, "expected 'world' or 'needle'")
