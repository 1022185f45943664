"""Declaring the node's parameters with rclpy: descriptions, ranges, read-only; a refused
override becomes a ConfigError naming the parameter (the only rclpy part of the parameters)."""
from __future__ import annotations

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.exceptions import (InvalidParameterTypeException, InvalidParameterValueException,
                              ParameterException)

from tissue_sim_ros.ros.parameters import PARAMETERS
from tissue_sim_ros.errors import ConfigError

__all__ = ['declare_parameters']


def _descriptor(p) -> ParameterDescriptor:
    text = p.description
    if p.choices:
        text += f' (one of: {", ".join(p.choices)})'
    d = ParameterDescriptor(description=text, read_only=True)
    if p.low is not None:
        if isinstance(p.default, float):
            d.floating_point_range = [FloatingPointRange(from_value=float(p.low),
                                                         to_value=float(p.high), step=0.0)]
        else:
            d.integer_range = [IntegerRange(from_value=int(p.low), to_value=int(p.high), step=0)]
    if p.choices:
        d.additional_constraints = f'one of: {", ".join(p.choices)}'
    return d


def _type_word(value) -> str:
    if isinstance(value, bool):
        return 'a boolean'
    if isinstance(value, int):
        return 'an integer'
    if isinstance(value, float):
        return 'a floating-point number'
    if isinstance(value, str):
        return 'a string'
    return type(value).__name__


def declare_parameters(node) -> dict:
    """Declare every parameter (descriptions, ranges, read-only); their values by name.

    Raises ConfigError naming the parameter and its value when rclpy refuses an override
    (wrong type, out of range).
    """
    values = {}
    for p in PARAMETERS:
        try:
            values[p.name] = node.declare_parameter(p.name, p.default, _descriptor(p)).value
        except InvalidParameterTypeException as exc:
            raise ConfigError(
                f'parameter {p.name}: {exc}; expected {_type_word(p.default)} like '
                f'{p.default!r}' + (' (write 50.0, not 50)' if isinstance(p.default, float) else '')
            ) from None
        except InvalidParameterValueException as exc:
            low, high = p.low, p.high
            raise ConfigError(f'parameter {p.name}: {exc}; expected {low} <= value <= {high}') \
                from None
        except ParameterException as exc:
            raise ConfigError(f'parameter {p.name}: {exc}') from None
    return values
