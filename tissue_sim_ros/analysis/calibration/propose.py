"""``tissue-sim propose``: a layered scene proposed from the data, the start ``calibrate`` takes.

1. The trials (a data description) and their punctures as the repeats of each speed share them
   (:mod:`~tissue_sim_ros.analysis.compare.shared_punctures`): the layers, each with its depth and
   peak force as distributions over the repeats. The speed with the most repeats (ties: the
   slowest) sets the count.
2. Each repeat's features (:mod:`.layer_estimates`), their mean, and the starting values they
   give (:func:`~.layer_estimates.starting_values`): a scene with one region per layer, the base
   scene's mesh, model, solver and needle; layer 0 is the outer surface (``select: all``), layer
   k >= 1 the half-space under its boundary (``below_z_m``, measured from the mesh's top; the
   needle goes down along -z). The spread between repeats becomes each layer's
   ``rupture_force_spread_n`` and ``depth_spread_m``.
3. ``refine_runs`` times: the scene simulated on the median repeat's motion (compare's plan),
   its features read from the simulated curve as from the data, and the values that a feature
   reads robustly moved by what it misses (a fixed-point step): every modulus by the ratio of the
   outer layer's loading levels over the same depths (the data's slopes keep the layers' ratios),
   each deeper boundary by the travel where the simulated layer starts loading less the data's
   (:func:`_boundary`: the data's onset lies deeper than the boundary at rest by what the layers
   above are compressed, 4 mm on the two-layer phantom, so the boundary starts there and moves
   up), the last layer's friction by the slopes after the last puncture, the relaxing part by
   the fraction of its force the pause relaxes (:func:`_relaxing`: a secant, the fraction being
   far from proportional to it; in the first run that punctures every layer within
   ``SAME_LAYER_M`` of the data's depth, a scan of it in one parallel batch places it,
   :func:`_scan_relaxing`, the later runs keep it, and the scan's runs are candidates too), and
   a deeper layer's rupture force (which starts at its peak less the shaft friction read off the
   data: the friction per length times the travel since the puncture above) set, once the
   simulation punctures that layer within ``SAME_LAYER_M`` of the data's depth, to the measured
   peak less the force the simulated load cell read beyond the membrane's contact force there
   (:func:`shaft_force_at_punctures`: the shaft's friction on the length inside, which the
   measured peak holds too; the data's estimate was 3x the simulator's on the two-layer phantom,
   the tissue moving with the shaft as the next layer loads), and an upper layer's friction whose
   cut is unread by the line after the last puncture on the boundaries as they stand
   (:func:`~.layer_estimates.held_friction`). A layer's cutting force stays as its own curve gave
   it. The values move together
   and pull on each other's features (a shallower deep layer stiffens the outer one's loading,
   a larger relaxing part softens every loading), so the runs need not improve one by one:
   a last run scores the result, and the best scene run is the proposal.
4. Outputs in ``--out DIR``: ``proposed.yaml`` (a complete scene every command takes; ``calibrate
   --scene DIR/proposed.yaml`` as it is), ``propose.json`` and ``propose.md`` (the layers, each
   value with how it was derived, each refinement run's NRMSE, the ``--fit`` keys and bounds to
   calibrate with), ``propose.csv`` (a row per layer), ``propose.png`` (the data by depth and by
   time, the punctures and pre-drops marked, each layer's depth spread, the proposal's
   simulation), ``simulations/`` (resume).
"""
from __future__ import annotations

import math
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ['layered_spec', 'main', 'propose', 'shaft_force_at_punctures']

#: a correction factor of one refinement run is held within [1 / CLAMP, CLAMP]; the relaxing
#: part's within [1 / RELAX_CLAMP, RELAX_CLAMP] and below MAX_RELAXING (it softens every loading
#: too: a long pause's relaxation moves the punctures)
CLAMP, RELAX_CLAMP, MAX_RELAXING = 3.0, 2.0, 0.9
#: the relaxing parts of the scan that places the relaxation (:func:`_scan_relaxing`)
RELAX_SCAN = (0.1, 0.3, 0.5, 0.7, 0.9)
#: a deeper boundary moves at most this far in one refinement run [m], and stays this far below
#: the one above it (or the surface)
BOUNDARY_STEP_M, BOUNDARY_GAP_M = 0.003, 0.0005
#: the last layer punctures where the data's does when within this much of its depth [m]
SAME_LAYER_M = 0.0015


