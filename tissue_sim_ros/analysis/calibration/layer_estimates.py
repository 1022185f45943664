"""What one force curve says about each layer, and a layered scene's starting values from it.

:func:`curve_features` reads, from one curve (time, travel since contact, axial force, its
punctures by layer), the numbers a scene's keys set, each where that key acts:

- each layer's puncture: its depth and peak force, and the lowest point of the fall after it (the
  valley: where the next layer's loading starts, at the force the tip keeps inside);
- where each deeper layer starts loading (its onset): after the previous valley the tip cuts
  through the layer it punctured (the force rises slowly, friction) until it meets the next one
  (it rises steeply): the break of a continuous two-line fit F = a + b x + c max(0, x - x0) from
  the valley to the puncture, x0 the least-squares one over the samples (a hinge regression);
- each layer's loading slope: the secant between 30 % and 80 % of its rise (from contact, or
  from its onset, to its peak): a stiffness's effect, free of the contact's onset and of the
  peak's rounding;
- after the last puncture, until the pause: a straight line F = c + f x (x the travel since
  contact), over the samples from 1 mm after the valley: f is the shaft friction per inserted
  length, c the cutting force (the force at the tip when no length is inside);
- the pause (the samples at the deepest travel): the part of its force it relaxes (its first
  samples' median to its last ones') and the time it takes to fall 63 % of that (robust to a
  pause too short to see the exponential's end, and read the same way from a simulation);
- each layer's loading level (:func:`loading_level`): the mean force above the level it starts
  from over the same depths in two curves, whose ratio scales a modulus;
- the retraction: per layer, the median force of the second half (in time) of the samples while
  the tip is within the layer (between the onsets: the boundaries it crosses going back), the
  plateau after the pull-out's transition, and the step between layers (the layers' onsets: the
  boundaries the tip crosses on its way out); and the strongest pull anywhere in it (the
  smoothed force's least value), which no one layer's pull exceeds: where the tip leaves a layer
  soon after the turn (dragging the tissue), that layer's window holds the transition and reads
  low, and the calibration's bound for it then comes from the strongest pull.

:func:`starting_values` turns the features of several repeats into scene keys (the rules are
in its docstring); :mod:`.propose` refines them against simulations of the scene.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ['CurveFeatures', 'accrued_friction', 'curve_features', 'held_friction', 'loading_level', 'mean_features',
           'starting_values', 'unread_cuts']

#: a layer's loading slope is the secant between these fractions of its rise
SLOPE_FRACTIONS = (0.3, 0.8)
#: the line after the last puncture starts this far past its valley
POST_START_M = 0.001
#: a pause relaxing by less than this fraction of its force states no relaxation. Low, because
#: the pause's fall is a small part of the relaxing part (much of the pause's force is the shaft's
#: friction): on the layered phantoms a relaxing part of 0.4 falls 3.6 %, and 0.7 (three layers)
#: 1.4-3.8 % in five repeats, while leaving it out costs that scene 0.083 of NRMSE against 0.016
MIN_RELAXATION = 0.01
#: a cut's slope above this many times its valley's force over the valley's depth is the next
#: layer's rise, not a cut (:func:`starting_values`)
MAX_CUT_OVER_VALLEY = 3.0
#: a deeper layer's rupture force starts at least at this fraction of its peak (:func:`starting_values`)
MIN_RUPTURE_OF_PEAK = 0.5


@dataclass
class CurveFeatures:
    """One curve's numbers (module docstring), per layer in depth order (NaN where the curve
    lacks it): ``depth_m``, ``onset_m`` (where its loading starts), ``cut_slope_n_per_m`` (from
    layer 1 on: the slope of the cut through the layer above before it), ``peak_n``, ``valley_m``
    and ``valley_n`` (after the puncture),
    ``slope_n_per_m`` (the loading); ``post_intercept_n`` and ``post_slope_n_per_m`` (after the
    last puncture); ``hold_start_n``, ``hold_end_n``, ``relaxing`` (fraction), ``relax_time_s``;
    ``retraction_n`` per layer (negative: the pull); ``strongest_pull_n`` (negative)."""

    depth_m: list = field(default_factory=list)
    onset_m: list = field(default_factory=list)
    cut_slope_n_per_m: list = field(default_factory=list)
    peak_n: list = field(default_factory=list)
    valley_m: list = field(default_factory=list)
    valley_n: list = field(default_factory=list)
    slope_n_per_m: list = field(default_factory=list)
    post_intercept_n: float = math.nan
    post_slope_n_per_m: float = math.nan
    hold_start_n: float = math.nan
    hold_end_n: float = math.nan
    relaxing: float = math.nan
    relax_time_s: float = math.nan
    retraction_n: list = field(default_factory=list)
    strongest_pull_n: float = math.nan


def _secant_slope(travel, force, start, peak, start_level) -> float:
    """The loading's secant slope between SLOPE_FRACTIONS of its rise from ``start_level`` to the
    force at ``peak`` (the last crossings before the peak)."""
    rise = force[peak] - start_level
    if not rise > 0 or peak - start < 3:
        return math.nan
    points = []
    for fraction in SLOPE_FRACTIONS:
        level = start_level + fraction * rise
        below = np.flatnonzero(force[start:peak + 1] <= level)
        if not below.size:
            return math.nan
        k = start + int(below[-1])
        k1 = min(k + 1, peak)
        span = force[k1] - force[k]
        x = travel[k] + (travel[k1] - travel[k]) * ((level - force[k]) / span if span > 0 else 0.0)
        points.append((x, level))
    (x0, f0), (x1, f1) = points
    return (f1 - f0) / (x1 - x0) if x1 > x0 else math.nan


def _relaxation(time, force):
    """(F at the pause's start, F at its end, the time it takes to fall 63 % of the way): the
    medians of its first 5 % and last 10 % of samples (at least 3), the crossing interpolated."""
    n = len(force)
    start = float(np.median(force[:max(3, n // 20)]))
    end = float(np.median(force[-max(3, n // 10):]))
    level = start - (1.0 - math.exp(-1.0)) * (start - end)
    t = time - time[0]
    crossed = np.flatnonzero(force <= level) if start > end else np.zeros(0, dtype=int)
    tau = float(t[crossed[0]]) if crossed.size else math.nan
    return start, end, max(tau, float(t[1] - t[0])) if math.isfinite(tau) else tau


def loading_onset(travel, force, start: int, stop: int) -> tuple[float, float]:
    """(x0, b): the travel of the least-squares break of a continuous two-line fit over the
    samples ``start`` to ``stop`` (module docstring) and the slope before it (the cut through the
    layer above: its shaft friction per length); (the first sample's travel, NaN) when there are
    too few."""
    x, y = np.asarray(travel[start:stop], float), np.asarray(force[start:stop], float)
    if len(x) < 6:
        return (float(travel[start]) if len(x) else math.nan), math.nan
    best, where, slope = math.inf, float(x[0]), math.nan
    for k in range(2, len(x) - 2):
        design = np.column_stack([np.ones_like(x), x, np.maximum(0.0, x - x[k])])
        coefficients, residual, *_ = np.linalg.lstsq(design, y, rcond=None)
        error = float(residual[0]) if residual.size else float(np.sum((design @ coefficients - y) ** 2))
        if coefficients[2] > 0 and error < best:
            best, where, slope = error, float(x[k]), float(coefficients[1])
    return where, slope


def loading_level(travel_m, force_n, start_m: float, end_m: float, base_n: float) -> float:
    """The mean force above ``base_n`` over the insertion's travel from ``start_m`` to ``end_m`` (a
    stiffness's effect: the force a layer builds is proportional to its modulus over the same
    depths)."""
    from tissue_sim_ros.analysis.compare.force_events import depth_bounds
    travel, force = np.asarray(travel_m, float), np.asarray(force_n, float)
    inside = (travel >= start_m) & (travel <= end_m) & (np.arange(len(travel)) < depth_bounds(travel)[0])
    if np.count_nonzero(inside) < 3 or not end_m > start_m:
        return math.nan
    return float(np.mean(force[inside]) - base_n)


def curve_features(time_s, travel_m, force_n, punctures, n_layers: int) -> CurveFeatures:
    """The features of one curve (module docstring): ``travel_m`` since contact, ``punctures`` the
    curve's punctures, each with its ``layer`` (0 the outer one; -1 taken in order)."""
    from scipy.ndimage import median_filter

    from tissue_sim_ros.analysis.compare.force_events import depth_bounds
    time, travel = np.asarray(time_s, float), np.asarray(travel_m, float)
    force = np.asarray(force_n, float)
    hold_start, hold_end = depth_bounds(travel)
    step = np.median(np.abs(np.diff(travel[:max(hold_start, 2)]))) or 1e-5
    smooth = median_filter(force, size=2 * int(min(50, 1e-4 / step // 2)) + 1, mode='nearest')
    by_layer = {}
    for order, p in enumerate(punctures):
        layer = p.layer if p.layer >= 0 else order
        if layer < n_layers and layer not in by_layer:
            by_layer[layer] = p
    out = CurveFeatures()
    contact = int(np.argmin(np.abs(travel[:max(hold_start, 1)])))
    previous_valley, previous_level = contact, 0.0
    for layer in range(n_layers):
        p = by_layer.get(layer)
        if p is None or p.index >= hold_start:
            for name in ('depth_m', 'onset_m', 'peak_n', 'valley_m', 'valley_n', 'slope_n_per_m'):
                getattr(out, name).append(math.nan)
            if layer:
                out.cut_slope_n_per_m.append(math.nan)
            continue
        if layer == 0:
            onset = 0.0
        else:
            start = int(np.searchsorted(travel[:p.index + 1], travel[previous_valley] + POST_START_M))
            onset, cut = loading_onset(travel, smooth, min(start, p.index - 6), p.index + 1)
            out.cut_slope_n_per_m.append(cut)
        out.onset_m.append(onset)
        if layer:
            previous_valley = max(previous_valley, int(np.searchsorted(travel[:p.index + 1], onset)))
            previous_level = float(smooth[previous_valley])
        later = [q.index for q in by_layer.values() if q.index > p.index]
        stop = min(later + [hold_start])
        valley = p.index + 1 + int(np.argmin(smooth[p.index + 1:stop])) if stop > p.index + 1 else p.index
        out.depth_m.append(float(p.travel_m))
        out.peak_n.append(float(p.force_n))
        out.valley_m.append(float(travel[valley]))
        out.valley_n.append(float(smooth[valley]))
        out.slope_n_per_m.append(_secant_slope(travel, smooth, previous_valley, p.index, previous_level))
        previous_valley, previous_level = valley, float(smooth[valley])
    if by_layer and not math.isnan(out.valley_m[-1] if out.valley_m else math.nan):
        after = (np.arange(len(travel)) < hold_start) & (travel >= out.valley_m[-1] + POST_START_M)
        if np.count_nonzero(after) >= 5:
            out.post_slope_n_per_m, out.post_intercept_n = map(float, np.polyfit(travel[after], force[after], 1))
    if hold_end > hold_start + 4:
        start, end, tau = _relaxation(time[hold_start:hold_end + 1], force[hold_start:hold_end + 1])
        out.hold_start_n, out.hold_end_n, out.relax_time_s = start, end, tau
        out.relaxing = (start - end) / start if start > 0 else math.nan
    back = np.arange(len(travel)) > hold_end
    edges = [0.0] + [v for v in out.onset_m[1:] if not math.isnan(v)] + [math.inf]
    for layer in range(n_layers):
        low, high = (edges[layer], edges[layer + 1]) if layer + 1 < len(edges) else (math.nan, math.nan)
        inside = np.flatnonzero(back & (travel > low) & (travel <= high))
        out.retraction_n.append(float(np.median(force[inside[len(inside) // 2:]])) if inside.size >= 4 else math.nan)
    if np.count_nonzero(back) >= 4:
        out.strongest_pull_n = float(min(smooth[back].min(), 0.0))
    return out


def _nanmean(values) -> float:
    values = np.asarray([v for v in values if v is not None], dtype=float)
    return float(np.nanmean(values)) if np.isfinite(values).any() else math.nan


def mean_features(features: list[CurveFeatures]) -> CurveFeatures:
    """The mean over repeats of each feature (NaN entries left out)."""
    n = max(len(f.depth_m) for f in features)
    out = CurveFeatures()
    for name in ('depth_m', 'onset_m', 'cut_slope_n_per_m', 'peak_n', 'valley_m', 'valley_n', 'slope_n_per_m',
                 'retraction_n'):
        setattr(out, name, [_nanmean([getattr(f, name)[k] if k < len(getattr(f, name)) else math.nan
                                      for f in features]) for k in range(n)])
    for name in ('post_intercept_n', 'post_slope_n_per_m', 'hold_start_n', 'hold_end_n', 'relaxing',
                 'relax_time_s', 'strongest_pull_n'):
        setattr(out, name, _nanmean([getattr(f, name) for f in features]))
    return out


def accrued_friction(depths_m, friction_n_per_m, k: int) -> float:
    """The shaft's friction [N] when the tip reaches layer ``k``'s puncture depth: for each layer j
    above it, its friction per length times the travel from its puncture (where the shaft enters
    it) to the next puncture or to that depth; 0 for the outer layer, NaN where a depth is."""
    total = 0.0
    for j in range(k):
        length = min(depths_m[j + 1], depths_m[k]) - depths_m[j]
        total += friction_n_per_m[j] * max(length, 0.0)
    return float(total)


def unread_cuts(measured: CurveFeatures) -> list[int]:
    """The layers above the last whose cut cannot be read: its slope above ``MAX_CUT_OVER_VALLEY``
    times the valley's force over its depth (the next layer's rise, :func:`starting_values`)."""
    out = []
    for k in range(len(measured.depth_m) - 1):
        cut = measured.cut_slope_n_per_m[k] if k < len(measured.cut_slope_n_per_m) else math.nan
        if not np.isfinite(cut) or cut <= 0:
            continue
        valley_n, valley_m = measured.valley_n[k], measured.valley_m[k]
        readable = np.isfinite(valley_n) and np.isfinite(valley_m) and valley_m > 0
        if readable and cut > MAX_CUT_OVER_VALLEY * valley_n / valley_m:
            out.append(k)
    return out


def held_friction(measured: CurveFeatures, friction_n_per_m, boundaries_m, cutting_last_n: float,
                  unread) -> float:
    """The friction per length [N/m] of the ``unread`` layers (:func:`unread_cuts`), from
    the line F = c + f x after the last puncture (x the travel since contact): behind the tip the
    shaft then crosses every layer above the last over its thickness, so where the tip enters the
    last layer (x = its boundary z_last) the line reads the last layer's cutting force plus each
    upper layer's friction per length times its thickness: c + f z_last - cutting - (the layers'
    whose cut was read) = (the unread ones' friction) x (their thickness). The valley right after
    a puncture reads far less (on the layered phantoms 30 N/m for 100: the shaft's friction there
    has not built up yet). ``boundaries_m``: per layer its top's depth below the surface (0 for
    layer 0). NaN when the line is missing, nothing is unread, or the remainder is not positive."""
    n = len(friction_n_per_m)
    c, f = measured.post_intercept_n, measured.post_slope_n_per_m
    if n < 2 or not unread or not (np.isfinite(c) and np.isfinite(f)):
        return math.nan
    thickness = [boundaries_m[j + 1] - boundaries_m[j] for j in range(n - 1)]
    remainder = c + max(f, 0.0) * boundaries_m[n - 1] - cutting_last_n - sum(
        friction_n_per_m[j] * thickness[j] for j in range(n - 1) if j not in unread)
    length = sum(thickness[j] for j in unread)
    return remainder / length if length > 0 and remainder > 0 else math.nan


def starting_values(measured: CurveFeatures, base_modulus_pa: float) -> dict:
    """Starting values of a layered scene from the measured features (each with the rule it came
    from, as ``{name: (value, how)}``); layer k's keys are suffixed ``[k]``:

    - ``boundary_m[k]`` (k >= 1): where layer k starts loading (its onset: deeper than the boundary
      at rest by the compression of the layers above; the refinement moves it up, :mod:`.propose`);
    - ``modulus_pa[k]``: layer 0 the base scene's, layer k that times the square root of its
      loading slope over layer 0's (a deeper layer's loading rises more steeply than its modulus
      alone makes it: the layers above already hold the needle; on the layered phantoms the slope
      ratio is about the square of the moduli's), then every one scaled by the simulations
      (:mod:`.propose`);
    - ``rupture_n[k]``: the peak less the shaft's friction accrued at its depth (a membrane
      ruptures at the tip's contact force, and the load cell reads that plus the friction on the
      length already inside: for each layer j above, ``friction_n_per_m[j]`` times the travel from
      puncture j to puncture j + 1, or to this depth; :func:`accrued_friction`), at least half the
      peak (``MIN_RUPTURE_OF_PEAK``: a friction overestimated from a short cut cannot take the
      whole peak); the refinement replaces it by the simulator's own shaft force where the
      simulation punctures the layer where the data does (:func:`~.propose.shaft_force_at_punctures`);
    - ``friction_n_per_m[k]``: the slope of the cut through layer k before layer k + 1 loads (the
      hinge's first line); where that slope exceeds ``MAX_CUT_OVER_VALLEY`` times the valley's
      force over its depth, the valley's force over its depth instead (the shaft's friction up to
      the valley cannot be far above the force there: layers close together leave no cut to read,
      and the next layer's rise read as a cut is several times that bound, where a true cut stays
      near it, above it only as far as the tissue relaxes after the puncture), and where the line
      after the last puncture gives one, that line's (:func:`held_friction`, the boundaries at the
      onsets); the last layer's the slope f after the last puncture;
    - ``cutting_n[k]``: the last layer c; a layer before it its valley force less f x there;
    - ``retraction_n[k]``: the retraction plateau while the tip is in it (a constant pull);
    - ``relaxing`` and ``relax_time_s``: the pause's fit, when it relaxes by MIN_RELAXATION at least.
    """
    n = len(measured.depth_m)
    f = measured.post_slope_n_per_m if np.isfinite(measured.post_slope_n_per_m) else 0.0
    f = max(f, 0.0)
    values = {}
    unread = unread_cuts(measured)
    for k in range(n):
        cut = measured.cut_slope_n_per_m[k] if k < len(measured.cut_slope_n_per_m) else math.nan
        if k == n - 1 or not np.isfinite(cut) or cut <= 0:
            values[f'friction_n_per_m[{k}]'] = (f, 'the slope of the force after the last puncture')
            continue
        if k not in unread:
            values[f'friction_n_per_m[{k}]'] = (cut, f'the slope of the cut through it, before layer {k + 1} '
                                                     'loads')
        else:
            how = (f"its valley force over the valley's depth (the cut through it rises at {cut:.3g} N/m: "
                   'the next layer loads before its onset is seen)')
            values[f'friction_n_per_m[{k}]'] = (max(measured.valley_n[k] / measured.valley_m[k], 0.0), how)
    c = measured.post_intercept_n
    boundaries = [0.0] + [measured.onset_m[k] for k in range(1, n)]
    held = held_friction(measured, [values[f'friction_n_per_m[{j}]'][0] for j in range(n)], boundaries,
                         max(0.0, c) if np.isfinite(c) else 0.0, unread)
    if np.isfinite(held):
        for k in unread:
            values[f'friction_n_per_m[{k}]'] = (held, 'the line after the last puncture at the last boundary, '
                                                      'less the cutting force and the other layers\' friction, '
                                                      'over the thickness of the layers whose cut is unread')
    slope0 = measured.slope_n_per_m[0] if n else math.nan
    for k in range(n):
        if k >= 1:
            values[f'boundary_m[{k}]'] = (measured.onset_m[k], f'where layer {k} starts loading (the break '
                                                               'between the cut and its rise)')
        ratio = measured.slope_n_per_m[k] / slope0 if k and np.isfinite(slope0) and slope0 > 0 \
            and np.isfinite(measured.slope_n_per_m[k]) and measured.slope_n_per_m[k] > 0 else 1.0
        values[f'modulus_pa[{k}]'] = (base_modulus_pa * math.sqrt(ratio), 'the base scene\'s' if k == 0 else
                                      f'layer 0\'s times the square root of its loading slope over layer 0\'s '
                                      f'({ratio:.3g})')
        peak = measured.peak_n[k]
        per_length = [values[f'friction_n_per_m[{j}]'][0] for j in range(n)]
        friction = accrued_friction(measured.depth_m, per_length, k)
        if k and np.isfinite(friction) and friction > 0:
            rupture = max(peak - friction, MIN_RUPTURE_OF_PEAK * peak)
            values[f'rupture_n[{k}]'] = (rupture, 'the peak force less the shaft friction accrued at its '
                                                  f'depth ({peak:.4g} - {peak - rupture:.3g} N)')
        else:
            values[f'rupture_n[{k}]'] = (peak, 'the peak force')
        if k == n - 1:
            c = measured.post_intercept_n
            values[f'cutting_n[{k}]'] = (max(0.0, c) if np.isfinite(c) else 0.0,
                                         'the intercept of the line after the last puncture')
        else:
            friction = values[f'friction_n_per_m[{k}]'][0]
            values[f'cutting_n[{k}]'] = (max(0.0, measured.valley_n[k] - friction * measured.valley_m[k]),
                                         'its valley force less the shaft friction there')
        plateau = measured.retraction_n[k] if k < len(measured.retraction_n) else math.nan
        values[f'retraction_n[{k}]'] = (max(0.0, -plateau) if np.isfinite(plateau) else 0.0,
                                        'the retraction plateau while the tip is in it')
    if np.isfinite(measured.relaxing) and measured.relaxing >= MIN_RELAXATION and np.isfinite(measured.relax_time_s):
        values['relaxing'] = (min(0.9, measured.relaxing), 'the part of the force the pause relaxes')
        values['relax_time_s'] = (measured.relax_time_s, 'the time constant of the pause\'s exponential')
    return values
