"""Scene values by key path: ``regions[0].young_modulus_pa``, read and set on a scene's keys.

A key path is the dotted names ``tissue-sim scene-keys`` prints. A name whose value is a list
takes an entry: ``[index]`` or ``[name]`` (the entry whose ``name`` is that), at any depth and
for any list: ``regions[liver].membrane.rupture_force_n``, ``regions[1].select.below_z_m`` (a
layer boundary's depth), ``model.relaxation[0].time_constant_s``, ``needles[probe].length_m``,
``targets[tumour].position_m``; a list of numbers takes an index too
(``needle.initial_position_m[2]``).

:func:`set_key` checks the value against the schema where it is set, so that an impossible
value is refused naming its key path, before any scene is built; calibration, recommendation
and predictions set values this way, as numbers, never through text. ``--set KEY=VALUE`` of the
commands (:func:`apply_overrides`) reads VALUE as YAML and sets it the same way.
"""
from __future__ import annotations

import copy
import re

import yaml

from tissue_sim_ros.engine.scene.checks import MappingList, apply_schema, check_value, select_keys
from tissue_sim_ros.engine.scene.schema import SCHEMA
from tissue_sim_ros.errors import SceneError

__all__ = ['KeyPath', 'apply_overrides', 'get_key', 'override_text', 'parse_key', 'parse_override', 'set_key',
           'set_keys', 'with_mass_scaling']

_PART = re.compile(r'^([A-Za-z_][A-Za-z0-9_]*)(?:\[([^\]]*)\])?$')

#: a parsed key path: [(name, selector or None), ...]
KeyPath = list


def parse_key(text: str, *, context: str = '') -> KeyPath:
    """``regions[0].young_modulus_pa`` -> [('regions', '0'), ('young_modulus_pa', None)]."""
    where = context or f'scene key {text!r}'
    parts = []
    for part in text.strip().split('.'):
        match = _PART.match(part)
        if not match:
            raise SceneError(f'{where}: {part!r} is not a scene key (expected names like '
                             'regions[0].young_modulus_pa)')
        parts.append((match.group(1), match.group(2)))
    return parts


def parse_override(text: str) -> tuple[KeyPath, object]:
    """``KEY=VALUE`` -> (key path, VALUE read as YAML)."""
    if '=' not in text:
        raise SceneError(f'--set {text!r}: expected KEY=VALUE, e.g. solver.mass_scaling=100')
    key, raw = text.split('=', 1)
    parts = parse_key(key, context=f'--set {text!r}')
    try:
        value = yaml.safe_load(raw) if raw.strip() else ''
    except yaml.YAMLError as exc:
        raise SceneError(f'--set {text!r}: the value is not valid YAML ({exc})') from None
    return parts, value


def _dotted(parts: KeyPath) -> str:
    return '.'.join(name + ('' if sel is None else f'[{sel}]') for name, sel in parts)


def _entry(items: list, selector: str | None, dotted: str, where: str, default_name=None):
    """The index of the entry of ``items`` that ``selector`` picks (an index or a name)."""
    if selector is None or selector == '':
        raise SceneError(f'{where}: {dotted} is a list; pick an entry by index or name, e.g. '
                         f'{dotted}[0]')
    if re.fullmatch(r'-?\d+', selector):
        index = int(selector)
        if not 0 <= index < len(items):
            raise SceneError(f'{where}: {dotted}[{index}]: the list has {len(items)} entr'
                             f'{"y" if len(items) == 1 else "ies"}'
                             + (f', indices 0 to {len(items) - 1}' if items else ''))
        return index
    names = [e.get('name', default_name) if isinstance(e, dict) else None for e in items]
    if selector not in names:
        raise SceneError(f'{where}: no entry of {dotted} named {selector!r} (it has '
                         f'{", ".join(repr(n) for n in names) or "none"})')
    return names.index(selector)