def _finite(value) -> bool:
    return value is not None and isinstance(value, (int, float)) and math.isfinite(value)


def _factor(measured, simulated, clamp=CLAMP) -> float:
    if not (_finite(measured) and _finite(simulated)) or measured <= 0 or simulated <= 0:
        return 1.0
    return float(np.clip(measured / simulated, 1.0 / clamp, clamp))


def layered_spec(base_spec: dict, values: dict, layers, top_z_m: float) -> dict:
    """The base scene's keys with one region per layer set from ``values`` (the names of
    :func:`~.layer_estimates.starting_values`, numbers only), the spread from ``layers``."""
    import copy
    spec = copy.deepcopy(base_spec)
    first = base_spec['regions'][0]
    regions = []
    for k, layer in enumerate(layers):
        region = {'name': f'layer{k}', 'young_modulus_pa': float(values[f'modulus_pa[{k}]']),
                  'poisson_ratio': first['poisson_ratio'], 'density_kg_per_m3': first['density_kg_per_m3'],
                  'membrane': {'criterion': 'force', 'rupture_force_n': float(values[f'rupture_n[{k}]']),
                               'rupture_force_spread_n': float(layer.force_sd_n)},
                  'cutting_force_n': float(values[f'cutting_n[{k}]']),
                  'friction': {'insertion_static_n_per_m': first['friction']['insertion_static_n_per_m'],
                               'insertion_coulomb_n_per_m': float(values[f'friction_n_per_m[{k}]']),
                               'stick_band_m_per_s': first['friction']['stick_band_m_per_s'],
                               'retraction_constant_n': float(values[f'retraction_n[{k}]'])}}
        if k == 0:
            region['select'] = 'all'
        else:
            region['select'] = {'below_z_m': float(top_z_m - values[f'boundary_m[{k}]'])}
            region['depth_spread_m'] = float(layer.depth_sd_m)
        regions.append(region)
    spec['regions'] = regions
    if 'relaxing' in values:
        spec['model']['relaxation'] = [{'relative_modulus': float(values['relaxing']),
                                        'time_constant_s': float(values['relax_time_s'])}]
    return spec


def _curves(comparisons, simulated=False):
    """(travel since contact, force) of each comparison's data, or of its simulation (NaN filled)."""
    out = []
    for c in comparisons:
        force = np.asarray(c.simulated_n if simulated else c.measured_n, float)
        finite = np.isfinite(force)
        if finite.sum() >= 10:
            out.append((c.travel_since_contact_m, np.interp(np.arange(len(force)), np.flatnonzero(finite),
                                                            force[finite])))
    return out


def _modulus_factors(measured, measured_curves, simulated, simulated_curves, n_layers: int) -> list[float]:
    """Per layer, the ratio of the data's loading level to the simulation's over the same depths
    (:func:`~.layer_estimates.loading_level`: from 10 % to 90 % of the way from where the layer
    starts loading to the shallower of the two punctures)."""
    from tissue_sim_ros.analysis.calibration.layer_estimates import loading_level
    factors = []
    for k in range(n_layers):
        start = 0.0 if k == 0 else measured.valley_m[k - 1]
        end = min(measured.depth_m[k], simulated.depth_m[k]) if _finite(simulated.depth_m[k]) else measured.depth_m[k]
        if not (_finite(start) and _finite(end)) or end <= start:
            factors.append(1.0)
            continue
        low, high = start + 0.1 * (end - start), start + 0.9 * (end - start)
        base_data = 0.0 if k == 0 else measured.valley_n[k - 1]
        base_sim = 0.0 if k == 0 else simulated.valley_n[k - 1]
        data = np.nanmean([loading_level(t, f, low, high, base_data) for t, f in measured_curves])
        sim = np.nanmean([loading_level(t, f, low, high, base_sim) for t, f in simulated_curves[:1]])
        factors.append(_factor(float(data), float(sim)))
    return factors


