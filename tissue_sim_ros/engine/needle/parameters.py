"""What a needle and each tissue region bring to their interaction: geometry, membrane, friction.

Frozen dataclasses read from the scene file (``needle`` and ``regions[i]``); SI units.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from tissue_sim_ros.engine.needle.pose import DEFAULT_MAX_JUMP_M

__all__ = ['Friction', 'MIN_RATE_SPEED_M_S', 'Membrane', 'RegionInteraction', 'FlexibleShaft', 'NeedleGeometry',
           'TipShape']


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
        """(9,) the coefficients in the order :func:`~.kernels.shaft_solve` reads them."""
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
    """Puncture criterion of a region's boundary: 'force', the axial force reaches
    ``rupture_force_n`` x (v / ``reference_speed_m_s``)^``rate_exponent`` at the needle's axial
    speed v; or 'energy', the work done on the tissue since contact reaches ``toughness_j_per_m2``
    times the needle's cross-section area.

    The rate law: rupture forces measured at several insertion speeds follow a power law over a
    decade or more, the force falling with speed in soft tissue (Mahvash and Dupont 2010 explain
    the fall by the tissue's fracture toughness and viscoelasticity: the 'energy' criterion is
    that mechanism; the power law is the empirical form such data are fitted with). Exponent 0:
    the force does not depend on speed. The speed is held to at least ``MIN_RATE_SPEED_M_S`` (a
    needle stopped at the membrane would make the law 0 or infinite)."""
    criterion: str = 'force'
    rupture_force_n: float = 1.0
    toughness_j_per_m2: float = 0.0
    rate_exponent: float = 0.0
    reference_speed_m_s: float = 0.001

    def rupture_force(self, speed_m_s: float) -> float:
        """The axial force [N] that ruptures the membrane at this axial speed [m/s]."""
        return rupture_force_at(self.rupture_force_n, self.rate_exponent, self.reference_speed_m_s, speed_m_s)

    def rupture_work_j(self, diameter_m: float) -> float:
        """The work [J] since contact that ruptures it under the 'energy' criterion, for a
        needle of this diameter: the toughness times its cross-section area."""
        return self.toughness_j_per_m2 * 0.25 * math.pi * diameter_m ** 2


#: the slowest speed the rupture rate law uses [m/s]
MIN_RATE_SPEED_M_S = 1e-5


@njit(cache=True)
def rupture_force_at(rupture_force_n, rate_exponent, reference_speed_m_s, speed_m_s):
    """:meth:`Membrane.rupture_force` (the rate law) with the membrane's numbers: one function
    for the Python and the compiled contact step (engine.compiled.substeps)."""
    if rate_exponent == 0.0:
        return rupture_force_n
    return rupture_force_n * (max(abs(speed_m_s), MIN_RATE_SPEED_M_S) / reference_speed_m_s) ** rate_exponent


@dataclass(frozen=True)
class TipShape:
    """The needle's tip (:mod:`~tissue_sim_ros.engine.needle.tip`): 'flat', 'conical' (its
    half-angle) or 'bevel' (the angle between the bevel face and the axis, and the direction of
    the sharp point about the axis from the needle frame's +x)."""
    shape: str = 'flat'
    half_angle_deg: float = 30.0
    bevel_angle_deg: float = 20.0
    bevel_orientation_deg: float = 0.0


@dataclass(frozen=True)
class RegionInteraction:
    """What a region does to the needle: its membrane (None: entered without resistance), the
    cutting force at the tip [N], and the shaft friction."""
    name: str
    membrane: Membrane | None = None
    cutting_force_n: float = 0.0
    friction: Friction = field(default_factory=Friction)


@dataclass(frozen=True)
class FlexibleShaft:
    """A shaft that bends (:mod:`~tissue_sim_ros.engine.needle.rod`): the tube's inner diameter
    [m] (0: a solid rod; the outer one is the needle's), its Young's modulus [Pa] and the
    segments the rod is divided into."""
    inner_diameter_m: float = 0.0
    young_modulus_pa: float = 200e9
    segments: int = 60


@dataclass(frozen=True)
class NeedleGeometry:
    """The needle: outer diameter and length [m] (base to the tip's apex), the spacing of the
    shaft's material points along the inserted length [m], the largest base or tip move one
    ``advance`` accepts [m], its tip, and its shaft: None, rigid and straight, or a
    :class:`FlexibleShaft`."""
    diameter_m: float = 0.0024
    length_m: float = 0.15
    shaft_point_spacing_m: float = 0.001
    max_jump_m: float = DEFAULT_MAX_JUMP_M
    tip: TipShape = field(default_factory=TipShape)
    shaft: FlexibleShaft | None = None
