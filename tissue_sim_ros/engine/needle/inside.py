"""The needle inside the tissue (phases ``inserted``, ``retracting``): shaft points, friction,
cutting and the layers the tip meets.

Shaft points are material points created at the tip each ``shaft_point_spacing_m`` of advance.
Each is held on the needle axis (lateral constraint, so the tissue follows the needle sideways)
and dragged along it by friction: a modified Karnopp law per unit length (Okamura et al. 2004),
each point standing for its trapezoid share of the inserted length, plus constant terms for a
pull that does not scale with it. Relative velocity v (needle minus tissue, along the axis):
inside the stick band |v| <= stick_band / 2 the impulse that stops the relative motion is applied, up
to the static limit D; outside, the slip force (C + b |v|) opposes v. The slip force is solved
implicitly (the tissue point's velocity after the impulse enters b |v|), so it is stable for any
step. Insertion uses the ``insertion`` coefficients, retraction the ``retraction`` ones
(magnitudes). A shaft point the tip has passed back over is released; the needle is out when
none is left.

Cutting. The material points under the needle end (samples over the end's disc or a sharp tip's
faces, found again every step) are pushed along the axis by the same velocity-level solve with a
one-sided limit: the tip carries the tissue in front of it at its own speed until that takes more than the
region's ``cutting_force_n`` (shared between the samples); then the tissue is cut and the force
is the cutting force. It never pulls, so retraction has no cutting force, and a needle stopped
inside still feels the compressed tissue push back (up to the cutting force). A sharp tip's
faces also push the tissue they displace sideways out of the tip, frictionless (a bevel's face
pushes it sideways and the tissue pushes the needle toward the sharp point).

Layers are surfaces, not element sets. Every step the tip's apex is found in the deformed mesh
(a walk from where it was) and taken back to rest coordinates; when that material point enters
another region (its selector: a plane, box or sphere in metres, :mod:`~tissue_sim_ros.engine.mesh.selectors`), the
needle meets that layer there, wherever the element faces lie. A region with a membrane starts
a new contact (a flat end bonded to the material in front of it, a sharp tip touching it point
by point) that must be punctured in turn; one without switches the friction and cutting laws.

:class:`InsideTissue` is the part of :class:`~tissue_sim_ros.engine.needle.interaction.NeedleTissue`
that does this, as :class:`~tissue_sim_ros.engine.needle.membrane.MembraneContact` is the part that
meets a membrane; it reads and writes the needle's state (the arrays made in its constructor). The
common case runs in one compiled call (:func:`~tissue_sim_ros.engine.needle.step.inserted_step`).
"""
from tissue_sim_ros.engine.needle.kernels import follow_rigid_samples, locate_point, locate_walk, put_rows
from tissue_sim_ros.engine.needle.rod_step import rod_inserted_step
from tissue_sim_ros.engine.needle.step import inserted_step

__all__ = ['InsideTissue']


