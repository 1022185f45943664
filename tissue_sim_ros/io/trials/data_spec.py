"""A study's load-cell recordings described once (a YAML data description) and loaded as Trials.

A study has dozens of files recorded the same way; the description says once where they are,
how their columns read (units, signs), what the file names carry (speed, repeat) and what the
stage did when there is no position column. Its keys are documented in
:mod:`tissue_sim_ros.io.trials.data_spec_keys`. ``DataSpec.from_file(path)`` reads one,
``DataSpec.from_dict(d, base_dir)`` builds one from a command line's files and column options,
:func:`load_trials` imports every file, :func:`group_by_speed` gathers the repeats of a speed.
"""
from __future__ import annotations

import dataclasses
import glob
import re
from dataclasses import dataclass
from pathlib import Path

import yaml

from tissue_sim_ros.io.trials.data_spec_keys import check_data_spec
from tissue_sim_ros.errors import DataSpecError
from tissue_sim_ros.io.trials.mcap_files import read_mcap_trial
from tissue_sim_ros.io.trials.measurement_units import unit_factor
from tissue_sim_ros.io.trials.text_files import read_text_trial
from tissue_sim_ros.io.trials.trial import Trial
from tissue_sim_ros.errors import DataError

__all__ = ['DataSpec', 'file_name_labels', 'group_by_speed', 'load_trials', 'read_trial',
           'speed_from_text']

#: Significant digits a speed keeps when trials are grouped by speed.
SPEED_SIGNIFICANT_DIGITS = 6


def _is_mcap(path: Path) -> bool:
    return path.suffix.lower() == '.mcap'


def _matches(source: str, base_dir: Path, patterns: list[str]) -> tuple[Path, ...]:
    """The files the globs match (relative ones from ``base_dir``), sorted, each once."""
    files: set[Path] = set()
    for pattern in patterns:
        full = pattern if Path(pattern).is_absolute() else str(base_dir / pattern)
        found = [Path(p) for p in glob.glob(full, recursive=True) if Path(p).is_file()]
        if not found:
            raise DataSpecError(f'{source}: files: {pattern!r} matches no file (looked for '
                                f'{full})')
        files.update(found)
    return tuple(sorted(files))


@dataclass(frozen=True)
class DataSpec:
    """A checked data description: ``values`` holds every key (see
    :func:`~tissue_sim_ros.io.trials.data_spec_keys.check_data_spec`), ``files`` the matched files."""

    source: str
    base_dir: Path
    values: dict
    files: tuple[Path, ...]

    @classmethod
    def from_dict(cls, data: dict, base_dir='.', source: str = 'data description') -> DataSpec:
        """A description from a dict; globs are relative to ``base_dir``."""
        values = check_data_spec(data, source)
        base_dir = Path(base_dir)
        files = _matches(source, base_dir, values['files'])
        text_files = [f for f in files if not _is_mcap(f)]
        for section in ('time', 'force'):
            if text_files and values[section] is None:
                raise DataSpecError(f'{source}: {section}: required to read text files such as '
                                    f'{text_files[0]}')
        mcap_files = [f for f in files if _is_mcap(f)]
        if mcap_files and values['mcap'] is None:
            raise DataSpecError(f'{source}: mcap.wrench_topic: required to read MCAP files such '
                                f'as {mcap_files[0]}')
        return cls(source, base_dir, values, files)

    @classmethod
    def from_file(cls, path) -> DataSpec:
        """A description from a YAML file; globs are relative to its folder."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text(encoding='utf-8'))
        except OSError as exc:
            raise DataSpecError(f'{path}: cannot be read ({exc.strerror or exc})') from None
        except yaml.YAMLError as exc:
            raise DataSpecError(f'{path}: not valid YAML ({exc})') from None
        return cls.from_dict(data, path.parent, source=str(path))


def speed_from_text(text: str, file) -> float:
    """A number written in a file name, '_' or 'p' standing for the decimal point ('2_0',
    '0p5', '3')."""
    written = text.replace('p', '.').replace('_', '.')
    if written.count('.') > 1 or not re.fullmatch(r'\d*\.?\d+|\d+\.', written):
        raise DataError(file, f'{text!r} in the file name is not a number (write 2_5 or 2p5 for '
                              '2.5)')
    return float(written)


def file_name_labels(file, pattern: str, speed_unit: str = 'mm/s'
                     ) -> tuple[dict[str, str], float | None, int | None]:
    """(labels, speed [m/s] or None, repeat or None) from the named groups of ``pattern``
    searched in the file's name; a name the pattern does not match is a DataError."""
    match = re.search(pattern, Path(file).name)
    if match is None:
        raise DataError(file, f'the file name does not match the pattern {pattern!r}')
    labels = {name: value for name, value in match.groupdict().items() if value is not None}
    speed_m_s = None
    if 'speed' in labels:
        speed_m_s = speed_from_text(labels['speed'], file) * unit_factor('speed', speed_unit)
    repeat = None
    if 'repeat' in labels:
        if not labels['repeat'].isdigit():
            raise DataError(file, f'repeat {labels["repeat"]!r} in the file name is not a whole '
                                  'number')
        repeat = int(labels['repeat'])
    return labels, speed_m_s, repeat


