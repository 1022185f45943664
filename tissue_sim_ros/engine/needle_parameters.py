"""What a needle and each tissue region bring to their interaction: geometry, membrane, friction.

Frozen dataclasses read from the scene file (``needle`` and ``regions[i]``); SI units.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tissue_sim_ros.engine.pose import DEFAULT_MAX_JUMP_M

__all__ = ['Friction', 'Membrane', 'RegionInteraction', 'NeedleGeometry']


@dataclass(frozen=True)
class Friction:
    """Modified Karnopp friction per unit inserted length (Okamura et al. 2004): static limit D
    [N/m], Coulomb C [N/m], viscous b [N s/m^2] for insertion and for retraction (magnitudes), the
    stick band [m/s] of relative velocity inside which the tissue sticks to the needle, and a
    constant term [N] for each direction that does not scale with the inserted length (the
    near-constant pull measured while a needle is withdrawn: the tissue gripping the shaft where
    it enters), added to the slip force and to the static limit while any length is inserted."""
    insertion_static_n_per_m: float = 0.0
    insertion_coulomb_n_per_m: float = 0.0
    insertion_viscous_n_s_per_m2: float = 0.0
    retraction_static_n_per_m: float = 0.0
    retraction_coulomb_n_per_m: float = 0.0
    retraction_viscous_n_s_per_m2: float = 0.0
    stick_band_m_per_s: float = 5e-4
    insertion_constant_n: float = 0.0
    retraction_constant_n: float = 0.0

    def as_array(self):
        """(9,) the coefficients in the order :func:`~.needle_kernels.shaft_solve` reads them."""
        return np.array([self.insertion_static_n_per_m, self.insertion_coulomb_n_per_m,
                         self.insertion_viscous_n_s_per_m2, self.retraction_static_n_per_m,
                         self.retraction_coulomb_n_per_m, self.retraction_viscous_n_s_per_m2,
                         self.stick_band_m_per_s, self.insertion_constant_n, self.retraction_constant_n])

    def slip_force(self, relative_velocity, length):
        """Slip force magnitude [N] on ``length`` metres at a relative velocity [m/s] (the
        constant term included whenever some length is inserted)."""
        if length <= 0:
            return 0.0
        if relative_velocity >= 0:
            return length * (self.insertion_coulomb_n_per_m + self.insertion_viscous_n_s_per_m2 * relative_velocity) \
                + self.insertion_constant_n
        return length * (self.retraction_coulomb_n_per_m - self.retraction_viscous_n_s_per_m2 * relative_velocity) \
            + self.retraction_constant_n


@dataclass(frozen=True)
class Membrane:
    """Puncture criterion of a region's boundary: 'force' (rupture_force_n) or 'energy'
    (toughness_j_per_m2 times the needle cross-section area)."""
    criterion: str = 'force'
    rupture_force_n: float = 1.0
    toughness_j_per_m2: float = 0.0


@dataclass(frozen=True)
class RegionInteraction:
    """What a region does to the needle: its membrane (None: entered without resistance), the
    cutting force at the tip [N], and the shaft friction."""
    name: str
    membrane: Membrane | None = None
    cutting_force_n: float = 0.0
    friction: Friction = field(default_factory=Friction)


@dataclass(frozen=True)
class NeedleGeometry:
    """The rigid needle: outer diameter and length [m], the spacing of the shaft's material points
    along the inserted length [m], and the largest base or tip move one ``advance`` accepts [m]."""
    diameter_m: float = 0.0024
    length_m: float = 0.15
    shaft_point_spacing_m: float = 0.001
    max_jump_m: float = DEFAULT_MAX_JUMP_M
