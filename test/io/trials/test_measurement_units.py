"""Units of recordings (io/trials/measurement_units.py): factors against their definitions."""

import pytest

from tissue_sim_ros.errors import UnitError
from tissue_sim_ros.io.trials.measurement_units import to_si, unit_factor

# Independent definitions: standard gravity, the avoirdupois pound, the inch.
G0 = 9.80665
LBF_N = 0.45359237 * G0
INCH_M = 25.4e-3


@pytest.mark.parametrize('quantity, unit, si', [
    ('time', 's', 1.0), ('time', 'ms', 1e-3), ('time', 'us', 1e-6), ('time', 'µs', 1e-6),
    ('time', 'μs', 1e-6), ('time', 'ns', 1e-9),
    ('force', 'N', 1.0), ('force', 'mN', 1e-3), ('force', 'kN', 1e3), ('force', 'gf', 1e-3 * G0),
    ('force', 'kgf', G0), ('force', 'lbf', LBF_N), ('force', 'ozf', LBF_N / 16),
    ('torque', 'N m', 1.0), ('torque', 'Nm', 1.0), ('torque', 'N*m', 1.0), ('torque', 'N.m', 1.0),
    ('torque', 'N mm', 1e-3), ('torque', 'Nmm', 1e-3), ('torque', 'mN m', 1e-3),
    ('position', 'm', 1.0), ('position', 'cm', 1e-2), ('position', 'mm', 1e-3),
    ('position', 'um', 1e-6), ('position', 'µm', 1e-6), ('position', 'in', INCH_M),
    ('speed', 'm/s', 1.0), ('speed', 'mm/s', 1e-3), ('speed', 'um/s', 1e-6),
])
def test_unit_factor_matches_its_definition(quantity, unit, si):
    assert unit_factor(quantity, unit) == pytest.approx(si, rel=1e-15)
    assert to_si([2.0, -3.0], quantity, unit) == pytest.approx([2 * si, -3 * si], rel=1e-15)


def test_pound_force_is_the_published_value():
    assert unit_factor('force', 'lbf') == pytest.approx(4.4482216152605, rel=1e-14)


@pytest.mark.parametrize('quantity, unit', [('force', 'MN'), ('force', 'lb'), ('torque', 'N'),
                                            ('time', 'Hz'), ('position', 'furlong')])
def test_unknown_unit_names_quantity_unit_and_known_units(quantity, unit):
    with pytest.raises(UnitError) as err:
        unit_factor(quantity, unit)
    message = str(err.value)
    assert quantity in message and repr(unit) in message
    assert all(known in message for known in {'force': ['N', 'mN', 'lbf'], 'torque': ['N mm'],
                                              'time': ['ms', 'us'],
                                              'position': ['mm', 'in']}[quantity])