def _kind_of(schema_node):
    """('section', schema) | ('sections', entry schema, default name) | ('entries', entry schema,
    default name) | ('select',) | ('numbers',) | ('leaf', kind)."""
    if isinstance(schema_node, dict):
        return ('section', schema_node)
    if isinstance(schema_node, list):
        return ('sections', schema_node[0], schema_node[0].get('name', (None,))[0])
    kind = schema_node[1]
    if isinstance(kind, MappingList):
        return ('entries', kind.entry, None)
    if kind == 'needles':
        return ('entries', {'name': (None, 'str', ''), **SCHEMA['needle']}, None)
    if kind == 'select':
        return ('select',)
    if kind in ('vec2', 'vec3', 'vec3+', 'quat', 'floats'):
        return ('numbers', kind)
    return ('leaf', kind)


def _locate(spec: dict, parts: KeyPath, where: str, *, create: bool):
    """(container, key, schema node) of the last part of ``parts`` in ``spec``; containers on the
    way are made when ``create`` (a scene file need not write the sections it leaves at their
    defaults)."""
    node, schema, dotted = spec, SCHEMA, ''
    for i, (name, selector) in enumerate(parts):
        last = i == len(parts) - 1
        shown = f'{dotted}.{name}' if dotted else name
        kind = _kind_of(schema) if not isinstance(schema, dict) else ('section', schema)
        if kind[0] == 'select':
            allowed = select_keys()
            if name not in allowed or selector is not None or not last:
                raise SceneError(f'{where}: unknown scene key {shown}; a region select takes one of '
                                 f'{", ".join(allowed)}')
            return node, name, ('select-part', name)
        if kind[0] != 'section' or name not in kind[1]:
            known = ', '.join(kind[1]) if kind[0] == 'section' else '(none: a value)'
            raise SceneError(f'{where}: unknown scene key {shown}; known keys here: {known}')
        child = kind[1][name]
        child_kind = _kind_of(child)
        dotted = shown
        if child_kind[0] in ('sections', 'entries') and selector is None and last:
            return node, name, ('whole-list', child)
        if child_kind[0] in ('sections', 'entries'):
            items = node.get(name) if isinstance(node, dict) else None
            if not isinstance(items, list) or (child_kind[0] == 'sections' and not items):
                if not create and child_kind[0] == 'entries':
                    items = []
                else:
                    items = [{}] if child_kind[0] == 'sections' else []
                    if create:
                        node[name] = items
            index = _entry(items, selector, dotted, where, child_kind[2])
            dotted += f'[{selector}]'
            if last:
                raise SceneError(f'{where}: {dotted} is a list entry; set one of its keys '
                                 f'({", ".join(child_kind[1])})')
            node, schema = items[index], child_kind[1]
            continue
        if child_kind[0] == 'numbers' and selector is not None:
            if not last:
                raise SceneError(f'{where}: {dotted}[{selector}] is a number; it has no keys')
            return node, name, ('number-of', child, selector)
        if selector is not None:
            raise SceneError(f'{where}: {dotted} is not a list; no [{selector}]')
        if last:
            if child_kind[0] == 'section':
                raise SceneError(f'{where}: {dotted} is a section; set one of its keys ({", ".join(child)})')
            return node, name, child
        if child_kind[0] == 'select':
            value = node.get(name) if isinstance(node, dict) else None
            if not isinstance(value, dict):
                if not create:
                    raise SceneError(f'{where}: {dotted} = {value!r} has no {parts[i + 1][0]}')
                value = node[name] = {}
            node, schema = value, child
            continue
        if not isinstance(node.get(name), dict):
            if not create:
                return {}, parts[-1][0], None        # a section left at its defaults
            node[name] = {}
        node, schema = node[name], child
    raise AssertionError(parts)


