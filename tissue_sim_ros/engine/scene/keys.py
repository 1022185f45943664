"""``--set KEY=VALUE``: changing scene keys from the command line, checked like the file.

KEY is a dotted scene key as ``tissue-sim scene-keys`` prints it, with a region picked by index
or by name: ``model.geometric=false``, ``solver.mass_scaling=100``,
``regions[0].young_modulus_pa=20000``, ``regions[capsule].membrane.rupture_force_n=2.1``.
VALUE is read as YAML (``20000``, ``true``, ``null``, ``[0.0, 0.0, 0.16]``, ``exponential``).
An override is applied to the scene file's keys before they are checked, so an impossible value
gets the file's own error naming the key; an unknown key is refused here, naming the override
and the keys known at that level. ``with_mass_scaling``: a scene's keys at another mass
scaling, the damping force kept (the rule of Simulation.rescale_masses, at set-up).
"""
from __future__ import annotations

import copy
import re

import yaml

from tissue_sim_ros.engine.scene.schema import SCHEMA, SceneError

__all__ = ['parse_override', 'apply_overrides', 'select_region', 'with_mass_scaling']

_PART = re.compile(r'^([A-Za-z_][A-Za-z0-9_]*)(?:\[([^\]]*)\])?$')


def parse_override(text: str) -> tuple[list[tuple[str, str | None]], object]:
    """``KEY=VALUE`` -> ([(key, selector or None), ...], value)."""
    if '=' not in text:
        raise SceneError(f'--set {text!r}: expected KEY=VALUE, e.g. solver.mass_scaling=100')
    key, raw = text.split('=', 1)
    parts = []
    for part in key.strip().split('.'):
        match = _PART.match(part)
        if not match:
            raise SceneError(f'--set {text!r}: {part!r} is not a scene key (expected names like '
                             'regions[0].young_modulus_pa)')
        parts.append((match.group(1), match.group(2)))
    try:
        value = yaml.safe_load(raw) if raw.strip() else ''
    except yaml.YAMLError as exc:
        raise SceneError(f'--set {text!r}: the value is not valid YAML ({exc})') from None
    return parts, value


def select_region(items: list, selector: str | None, text: str, dotted: str) -> dict:
    if selector is None or selector == '':
        raise SceneError(f'--set {text!r}: {dotted} is a list; pick a region by index or name, '
                         f'e.g. {dotted}[0] or {dotted}[liver]')
    if re.fullmatch(r'-?\d+', selector):
        index = int(selector)
        if not 0 <= index < len(items):
            raise SceneError(f'--set {text!r}: {dotted}[{index}]: the scene has {len(items)} '
                             f'region(s), indices 0 to {len(items) - 1}')
        return items[index]
    default_name = SCHEMA['regions'][0]['name'][0]
    named = [r for r in items if isinstance(r, dict) and r.get('name', default_name) == selector]
    if not named:
        names = [r.get('name', default_name) if isinstance(r, dict) else '?' for r in items]
        raise SceneError(f'--set {text!r}: no region named {selector!r} (the scene has '
                         f'{", ".join(map(repr, names))})')
    return named[0]


def apply_overrides(spec: dict, overrides) -> dict:
    """A copy of the scene keys ``spec`` (as read from the file) with each ``KEY=VALUE`` of
    ``overrides`` applied in order."""
    spec = copy.deepcopy(spec or {})
    for text in overrides or ():
        parts, value = parse_override(text)
        node, schema, dotted = spec, SCHEMA, ''
        for i, (key, selector) in enumerate(parts):
            dotted = f'{dotted}.{key}' if dotted else key
            if not isinstance(schema, dict) or key not in schema:
                known = ', '.join(schema) if isinstance(schema, dict) else '(none: a value)'
                raise SceneError(f'--set {text!r}: unknown scene key {dotted}; known keys here: {known}')
            last = i == len(parts) - 1
            if isinstance(schema[key], list):
                if not isinstance(node.get(key), list) or not node[key]:
                    node[key] = [{}]
                node, schema = select_region(node[key], selector, text, dotted), schema[key][0]
                dotted += f'[{selector}]'
                if last:
                    raise SceneError(f'--set {text!r}: {dotted} is a region; set one of its keys')
                continue
            if selector is not None:
                raise SceneError(f'--set {text!r}: {dotted} is not a list of regions; no [{selector}]')
            if last:
                if isinstance(schema[key], dict):
                    raise SceneError(f'--set {text!r}: {dotted} is a section; set one of its keys '
                                     f'({", ".join(schema[key])})')
                node[key] = value
            else:
                if not isinstance(node.get(key), dict):
                    node[key] = {}
                node, schema = node[key], schema[key]
    return spec


def with_mass_scaling(spec: dict, mass_scaling: float) -> dict:
    """``spec`` (its ``solver.mass_scaling`` a number) at ``mass_scaling``, its mass-proportional
    damping rate lowered by the same ratio so that the damping force is the one the scene states:
    a mass scaling raised to afford a stiffer scene or a cheaper run changes only the inertia
    (Simulation.rescale_masses, the same rule at run time)."""
    solver = spec['solver']
    ratio = float(mass_scaling) / float(solver['mass_scaling'])
    return dict(spec, solver=dict(solver, mass_scaling=float(mass_scaling),
                                  damping_per_s=float(solver['damping_per_s']) / ratio))
