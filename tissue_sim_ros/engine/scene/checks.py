"""The kinds of scene values and their checks: each value checked once, where it enters.

A kind is a string (``'float+'``: a number > 0, ``'float0'``: >= 0, ``'float'``, ``'int+'``: a
whole number >= 1, ``'int0'``: a whole number >= 0, ``'bool'``, ``'str'``, ``'vec2'``, ``'vec3'``,
``'vec3+'``, ``'quat'``, ``'floats'``, ``'scaling'``: a number >= 1 or ``'auto'``, ``'faces'``,
``'select'``: a region's volume, ``'support'``: a selector of nodes (a volume's, or the surface
near a point, or a mesh file's node set), ``'supports'``: a list of box faces and support
selectors, ``'needles'``), a tuple of allowed strings, a :class:`Range` or a :class:`MappingList`. A refusal is a SceneError naming the dotted
key, the value and what was expected.

Units (REP 103): a key's unit is in its name (``_m``, ``_pa``, ``_s``, ...; :func:`unit_of`).
A number may be written with another unit of the same quantity beside it, as text
(``young_modulus_pa: 22 kPa``, ``fine_size_m: 1.5 mm``): it is converted here, once.
"""
from __future__ import annotations

import contextlib
import copy
import math
import re
from dataclasses import dataclass
from typing import Callable

from tissue_sim_ros.errors import SceneError

__all__ = ['FACES', 'node_select_keys', 'MappingList', 'Range', 'apply_schema', 'check_value', 'select_keys', 'unit_of']

FACES = ('bottom', 'top', 'walls', 'x_min', 'x_max', 'y_min', 'y_max')
_SELECT_KEYS = ('below_z_m', 'above_z_m', 'box_m', 'sphere_m', 'half_space_m', 'tag')
#: selectors of nodes only (supports): not volumes, so not a region's
_NODE_SELECT_KEYS = ('surface_near_m', 'node_set')


@dataclass(frozen=True)
class MappingList:
    """Kind of a key holding a list of mappings (default: none): each entry is checked against
    the schema ``entry``, then the whole list by ``check(entries, dotted_name)``, which raises a
    ValueError naming what it refuses."""
    entry: dict
    check: Callable


@dataclass(frozen=True)
class Range:
    """Kind of a number in an interval: open at an end unless ``*_closed``; None: unbounded."""
    low: float | None = None
    high: float | None = None
    low_closed: bool = False
    high_closed: bool = False

    def contains(self, v: float) -> bool:
        return ((self.low is None or (v >= self.low if self.low_closed else v > self.low))
                and (self.high is None or (v <= self.high if self.high_closed else v < self.high)))

    def text(self) -> str:
        left = '[' if self.low_closed else '('
        right = ']' if self.high_closed else ')'
        low = '-inf' if self.low is None else f'{self.low:g}'
        high = 'inf' if self.high is None else f'{self.high:g}'
        return f'a number in {left}{low}, {high}{right}'


#: SI unit of a key from the end of its name (longest first), and the units a value may be
#: written in instead, with their factors to it
_SUFFIX_UNITS = (('_n_s_per_m2', 'N s/m^2'), ('_n_per_m3', 'N/m^3'), ('_j_per_m2', 'J/m^2'), ('_kg_per_m3', 'kg/m^3'),
                 ('_n_per_m', 'N/m'), ('_pa_s', 'Pa s'), ('_m_s2', 'm/s^2'), ('_m_s', 'm/s'),
                 ('_per_s', '1/s'), ('_pa', 'Pa'), ('_deg', 'deg'), ('_m', 'm'), ('_s', 's'),
                 ('_n', 'N'), ('_hz', 'Hz'), ('_xyzw', '-'))
_CONVERSIONS = {
    'm': {'m': 1.0, 'cm': 1e-2, 'mm': 1e-3, 'um': 1e-6},
    'Pa': {'Pa': 1.0, 'kPa': 1e3, 'MPa': 1e6, 'GPa': 1e9},
    's': {'s': 1.0, 'ms': 1e-3, 'us': 1e-6, 'min': 60.0},
    'N': {'N': 1.0, 'mN': 1e-3},
    'm/s': {'m/s': 1.0, 'mm/s': 1e-3, 'cm/s': 1e-2},
    'Pa s': {'Pa s': 1.0, 'kPa s': 1e3},
    'deg': {'deg': 1.0, 'rad': 180.0 / math.pi},
}
_WITH_UNIT = re.compile(r'^\s*([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)\s*([A-Za-z/ ]+?)\s*$')