def shaft_force_at_punctures(study, scene, n_layers: int) -> list[float]:
    """Per layer, what the simulated load cell read at the layer's puncture beyond the membrane's
    contact force (the shaft's friction, and the cutting of a layer above where it still acts),
    averaged over the study's simulations: the force just before the puncture (the largest of
    the samples up to the one after it) less the contact force the scene's puncture event
    records; NaN where no simulation punctured the layer."""
    start, axis = scene.needle_pose[0], scene.needle.axis
    found: dict = {}
    for job, result in zip(study['plan'].jobs, study['results']):
        if result.diverged or not len(result.puncture_travel_m):
            continue
        travel = (np.asarray(job.positions) - start) @ axis
        inserting = np.arange(len(travel)) <= int(np.argmax(travel))
        seen = set()
        events = zip(result.puncture_travel_m, result.puncture_force_n, result.puncture_layer)
        for where, contact, layer in events:
            after = np.flatnonzero(inserting & (travel >= where))
            if not 0 <= layer < n_layers or not after.size or layer in seen:
                continue
            seen.add(int(layer))
            i = int(after[0])
            total = float(np.nanmax(result.axial_force_n[max(0, i - 3):i + 1]))
            found.setdefault(int(layer), []).append(total - float(contact))
    return [float(np.mean(found[k])) if k in found else math.nan for k in range(n_layers)]


def _secant(value, feature, previous_value, previous_feature) -> float:
    """The slope of a feature over its value through two runs (NaN where they do not give one)."""
    if not all(_finite(v) for v in (value, feature, previous_value, previous_feature)):
        return math.nan
    if abs(value - previous_value) <= 1e-9 * max(abs(value), abs(previous_value), 1e-12):
        return math.nan
    return (feature - previous_feature) / (value - previous_value)


def _boundary(values, measured, simulated, k: int) -> float:
    """Layer k's boundary (its depth below the top) moved by what the simulated onset of its
    loading misses of the data's (an additive fixed point: a boundary moved by d moves the onset
    by about d, 1.3 d on the two-layer phantom, so the steps shrink), at most ``BOUNDARY_STEP_M``,
    and ``BOUNDARY_GAP_M`` below the boundary above. The onset, not the puncture's depth: the
    puncture moves with the layer's modulus and rupture force too. No secant: between two runs
    the moduli move as well, and the onset with them. A layer the simulation is not seen loading
    within the travel moves up a whole step: its boundary starts at the data's onset, deeper than
    at rest by what the layers above compress (on the graded three-layer phantom the core's
    onset lies 3 mm below its boundary, at 21 mm of a 25 mm travel)."""
    name = f'boundary_m[{k}]'
    here, data, sim = values[name], measured.onset_m[k], simulated.onset_m[k]
    if not _finite(data):
        return here
    step = float(np.clip(data - sim, -BOUNDARY_STEP_M, BOUNDARY_STEP_M)) if _finite(sim) else -BOUNDARY_STEP_M
    above = values[f'boundary_m[{k - 1}]'] if k > 1 else 0.0
    return max(here + step, above + BOUNDARY_GAP_M)


def _relaxing(values, measured, simulated, previous) -> float:
    """The relaxing part moved so that the simulated pause relaxes the data's fraction of its
    force. The fraction is far below the relaxing part and not proportional to it (on the
    two-layer phantom a relaxing part of 0.1, 0.2, 0.4, 0.7 relaxes 0.003, 0.017, 0.036, 0.087
    of it: about affine, from 0.08 on: much of the pause's force does not relax), so the step
    is the secant's (this run and the previous one) where it rises, else the ratio of the
    fractions (a simulation that does not relax at all: ``RELAX_CLAMP``), held within [1 /
    ``RELAX_CLAMP``, ``RELAX_CLAMP``] and below ``MAX_RELAXING``."""
    here, data, sim = values['relaxing'], measured.relaxing, simulated.relaxing
    if not (_finite(data) and _finite(sim)):
        return here
    slope = math.nan
    if previous is not None:
        slope = _secant(here, sim, previous[0].get('relaxing'), previous[1].relaxing)
    if _finite(slope) and slope > 0:
        factor = (here + (data - sim) / slope) / here
    elif sim <= 0 < data:
        factor = RELAX_CLAMP
    else:
        factor = _factor(data, sim, RELAX_CLAMP)
    return min(MAX_RELAXING, here * float(np.clip(factor, 1.0 / RELAX_CLAMP, RELAX_CLAMP)))


