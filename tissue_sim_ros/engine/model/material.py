"""Material parameters: Lamé coefficients of linear isotropic elasticity, validated.

lambda = E nu / ((1 + nu)(1 - 2 nu)),  mu = E / (2 (1 + nu))   (any elasticity text).
"""
from dataclasses import dataclass
import math

import numpy as np

from tissue_sim_ros.engine.model.kernels import LAW_EXPONENTIAL, LAW_NONE, LAW_POLYNOMIAL
from tissue_sim_ros.errors import MaterialError


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


@dataclass(frozen=True)
class Viscosity:
    """Kelvin-Voigt viscosity (seed section 4.3): sigma_v = lambda_v tr(d eps/dt) I + 2 mu_v d eps/dt.

    lambda_v, mu_v [Pa s] play the role of the Lamé coefficients for the strain rate, so the
    viscous tensors are built like K: Kv_jk = lambda_v A_jk + mu_v B_jk.
    """

    lambda_v: float
    mu_v: float

    def __post_init__(self):
        _require('lambda_v', self.lambda_v, lambda v: v >= 0, 'a finite value >= 0 Pa s')
        _require('mu_v', self.mu_v, lambda v: v >= 0, 'a finite value >= 0 Pa s')


class MeanRatioLaw:
    """Physically non-linear Lamé corrections (seed section 4.1) driven by element distortion.

    The distortion of an element is s = max(0, 1 - q / q_rest), q its Liu-Joe mean ratio
    (docs/method.md, "Liu-Joe mean ratio"); the element's coefficients become
    lambda (1 + g_lambda(s)), mu (1 + g_mu(s)).
    Build one with ``MeanRatioLaw.none()``, ``.polynomial(...)`` or ``.exponential(...)``;
    ``kind`` and ``parameters`` are what the force kernel reads, and ``corrections(s)`` is the
    same law in numpy (for tests and fitting).
    """

    def __init__(self, kind, parameters, description):
        self.kind = kind
        self.parameters = np.asarray(parameters, dtype=float)
        self.description = description

    @classmethod
    def none(cls):
        """No correction: the linear coefficients."""
        return cls(LAW_NONE, [0.0], 'none')

    @classmethod
    def polynomial(cls, lambda_coefficients=(), mu_coefficients=()):
        """g(s) = c_1 s + c_2 s^2 + ... (dimensionless coefficients, one list per Lamé coefficient)."""
        order = max(len(lambda_coefficients), len(mu_coefficients))
        lam = list(lambda_coefficients) + [0.0] * (order - len(lambda_coefficients))
        mu = list(mu_coefficients) + [0.0] * (order - len(mu_coefficients))
        for name, values in (('lambda_coefficients', lam), ('mu_coefficients', mu)):
            for v in values:
                _require(name, v, lambda x: True, 'finite numbers')
        return cls(LAW_POLYNOMIAL, [order] + lam + mu, f'polynomial(lambda {lam}, mu {mu})')

    @classmethod
    def exponential(cls, lambda_amplitude=0.0, lambda_rate=0.0, mu_amplitude=0.0, mu_rate=0.0):
        """g(s) = amplitude (exp(rate s) - 1): stiffening that grows fast with distortion."""
        for name, v in (('lambda_amplitude', lambda_amplitude), ('lambda_rate', lambda_rate),
                        ('mu_amplitude', mu_amplitude), ('mu_rate', mu_rate)):
            _require(name, v, lambda x: True, 'a finite number')
        return cls(LAW_EXPONENTIAL, [lambda_amplitude, lambda_rate, mu_amplitude, mu_rate],
                   f'exponential(lambda {lambda_amplitude} (e^({lambda_rate} s) - 1), '
                   f'mu {mu_amplitude} (e^({mu_rate} s) - 1))')

    def corrections(self, distortion):
        """(g_lambda(s), g_mu(s)) in numpy, the same law the kernel evaluates."""
        s = np.asarray(distortion, dtype=float)
        p = self.parameters
        if self.kind == LAW_POLYNOMIAL:
            order = int(p[0])
            powers = s[..., None] ** np.arange(1, order + 1)
            return powers @ p[1:1 + order], powers @ p[1 + order:]
        if self.kind == LAW_EXPONENTIAL:
            return p[0] * np.expm1(p[1] * s), p[2] * np.expm1(p[3] * s)
        return np.zeros_like(s), np.zeros_like(s)

    def __repr__(self):
        return f'MeanRatioLaw.{self.description}'
