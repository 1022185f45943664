"""Every key of a data description (a study's load-cell files described once), and their checks.

The one place the keys are documented (:func:`describe_data_keys` prints them), the way
:mod:`tissue_sim_ros.engine.scene.schema` documents scene keys. A data description says where the
files are, how to read their columns and in which units and signs, and what the file names and
the stage say about each trial; :mod:`tissue_sim_ros.io.trials.data_spec` loads the trials it describes.
Unknown keys are refused with their dotted path; a bad value with its path, the value and what
was expected.
"""
from __future__ import annotations

import math
import re

from tissue_sim_ros.io.trials.measurement_units import unit_factor
from tissue_sim_ros.errors import DataSpecError, UnitError

__all__ = ['DATA_SPEC_KEYS', 'check_data_spec', 'check_section',
           'data_keys_markdown', 'describe_data_keys']


# -- the keys: key -> (default, kind, meaning); a nested dict is a section ---------------------
# kinds: 'globs', 'str', 'column' (header name or 0-based index), 'columns3', 'unit:<quantity>',
# 'float+' (> 0), 'float0' (>= 0), 'int0' (>= 0), 'bool', 'sign' (+1 or -1), 'vec3' (not zero),
# 'regex', or a tuple of allowed values. A default of None: not given.
DATA_SPEC_KEYS = {
    'files': ([], 'globs', 'file globs relative to the spec file (absolute ones as they are); '
                           'the matches are sorted; .mcap files are read as ROS 2 logs, others '
                           'as text'),
    'format': {
        'delimiter': ('auto', ('auto', ',', ';', 'tab', '\t', 'whitespace'),
                      "column separator; auto: tab, ';' or ',' if the first line has one, else "
                      'whitespace'),
        'header': ('auto', ('auto', True, False),
                   'whether the first line names the columns; auto: yes when it is not all '
                   'numbers'),
        'skip_rows': (0, 'int0', 'lines skipped at the top of each file before anything is read'),
        'comment': ('#', 'str', 'lines starting with this (after spaces) are skipped'),
    },
    'time': {
        'column': (None, 'column', 'time column (name or 0-based index); or give rate_hz'),
        'unit': ('s', 'unit:time', 'unit of the time column: s, ms, us (µs), ns'),
        'rate_hz': (None, 'float+', 'sample rate [Hz] when there is no time column: row k at '
                                    'k / rate'),
    },
    'force': {
        'column': (None, 'column', 'the axial force column; or give columns'),
        'columns': (None, 'columns3', 'three force columns [fx, fy, fz], reduced by reduce'),
        'unit': ('N', 'unit:force', 'force unit: N, mN, kN, gf, kgf, lbf, ozf'),
        'sign': (1, 'sign', '+1 or -1: the factor that makes the axial force positive while the '
                            'tissue resists insertion'),
        'reduce': ('norm', ('norm', 'projection'),
                   'with columns: the norm of the three, or their projection on direction'),
        'direction': (None, 'vec3', 'reduce: projection: the needle axis in the sensor frame '
                                    '(normalised)'),
    },
    'torque': {
        'columns': (None, 'columns3', 'three torque columns [tx, ty, tz]'),
        'unit': ('N m', 'unit:torque', 'torque unit: N m, N mm, mN m'),
    },
    'position': {
        'column': (None, 'column', 'needle position along its axis; travel is taken from the '
                                   'first sample'),
        'unit': ('m', 'unit:position', 'position unit: m, cm, mm, um (µm), in'),
        'sign': (1, 'sign', '+1 or -1: the factor that makes travel positive while inserting'),
    },
    'motion': {
        'speed_mm_s': (None, 'float+', 'stage speed [mm/s]; wins over the file name\'s speed'),
        'start_s': (None, 'float0', 'when the stage starts, after the first sample [s]; null: to '
                                    'be detected from the force'),
        'travel_mm': (None, 'float+', 'how far the stage inserts [mm]'),
        'hold_s': (0.0, 'float0', 'pause at full travel before retraction [s]'),
        'retract': (False, 'bool', 'whether the stage retracts at the same speed after the hold'),
    },
    'file_name': {
        'pattern': (None, 'regex', "regular expression searched in each file's name; its named "
                                   "groups become labels; 'speed' and 'repeat' are read as numbers "
                                   "('_' or 'p' stands for the decimal point)"),
        'speed_unit': ('mm/s', 'unit:speed', 'unit of the speed group: m/s, mm/s, um/s'),
    },
    'drop_nan_rows': (False, 'bool', 'drop rows with NaN, inf or empty cells (counted per trial) '
                                     'instead of refusing the file'),
    'mcap': {
        'wrench_topic': (None, 'str', 'topic of geometry_msgs/WrenchStamped (for .mcap files)'),
        'pose_topic': (None, 'str', 'topic of the needle base pose, geometry_msgs/PoseStamped or '
                                    'TransformStamped; null: no travel'),
        'needle_axis': ([0.0, 0.0, 1.0], 'vec3', 'the needle axis in the needle (pose) frame'),
        'needle_frame': ('needle', 'str', "frame_id of a wrench expressed in the needle's frame"),
        'wrench_frame': ('auto', ('auto', 'needle', 'parent'),
                         "which frame the wrench is in; auto: from its frame_id"),
        'sign': (-1, 'sign', 'axial force = sign x (force . axis); -1 for the force on the needle'),
        'time_source': ('header', ('header', 'log'), 'time from header stamps or MCAP log times'),
    },
}