def _score(study) -> float:
    """A run's NRMSE over every sample, the trials' mean (inf when none has one)."""
    nrmse = [c.errors.get('nrmse_all_samples', math.nan) for c in study['comparisons']]
    return float(np.nanmean(nrmse)) if np.isfinite(nrmse).any() else math.inf


def _scan_relaxing(trials, base_scene, values, layers, top, n_layers, measured, **compare) -> tuple:
    """The relaxing part whose simulated pause relaxes the data's fraction of its force, read off
    one parallel batch of simulations at ``RELAX_SCAN`` (every other value as ``values``): the
    fraction climbs slowly and not in proportion (most of the pause's force is the shaft's
    friction, which does not relax), so a fixed-point step from a small start needs more runs
    than the proposal has. Linear between the two scan points around the data's fraction; above
    every simulated one, the largest; below, the smallest scaled down by the ratio of the
    fractions. Also the scan's rows (relaxing part, simulated fraction, NRMSE) and each of its
    runs as a candidate proposal (score, spec, values, study)."""
    from tissue_sim_ros.analysis.compare.compare import compare_scenes
    from tissue_sim_ros.engine.scene.scene import Scene
    specs = [layered_spec(base_scene.spec, dict(values, relaxing=part), layers, top) for part in RELAX_SCAN]
    studies = compare_scenes(trials, [Scene(spec, base_dir=base_scene.base_dir) for spec in specs], quiet=True,
                             **compare)
    rows, candidates = [], []
    for part, spec, study in zip(RELAX_SCAN, specs, studies):
        features = _trial_features(study['comparisons'], n_layers, simulated=True)
        rows.append({'relaxing': part, 'simulated_fraction': features.relaxing if features is not None else math.nan,
                     'nrmse_all_samples': _score(study)})
        candidates.append((rows[-1]['nrmse_all_samples'], spec, dict(values, relaxing=part), study))
    data = measured.relaxing
    pairs = [(row['relaxing'], row['simulated_fraction']) for row in rows if _finite(row['simulated_fraction'])]
    chosen = values['relaxing']
    if pairs and _finite(data):
        crossing = [p0 + (data - f0) / (f1 - f0) * (p1 - p0)
                    for (p0, f0), (p1, f1) in zip(pairs, pairs[1:]) if f0 <= data <= f1 and f1 > f0]
        if crossing:
            chosen = crossing[0]
        elif data > max(f for _, f in pairs):
            chosen = pairs[-1][0]
        elif pairs[0][1] > 0:
            chosen = pairs[0][0] * data / pairs[0][1]
    return chosen, rows, candidates


def _punctures_placed(measured, simulated, n_layers: int) -> bool:
    """Whether the simulation punctures every layer within ``SAME_LAYER_M`` of the data's depth
    (its pause then holds the tip where the data's does)."""
    return all(_finite(simulated.depth_m[k]) and _finite(measured.depth_m[k])
               and abs(simulated.depth_m[k] - measured.depth_m[k]) <= SAME_LAYER_M for k in range(n_layers))


