"""Repeats of one condition on a common grid: their mean and spread, and the floors they set.

Dozens of trials repeat each condition; their repeat-to-repeat spread is the floor no model can
beat, and a report shows it beside the model's error. The rules:

- Alignment: each repeat is put at its contact (``ForceCurve.contact_index``, else
  :func:`~tissue_sim_ros.analysis.compare.force_events.detect_contact` on its force and travel) and
  resampled linearly (np.interp) onto a grid from the contact over the span every repeat covers.
- ``by='time_since_contact'``: the grid is time since contact [s], default step 10 ms; it holds
  everything after the contact (advance, hold and retraction).
- ``by='travel_since_contact'``: the grid is travel since contact [m], default step 0.1 mm. A force
  curve is not single-valued in travel (the needle passes each depth going in and coming out), so
  the two legs are resampled separately: the insertion leg (contact to the hold, grid ascending
  from 0) and the retraction leg (after the hold, grid descending), concatenated in path order
  and labelled by ``leg``; the hold (many forces at one travel) is on the time grid only. Within a
  leg samples are ordered by travel (noisy travel need not be monotonic) and samples at one travel
  averaged. A leg some repeat lacks is left out.
- Noise floor: each repeat against the mean of the others (leave-one-out) on the grid, as an NRMSE
  normalised by that repeat's own force range there (the normaliser the model's NRMSE of a trial
  uses), averaged over the repeats. Linear resampling between two samples averages their noise:
  on a grid that misses the samples, white noise reads sqrt(2/3) of its size on average (choose
  the grid at the samples to see all of it); differences between the repeats' curves are kept.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from tissue_sim_ros.analysis.compare.alignment import increasing_time, resample, sample_array
from tissue_sim_ros.analysis.compare.force_events import depth_bounds, detect_contact
from tissue_sim_ros.analysis.compare.force_metrics import curve_errors

__all__ = ['AlignedRepeats', 'ForceCurve', 'RepeatSpread', 'common_grid', 'mean_and_spread',
           'nearest_speed_baseline', 'noise_floor_nrmse']

GRID_KINDS = ('travel_since_contact', 'time_since_contact')
DEFAULT_STEP = {'travel_since_contact': 1e-4, 'time_since_contact': 0.01}


@dataclass(frozen=True)
class ForceCurve:
    """One insertion's samples: ``time_s``, axial ``force_n`` (positive while the tissue resists),
    ``travel_m`` (or None), and its ``contact_index`` when known (None: detected)."""

    time_s: np.ndarray
    force_n: np.ndarray
    travel_m: np.ndarray | None = None
    contact_index: int | None = None

    def __post_init__(self):
        time = increasing_time('time_s', self.time_s)
        object.__setattr__(self, 'time_s', time)
        object.__setattr__(self, 'force_n', sample_array('force_n', self.force_n, len(time)))
        if self.travel_m is not None:
            object.__setattr__(self, 'travel_m', sample_array('travel_m', self.travel_m, len(time),
                                                              finite=True))
        if self.contact_index is not None and not 0 <= self.contact_index < len(time):
            raise ValueError(f'contact_index = {self.contact_index!r}; expected a sample index '
                             f'in [0, {len(time)})')

    @classmethod
    def from_trial(cls, trial, contact_index: int | None = None) -> ForceCurve:
        """The curve of a :class:`tissue_sim_ros.io.trials.trial.Trial` (its axial force)."""
        return cls(trial.time_s, trial.axial_force_n, trial.travel_m, contact_index)


@dataclass(frozen=True)
class AlignedRepeats:
    """Repeats on one grid: ``grid`` (g,) [s or m since contact], ``leg`` (g,) 'insertion' or
    'retraction' on a travel grid (None on a time grid), ``forces`` (repeats, g) [N]."""

    by: str
    grid: np.ndarray
    leg: np.ndarray | None
    forces: np.ndarray
    contact_indices: tuple[int, ...]

    @property
    def count(self) -> np.ndarray:
        """Repeats with a finite force at each grid point."""
        return np.isfinite(self.forces).sum(axis=0)

    @property
    def mean(self) -> np.ndarray:
        return _mean_of(self.forces)

    @property
    def std(self) -> np.ndarray:
        """The sample standard deviation (ddof 1) across repeats; NaN with fewer than 2."""
        return _nan_statistic(lambda f, axis: np.nanstd(f, axis=axis, ddof=1), self.forces,
                              self.count >= 2)


class RepeatSpread(NamedTuple):
    grid: np.ndarray
    mean: np.ndarray
    std: np.ndarray
    count: np.ndarray


def _mean_of(forces: np.ndarray) -> np.ndarray:
    """The mean over repeats (rows) of the finite forces at each grid point; NaN where none."""
    return _nan_statistic(np.nanmean, forces, np.isfinite(forces).any(axis=0))


def _nan_statistic(statistic, forces, defined):
    result = np.full(forces.shape[1], np.nan)
    if defined.any():
        result[defined] = statistic(forces[:, defined], axis=0)
    return result


def common_grid(curves: Sequence[ForceCurve], *, by: str = 'travel_since_contact',
                step: float | None = None) -> AlignedRepeats:
    """``curves`` aligned at their contact and resampled onto one grid (rules in the module
    docstring); ``step`` in m or s, default 0.1 mm or 10 ms."""
    if by not in GRID_KINDS:
        raise ValueError(f'by = {by!r}; expected one of {GRID_KINDS}')
    step = DEFAULT_STEP[by] if step is None else step
    if not (np.isfinite(step) and step > 0):
        raise ValueError(f'step = {step!r}; expected a finite step > 0')
    if len(curves) == 0:
        raise ValueError('curves is empty; expected at least one force curve')
    contacts, legs = [], []
    for number, curve in enumerate(curves):
        if by == 'travel_since_contact' and curve.travel_m is None:
            raise ValueError(f'curves[{number}] has no travel_m; by={by!r} needs it')
        contact = curve.contact_index
        if contact is None:
            contact = detect_contact(curve.time_s, curve.force_n, curve.travel_m)
        if contact is None:
            raise ValueError(f'curves[{number}]: no contact found; give its contact_index')
        contacts.append(int(contact))
        legs.append(_legs(curve, contact, by))
    leg_names = ('insertion', 'retraction') if by == 'travel_since_contact' else ('time',)
    grids, labels, columns = [], [], []
    for label, samples in zip(leg_names, zip(*legs)):
        grid = _leg_grid(label, samples, step)
        grids.append(grid)
        labels.append(np.full(len(grid), label, dtype='<U10'))
        columns.append(np.array([resample(position, force, grid) for position, force in samples]))
    leg = np.concatenate(labels) if by == 'travel_since_contact' else None
    return AlignedRepeats(by, np.concatenate(grids), leg, np.concatenate(columns, axis=1),
                          tuple(contacts))


def _leg_grid(label: str, samples, step: float) -> np.ndarray:
    """The grid of one leg over the span every repeat covers (from 0 but on the retraction leg),
    ascending but on the retraction leg; empty when a repeat lacks the leg."""
    if any(position.size < 2 for position, _ in samples):
        return np.zeros(0)
    low = max(position[0] for position, _ in samples) if label == 'retraction' else 0.0
    high = min(position[-1] for position, _ in samples)
    if high < low:
        return np.zeros(0)
    offsets = step * np.arange(int(np.floor((high - low) / step + 1e-9)) + 1)
    return high - offsets if label == 'retraction' else low + offsets


def _legs(curve: ForceCurve, contact: int, by: str):
    """``[(position, force), ...]`` per leg, position ascending, since contact."""
    if by == 'time_since_contact':
        return [(curve.time_s[contact:] - curve.time_s[contact], curve.force_n[contact:])]
    hold_start, hold_end = depth_bounds(curve.travel_m)
    since_contact = curve.travel_m - curve.travel_m[contact]
    stretches = (slice(contact, max(contact, hold_start)), slice(max(contact, hold_end + 1), None))
    return [_single_valued(since_contact[stretch], curve.force_n[stretch]) for stretch in stretches]


def _single_valued(position: np.ndarray, force: np.ndarray):
    """Samples ordered by position, the forces at one position averaged."""
    unique, inverse, counts = np.unique(position, return_inverse=True, return_counts=True)
    return unique, np.bincount(inverse, weights=force, minlength=len(unique)) / counts


def mean_and_spread(curves: Sequence[ForceCurve], *, by: str = 'travel_since_contact',
                    step: float | None = None) -> RepeatSpread:
    """``(grid, mean, std, count)`` of the repeats on :func:`common_grid` (its ``leg`` tells the
    legs of a travel grid apart): the mean curve [N], the sample standard deviation across repeats
    [N] (NaN with fewer than 2) and the number of repeats at each grid point."""
    aligned = common_grid(curves, by=by, step=step)
    return RepeatSpread(aligned.grid, aligned.mean, aligned.std, aligned.count)


def noise_floor_nrmse(curves: Sequence[ForceCurve], *, by: str = 'travel_since_contact',
                      step: float | None = None) -> float:
    """The repeat-to-repeat spread as an NRMSE (leave-one-out; rule in the module docstring):
    what the best possible model would score against one repeat. NaN with fewer than 2 repeats."""
    if len(curves) < 2:
        return float('nan')
    forces = common_grid(curves, by=by, step=step).forces
    scores = []
    for number in range(len(forces)):
        others = np.delete(forces, number, axis=0)
        scores.append(curve_errors(forces[number], _mean_of(others))['nrmse'])
    return float(np.nanmean(scores)) if np.isfinite(scores).any() else float('nan')


def nearest_speed_baseline(curves_by_speed: Mapping[float, Sequence[ForceCurve]], *,
                           step: float | None = None) -> dict[float, dict]:
    """For each speed [m/s] (key): how well the measured mean curve of the nearest other speed
    (ties: the slower) predicts this speed's mean curve, on one travel-since-contact grid of both
    speeds' repeats (``step`` as in :func:`common_grid`). Returns ``{speed: {'nearest_speed_m_s',
    'nrmse', 'rmse_n', 'r2', 'normaliser_n', 'count'}}``, the normaliser being this speed's mean
    force range on that grid: the baseline a model must beat to be worth more than the data of a
    neighbouring speed."""
    speeds = sorted(curves_by_speed)
    if len(speeds) < 2:
        raise ValueError(f'curves_by_speed has {len(speeds)} speed(s); expected at least 2')
    baseline = {}
    for speed in speeds:
        nearest = min((other for other in speeds if other != speed),
                      key=lambda other: (abs(other - speed), other))
        own, neighbour = list(curves_by_speed[speed]), list(curves_by_speed[nearest])
        forces = common_grid(own + neighbour, by='travel_since_contact', step=step).forces
        errors = curve_errors(_mean_of(forces[:len(own)]), _mean_of(forces[len(own):]))
        baseline[speed] = {'nearest_speed_m_s': float(nearest), 'nrmse': errors['nrmse'],
                           'rmse_n': errors['rmse_n'], 'r2': errors['r2'],
                           'normaliser_n': errors['normaliser_n'], 'count': errors['count']}
    return baseline
