"""The needle against a membrane: contact, puncture and the layers it meets (phase ``contact``).

Contact (phase ``contact``). When the tip crosses the deformed surface, a flat end is bonded to
the surface under it as a hard constraint solved exactly each step
(:mod:`~tissue_sim_ros.engine.needle.contact`); the contact lets go when the needle, not
advancing, would pull the tissue (while it advances, a momentary pull from the tissue's rebound
keeps the bond: letting go there would make the contact chatter on visco-elastic tissue). A conical or
bevelled tip touches the tissue point by point as it goes in and each point is bonded to the
tip where it touched, so the loaded area grows with the indentation as under a real sharp tip
(:mod:`~tissue_sim_ros.engine.needle.tip`); its contact ends when no point is pushed and the
needle does not advance.

Puncture (the region's membrane). Criterion ``force``: the axial contact force reaches
``rupture_force_n``, scaled by the rate law (v / v0)^n when the membrane has one (checked every
step, so puncture happens within one step of the crossing).
Criterion ``energy``: the work the needle has done on the tissue since contact reaches
``toughness_j_per_m2`` times the needle's cross-section area (fracture-mechanics view of
Mahvash and Dupont 2010); viscous work counts, so a faster insertion ruptures earlier. With
F = f(d) + v beta(d), dF_rupture/dv = beta(d) - F'(d) B(d) / F (B the integral of beta): the rupture
force falls with speed where the curve stiffens faster than the viscous force grows (a stiffening
law; a flat punch on a linear material is about neutral). At puncture the contact is released,
the tissue relaxes and the needle is inside (a sharp tip's faces go on pushing the tissue they
displace, :meth:`~tissue_sim_ros.engine.needle.tip.SharpTipContact.follow`).

Layers are surfaces, not element sets: a region's selector
(:mod:`~tissue_sim_ros.engine.mesh.selectors`) says which material point belongs to which layer,
so :meth:`MembraneContact._region_of` reads the region of the material point itself, wherever the
element faces lie.

:class:`MembraneContact` is the part of :class:`~tissue_sim_ros.engine.needle.interaction.NeedleTissue` that
does this; it reads and writes the needle's state (the arrays made in its constructor).
"""
import math

import numpy as np

from tissue_sim_ros.engine.needle.contact import ContactPatch, bond_offsets, end_samples
from tissue_sim_ros.engine.needle.kernels import approach_hit, dot3, locate_point, put_rows

__all__ = ['MembraneContact']