def _corrected(values: dict, measured, simulated, n_layers: int, factors, shaft=(), previous=None) -> dict:
    """``values`` moved by what the simulation's features miss of the data's (module docstring, 3):
    every modulus by the outer layer's loading-level ratio (``factors[0]``,
    :func:`_modulus_factors`), each deeper boundary by its onset's error (:func:`_boundary`), the
    last layer's friction by the slopes after the last puncture once it punctures within
    ``SAME_LAYER_M`` of the data's, the relaxing part by the pause's (:func:`_relaxing`), each
    deeper layer the simulation punctures within ``SAME_LAYER_M`` of the data's its rupture
    force to its measured peak less ``shaft`` (per layer, :func:`shaft_force_at_punctures`), at
    least ``MIN_RUPTURE_OF_PEAK`` of the peak (a layer punctured deeper has more shaft inside).
    ``previous``: the previous run's (values, simulated features), for the secants."""
    from tissue_sim_ros.analysis.calibration.layer_estimates import MIN_RELAXATION, MIN_RUPTURE_OF_PEAK, \
        held_friction, unread_cuts
    out = dict(values)
    for k, force in enumerate(shaft):
        peak, depth = measured.peak_n[k], simulated.depth_m[k]
        if k and _finite(force) and _finite(peak) and _finite(depth) and \
                abs(depth - measured.depth_m[k]) <= SAME_LAYER_M:
            out[f'rupture_n[{k}]'] = max(peak - max(force, 0.0), MIN_RUPTURE_OF_PEAK * peak)
    for k in range(n_layers):
        out[f'modulus_pa[{k}]'] *= factors[0]
    for k in range(1, n_layers):
        out[f'boundary_m[{k}]'] = _boundary(out, measured, simulated, k)
    boundaries = [0.0] + [out[f'boundary_m[{k}]'] for k in range(1, n_layers)]
    unread = unread_cuts(measured)
    held = held_friction(measured, [out[f'friction_n_per_m[{j}]'] for j in range(n_layers)], boundaries,
                         out[f'cutting_n[{n_layers - 1}]'], unread)
    for k in unread if _finite(held) else ():
        out[f'friction_n_per_m[{k}]'] = held          # on the boundaries as they now stand
    last = n_layers - 1
    if _finite(simulated.depth_m[last]) and abs(measured.depth_m[last] - simulated.depth_m[last]) <= SAME_LAYER_M:
        out[f'friction_n_per_m[{last}]'] *= _factor(measured.post_slope_n_per_m, simulated.post_slope_n_per_m)
    if 'relaxing' in out:
        out['relaxing'] = _relaxing(values, measured, simulated, previous)
        if _finite(simulated.relaxing) and simulated.relaxing >= MIN_RELAXATION:   # else its time is noise's
            out['relax_time_s'] *= _factor(measured.relax_time_s, simulated.relax_time_s)
    return out


def _trial_features(comparisons, n_layers, simulated=False):
    from tissue_sim_ros.analysis.calibration.layer_estimates import curve_features, mean_features
    features = []
    for c in comparisons:
        force = c.simulated_n if simulated else c.measured_n
        finite = np.isfinite(force)
        if finite.sum() < 10:
            continue
        force = np.interp(np.arange(len(force)), np.flatnonzero(finite), force[finite])
        punctures = _with_events(c, force) if simulated else c.measured_punctures
        features.append(curve_features(c.time_since_contact_s, c.travel_since_contact_m, force, punctures, n_layers))
    return mean_features(features) if features else None


def _with_events(comparison, force):
    """The simulated punctures, and for a layer the force shows no drop of (it ruptured while the
    needle already pressed the next one) the scene's own event: its travel (its peak unknown)."""
    from dataclasses import replace as replaced

    from tissue_sim_ros.analysis.compare.force_events import Puncture, depth_bounds
    found = list(comparison.simulated_punctures)
    have = {p.layer for p in found}
    travel = comparison.travel_since_contact_m
    inserting = np.arange(len(travel)) < depth_bounds(travel)[0]
    for where, layer in comparison.simulated_events:
        if layer in have or layer < 0 or not inserting.any():
            continue
        index = int(np.argmin(np.where(inserting, np.abs(travel - where), np.inf)))
        found.append(Puncture(index, float(travel[index]), math.nan, 0.0, layer=layer))
        have.add(layer)
    return sorted((replaced(p) for p in found), key=lambda p: p.travel_m)


