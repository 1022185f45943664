"""Events in one axial force curve: contact, punctures, and the phases of an insertion.

One detector serves measured load-cell curves and simulated ones alike, so that the events
compared between them are found by the same rule. Force is positive while the tissue resists.
The rules (module constants, SI units):

- Pre-contact level: the samples before the force starts to rise: the longest prefix of the
  first 10 % of the record (at least 10 samples) doubling from 10 samples while its last
  quarter's median stays within 3 standard errors and 1 mN of its first quarter's
  (:func:`_quiet_prefix`); the ``baseline`` is their median, the ``noise`` their robust standard
  deviation (1.4826 x the median absolute deviation), zero for a noiseless simulated curve. A
  prefix of fewer than 20 samples gives the noise of the whole first 10 % instead (the smaller of
  its spread and its spread about a quadratic fit to it: a head that reaches into the loading has
  its trend, which is not noise). A recording that starts just above the tissue has the
  loading's rise in its first 10 %: a 0.5 s approach in a 37 s record put the median of the first
  tenth, or of its first third, 23-30 mN up on 5 mN noise and the contact 0.25 mm late, and the
  spread about the quadratic read the contact's kink as noise (17 mN on 5).
- Contact: found where the force stays above ``baseline + 5 noise + 1 mN`` for ``sustain_s`` (and
  the travel, when given, rises meanwhile by more than 3 travel-noise: the median of the last
  quarter of that window above the median of its first quarter); the index returned is the onset
  of that rise: the first sample after the last one where the force averaged over
  ``sustain_s / 2`` (w samples) is at or below ``baseline + 2 noise / sqrt(w) + 1 mN``. The 5
  noise make a false start unlikely (3e-7 a sample) and the sustain excludes spikes; the walk
  back on the averaged force puts the onset near where the force leaves the noise, not 5 noise
  later, and closer to it the more samples a second the record holds.
- Drops: the force is smoothed by a running median over 0.1 mm of travel (a puncture's step
  survives a median; spikes and noise do not); each local maximum of prominence >= ``min_drop_n``
  (scipy.signal.find_peaks) during insertion is a candidate, its drop the fall to the lowest
  point within ``window_m`` of further travel (4 mm: a rounded peak falls over millimetres, not
  at one sample) before the force climbs back above the peak. A drop of at least
  ``max(min_drop_fraction x peak, min_drop_n)`` is an event. Lower tops between a peak and the
  lowest point of its fall (a double top) belong to its event. ``min_drop_n`` defaults to
  ``8 noise + 10 mN``: the range of a thousand Gaussian samples rarely reaches 8 sigma, and 10 mN
  keeps a noiseless simulation's numerical ripples out. The noise here is the smaller of the
  pre-contact one and the whole record's sample-to-sample noise (the robust standard deviation of
  the force's second differences over sqrt(6), white noise's own; the curve's trend, its kinks
  and its few drops barely move a median): a recording that starts a millimetre above the tissue
  has little before contact to read the noise from, and the loading's shape read as noise set the
  threshold above a layer's drop.
- Puncture or pre-drop: a puncture ends the loading that built its peak (the force has to build a
  new one, in a new layer or inside the tissue), so the force stays below the peak for a while; a
  pre-drop (a surface dimple giving way, a slip) is a drop the same loading recovers from at once.
  An event whose peak the force regains within ``regain_fraction`` (0.15) of the travel that
  built it (from the last sample before the peak at 10 % of its rise above the lowest force since
  the previous puncture), and within 0.3 mm at least, is a pre-drop: also the first top of a double
  top whose second top is higher (a digitized curve's vertical line). The others are punctures. A
  layer's puncture is a drop the repeats share: :mod:`.shared_punctures` groups the events of
  several repeats.
- At depth (hold): the travel smoothed by a 5-sample running median is within
  ``max(4 travel-noise, 10 um)`` of its maximum, from the first such sample to the last.
  Travel noise is the robust standard deviation of the travel's second differences / sqrt(6): zero
  for a uniform motion, the sensor's noise for a noisy one, barely touched by jittered sampling.
- Phases: 'approach' before contact, 'loading' from contact through the first puncture's peak,
  'inserted' after it until the hold, 'hold' at depth, 'retraction' from the hold's end on (a rest
  at the end of the record included).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import median_filter, uniform_filter1d
from scipy.signal import find_peaks

from tissue_sim_ros.analysis.compare.alignment import increasing_time, sample_array

__all__ = ['PHASES', 'PRE_DROP', 'PUNCTURE', 'Puncture', 'baseline_and_noise', 'contact_in_noise', 'depth_bounds',
           'detect_contact', 'detect_drops', 'detect_punctures', 'sample_noise_n', 'segment_phases', 'travel_noise_m']

PHASES = ('approach', 'loading', 'inserted', 'hold', 'retraction')
MAD_TO_SIGMA = 1.4826
HEAD_FRACTION, MIN_HEAD_SAMPLES = 0.1, 10
#: a prefix of the head is before contact while its last quarter's median is within this many
#: standard errors of its first quarter's; a median's standard error in noise units times sqrt(n)
QUIET_STANDARD_ERRORS, MEDIAN_STANDARD_ERROR = 3.0, 1.2533
CONTACT_NOISE_MULTIPLE, ONSET_NOISE_MULTIPLE, CONTACT_FLOOR_N = 5.0, 2.0, 1e-3
CONTACT_TRAVEL_NOISE_MULTIPLE = 3.0
PUNCTURE_NOISE_MULTIPLE, PUNCTURE_FLOOR_N = 8.0, 1e-2
PUNCTURE_SMOOTHING_M, MAX_SMOOTHING_HALF_WIDTH = 1e-4, 100
DEPTH_NOISE_MULTIPLE, DEPTH_TOLERANCE_FLOOR_M, TRAVEL_MEDIAN_SAMPLES = 4.0, 1e-5, 5
#: the travel within which a peak's force must fall to count as an event (``window_m``)
PUNCTURE_WINDOW_M = 0.004
#: a drop regained within this fraction of the travel that built its peak is a pre-drop, and within
#: PRE_DROP_MIN_REGAIN_M at least
PRE_DROP_REGAIN_FRACTION, PRE_DROP_MIN_REGAIN_M = 0.15, 3e-4
#: the loading that built a peak starts at this fraction of its rise
LOADING_START_FRACTION = 0.1
#: an event's kinds
PUNCTURE, PRE_DROP = 'puncture', 'pre-drop'
#: a noiseless curve's contact as the detector finds it in noise: the median over this many
#: copies with white noise drawn from this seed (:func:`contact_in_noise`)
NOISY_COPIES, NOISE_SEED = 15, 20260


@dataclass(frozen=True)
class Puncture:
    """A drop of the force during insertion (module docstring): ``index`` and ``travel_m`` of the
    peak sample, ``force_n`` the smoothed force at the peak, ``drop_n`` its smoothed fall [N];
    ``kind`` 'puncture' or 'pre-drop'; ``fall_m``, the travel from the peak to the lowest point of
    the fall; ``regained_m``, the travel after the peak at which the force climbs back above it
    (inf: not within the stretch); ``built_m``, the travel of the loading that built the peak;
    ``layer``: the layer it punctures, counted from the outer one, when known (-1: not known)."""

    index: int
    travel_m: float
    force_n: float
    drop_n: float
    kind: str = PUNCTURE
    fall_m: float = 0.0
    regained_m: float = float('inf')
    built_m: float = float('inf')
    layer: int = -1


def baseline_and_noise(force_n) -> tuple[float, float]:
    """The pre-contact ``(baseline, noise)`` [N] of a force curve (rule in the module docstring)."""
    force = sample_array('force_n', force_n, finite=True)
    n_head = min(len(force), max(MIN_HEAD_SAMPLES, int(round(HEAD_FRACTION * len(force)))))
    if n_head == 0:
        raise ValueError('force_n is empty; expected a force curve')
    head = force[:n_head]
    quiet = _quiet_prefix(head)
    if len(quiet) >= 2 * MIN_HEAD_SAMPLES:
        return float(np.median(quiet)), float(MAD_TO_SIGMA * np.median(np.abs(quiet - np.median(quiet))))
    noise = MAD_TO_SIGMA * np.median(np.abs(head - np.median(head)))
    if n_head >= 2 * MIN_HEAD_SAMPLES:      # a head that reaches into the loading: its trend is not noise
        k = np.arange(n_head, dtype=float)
        trend = np.polyval(np.polyfit(k, head, 2), k)
        noise = min(noise, MAD_TO_SIGMA * np.median(np.abs(head - trend)))
    return float(np.median(quiet)), float(noise)


def _quiet_prefix(head: np.ndarray) -> np.ndarray:
    """The longest of the head's prefixes of ``MIN_HEAD_SAMPLES`` times a power of 2 (and the
    whole head) whose last quarter's median lies within ``QUIET_STANDARD_ERRORS`` standard errors
    of its first quarter's (the noise: the head's sample-to-sample one), and ``CONTACT_FLOOR_N``:
    the samples before the force starts to rise; the first ``MIN_HEAD_SAMPLES`` at least."""
    noise = sample_noise_n(head)
    lengths = [MIN_HEAD_SAMPLES * 2 ** j for j in range(1, 64) if MIN_HEAD_SAMPLES * 2 ** j < len(head)]
    quiet = head[:MIN_HEAD_SAMPLES]
    for length in lengths + [len(head)]:
        quarter = length // 4
        spread = QUIET_STANDARD_ERRORS * MEDIAN_STANDARD_ERROR * noise * np.sqrt(2.0 / quarter)
        if np.median(head[length - quarter:length]) - np.median(head[:quarter]) > spread + CONTACT_FLOOR_N:
            break
        quiet = head[:length]
    return quiet


def sample_noise_n(force_n) -> float:
    """The sample-to-sample noise of a force record [N]: the robust standard deviation of its
    second differences over sqrt(6) (module docstring)."""
    force = sample_array('force_n', force_n, finite=True)
    if len(force) < 3:
        return 0.0
    second = np.diff(force, 2)
    return float(MAD_TO_SIGMA * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))


def travel_noise_m(travel_m) -> float:
    """The robust noise of a travel trace [m] (rule in the module docstring)."""
    travel = sample_array('travel_m', travel_m, finite=True)
    if len(travel) < 3:
        return 0.0
    second = np.diff(travel, 2)
    return float(MAD_TO_SIGMA * np.median(np.abs(second - np.median(second))) / np.sqrt(6.0))


def depth_bounds(travel_m) -> tuple[int, int]:
    """The first and the last index at the deepest travel (the hold; rule in the module
    docstring). Before the first the needle advances; after the last it retracts."""
    travel = sample_array('travel_m', travel_m, finite=True)
    smoothed = median_filter(travel, size=TRAVEL_MEDIAN_SAMPLES, mode='nearest')
    tolerance = max(DEPTH_NOISE_MULTIPLE * travel_noise_m(travel), DEPTH_TOLERANCE_FLOOR_M)
    at_depth = np.flatnonzero(smoothed >= smoothed.max() - tolerance)
    return int(at_depth[0]), int(at_depth[-1])


def detect_contact(time_s, force_n, travel_m=None, *, noise_n: float | None = None,
                   sustain_s: float = 0.1) -> int | None:
    """The index where the force starts its first sustained rise above the pre-contact noise,
    or None (rule in the module docstring). ``noise_n``: the force noise [N] when known (else
    estimated from the first part of the record); ``travel_m``: when given, a rise while the
    needle does not advance is not contact."""
    time = increasing_time('time_s', time_s)
    force = sample_array('force_n', force_n, len(time), finite=True)
    travel = (None if travel_m is None
              else sample_array('travel_m', travel_m, len(time), finite=True))
    if not (np.isfinite(sustain_s) and sustain_s >= 0):
        raise ValueError(f'sustain_s = {sustain_s!r}; expected a finite time >= 0 s')
    baseline, noise = baseline_and_noise(force)
    if noise_n is not None:
        if not (np.isfinite(noise_n) and noise_n >= 0):
            raise ValueError(f'noise_n = {noise_n!r}; expected a finite force >= 0 N')
        noise = float(noise_n)
    above = force > baseline + CONTACT_NOISE_MULTIPLE * noise + CONTACT_FLOOR_N
    window_last = np.searchsorted(time, time + sustain_s, side='right') - 1
    below = np.append(np.flatnonzero(~above), len(time))
    next_below = below[np.searchsorted(below, np.arange(len(time)))]
    sustained = above & (next_below > window_last) & (time[-1] >= time + sustain_s)
    min_rise = 0.0 if travel is None else CONTACT_TRAVEL_NOISE_MULTIPLE * travel_noise_m(travel)
    for start in np.flatnonzero(sustained):
        if travel is None or _rises(travel[start:max(window_last[start], start + 1) + 1], min_rise):
            return _onset(time, force, start, baseline, noise, sustain_s)
    return None


def contact_in_noise(time_s, force_n, travel_m, *, noise_n: float, record_time_s,
                     copies: int = NOISY_COPIES) -> int | None:
    """The index in ``time_s`` where :func:`detect_contact` finds the contact of a noiseless curve
    (a simulation's) as it finds it in the record it is compared with: the curve sampled at that
    record's times (``record_time_s``, on the curve's clock; before its first sample the curve's
    first force, after its last its last) with white noise of ``noise_n`` [N], the median time
    over ``copies`` seeded copies. The walk back from the sustained rise stops at the last sample
    the noise pulls below the onset level, and the record's head sets the baseline: on the layered
    bench's records (5-7 mN, 100 Hz) the noise puts the contact 0.02-0.04 mm later than on the
    noiseless curve; found without that lag, every simulated event would lie deeper since contact
    than the data's with the right parameters. ``noise_n`` 0: the noiseless curve's own."""
    time = increasing_time('time_s', time_s)
    force = sample_array('force_n', force_n, len(time), finite=True)
    travel = sample_array('travel_m', travel_m, len(time), finite=True)
    record = increasing_time('record_time_s', record_time_s)
    if not (np.isfinite(noise_n) and noise_n >= 0):
        raise ValueError(f'noise_n = {noise_n!r}; expected a finite force >= 0 N')
    if noise_n == 0 or copies < 1:
        return detect_contact(time, force, travel, noise_n=noise_n)
    on_record, travel_on_record = np.interp(record, time, force), np.interp(record, time, travel)
    rng = np.random.default_rng(NOISE_SEED)
    found = [record[index] for index in
             (detect_contact(record, on_record + rng.normal(0.0, noise_n, record.size), travel_on_record,
                             noise_n=noise_n) for _ in range(copies)) if index is not None]
    if not found:
        return detect_contact(time, force, travel, noise_n=noise_n)
    return int(np.searchsorted(time, float(np.median(found))).clip(0, len(time) - 1))


def _onset(time, force, detected, baseline, noise, sustain_s) -> int:
    """The first sample after the last one, before ``detected``, where the force averaged over
    ``sustain_s / 2`` (w samples) is at or below ``baseline + 2 noise / sqrt(w) + floor``."""
    width = max(1, int(round(0.5 * sustain_s / np.median(np.diff(time)))))
    smoothed = uniform_filter1d(force, size=width, mode='nearest')
    level = baseline + ONSET_NOISE_MULTIPLE * noise / np.sqrt(width) + CONTACT_FLOOR_N
    quiet = np.flatnonzero(smoothed[:detected] <= level)
    return int(quiet[-1]) + 1 if quiet.size else 0


def _rises(travel: np.ndarray, min_rise: float) -> bool:
    quarter = max(1, len(travel) // 4)
    return bool(np.median(travel[-quarter:]) - np.median(travel[:quarter]) > min_rise)


def detect_punctures(travel_m, force_n, *, min_drop_fraction: float = 0.15,
                     min_drop_n: float | None = None, window_m: float = PUNCTURE_WINDOW_M,
                     inserting=None) -> list[Puncture]:
    """The punctures of an insertion, in order of travel (rule in the module docstring): the
    events of :func:`detect_drops` that are not pre-drops."""
    return [event for event in detect_drops(travel_m, force_n, min_drop_fraction=min_drop_fraction,
                                            min_drop_n=min_drop_n, window_m=window_m, inserting=inserting)
            if event.kind == PUNCTURE]


def detect_drops(travel_m, force_n, *, min_drop_fraction: float = 0.15, min_drop_n: float | None = None,
                 window_m: float = PUNCTURE_WINDOW_M, inserting=None) -> list[Puncture]:
    """Every drop of an insertion, punctures and pre-drops, in order of travel (rule in the module
    docstring). ``inserting``: a boolean mask of the samples where the needle advances (default:
    those before the deepest travel); peaks and drops are searched within each stretch of it.
    ``min_drop_fraction`` 0 with ``min_drop_n`` 0 gives every local maximum that falls at all."""
    travel = sample_array('travel_m', travel_m, finite=True)
    force = sample_array('force_n', force_n, len(travel), finite=True)
    if not 0.0 <= min_drop_fraction < 1.0:
        raise ValueError(f'min_drop_fraction = {min_drop_fraction!r}; expected 0 <= value < 1')
    if not (np.isfinite(window_m) and window_m > 0):
        raise ValueError(f'window_m = {window_m!r}; expected a finite distance > 0 m')
    if min_drop_n is None:
        noise = min(baseline_and_noise(force)[1], sample_noise_n(force))
        min_drop_n = PUNCTURE_NOISE_MULTIPLE * noise + PUNCTURE_FLOOR_N
    elif not (np.isfinite(min_drop_n) and min_drop_n >= 0):
        raise ValueError(f'min_drop_n = {min_drop_n!r}; expected a finite force >= 0 N')
    if inserting is None:
        mask = np.arange(len(travel)) < depth_bounds(travel)[0]
    else:
        mask = np.asarray(inserting, dtype=bool)
        if mask.shape != travel.shape:
            raise ValueError(f'inserting has shape {mask.shape}; expected {travel.shape}')
    edges = np.flatnonzero(np.diff(np.concatenate([[0], mask.astype(np.int8), [0]])))
    events = []
    for start, stop in zip(edges[::2], edges[1::2]):
        events += _drops_in_stretch(travel[start:stop], force[start:stop], start, min_drop_fraction,
                                    float(min_drop_n), window_m)
    return events


def _drops_in_stretch(travel, force, offset, min_drop_fraction, min_drop_n, window_m):
    n_samples = len(force)
    if n_samples < 3:
        return []
    travel_step = (travel[-1] - travel[0]) / (n_samples - 1)
    half = 0 if travel_step <= 0 else int(min(MAX_SMOOTHING_HALF_WIDTH,
                                              PUNCTURE_SMOOTHING_M / travel_step // 2))
    smoothed = median_filter(force, size=2 * half + 1, mode='nearest')
    peaks, _ = find_peaks(smoothed, prominence=max(min_drop_n, 1e-12))
    found, fallen_at, loading_since = [], -1, 0
    for peak in peaks:
        peak_force = smoothed[peak]
        after = slice(peak + 1, n_samples)
        above = np.flatnonzero(smoothed[after] > peak_force)
        regain = peak + 1 + int(above[0]) if above.size else None
        beyond = np.flatnonzero((travel[after] > travel[peak] + window_m) | (smoothed[after] > peak_force))
        end = peak + 1 + (int(beyond[0]) if beyond.size else n_samples - peak - 1)
        if peak <= fallen_at or peak_force <= 0 or end == peak + 1:
            continue
        lowest = peak + 1 + int(np.argmin(smoothed[peak + 1:end]))
        drop = peak_force - smoothed[lowest]
        if drop < max(min_drop_fraction * peak_force, min_drop_n):
            continue
        low = max(0, peak - half)
        index = low + int(np.argmax(force[low:peak + half + 1]))
        built = _loading_length(travel, smoothed, loading_since, peak)
        regained = float('inf') if regain is None else float(travel[regain] - travel[peak])
        kind = PRE_DROP if regained < max(PRE_DROP_REGAIN_FRACTION * built, PRE_DROP_MIN_REGAIN_M) else PUNCTURE
        found.append(Puncture(offset + index, float(travel[index]), float(peak_force), float(drop), kind,
                              float(travel[lowest] - travel[peak]), regained, built))
        fallen_at = lowest
        if kind == PUNCTURE:
            loading_since = lowest
    return found


def _loading_length(travel, smoothed, since, peak) -> float:
    """The travel over which the loading built the peak at ``peak``: from the last sample before it
    at LOADING_START_FRACTION of its rise above the lowest force since ``since``."""
    before = smoothed[since:peak + 1]
    floor = float(before.min())
    level = floor + LOADING_START_FRACTION * (float(smoothed[peak]) - floor)
    low = np.flatnonzero(before <= level)
    start = since + (int(low[-1]) if low.size else 0)
    return float(travel[peak] - travel[start])


def segment_phases(time_s, travel_m, force_n, *, first_puncture: int | None = None,
                   contact: int | None = None) -> np.ndarray:
    """The phase of each sample, one of :data:`PHASES`: 'approach' before ``contact``,
    'loading' from it to ``first_puncture`` (inclusive), 'inserted' after that while the needle
    advances, 'hold' at depth (:func:`depth_bounds`), 'retraction' after the hold. ``contact``
    and ``first_puncture`` are sample indices, detected (:func:`detect_contact`,
    :func:`detect_punctures` on the advancing samples after contact) when not given; without a
    contact everything before the hold is 'approach', without a puncture 'loading'."""
    time = increasing_time('time_s', time_s)
    travel = sample_array('travel_m', travel_m, len(time), finite=True)
    force = sample_array('force_n', force_n, len(time), finite=True)
    for name, index in (('contact', contact), ('first_puncture', first_puncture)):
        if index is not None and not 0 <= index < len(time):
            raise ValueError(f'{name} = {index!r}; expected a sample index in [0, {len(time)})')
    hold_start, hold_end = depth_bounds(travel)
    phases = np.full(len(time), 'retraction', dtype='<U10')
    phases[:hold_start] = 'approach'
    phases[hold_start:hold_end + 1] = 'hold'
    if contact is None:
        contact = detect_contact(time, force, travel)
    if contact is None or contact >= hold_start:
        return phases
    if first_puncture is None:
        advancing = (np.arange(len(time)) >= contact) & (np.arange(len(time)) < hold_start)
        punctures = detect_punctures(travel, force, inserting=advancing)
        first_puncture = punctures[0].index if punctures else hold_start
    if first_puncture < contact:
        raise ValueError(f'first_puncture = {first_puncture} is before contact = {contact}')
    loading_end = min(first_puncture + 1, hold_start)
    phases[contact:loading_end] = 'loading'
    phases[loading_end:hold_start] = 'inserted'
    return phases