class InsideTissue:
    """The inside-the-tissue part of NeedleTissue (module docstring)."""

    def _inserted_step(self, inverse_mass, dt):
        """after_step inside the tissue, not touching a membrane: the same kernels in the same
        order as the general path, in one compiled call (engine.needle.step)."""
        step = inserted_step if self.rod is None else rod_inserted_step
        (self.friction_force, self.cutting_force, self.n_tip, self.n_applied, work, apex, travel_along, deepest,
         speed_along) = step(*self.inserted_arguments(inverse_mass, dt), self.apex_element, self._forces_applied)
        self.simulation.input_work += work
        self.after_inserted_step(inverse_mass, dt, apex, travel_along, deepest, speed_along)

    def inserted_arguments(self, inverse_mass, dt):
        """The arguments of ``step.inserted_step`` but the last two (the apex's element to
        walk from, whether to clear the applied forces first), as a tuple, and with a flexible
        shaft the rod's after them (``rod_step.rod_inserted_step``'s); valid until the needle's
        state changes outside that call (the compiled substep keeps it over a slice)."""
        sim, geometry, faces = self.simulation, self.geometry, self._faces
        return (self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.tetrahedra,
                self._neighbours, self.element_boxes, self.mesh_nodes, self.position, self.axis,
                self._previous_position, self._previous_axis, self.rotation, geometry.length_m, dt, self._tip,
                self._travel, self._base_velocity, self._axis_rate, self.point_nodes, self.point_weights,
                self.n_points, self._friction_laws[self.region], self._free_beyond, self._closing_m,
                self.point_offsets, self.point_forces, self.point_depths, self.point_shares, self.disc_offsets,
                self.tip_elements, self.tip_offsets, self.tip_nodes, self.tip_weights, self._weights,
                self._candidates, self._near_boxes, self.regions[self.region].cutting_force_n, self._cutting_law,
                self.tip_forces, self.tip_depths, self._unit_shares, self._no_offsets,
                self.sharp and self.tip_contact.cutting, faces.engaged, faces.new, faces.nodes, faces.weights,
                faces.params, faces.forces, faces.points, faces.total, self.applied_forces, self._applied_points,
                self._applied_point_forces, self.wrench_force, self.wrench_torque, self._apex_weights,
                self._apex_rest, sim.integrator == 'explicit') + (() if self.rod is None else self.rod.arguments())

    def after_inserted_step(self, inverse_mass, dt, apex, travel_along, deepest, speed_along):
        """What the Python decides after the compiled inside step, from the floats it returned:
        points released behind a retracting tip, the apex's layer and a new shaft point, the phase.
        (Under the explicit integrator the step zeroed what it applied; the implicit integrators'
        after_step needs the forces after it, the work over the needle's own moves.)"""
        self._forces_applied = self.n_applied > 0 and self.simulation.integrator != 'explicit'
        if travel_along < 0.0 and deepest > self._release_beyond:
            self._release_passed_points()
            deepest = None
        if not self._touching() and self.n_points:
            self._track_apex(inverse_mass, apex, deepest)
        self._update_phase(dt, speed_along)

    def _enter(self, region, nodes, weights):
        """Puncture done (or no membrane): the needle is inside ``region``; first shaft point
        (a flexible shaft leaves its guide from here, straight)."""
        if self.rod is not None and not self.n_points:
            self.rod.straighten(self.position, self.rotation, self._base_velocity)
        self.region = region
        self._add_point(nodes, weights)
        self.tip_elements[:] = -1
        self._follow_tip_samples()
        if self.sharp:
            self.tip_contact.follow()
        self.phase = 'inserted'

    def _push_with_tip_faces(self, inverse_mass, dt):
        """A sharp tip cutting its way in: the material it reaches is taken at the tip's samples
        and pushed sideways out of the tip until it passes the heel (needle_tip)."""
        contact, sim = self.tip_contact, self.simulation
        contact.engage_found(self.tip_elements, self.tip_nodes, self.tip_weights)
        contact.solve(self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self._tip,
                      self.tip_rotation, dt, self.applied_forces,
                      self.regions[self.region].cutting_force_n / len(contact.offsets))
        n = len(contact.offsets)
        start = self._add_applied(n)
        put_rows(contact.points, n, self._applied_points, start)
        put_rows(contact.forces, n, self._applied_point_forces, start)

    def _add_point(self, nodes, weights):
        if self.n_points == len(self.point_nodes):
            return
        k = self.n_points
        self.point_nodes[k] = 0
        self.point_weights[k] = 0.0
        self.point_nodes[k, :len(nodes)] = nodes
        self.point_weights[k, :len(weights)] = weights
        self.point_depths[k] = self.geometry.length_m
        self.point_offsets[k] = 0.0
        if self.rod is not None:
            self.rod.add_point(k)
        self.n_points += 1

    def _track_apex(self, inverse_mass, walked=None, deepest=None):
        """The tip's apex found in the deformed mesh (a walk from where it was): the layer it is
        in (its material point's region: layers are surfaces) and a new shaft point each spacing
        of advance. Entering a region with a membrane not yet punctured starts a contact with that
        layer (one punctured stays open: just after a layer's puncture the apex's material point
        can lie on the near side of the plane, and the layer left was met, and punctured, again:
        six punctures in 0.04 mm). ``walked``, ``deepest``: the walk's element (its rest point in
        ``_apex_rest``) and the deepest shaft point, when the compiled inside step has them."""
        disp = self.simulation.displacement
        element = walked
        if element is None:
            element = -2 if self.apex_element < 0 else locate_walk(
                self.rest, disp, self.tetrahedra, self._neighbours, self.apex_element, self._tip, 64,
                self._apex_weights)
        if element == -2:
            element, weights = locate_point(self.rest, disp, self.tetrahedra, self._tip, 0.0)
            self._apex_weights[:] = weights
            walked = None
        self.apex_element = element
        if element < 0:                     # the tip has left the mesh
            self.n_tip = 0
            return
        nodes = self.tetrahedra[element]
        region = self._region_of(self._apex_weights @ self.rest[nodes] if walked is None else self._apex_rest,
                                 element)
        if region != self.region:
            if self.regions[region].membrane is not None and region not in self.punctured_regions:
                if self.sharp:
                    self.tip_contact.begin(region, on_surface=False)
                    self.phase = 'contact'
                else:
                    n = self.n_tip
                    self.n_tip = 0
                    self._begin_patch(self.tip_offsets[:n].copy(), self.tip_nodes[:n].copy(),
                                      self.tip_weights[:n].copy(), region, inverse_mass)
                return
            self.region = region
        if deepest is None:
            deepest = float(self.point_depths[:self.n_points].max())
        if self.geometry.length_m - deepest >= self.geometry.shaft_point_spacing_m:
            self._add_point(nodes, self._apex_weights.copy())

    def _follow_tip_samples(self):
        """The cutting samples are the material under the needle end now: found again every step
        (walking from where each was found last), so the cutting force moves with the tip from
        element to element continuously (barycentric weights agree across a shared face). Found
        only at each new shaft point, they stayed with the tissue in between and the force built
        up again after each: a dip of up to 9 % every shaft point spacing."""
        self.n_tip = follow_rigid_samples(self.rest, self.simulation.displacement, self.tetrahedra,
                                          self._neighbours, self.element_boxes, self.mesh_nodes, self._tip,
                                          self.tip_rotation, self.disc_offsets,
                                          self.tip_elements, self.tip_offsets, self.tip_nodes,
                                          self.tip_weights, self._weights, self._candidates, self._near_boxes)

    def _release_passed_points(self):
        """Shaft points the tip has gone back over leave the needle (retraction). Only while it
        goes back: advancing, the cutting push can carry the first point (a surface node of a
        coarse element) ahead of the tip, and releasing it took the needle out, so the same
        membrane was punctured again at once (three times in 1 mm at 10 mm/s on 2 mm cells)."""
        limit = self._release_beyond
        if float(self._travel @ self.tip_axis) >= 0.0 or self.point_depths[:self.n_points].max() <= limit:
            return
        keep = self.point_depths[:self.n_points] <= limit
        n = int(keep.sum())
        if self.rod is not None:
            self.rod.keep_points(keep, self.n_points)
        for arr in (self.point_nodes, self.point_weights, self.point_depths, self.point_offsets):
            arr[:n] = arr[:self.n_points][keep]
        self.n_points = n
        if n == 0:
            self.region = -1
            self.n_tip = 0
            self.punctured_regions.clear()
            if self.sharp:
                self.tip_contact.release()