def propose(trials, base_scene, *, refine_runs: int = 3, align: str = 'contact', tick_s: float = 0.01,
            out=None, workers=None, scheduler=None, log=print) -> dict:
    """Everything the outputs need (module docstring)."""
    from tissue_sim_ros.analysis.calibration.fit_bounds import fit_suggestions
    from tissue_sim_ros.analysis.calibration.layer_estimates import starting_values
    from tissue_sim_ros.analysis.calibration.layer_resolution import elements_across, path_edge_length, \
        resolution_warnings
    from tissue_sim_ros.analysis.compare.compare import compare_trials, measured_layers
    from tissue_sim_ros.analysis.compare.measured_motion import measured_motion
    from tissue_sim_ros.analysis.compare.trial_simulation import ResultStore
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.errors import InputError
    wall0 = time.perf_counter()
    axis = base_scene.needle.axis
    if axis[2] > -0.99:
        raise InputError(f'propose: the base scene\'s needle axis is {np.round(axis, 3).tolist()}; the layers it '
                         'writes are horizontal planes, for a needle going down along -z')
    speeds: dict = {}
    for trial in trials:
        speeds.setdefault(None if trial.speed_m_s is None else round(trial.speed_m_s, 9), []).append(trial)
    speed = max(speeds, key=lambda s: (len(speeds[s]), -(s or 0.0)))
    chosen = speeds[speed]
    motions = [measured_motion(t) for t in chosen]
    punctures, layer_lists = measured_layers(chosen, motions)
    layers = layer_lists[0]
    if not layers:
        raise InputError(f'propose: no puncture the repeats at {speed * 1e3 if speed else "?"} mm/s share; '
                         'nothing to build layers from')
    n = len(layers)
    log(f'propose: {len(chosen)} repeat(s) at {"unknown speed" if speed is None else f"{speed * 1e3:g} mm/s"}: '
        f'{n} layer(s) at ' + ', '.join(f'{1e3 * l.depth_m:.2f} +- {1e3 * l.depth_sd_m:.2f} mm' for l in layers))
    store = ResultStore(Path(out) / 'simulations') if out is not None else None
    top = float(base_scene.mesh.rest_positions[:, 2].max())
    base_modulus = float(base_scene.spec['regions'][0]['young_modulus_pa'])
    # the data's features, read as the simulation's will be (compare's samples since contact)
    empty = [_measured_comparison(t, m, p) for t, m, p in zip(chosen, motions, punctures)]
    measured = _trial_features(empty, n)
    derived = starting_values(measured, base_modulus)
    values = {name: value for name, (value, _) in derived.items()}
    runs, best, previous, scanned = [], None, None, None
    for run in range(refine_runs + 1):
        spec = layered_spec(base_scene.spec, values, layers, top)
        try:
            scene = Scene(spec, base_dir=base_scene.base_dir)
        except InputError as exc:
            log(f'propose: run {run}: the scene refuses {exc}; stopping the refinement')
            break
        study = compare_trials(chosen, scene, align=align, tick_s=tick_s, store=store, workers=workers,
                               scheduler=scheduler, quiet=True)
        score = _score(study)
        runs.append({'run': run, 'nrmse_all_samples': score, 'values': dict(values)})
        log(f'propose: run {run}: NRMSE {score:.4f} over every sample')
        if best is None or score < best[0]:
            best = (score, spec, dict(values), study)
        if run == refine_runs:
            break
        simulated = _trial_features(study['comparisons'], n, simulated=True)
        if simulated is None:
            log(f'propose: run {run}: the simulation gave no curve to read; stopping the refinement')
            break
        factors = _modulus_factors(measured, _curves(empty), simulated, _curves(study['comparisons'], True), n)
        runs[-1]['simulated'] = {'depth_m': simulated.depth_m, 'peak_n': simulated.peak_n,
                                 'valley_n': simulated.valley_n, 'post_slope_n_per_m': simulated.post_slope_n_per_m,
                                 'relaxing': simulated.relaxing, 'modulus_factors': factors}
        shaft = shaft_force_at_punctures(study, scene, n)
        runs[-1]['simulated']['shaft_force_at_puncture_n'] = shaft
        runs[-1]['simulated']['onset_m'] = simulated.onset_m
        corrected = _corrected(values, measured, simulated, n, factors, shaft, previous)
        if scanned is not None:
            corrected['relaxing'] = scanned        # the scan placed it; the moduli follow
        elif 'relaxing' in corrected and _punctures_placed(measured, simulated, n):
            scanned, runs[-1]['relaxation_scan'], candidates = _scan_relaxing(
                chosen, base_scene, corrected, layers, top, n, measured, align=align, tick_s=tick_s, store=store,
                workers=workers, scheduler=scheduler)
            corrected['relaxing'] = scanned
            best = min([best] + candidates, key=lambda candidate: candidate[0])
            log(f'propose: run {run}: the relaxation scan puts the relaxing part at {scanned:.3f}')
        previous, values = (values, simulated), corrected
    score, spec, values, study = best
    simulated = _trial_features(study['comparisons'], n, simulated=True)
    onset_miss = [simulated.onset_m[k] - measured.onset_m[k] if simulated and k < len(simulated.onset_m)
                  and k < len(measured.onset_m) else math.nan for k in range(n)]
    edge = path_edge_length(base_scene.mesh.rest_positions, base_scene.mesh.tetrahedra, base_scene.needle_pose[0], axis)
    deepest = max(float(np.nanmax(c.travel_since_contact_m)) for c in empty)
    resolution = elements_across([top - r['select']['below_z_m'] for r in spec['regions'][1:n]], deepest, edge)
    return {'resolution': resolution, 'path_edge_m': edge, 'warnings': resolution_warnings(resolution, edge),
            'speed_m_s': speed, 'trials': chosen, 'layers': layers, 'measured': measured, 'derived': derived,
            'values': values, 'spec': spec, 'runs': runs, 'nrmse_all_samples': score, 'study': study,
            'fits': fit_suggestions(spec, n, layers, measured.strongest_pull_n, onset_miss),
            'base_dir': base_scene.base_dir,
            'pre_drops': sum(len(_pre_drops(c)) for c in study['comparisons']),
            'wall_s': time.perf_counter() - wall0}