def unit_of(name: str) -> str:
    """The SI unit a key's name says (``fine_size_m`` -> 'm'), '-' for a dimensionless one."""
    return next((unit for suffix, unit in _SUFFIX_UNITS if name.endswith(suffix)), '-')


def select_keys() -> tuple[str, ...]:
    """The shapes a region's ``select`` may take as a mapping."""
    return _SELECT_KEYS


def node_select_keys() -> tuple[str, ...]:
    """The selectors of nodes a support may use besides a region's shapes."""
    return _NODE_SELECT_KEYS


def _number_text(name, value):
    """A number written as text: plain (YAML 1.1 reads ``1e-5`` as text) or with a unit of the
    key's quantity beside it, converted to the key's SI unit."""
    if not isinstance(value, str) or not value.isascii():
        return value
    with contextlib.suppress(ValueError):
        return float(value)
    match = _WITH_UNIT.match(value)
    si = unit_of(name.rsplit('.', 1)[-1].split('[')[0])
    if match and si in _CONVERSIONS:
        factor = _CONVERSIONS[si].get(match.group(2).strip())
        if factor is None:
            raise SceneError(f'{name} = {value!r}: unknown unit {match.group(2).strip()!r} for this key; '
                             f'expected a number in {si} or one of {", ".join(_CONVERSIONS[si])}')
        return float(match.group(1)) * factor
    return value


def check_value(name, value, kind):
    """``value`` of the key ``name`` checked against ``kind`` and normalised (floats, lists)."""
    def fail(expected):
        raise SceneError(f'{name} = {value!r}: expected {expected}')

    def number(v):
        v = _number_text(name, v)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            fail('a finite number')
        return float(v)

    if isinstance(kind, tuple):
        if value not in kind:
            fail('one of ' + ', '.join(kind))
        return value
    if isinstance(kind, Range):
        v = number(value)
        if not kind.contains(v):
            fail(kind.text())
        return v
    if kind in ('str', 'bool'):
        if not isinstance(value, {'str': str, 'bool': bool}[kind]):
            fail('a string' if kind == 'str' else 'true or false')
        return value
    if kind == 'scaling':
        if value == 'auto':
            return value
        v = number(value)
        if not v >= 1:
            fail("a factor >= 1 or 'auto'")
        return v
    if kind == 'int+':
        v = number(value)
        if not (v >= 1 and v == int(v)):
            fail('a whole number >= 1')
        return int(v)
    if kind == 'int0':
        v = number(value)
        if not (v >= 0 and v == int(v)):
            fail('a whole number >= 0')
        return int(v)
    if kind in ('float', 'float+', 'float0'):
        v = number(value)
        if kind == 'float+' and not v > 0:
            fail('a number > 0')
        if kind == 'float0' and not v >= 0:
            fail('a number >= 0')
        return v
    if kind in ('vec3', 'vec3+', 'vec2', 'quat', 'floats'):
        if not isinstance(value, (list, tuple)):
            fail('a list of numbers')
        v = [number(x) for x in value]
        size = {'vec3': 3, 'vec3+': 3, 'vec2': 2, 'quat': 4}.get(kind)
        if size is not None and len(v) != size:
            fail(f'{size} numbers')
        if kind == 'vec3+' and min(v) <= 0:
            fail('3 numbers > 0')
        return v
    if kind == 'needles':
        return _needle_entries(name, value)
    if kind == 'faces':
        if not isinstance(value, (list, tuple)) or any(f not in FACES for f in value):
            fail('a list of ' + ', '.join(FACES))
        return list(value)
    if kind == 'supports':
        if not isinstance(value, (list, tuple)):
            fail('a list of box faces (' + ', '.join(FACES) + ') and selectors')
        return [f if isinstance(f, str) and f in FACES else check_value(f'{name}[{i}]', f, 'support')
                for i, f in enumerate(value)]
    if kind == 'support':
        return _select(name, value, number, fail, nodes=True)
    if isinstance(kind, MappingList):
        if not isinstance(value, (list, tuple)):
            fail('a list of mappings')
        entries = [apply_schema(f'{name}[{i}]', entry, kind.entry) for i, entry in enumerate(value)]
        try:
            kind.check(entries, name)
        except SceneError:
            raise
        except ValueError as exc:           # the check names the key path itself
            raise SceneError(str(exc)) from exc
        return entries
    if kind == 'select':
        return _select(name, value, number, fail)
    raise AssertionError(kind)


