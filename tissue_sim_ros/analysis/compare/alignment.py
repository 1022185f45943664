"""Putting two force records on one time base: linear resampling and the cross-correlation shift.

A measured and a simulated insertion start at different clocks and are sampled differently
(a load cell at 88 to 1000 Hz with jitter, the simulator once per tick). Both are resampled
linearly onto a common uniform grid whose step is a quarter of the finer of the two median sample
intervals; the shift is the lag that maximises the Pearson correlation of the two over their
overlap at that lag (each lag normalised by its own overlap, so that a smaller overlap is not
penalised), refined by a parabola through the best lag and its two neighbours. Samples outside a
record are NaN, never extrapolated. The smooth parts of a curve fix the shift to a small fraction
of a sample; a step (a puncture) sampled once on each side is only located to within half a
sample interval by either record, whatever the method.

The array checks every analysis module needs (1-D, one value per sample, finite, time strictly
increasing) live here too, so that each refusal reads the same.
"""
from __future__ import annotations

import numpy as np
from scipy.signal import correlate, correlation_lags

__all__ = ['best_time_shift', 'increasing_time', 'resample', 'sample_array']

GRID_REFINEMENT = 4          # grid points per median sample interval of the finer record
MAX_GRID_SAMPLES = 2_000_000   # a longer common grid is coarsened to this many points
MIN_OVERLAP_FRACTION = 0.5     # a lag counts when the records overlap on half the shorter one


def sample_array(name: str, values, length: int | None = None, *,
                 finite: bool = False) -> np.ndarray:
    """``values`` as a 1-D float array, refused (naming ``name``) when not 1-D, when it has not
    ``length`` samples, or, with ``finite``, when it holds NaN or inf."""
    array = np.asarray(values, dtype=float)
    if array.ndim != 1:
        raise ValueError(f'{name} has shape {array.shape}; expected a 1-D array')
    if length is not None and len(array) != length:
        raise ValueError(f'{name} has {len(array)} samples; expected {length} '
                         f'(one per time sample)')
    if finite and not np.isfinite(array).all():
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise ValueError(f'{name}[{bad}] = {float(array[bad])!r}; expected finite values')
    return array


def increasing_time(name: str, time_s) -> np.ndarray:
    """``time_s`` as a finite 1-D array of at least 2 strictly increasing times [s]."""
    time = sample_array(name, time_s, finite=True)
    if len(time) < 2:
        raise ValueError(f'{name} has {len(time)} sample(s); expected at least 2')
    steps = np.diff(time)
    if not (steps > 0).all():
        bad = int(np.flatnonzero(~(steps > 0))[0]) + 1
        raise ValueError(f'{name}[{bad}] = {float(time[bad])!r} after {float(time[bad - 1])!r}; '
                         f'expected strictly increasing time')
    return time


def resample(time_s, values, new_time_s) -> np.ndarray:
    """``values`` sampled at ``time_s`` interpolated linearly at ``new_time_s``; NaN outside
    ``[time_s[0], time_s[-1]]`` (no extrapolation)."""
    time = increasing_time('time_s', time_s)
    samples = sample_array('values', values, len(time))
    return np.interp(np.asarray(new_time_s, dtype=float), time, samples, left=np.nan, right=np.nan)


def best_time_shift(reference_time, reference_force, other_time, other_force, *,
                    max_shift_s: float = 0.5) -> float:
    """The shift [s] that best lines ``other`` up with ``reference``: ``other(t + shift)``
    resembles ``reference(t)``, so a positive shift means ``other`` lags. Searched within
    ``+-max_shift_s`` (the result never leaves it); see the module docstring for the rule."""
    ref_time = increasing_time('reference_time', reference_time)
    ref_force = sample_array('reference_force', reference_force, len(ref_time))
    oth_time = increasing_time('other_time', other_time)
    oth_force = sample_array('other_force', other_force, len(oth_time))
    if not (np.isfinite(max_shift_s) and max_shift_s > 0):
        raise ValueError(f'max_shift_s = {max_shift_s!r}; expected a finite time > 0 s')
    step = min(np.median(np.diff(ref_time)), np.median(np.diff(oth_time))) / GRID_REFINEMENT
    start, stop = min(ref_time[0], oth_time[0]), max(ref_time[-1], oth_time[-1])
    n_grid = int(np.floor((stop - start) / step)) + 1
    if n_grid > MAX_GRID_SAMPLES:
        n_grid = MAX_GRID_SAMPLES
        step = (stop - start) / (n_grid - 1)
    grid = start + step * np.arange(n_grid)
    correlation, lags = _correlation_by_lag(resample(oth_time, oth_force, grid),
                                            resample(ref_time, ref_force, grid))
    max_lag = int(np.floor(max_shift_s / step))
    correlation = np.where(np.abs(lags) <= max_lag, correlation, np.nan)
    if not np.isfinite(correlation).any():
        raise ValueError(f'the records do not overlap enough within max_shift_s = {max_shift_s} s '
                         f'(or one of them is constant there)')
    best = int(np.nanargmax(correlation))
    shift_samples = float(lags[best]) + _parabola_vertex(correlation, best)
    return float(np.clip(shift_samples * step, -max_shift_s, max_shift_s))


def _correlation_by_lag(other: np.ndarray, reference: np.ndarray):
    """The Pearson correlation of ``other[n + lag]`` with ``reference[n]`` over the samples both
    hold (NaN where the overlap is short or constant), and the lags."""
    other_held, reference_held = np.isfinite(other), np.isfinite(reference)
    x = np.where(other_held, other - np.nanmean(other), 0.0)
    y = np.where(reference_held, reference - np.nanmean(reference), 0.0)
    held_x, held_y = other_held.astype(float), reference_held.astype(float)
    count = np.rint(correlate(held_x, held_y))
    sum_x, sum_y = correlate(x, held_y), correlate(held_x, y)
    sum_xx, sum_yy = correlate(x * x, held_y), correlate(held_x, y * y)
    sum_xy = correlate(x, y)
    min_count = max(3.0, MIN_OVERLAP_FRACTION * min(held_x.sum(), held_y.sum()))
    with np.errstate(invalid='ignore', divide='ignore'):
        covariance = sum_xy - sum_x * sum_y / count
        variance_x = sum_xx - sum_x ** 2 / count
        variance_y = sum_yy - sum_y ** 2 / count
        correlation = covariance / np.sqrt(variance_x * variance_y)
    correlation[(count < min_count) | ~(variance_x > 0) | ~(variance_y > 0)] = np.nan
    return correlation, correlation_lags(len(other), len(reference))


def _parabola_vertex(values: np.ndarray, best: int) -> float:
    """The offset (in samples, within +-0.5) of the vertex of the parabola through
    ``values[best - 1 : best + 2]``; 0 at an edge or where a neighbour is NaN."""
    if best == 0 or best == len(values) - 1:
        return 0.0
    before, peak, after = values[best - 1], values[best], values[best + 1]
    curvature = before - 2.0 * peak + after
    if not (np.isfinite(before) and np.isfinite(after) and curvature < 0):
        return 0.0
    return float(np.clip(0.5 * (before - after) / curvature, -0.5, 0.5))