class MembraneContact:
    """Contact with membranes and their puncture, for NeedleTissue (see the module docstring)."""

    def _detect_surface_contact(self, inverse_mass):
        """Start a contact when the tip has crossed the deformed surface (not while the needle
        goes back: the tip coming up through the surface it left is not a new contact; a bevel
        would grip the surface there and rupture it again on its way out)."""
        # the tip is past the surface if the surface lies within the last step's travel or one
        # diameter behind the tip (the surface may have come up to a needle at rest)
        hit, t, w0, w1, w2, back = approach_hit(self.rest, self.simulation.displacement, self.surface_triangles,
                                                self.surface_boxes, self.surface_nodes, self._tip, self._travel,
                                                self.axis, self.geometry.diameter_m, self._ray_origin)
        if hit < 0:
            return
        disp = self.simulation.displacement
        self.surface_point = self.tip - (back - t) * self.axis
        owner = int(self.surface_owner[hit])
        region = self._region_of(self.rest[self.surface_triangles[hit]].T @ np.array([w0, w1, w2]), owner)
        if self.sharp:
            if self.regions[region].membrane is None:      # no membrane: the needle enters at once
                element, weights = locate_point(self.rest, disp, self.tetrahedra, self.tip, 1e-9)
                self._enter(region, self.tetrahedra[element if element >= 0 else owner],
                            weights if element >= 0 else np.full(4, 0.25))
                return
            self.tip_contact.begin(region, on_surface=True)
            self.phase = 'contact'
            return
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
        held = patch is self._bonds_in_solve          # an implicit step held it: its forces are written
        self._bonds_in_solve = None
        if held:
            patch.sample_forces[:] = self._patch_rows.forces.reshape(-1, 3)
            total = patch.sample_forces.sum(axis=0, out=patch.total)
        else:
            total = patch.solve(self.rest, sim.displacement, self._tip, self.tip_rotation, dt)
        advancing = float(self._travel @ self.tip_axis) > 0.0
        if float(total @ self.tip_axis) < 0.0 and not advancing:   # it would pull back: contact lost
            self.patch = None
            if self.tip_contact is not None:
                self.tip_contact.release()
            if self.n_points == 0:
                self.phase = 'approach'
            return
        if not held:                # (held: the step counted the bonds' work itself)
            patch.apply(sim.displacement, sim.velocity, inverse_mass, self._force_scale, dt, self.applied_forces)
        self.contact_force[:] = total
        patch.work += dot3(total, self._travel)
        start = self._add_applied(n)
        put_rows(patch.targets, n, self._applied_points, start)
        put_rows(patch.sample_forces, n, self._applied_point_forces, start)
        axial = float(total @ self.tip_axis)
        if patch.ruptured(self.regions[patch.region].membrane, axial, self.geometry.diameter_m,
                          float(self._base_velocity @ self.axis)):
            self._punctured(axial, patch.work, patch.region)
            self.patch = None
            self._enter(patch.region, *patch.entry_point())     # a sharp tip's contact follows the cut

    def _punctured(self, axial, work, region):
        self.punctured_regions.add(region)
        self.puncture_events.append({'time_s': self.simulation.time, 'tip_depth_m': self.tip_depth(),
                                     'axial_force_n': axial, 'work_j': work,
                                     'speed_m_s': float(self._base_velocity @ self.axis),
                                     'region': self.regions[region].name})

    def _touching(self):
        """In contact with a membrane (the end bonded, or a sharp tip about to touch)."""
        return self.patch is not None or (self.tip_contact is not None and self.tip_contact.active)

    def _engage_tip(self):
        """A sharp tip against a membrane: new points touch (at the outer surface, or in the layer
        met inside); :meth:`_take_engaged` takes them. Called after the patch's correction: a point
        taken before it would be off by the step's rebound of the nodes it shares with the bonds,
        and the exact solve would move their other nodes by much more to agree."""
        contact, disp = self.tip_contact, self.simulation.displacement
        if contact.on_surface:
            back = math.sqrt(dot3(self._travel, self._travel)) + self.geometry.diameter_m
            contact.engage_on_surface(self.rest, disp, self.surface_triangles, self.surface_boxes,
                                      self.surface_nodes, self._tip, self.tip_rotation, self.tip_axis, back)
        else:
            contact.engage_in_region(self.rest, disp, self.tetrahedra, self._neighbours, self.element_boxes,
                                     self.mesh_nodes, self._tip, self.tip_rotation, self.selectors,
                                     self.mesh.element_tags)

    def _take_engaged(self, inverse_mass):
        """The points that touched rebuild the bonded patch for the next step (its work carried
        over); a contact nothing touches ends when the needle does not advance. Returns whether
        the first bonds were made (the caller enforces them in this step, as a flat end's)."""
        contact = self.tip_contact
        if contact.take_new():
            first = self.patch is None
            work = 0.0 if first else self.patch.work
            offsets, nodes, weights = contact.engaged_samples()
            offsets = bond_offsets(offsets, self.rest, self.simulation.displacement, nodes, weights, self._tip,
                                   self.rotation, self._crossing_tolerance())
            self.patch = ContactPatch.from_samples(offsets, nodes, weights, inverse_mass, contact.region)
            self.patch.work = work
            self._reserve_applied(len(contact.offsets) + len(self.point_nodes) + len(self.disc_offsets))
            return first
        elif self.patch is None and float(self._travel @ self.tip_axis) <= 0.0:
            contact.release()
            if self.n_points == 0:
                self.phase = 'approach'
        return False

    def _crossing_tolerance(self):
        """How far past the surface a sharp tip's sample may be and still be pulled onto the
        needle: this step's travel along the axis, and a hundredth of the diameter
        (contact.bond_offsets)."""
        return max(float(self._travel @ self.axis), 0.0) + 0.01 * self.geometry.diameter_m

    def _region_of(self, rest_point, element):
        """The region of a material point (layers as surfaces), or its element's when the needle
        was given no selectors."""
        if self.selectors is None:
            return int(self.element_region[element])
        region = self.selectors.region_at(rest_point, element)
        return region if region >= 0 else int(self.element_region[element])