def set_key(spec: dict, key: str | KeyPath, value, *, where: str = '') -> dict:
    """A copy of the scene keys ``spec`` with ``key`` set to ``value``, the value checked against
    the schema (a SceneError naming the key path and the value)."""
    parts = parse_key(key) if isinstance(key, str) else key
    dotted = _dotted(parts)
    where = where or f'scene key {dotted}'
    spec = copy.deepcopy(spec or {})
    container, name, schema_node = _locate(spec, parts, where, create=True)
    if schema_node[0] == 'select-part':
        container.clear()                     # a select holds one shape: the new one replaces it
        container[name] = value
        check_value(dotted.rsplit('.', 1)[0], dict(container), 'select')
        return spec
    if schema_node[0] == 'whole-list':
        child = schema_node[1]
        if isinstance(child, list):               # a list of sections (regions): each checked
            if not isinstance(value, list) or not value:
                raise SceneError(f'{where}: {dotted} = {value!r}: expected a non-empty list of mappings')
            for i, entry in enumerate(value):
                apply_schema(f'{dotted}[{i}]', entry, child[0])
            container[name] = copy.deepcopy(value)
        else:
            container[name] = check_value(dotted, value, child[1])
        return spec
    if schema_node[0] == 'number-of':
        _, child, selector = schema_node
        current = container.get(name, copy.deepcopy(child[0]))
        numbers = check_value(dotted.rsplit('[', 1)[0], current, child[1])
        index = int(selector) if re.fullmatch(r'\d+', selector or '') else -1
        if not 0 <= index < len(numbers):
            raise SceneError(f'{where}: {dotted}: {dotted.rsplit("[", 1)[0]} has {len(numbers)} numbers')
        numbers[index] = value
        container[name] = check_value(dotted.rsplit('[', 1)[0], numbers, child[1])
        return spec
    default, kind, _ = schema_node
    container[name] = None if value is None and default is None else check_value(dotted, value, kind)
    return spec


def set_keys(spec: dict, values: dict | None) -> dict:
    """``spec`` with every ``{key path: value}`` of ``values`` set, in order (:func:`set_key`)."""
    for key, value in (values or {}).items():
        spec = set_key(spec, key, value)
    return spec


def get_key(spec: dict, key: str | KeyPath):
    """The value at ``key`` in ``spec`` (a checked scene's keys, ``Scene.spec``); a SceneError
    naming the key path when the scene has no such value."""
    parts = parse_key(key) if isinstance(key, str) else key
    where = f'scene key {_dotted(parts)}'
    container, name, schema_node = _locate(spec, parts, where, create=False)
    if schema_node is not None and schema_node[0] == 'number-of':
        return container[name][int(schema_node[2])]
    if schema_node is not None and schema_node[0] == 'whole-list':
        return container.get(name, [])
    if name not in container:
        raise SceneError(f'{where}: the scene has no value there')
    return container[name]


def apply_overrides(spec: dict, overrides) -> dict:
    """A copy of the scene keys ``spec`` (as read from the file) with each ``KEY=VALUE`` text of
    ``overrides`` applied in order, each value checked where it is set."""
    spec = copy.deepcopy(spec or {})
    for text in overrides or ():
        parts, value = parse_override(text)
        spec = set_key(spec, parts, value, where=f'--set {text!r}')
    return spec


def override_text(key: str, value) -> str:
    """``KEY=VALUE`` as ``--set`` reads it back to the same value (a report's way to say how to
    reproduce a setting): numbers with every digit, YAML 1.1 exponents with a dot."""
    if isinstance(value, float):
        text = repr(value)
        mantissa, e, exponent = text.partition('e')
        shown = f'{mantissa}.0e{exponent}' if e and '.' not in mantissa else text
    else:
        shown = yaml.safe_dump(value, default_flow_style=True, width=1 << 16).strip()
        shown = shown[:-4].rstrip() if shown.endswith('\n...') else shown.removesuffix('...').rstrip()
    return f'{key}={shown}'


def with_mass_scaling(spec: dict, mass_scaling: float) -> dict:
    """``spec`` (its ``solver.mass_scaling`` a number) at ``mass_scaling``, its mass-proportional
    damping rate lowered by the same ratio so that the damping force is the one the scene states:
    a mass scaling raised to afford a stiffer scene or a cheaper run changes only the inertia
    (Simulation.rescale_masses, the same rule at run time)."""
    solver = spec['solver']
    ratio = float(mass_scaling) / float(solver['mass_scaling'])
    return dict(spec, solver=dict(solver, mass_scaling=float(mass_scaling),
                                  damping_per_s=float(solver['damping_per_s']) / ratio))
