"""A load-cell recording in a text file (CSV, TSV, ';' or whitespace separated) as a Trial.

The columns, units and signs come from the sections of a data description
(:mod:`tissue_sim_ros.io.trials.data_spec_keys`): ``time``, ``force``, optional ``torque`` and
``position``, and ``format``. Lines are split by the ``csv`` module (quoted header names
included) or at whitespace, and only the columns used are converted to numbers, by numpy.
Rows in errors are the file's 1-based line numbers, so that an editor opens the file there.
"""
from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tissue_sim_ros.io.trials.data_spec_keys import check_section
from tissue_sim_ros.io.trials.measurement_units import unit_factor
from tissue_sim_ros.io.trials.trial import Trial, check_increasing_time, drop_nonfinite_rows
from tissue_sim_ros.errors import DataError

__all__ = ['read_text_trial']

_DELIMITERS = {'tab': '\t', '\t': '\t', ',': ',', ';': ';', 'whitespace': None}


@dataclass
class _Table:
    """The split lines of a file: header names (None without a header), rows of cells, and the
    1-based file line of each row."""

    header: list[str] | None
    rows: list[list[str]]
    lines: np.ndarray


def _text(path: Path) -> str:
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise DataError(path, f'cannot be read ({exc.strerror or exc})') from None
    try:
        return data.decode('utf-8-sig')
    except UnicodeDecodeError:
        return data.decode('latin-1')  # a header written as 'µs' by a Windows logger


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _split(lines: list[str], delimiter_option: str) -> list[list[str]]:
    """Cells of each line; 'auto' picks tab, ';' or ',' when the first line has one."""
    delimiter = _DELIMITERS.get(delimiter_option)
    if delimiter_option == 'auto':
        delimiter = next((d for d in ('\t', ';', ',') if d in lines[0]), None)
    if delimiter is None:
        return [line.split() for line in lines]
    return list(csv.reader(lines, delimiter=delimiter))


def _read_table(path: Path, text_format: dict) -> _Table:
    """The data lines of the file, its header split off (given or detected)."""
    comment = text_format['comment']
    numbered = [(number, line) for number, line in
                enumerate(_text(path).splitlines()[text_format['skip_rows']:],
                          start=text_format['skip_rows'] + 1)
                if line.strip() and not line.lstrip().startswith(comment)]
    if not numbered:
        raise DataError(path, 'no data rows (the file is empty, or holds only comments)')
    rows = _split([line for _, line in numbered], text_format['delimiter'])
    lines = np.array([number for number, _ in numbered])
    has_header = text_format['header']
    if has_header == 'auto':
        has_header = not all(_is_number(cell) for cell in rows[0])
    if not has_header:
        return _Table(None, rows, lines)
    if len(rows) == 1:
        raise DataError(path, 'no data rows after the header line', row=int(lines[0]))
    return _Table([name.strip() for name in rows[0]], rows[1:], lines[1:])


def _column_index(path: Path, table: _Table, column) -> int:
    """The 0-based index of a column given by header name (case-insensitive) or index."""
    n_columns = len(table.header) if table.header is not None else len(table.rows[0])
    if isinstance(column, int):
        if column >= n_columns:
            raise DataError(path, f'column index {column} is out of range: the file has '
                                  f'{n_columns} columns (0 to {n_columns - 1})', column=column)
        return column
    if table.header is None:
        raise DataError(path, f'the file has no header line to find column {column!r} by name; '
                              f'name columns by 0-based index (0 to {n_columns - 1})',
                        column=column)
    wanted = column.strip().casefold()
    for index, name in enumerate(table.header):
        if name.casefold() == wanted:
            return index
    raise DataError(path, f'no such column; the columns are: {", ".join(table.header)}',
                    column=column)


def _cell_value(path: Path, cell: str, column, line: int) -> float:
    try:
        return float(cell)
    except ValueError:
        raise DataError(path, f'{cell!r} is not a number', column=column, row=line) from None