def _motion_si(motion: dict, speed_m_s: float | None) -> dict:
    travel_mm = motion['travel_mm']
    return {'speed_m_s': speed_m_s, 'start_s': motion['start_s'],
            'travel_m': None if travel_mm is None else travel_mm * unit_factor('position', 'mm'),
            'hold_s': motion['hold_s'], 'retract': motion['retract']}


def read_trial(spec: DataSpec, file) -> Trial:
    """One file of the study as a :class:`Trial`, with its labels, speed, repeat and motion."""
    values, file = spec.values, Path(file)
    if _is_mcap(file):
        options = dict(values['mcap'])
        trial = read_mcap_trial(file, options.pop('wrench_topic'), options.pop('pose_topic'),
                                drop_nan_rows=values['drop_nan_rows'], **options)
    else:
        trial = read_text_trial(file, time=values['time'], force=values['force'],
                                torque=values['torque'], position=values['position'],
                                text_format=values['format'],
                                drop_nan_rows=values['drop_nan_rows'])
    labels, speed_m_s, repeat = {}, None, None
    if values['file_name'] is not None:
        labels, speed_m_s, repeat = file_name_labels(file, values['file_name']['pattern'],
                                                     values['file_name']['speed_unit'])
    motion = values['motion']
    if motion is not None and motion['speed_mm_s'] is not None:
        speed_m_s = motion['speed_mm_s'] * unit_factor('speed', 'mm/s')
    return dataclasses.replace(trial, speed_m_s=speed_m_s, repeat=repeat, labels=labels,
                               motion=None if motion is None else _motion_si(motion, speed_m_s))


def load_trials(spec) -> list[Trial]:
    """Every file of a study (a :class:`DataSpec`, or the path of its YAML) as Trials, in the
    order of the sorted file names."""
    if not isinstance(spec, DataSpec):
        spec = DataSpec.from_file(spec)
    return [read_trial(spec, file) for file in spec.files]


def group_by_speed(trials: list[Trial]) -> dict[float | None, list[Trial]]:
    """speed [m/s] (to :data:`SPEED_SIGNIFICANT_DIGITS` digits) -> its trials, slowest first;
    trials of unknown speed last, under None."""
    groups: dict[float | None, list[Trial]] = {}
    for trial in trials:
        key = (None if trial.speed_m_s is None
               else float(f'{trial.speed_m_s:.{SPEED_SIGNIFICANT_DIGITS}g}'))
        groups.setdefault(key, []).append(trial)
    return dict(sorted(groups.items(), key=lambda item: (item[0] is None, item[0] or 0.0)))
