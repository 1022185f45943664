"""Units of load-cell recordings and their factors to SI (REP 103), with one clear refusal.

A recording says its units beside its columns (time in us from a microcontroller timer, force in
mN or lbf, torque in N mm, position in mm); the data description names them and this module turns
them into the factor that brings a column to seconds, newtons, newton metres, metres or metres
per second. Spellings are matched after removing spaces, '*', '.' and the middle dot, and with
the micro sign or the Greek mu read as 'u' ('N m' = 'Nm' = 'N*m' = 'N.m', 'µs' = 'us'); case
matters ('mN' is not 'MN').
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.errors import UnitError

__all__ = ['STANDARD_GRAVITY_M_PER_S2', 'UNITS', 'known_units', 'to_si',
           'unit_factor']

#: Standard gravity [m/s^2] (CGPM 1901), the factor of the gram-force and the pound-force.
STANDARD_GRAVITY_M_PER_S2 = 9.80665
#: The international avoirdupois pound [kg] (1959).
_POUND_KG = 0.45359237
_POUND_FORCE_N = _POUND_KG * STANDARD_GRAVITY_M_PER_S2  # 4.4482216152605 N

#: quantity -> {unit as documented: factor to SI}; the SI unit of each quantity comes first.
UNITS: dict[str, dict[str, float]] = {
    'time': {'s': 1.0, 'ms': 1e-3, 'us': 1e-6, 'ns': 1e-9},
    'force': {'N': 1.0, 'mN': 1e-3, 'kN': 1e3, 'gf': 1e-3 * STANDARD_GRAVITY_M_PER_S2,
              'kgf': STANDARD_GRAVITY_M_PER_S2, 'lbf': _POUND_FORCE_N,
              'ozf': _POUND_FORCE_N / 16.0},
    'torque': {'N m': 1.0, 'N mm': 1e-3, 'mN m': 1e-3},
    'position': {'m': 1.0, 'cm': 1e-2, 'mm': 1e-3, 'um': 1e-6, 'in': 0.0254},
    'speed': {'m/s': 1.0, 'mm/s': 1e-3, 'um/s': 1e-6},
}

_SEPARATORS = str.maketrans({' ': None, '*': None, '.': None, '\u00b7': None,
                             '\u00b5': 'u', '\u03bc': 'u'})


def _compact(unit: str) -> str:
    """The spelling a unit is matched by: no separators, micro as 'u'."""
    return unit.strip().translate(_SEPARATORS)


_BY_SPELLING = {quantity: {_compact(unit): factor for unit, factor in table.items()}
                for quantity, table in UNITS.items()}


def known_units(quantity: str) -> list[str]:
    """The units documented for ``quantity`` (one of :data:`UNITS`), SI first."""
    if quantity not in UNITS:
        raise UnitError(f'quantity {quantity!r}: expected one of {", ".join(UNITS)}')
    return list(UNITS[quantity])


def unit_factor(quantity: str, unit: str) -> float:
    """The factor that turns a value of ``quantity`` in ``unit`` into SI.

    ``unit_factor('force', 'lbf')`` is 4.4482216152605; ``unit_factor('torque', 'Nmm')`` 1e-3.
    An unknown unit raises :class:`UnitError` naming the quantity, the unit and the known units.
    """
    known = known_units(quantity)
    factor = _BY_SPELLING[quantity].get(_compact(unit)) if isinstance(unit, str) else None
    if factor is None:
        raise UnitError(f'{quantity} unit {unit!r} is not known; known {quantity} units: '
                        f'{", ".join(known)}')
    return factor


def to_si(values, quantity: str, unit: str) -> np.ndarray:
    """``values`` (any array-like) in ``unit`` as a float64 array in SI."""
    return np.asarray(values, dtype=np.float64) * unit_factor(quantity, unit)