def _pre_drops(comparison):
    from tissue_sim_ros.analysis.compare.force_events import PRE_DROP, detect_drops
    return [p for p in detect_drops(comparison.travel_since_contact_m, comparison.measured_n) if p.kind == PRE_DROP]


def _measured_comparison(trial, motion, punctures):
    """A comparison without a simulation: the trial's samples since contact and its punctures."""
    from types import SimpleNamespace
    return SimpleNamespace(time_since_contact_s=motion.time_s - motion.time_s[motion.contact_index],
                           travel_since_contact_m=motion.travel_m - motion.gap_m,
                           measured_n=np.asarray(trial.axial_force_n, float), measured_punctures=punctures)


def main(*, data_spec, scene_file=None, sets=(), out='out/propose', refine_runs=3, align='contact',
         max_depth_mm=None, tick_ms=10.0, workers=None, scheduler=None, stream=None) -> dict:
    """The ``tissue-sim propose`` command."""
    from tissue_sim_ros.analysis.calibration.propose_report import write_proposal
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    stream = sys.stdout if stream is None else stream
    spec = DataSpec.from_file(data_spec)
    trials = load_trials(spec)
    if max_depth_mm is not None:
        from tissue_sim_ros.analysis.compare.measured_motion import within_depth
        trials = [within_depth(t, max_depth_mm * 1e-3) for t in trials]
    base = load_scene(scene_file, sets=sets)
    proposal = propose(trials, base, refine_runs=refine_runs, align=align, tick_s=tick_ms * 1e-3, out=out,
                       workers=workers, scheduler=scheduler, log=lambda text: print(text, file=stream))
    report = write_proposal(Path(out), proposal, data_spec=str(data_spec), scene_file=scene_file, sets=sets)
    print(f"proposed {len(proposal['layers'])} layer(s); NRMSE {proposal['nrmse_all_samples']:.4f} over every "
          f"sample of {len(proposal['trials'])} repeat(s); {proposal['wall_s']:.1f} s", file=stream)
    for warning in report['warnings']:
        print(f'  warning: {warning}', file=stream)
    print('calibrate it with:\n  ' + report['calibrate_command'], file=stream)
    print(f"wrote {', '.join(report['outputs'].values())}", file=stream)
    return report
