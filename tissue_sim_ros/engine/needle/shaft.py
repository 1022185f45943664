"""The needle's shaft as the rest of the needle sees it: the tip's frame, the centreline's shape, and
a flexible shaft's part of the general step.

:class:`NeedleShaft` is the part of :class:`~tissue_sim_ros.engine.needle.interaction.NeedleTissue`
that knows whether the shaft is rigid (``rod`` None: the tip's frame is the base frame, the shape
the straight needle) or an elastic rod (:mod:`.rod_coupling`: the tip's frame is the rod's last
segment's, the shape the rod's nodes), as :class:`~.inside.InsideTissue` is the part inside the
tissue; it reads and writes the needle's state.
"""
import numpy as np

from tissue_sim_ros.engine.needle.rod import frame_quaternions, straight_nodes
from tissue_sim_ros.engine.needle.rod_step import rod_shaft_step

__all__ = ['NeedleShaft']


class NeedleShaft:
    """The shaft's part of NeedleTissue (module docstring)."""

    @property
    def tip_rotation(self):
        """(3, 3) the tip's frame (world; the base frame's rotation for a rigid needle, the rod's
        last segment's frame for a flexible one): the tip's kernels work in it."""
        return self.rotation if self.rod is None else self.rod.tip_rotation

    @property
    def tip_axis(self):
        """(3,) the tip's axis (world): the needle axis, or the rod's last segment's."""
        return self.axis if self.rod is None else self.rod.tip_axis

    def _cutting_frame(self):
        """(base, axis, rotation, base velocity, axis rate) of the straight needle whose tip is
        the tip: the cutting law's frame (shaft_solve on the tip's samples)."""
        if self.rod is None:
            return self.position, self.axis, self.rotation, self._base_velocity, self._axis_rate
        rod = self.rod
        return rod.virtual_base, rod.tip_axis, rod.tip_rotation, rod.tip_velocity, rod.no_rate

    def _rod_shaft(self, inverse_mass, dt):
        """A flexible shaft's part of the general step, after the base's kinematics: straight in
        its guide while no point holds it, else the rod and the shaft's points solved together
        (rod_step.rod_shaft_step: the guide, the points, friction, the tip's frame), its points of
        action the first rows of the applied lists. The tip's kernels that follow work in the
        tip's frame."""
        rod, sim, n = self.rod, self.simulation, self.n_points
        self._rod_rows = n
        if not n:
            rod.straighten(self.position, self.rotation, self._base_velocity)
            return
        self.friction_force = rod_shaft_step(
            self.rest, sim.displacement, sim.velocity, inverse_mass, self._force_scale, self.point_nodes,
            self.point_weights, n, self.position, self.axis, self._previous_position, self.rotation,
            self.geometry.length_m, dt, self._tip, self._travel, self._friction_laws[self.region], self._free_beyond,
            self._closing_m, self.point_offsets, self.point_forces, self.point_depths, self.point_shares,
            self.applied_forces, self._applied_points, self._applied_point_forces, self._add_applied(n),
            *rod.arguments()[:-1])

    @property
    def shape_size(self):
        """How many points :meth:`shape` has: a rigid needle's 2 (base, tip), a flexible one's rod
        nodes."""
        return 2 if self.rod is None else self.rod.segments + 1

    def write_shape(self, positions, quaternions):
        """Write the needle's centreline into ``positions`` (shape_size, 3) [m] and the needle's
        frame at each point into ``quaternions`` (shape_size, 4; x, y, z, w; the frame's +z along
        the needle), world frame: a flexible shaft's rod nodes with the frame of the segment that
        starts there (the tip's frame at the tip; straight along the base frame while no shaft
        point holds it), or a rigid needle's base and tip in the base frame."""
        if self.rod is None or not self.n_points:
            positions[:] = straight_nodes(self.position, self.axis, self.geometry.length_m, self.shape_size - 1)
            quaternions[:] = self.orientation
            return
        positions[:] = self.rod.nodes
        frame_quaternions(self.rod.frames, quaternions[:-1])
        frame_quaternions(self.rod.tip_rotation[None], quaternions[-1:])

    def shape(self):
        """(shape_size, 3) points along the needle's centreline from the base to the tip [m]
        (:meth:`write_shape`)."""
        positions, quaternions = np.empty((self.shape_size, 3)), np.empty((self.shape_size, 4))
        self.write_shape(positions, quaternions)
        return positions

    def tip_deflection(self):
        """The tip's distance [m] from the base frame's axis (0 for a rigid needle)."""
        if self.rod is None or not self.n_points:
            return 0.0
        return self.rod.deflection(self.position, self.axis)