#: Sections that may be left out (then None, not filled with defaults), and when they are needed.
OPTIONAL_SECTIONS = {
    'time': 'required for text files', 'force': 'required for text files',
    'torque': 'optional', 'position': 'optional',
    'motion': 'optional: what the stage did, for recordings without a position column',
    'file_name': 'optional', 'mcap': 'required for .mcap files',
}
#: section -> groups of keys of which exactly one must be given (a one-key group: required).
_EXACTLY_ONE = {
    'time': [('column', 'rate_hz')],
    'force': [('column', 'columns')],
    'torque': [('columns',)],
    'position': [('column',)],
    'file_name': [('pattern',)],
    'mcap': [('wrench_topic',)],
}


def _fail(source, dotted, value, expected):
    raise DataSpecError(f'{source}: {dotted} = {value!r}: expected {expected}')


def _number(source, dotted, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        _fail(source, dotted, value, 'a finite number')
    return float(value)


def _column(source, dotted, value):
    if isinstance(value, str) and value.strip():
        return value
    if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    _fail(source, dotted, value, 'a column name or a 0-based column index')


def _check_value(source, dotted, value, kind):
    """One value against its kind; the value normalised (floats, lists)."""
    if isinstance(kind, tuple):
        if not any(value is choice or (type(value) is type(choice) and value == choice)
                   for choice in kind):
            _fail(source, dotted, value, 'one of ' + ', '.join(map(repr, kind)))
        return value
    if kind.startswith('unit:'):
        try:
            unit_factor(kind[5:], value)
        except UnitError as exc:
            raise DataSpecError(f'{source}: {dotted}: {exc}') from None
        return value
    if kind == 'globs':
        globs = [value] if isinstance(value, str) else value
        if not isinstance(globs, list) or not globs or not all(
                isinstance(g, str) and g for g in globs):
            _fail(source, dotted, value, 'a non-empty list of file globs')
        return list(globs)
    if kind == 'column':
        return _column(source, dotted, value)
    if kind == 'columns3':
        if not isinstance(value, list) or len(value) != 3:
            _fail(source, dotted, value, 'a list of 3 columns (names or 0-based indices)')
        return [_column(source, f'{dotted}[{i}]', v) for i, v in enumerate(value)]
    if kind == 'vec3':
        if not isinstance(value, (list, tuple)) or len(value) != 3:
            _fail(source, dotted, value, '3 numbers')
        vector = [_number(source, dotted, v) for v in value]
        if not any(vector):
            _fail(source, dotted, value, 'a direction (3 numbers, not all 0)')
        return vector
    if kind == 'str' and isinstance(value, str) and value:
        return value
    if kind == 'regex' and isinstance(value, str):
        try:
            re.compile(value)
        except re.error as exc:
            _fail(source, dotted, value, f'a regular expression ({exc})')
        return value
    if kind == 'bool' and isinstance(value, bool):
        return value
    if kind == 'sign' and value in (1, -1) and not isinstance(value, bool):
        return int(value)
    if kind == 'int0' and isinstance(value, int) and not isinstance(value, bool) and value >= 0:
        return value
    if kind in ('float+', 'float0'):
        number = _number(source, dotted, value)
        if number > 0 or (kind == 'float0' and number == 0):
            return number
    expected = {'str': 'a non-empty string', 'regex': 'a regular expression',
                'bool': 'true or false', 'sign': '+1 or -1', 'int0': 'an integer >= 0',
                'float+': 'a number > 0', 'float0': 'a number >= 0'}[kind]
    _fail(source, dotted, value, expected)


def _apply(source, prefix, data, keys):
    """Defaults filled and values checked; unknown keys refused with their dotted path."""
    if not isinstance(data, dict):
        _fail(source, prefix.rstrip('.') or 'the data description', data, 'a mapping of keys')
    unknown = sorted(set(data) - set(keys), key=str)
    if unknown:
        raise DataSpecError(f'{source}: unknown key {prefix}{unknown[0]}; known keys here: '
                            f'{", ".join(keys)}')
    out = {}
    for key, spec in keys.items():
        dotted = f'{prefix}{key}'
        if isinstance(spec, dict):
            given = data.get(key)
            out[key] = (None if given is None and key in OPTIONAL_SECTIONS
                        else _checked_section(source, dotted, {} if given is None else given,
                                              spec))
        elif data.get(key) is None:
            out[key] = list(spec[0]) if isinstance(spec[0], list) else spec[0]
        else:
            out[key] = _check_value(source, dotted, data[key], spec[1])
    return out


def _checked_section(source, dotted, data, keys):
    section = _apply(source, f'{dotted}.', data, keys)
    for group in _EXACTLY_ONE.get(dotted, []):
        given = [key for key in group if section[key] is not None]
        if len(given) != 1:
            choices = ' or '.join(f'{dotted}.{key}' for key in group)
            one_of = 'exactly one of ' if len(group) > 1 else ''
            raise DataSpecError(f'{source}: {dotted}: give {one_of}{choices} (given: '
                                f'{", ".join(given) or "none"})')
    if (dotted == 'force' and section['columns'] is not None
            and section['reduce'] == 'projection' and section['direction'] is None):
        raise DataSpecError(f'{source}: force.direction: required with force.reduce: projection '
                            '(the needle axis in the sensor frame, 3 numbers)')
    return section


def check_data_spec(data, source: str = 'data description') -> dict:
    """The whole description checked, every key present (sections left out are None, other
    keys take their defaults). ``source`` (the spec file) starts every error message."""
    spec = _apply(source, '', data if data is not None else {}, DATA_SPEC_KEYS)
    if not spec['files']:
        raise DataSpecError(f'{source}: files: expected a non-empty list of file globs')
    return spec


def check_section(name: str, data, source: str = 'column options') -> dict | None:
    """One section (``time``, ``force``, ``format``, ...) checked and filled; None stays None
    for an optional section."""
    spec = DATA_SPEC_KEYS.get(name)
    if not isinstance(spec, dict):
        sections = [key for key, value in DATA_SPEC_KEYS.items() if isinstance(value, dict)]
        raise DataSpecError(f'{source}: {name!r} is not a section; sections: '
                            f'{", ".join(sections)}')
    if data is None and name in OPTIONAL_SECTIONS:
        return None
    return _checked_section(source, name, {} if data is None else data, spec)


def describe_data_keys(keys=DATA_SPEC_KEYS, prefix: str = '') -> list[str]:
    """Every data-description key with its default and meaning, one per line."""
    lines = []
    for key, spec in keys.items():
        if isinstance(spec, dict):
            note = f' ({OPTIONAL_SECTIONS[key]})' if key in OPTIONAL_SECTIONS else ''
            lines.append(f'{prefix}{key}:{note}')
            lines += describe_data_keys(spec, f'{prefix}{key}.')
        else:
            lines.append(f'{prefix}{key} (default {spec[0]!r}): {spec[2]}')
    return lines


def _rows(keys=DATA_SPEC_KEYS, prefix: str = ''):
    for key, spec in keys.items():
        if isinstance(spec, dict):
            yield from _rows(spec, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', spec[0], spec[2]


def data_keys_markdown() -> str:
    """docs/data.md's table of every key (``tissue-sim data-keys --markdown``): key, default,
    meaning, and which sections are optional."""
    def shown(default):
        return '' if default is None or default == [] else f'`{default!r}`'
    lines = ['| key | default | meaning |', '|---|---|---|']
    lines += [f'| `{dotted}` | {shown(default)} | {meaning.replace("|", "/")} |' for dotted, default, meaning in _rows()]
    lines += ['', 'Sections: ' + '; '.join(f'`{name}` {note}' for name, note in OPTIONAL_SECTIONS.items()) + '. '
              'Within `time` and `force`, give exactly one of `column` / `rate_hz` and `column` / `columns`.']
    return '\n'.join(lines) + '\n'