def _numbers(path: Path, table: _Table, column) -> np.ndarray:
    """The column as float64; an empty or missing cell is NaN, any other text an error."""
    index = _column_index(path, table, column)
    cells = np.array([row[index] if index < len(row) else '' for row in table.rows])
    cells = np.where(np.char.strip(cells) == '', 'nan', cells)
    try:
        return cells.astype(np.float64)
    except ValueError:  # find the cell, for the message
        return np.array([_cell_value(path, str(cell), column, int(line))
                         for cell, line in zip(cells, table.lines)])


def _stacked(path: Path, table: _Table, columns: list, unit_scale: float,
             used: dict) -> np.ndarray:
    """Three columns as (k, 3) in SI; each is also entered in ``used`` for the NaN check."""
    stacked = np.column_stack([_numbers(path, table, c) for c in columns]) * unit_scale
    used.update({column: stacked[:, i] for i, column in enumerate(columns)})
    return stacked


def _axial_force(force_spec: dict, force_n: np.ndarray) -> np.ndarray:
    """The axial force of three columns: their norm, or their projection on the direction."""
    if force_spec['reduce'] == 'norm':
        return np.linalg.norm(force_n, axis=1)
    direction = np.asarray(force_spec['direction'], dtype=np.float64)
    return force_n @ (direction / np.linalg.norm(direction))


def _quantities(path: Path, table: _Table, time: dict, force: dict, torque: dict | None,
                position: dict | None) -> tuple[dict, dict]:
    """(time_s, axial_force_n, force_n, torque_nm, position_m by name, in SI, None where the
    file has none; every column read -> its values, for the NaN check)."""
    used: dict = {}

    def column(name, quantity: str, unit: str) -> np.ndarray:
        used[name] = _numbers(path, table, name) * unit_factor(quantity, unit)
        return used[name]

    si = {'force_n': None, 'torque_nm': None, 'position_m': None}
    if time['rate_hz'] is not None:
        si['time_s'] = np.arange(len(table.rows)) / time['rate_hz']
    else:
        si['time_s'] = column(time['column'], 'time', time['unit'])
    if force['column'] is not None:
        axial_force_n = column(force['column'], 'force', force['unit'])
    else:
        si['force_n'] = _stacked(path, table, force['columns'],
                                 unit_factor('force', force['unit']), used)
        axial_force_n = _axial_force(force, si['force_n'])
    si['axial_force_n'] = force['sign'] * axial_force_n
    if torque is not None:
        si['torque_nm'] = _stacked(path, table, torque['columns'],
                                   unit_factor('torque', torque['unit']), used)
    if position is not None:
        si['position_m'] = position['sign'] * column(position['column'], 'position',
                                                     position['unit'])
    return si, used


def read_text_trial(path, *, time: dict, force: dict, torque: dict | None = None,
                    position: dict | None = None, text_format: dict | None = None,
                    drop_nan_rows: bool = False) -> Trial:
    """The recording in a text file as a :class:`Trial` in SI.

    ``time``, ``force``, ``torque``, ``position``, ``text_format``: the sections ``time``,
    ``force``, ``torque``, ``position`` and ``format`` of a data description (keys left out take
    their defaults), e.g. ``time={'column': 'time', 'unit': 'us'}, force={'column': 'fz',
    'sign': -1}``. Travel is the position from the first sample. A bad file raises
    :class:`DataError` naming the file, the column and the row; bad options raise
    :class:`~tissue_sim_ros.io.trials.data_spec_keys.DataSpecError` naming the key.
    """
    path = Path(path)
    time, force = check_section('time', time or {}), check_section('force', force or {})
    torque, position = check_section('torque', torque), check_section('position', position)
    table = _read_table(path, check_section('format', text_format))
    si, used = _quantities(path, table, time, force, torque, position)
    keep = drop_nonfinite_rows(path, used, table.lines, drop_nan_rows)
    kept = {name: None if values is None else values[keep] for name, values in si.items()}
    if np.count_nonzero(keep) < 2:
        raise DataError(path, f'{np.count_nonzero(keep)} sample(s) with finite values; a trial '
                              'needs at least 2')
    check_increasing_time(path, kept['time_s'], table.lines[keep], time['column'])
    position_m = kept.pop('position_m')
    return Trial(file=str(path), **kept, nan_rows_dropped=int(np.count_nonzero(~keep)),
                 travel_m=None if position_m is None else position_m - position_m[0])
