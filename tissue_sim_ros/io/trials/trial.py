"""One measured insertion (a trial) in SI, and the error a bad recording gets.

Every importer (text files, MCAP logs) returns a :class:`Trial`, so the analysis that drives the
simulation from the measured motion and compares forces reads one shape of data whatever the rig
wrote. The checks every importer needs (time strictly increasing, rows with NaN counted and
refused or dropped) live here too, so that each file format reports them in the same words.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from tissue_sim_ros.errors import DataError

__all__ = ['Trial', 'check_increasing_time', 'drop_nonfinite_rows']


@dataclass
class Trial:
    """One recording in SI units.

    - ``time_s`` (k,): sample times [s], strictly increasing, with the file's own origin (see
      :attr:`time_from_start_s` for time from the first sample).
    - ``axial_force_n`` (k,): force along the needle axis [N], positive while the tissue resists
      insertion (the sign of the data description applied).
    - ``travel_m`` (k,) or None: needle travel along its axis from the first sample [m],
      positive inserting; None when the recording has no position.
    - ``force_n`` / ``torque_nm`` (k, 3) or None: the three force [N] and torque [N m] columns
      in the sensor's frame, as recorded (no sign applied), when the recording has them.
    - ``speed_m_s``: the insertion speed [m/s] (from the data description or the file name), or
      None when neither says it; ``repeat``: the repeat number from the file name, or None.
    - ``labels``: every named group of the file-name pattern, as text.
    - ``nan_rows_dropped``: rows (or MCAP messages) with NaN, inf or empty cells left out, when
      asked to.
    - ``motion``: what the stage did when the recording has no position, in SI:
      ``{'speed_m_s', 'start_s', 'travel_m', 'hold_s', 'retract'}`` (None: not described).
    """

    file: str
    time_s: np.ndarray
    axial_force_n: np.ndarray
    travel_m: np.ndarray | None = None
    force_n: np.ndarray | None = None
    torque_nm: np.ndarray | None = None
    speed_m_s: float | None = None
    repeat: int | None = None
    labels: dict[str, str] = field(default_factory=dict)
    nan_rows_dropped: int = 0
    motion: dict | None = None

    def __post_init__(self):
        n_samples = len(self.time_s)
        shapes = {'axial_force_n': (n_samples,), 'travel_m': (n_samples,),
                  'force_n': (n_samples, 3), 'torque_nm': (n_samples, 3)}
        for name, shape in shapes.items():
            value = getattr(self, name)
            if value is not None and np.shape(value) != shape:
                raise DataError(self.file, f'{name} has shape {np.shape(value)}; expected {shape} '
                                           f'(one value per sample of time_s)')
        if n_samples < 2:
            raise DataError(self.file, f'{n_samples} sample(s); a trial needs at least 2')
        check_increasing_time(self.file, np.asarray(self.time_s), np.arange(1, n_samples + 1),
                              'time_s')

    @property
    def n_samples(self) -> int:
        return len(self.time_s)

    @property
    def time_from_start_s(self) -> np.ndarray:
        """Sample times from the first sample [s] (the first is 0)."""
        return self.time_s - self.time_s[0]

    @property
    def duration_s(self) -> float:
        return float(self.time_s[-1] - self.time_s[0])

    @property
    def sample_rate_hz(self) -> float:
        """The median sample rate [Hz] (robust to jitter and to a gap)."""
        return float(1.0 / np.median(np.diff(self.time_s)))


def check_increasing_time(file, time_s: np.ndarray, rows: np.ndarray, column) -> None:
    """Refuse time that goes backwards or repeats, naming the first sample that does.

    ``rows``: the 1-based row (file line or message index) of each sample, for the message.
    """
    steps = np.diff(time_s)
    bad = np.flatnonzero(~(steps > 0))
    if bad.size:
        i = int(bad[0]) + 1
        what = 'repeats' if steps[i - 1] == 0 else 'goes backwards'
        raise DataError(file, f'time {what}: {time_s[i]!r} after {time_s[i - 1]!r} (row '
                              f'{int(rows[i - 1])}); time must increase strictly',
                        column=column, row=int(rows[i]))


def drop_nonfinite_rows(file, columns: dict, rows: np.ndarray, drop: bool) -> np.ndarray:
    """The mask of rows whose every value in ``columns`` (name -> (k,) or (k, n)) is finite.

    Rows with NaN, inf or an empty cell are refused with a :class:`DataError` naming how many
    there are, the first row and its column, unless ``drop``; then the mask leaves them out.
    """
    keep = np.ones(len(rows), dtype=bool)
    first_row, first_column = None, None
    for name, values in columns.items():
        finite = np.isfinite(values)
        finite_row = finite if finite.ndim == 1 else finite.all(axis=1)
        if not finite_row.all():
            i = int(np.argmin(finite_row))
            if first_row is None or rows[i] < first_row:
                first_row, first_column = int(rows[i]), name
            keep &= finite_row
    n_bad = int(np.count_nonzero(~keep))
    if n_bad and not drop:
        raise DataError(file, f'{n_bad} row(s) hold NaN, inf or empty cells in the columns used '
                              f'(first at row {first_row}); set drop_nan_rows: true to drop them',
                        column=first_column, row=first_row)
    return keep
