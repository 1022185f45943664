"""Material parameters: Lamé coefficients of linear isotropic elasticity, validated.

lambda = E nu / ((1 + nu)(1 - 2 nu)),  mu = E / (2 (1 + nu))   (any elasticity text).
"""
from dataclasses import dataclass
import math


class MaterialError(ValueError):
    """An impossible material parameter; the message names the field, value and allowed range."""


def _require(field, value, ok, expected):
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value) or not ok(value):
        raise MaterialError(f'{field} = {value!r} is not allowed: expected {expected}')


@dataclass(frozen=True)
class Material:
    """Isotropic elastic solid in SI units: Young's modulus [Pa], Poisson ratio [-], density [kg/m^3]."""

    young_modulus: float
    poisson_ratio: float
    density: float

    def __post_init__(self):
        _require('young_modulus', self.young_modulus, lambda v: v > 0, 'a finite value > 0 Pa')
        _require('poisson_ratio', self.poisson_ratio, lambda v: -1.0 < v < 0.5,
                 'a finite value in the open interval (-1, 0.5)')
        _require('density', self.density, lambda v: v > 0, 'a finite value > 0 kg/m^3')

    @property
    def lame_lambda(self) -> float:
        """First Lamé coefficient [Pa]."""
        nu = self.poisson_ratio
        return self.young_modulus * nu / ((1.0 + nu) * (1.0 - 2.0 * nu))

    @property
    def lame_mu(self) -> float:
        """Shear modulus [Pa]."""
        return self.young_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def dilatational_wave_speed(self) -> float:
        """sqrt((lambda + 2 mu) / rho) [m/s]: the speed that limits an explicit time step."""
        return math.sqrt((self.lame_lambda + 2.0 * self.lame_mu) / self.density)
