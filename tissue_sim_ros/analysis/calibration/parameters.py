"""The parameters a calibration fits: ``--fit KEY=LOW:HIGH[:log]``, and where each acts.

KEY is any scene key ``--set`` accepts (``regions[liver].young_modulus_pa``,
``model.physical.mu_amplitude``, ``regions[0].membrane.rupture_force_n``). The search works on
unit coordinates u in [0, 1] per key: ``value = low + u (high - low)``, or with ``log``
``value = low (high / low)^u`` (for keys that span decades: moduli, viscosities), so one
finite-difference step means the same relative change for every key.

Each key belongs to the phase of the curve where it acts, which the staged start fits it on
(:data:`PHASE_RULES`, first match on the key's name): stiffness and law coefficients on the
loading before the first puncture, the puncture threshold and a layer's boundary (where it is
punctured) on the peaks, cutting and insertion friction on the steady part after the puncture,
retraction friction on the retraction, relaxation on the hold; layer by layer
(:mod:`~tissue_sim_ros.analysis.calibration.stages`).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass

__all__ = ['FittedKey', 'PHASE_RULES', 'parse_fit', 'phase_of', 'read_key']

#: (pattern on the key, the phase it is fitted on in the staged start); the first match wins
PHASE_RULES = (
    (r'membrane|rupture|puncture|\.select\.', 'puncture'),
    (r'friction\.retraction', 'retraction'),
    (r'cutting|friction', 'inserted'),
    (r'relaxation|prony', 'hold'),
    (r'.', 'loading'),
)


def phase_of(key: str) -> str:
    """The phase of the curve where ``key`` acts (see :data:`PHASE_RULES`)."""
    return next(phase for pattern, phase in PHASE_RULES if re.search(pattern, key))


@dataclass(frozen=True)
class FittedKey:
    """A fitted scene key, its bounds and its scale."""

    key: str
    low: float
    high: float
    log: bool = False

    @property
    def phase(self) -> str:
        return phase_of(self.key)

    def value(self, u: float) -> float:
        """The value at unit coordinate ``u`` (clipped to [0, 1])."""
        u = min(1.0, max(0.0, float(u)))
        if self.log:
            return self.low * (self.high / self.low) ** u
        return self.low + u * (self.high - self.low)

    def unit(self, value: float) -> float:
        """The unit coordinate of ``value`` (clipped to the bounds)."""
        value = min(self.high, max(self.low, float(value)))
        if self.log:
            return math.log(value / self.low) / math.log(self.high / self.low)
        return (value - self.low) / (self.high - self.low)

    def value_per_unit(self, u: float) -> float:
        """d value / d u at ``u``: converts a unit-coordinate standard error to the key's unit."""
        if self.log:
            return self.value(u) * math.log(self.high / self.low)
        return self.high - self.low


def parse_fit(text: str) -> FittedKey:
    """``KEY=LOW:HIGH[:log]`` -> FittedKey; a clear error naming the option otherwise."""
    from tissue_sim_ros.engine.scene.keys import parse_key
    from tissue_sim_ros.errors import SceneError
    if '=' not in text:
        raise SceneError(f'--fit {text!r}: expected KEY=LOW:HIGH[:log], e.g. '
                         'regions[0].young_modulus_pa=5000:50000:log')
    key, bounds = text.split('=', 1)
    parts = bounds.split(':')
    log = len(parts) == 3 and parts[2].strip().lower() == 'log'
    if len(parts) not in (2, 3) or (len(parts) == 3 and not log):
        raise SceneError(f'--fit {text!r}: the bounds must read LOW:HIGH or LOW:HIGH:log')
    try:
        low, high = float(parts[0]), float(parts[1])
    except ValueError:
        raise SceneError(f'--fit {text!r}: LOW and HIGH must be numbers, got {parts[0]!r} and '
                         f'{parts[1]!r}') from None
    if not (math.isfinite(low) and math.isfinite(high) and low < high):
        raise SceneError(f'--fit {text!r}: expected finite bounds with LOW < HIGH, got {low} and {high}')
    if log and low <= 0:
        raise SceneError(f'--fit {text!r}: a log scale needs LOW > 0, got {low}')
    parse_key(key, context=f'--fit {text!r}')     # the key path's syntax
    return FittedKey(key.strip(), low, high, log)


def read_key(spec: dict, key: str) -> float:
    """The number at the fitted ``key`` in ``spec`` (a scene's checked keys, ``Scene.spec``), after
    checking that every value between its bounds can be set there (a SceneError naming the key
    before any evaluation runs, not a miss at every one)."""
    from tissue_sim_ros.engine.scene.keys import get_key
    from tissue_sim_ros.errors import SceneError
    value = get_key(spec, key)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SceneError(f'--fit {key}: its value {value!r} is not a number')
    return float(value)