def _needle_entries(name, value):
    if not isinstance(value, (list, tuple)):
        raise SceneError(f"{name} = {value!r}: expected a list of mappings, each with a 'name'")
    names = []
    for i, entry in enumerate(value):
        if not isinstance(entry, dict) or not isinstance(entry.get('name'), str) or not entry['name'].strip():
            raise SceneError(f'{name}[{i}] = {entry!r}: expected a mapping with a non-empty name')
        if entry['name'] in names or not entry['name'].replace('_', 'a').isalnum():
            raise SceneError(f"{name}[{i}].name = {entry['name']!r}: expected a unique name of letters, "
                             'digits and _ (it names the topics needle/<name>/pose and /wrench)')
        names.append(entry['name'])
    return [dict(entry) for entry in value]


def _select(name, value, number, fail, nodes=False):
    if value == 'all':
        return value
    if isinstance(value, dict) and len(value) == 1:
        (key, v), = value.items()
        if key == 'half_space_m':
            plane = check_value(f'{name}.half_space_m', v, 'floats')
            if len(plane) != 6 or not any(plane[3:]):
                fail('{half_space_m: [x, y, z, nx, ny, nz]}: a point of the plane and a normal that is not 0')
            return {key: plane}
        if nodes and key == 'surface_near_m':
            near = check_value(f'{name}.surface_near_m', v, 'floats')
            if len(near) != 4 or not near[3] > 0:
                fail('{surface_near_m: [x, y, z, d]}: the surface within d > 0 of the point')
            return {key: near}
        if nodes and key == 'node_set' and isinstance(v, str) and v:
            return value
        if key == 'tag' and isinstance(v, int) and not isinstance(v, bool):
            return value
        if key in ('above_z_m', 'below_z_m'):
            return {key: number(v)}
        if key == 'sphere_m':
            sphere = check_value(f'{name}.sphere_m', v, 'floats')
            if len(sphere) != 4 or not sphere[3] > 0:
                fail('{sphere_m: [x, y, z, r]} with r > 0')
            return {key: sphere}
        if key == 'box_m' and isinstance(v, (list, tuple)) and len(v) == 2:
            return {key: [check_value(f'{name}.box_m', c, 'vec3') for c in v]}
    fail("'all', {tag: N}, {box_m: [[x,y,z],[x,y,z]]}, {sphere_m: [x,y,z,r]}, {half_space_m: [x,y,z,nx,ny,nz]}, "
         "{above_z_m: z} or {below_z_m: z}" + (", {surface_near_m: [x,y,z,d]} or {node_set: NAME}" if nodes else
                                               ' (a volume: the surface and node-set selectors are for supports)'))


def apply_schema(name, data, schema):
    """Fill defaults and validate ``data`` against ``schema``; unknown keys refused by name."""
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise SceneError(f'{name or "scene"} = {data!r}: expected a mapping of keys')
    unknown = sorted(set(data) - set(schema))
    if unknown:
        where = f'{name}.' if name else ''
        raise SceneError(f'unknown scene key {where}{unknown[0]!s}; known keys here: {", ".join(schema)}')
    out = {}
    for key, spec in schema.items():
        dotted = f'{name}.{key}' if name else key
        if isinstance(spec, dict):
            out[key] = apply_schema(dotted, data.get(key), spec)
        elif isinstance(spec, list):
            items = data.get(key, [{}])
            if not isinstance(items, list) or not items:
                raise SceneError(f'{dotted} = {items!r}: expected a non-empty list')
            out[key] = [apply_schema(f'{dotted}[{i}]', item, spec[0]) for i, item in enumerate(items)]
        else:
            default, kind, _ = spec
            value = data.get(key, copy.deepcopy(default))
            out[key] = None if value is None and default is None else check_value(dotted, value, kind)
    return out
