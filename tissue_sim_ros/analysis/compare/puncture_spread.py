"""The punctures' spread: the repeats' against a simulated study's, layer by layer.

Repeats of one condition puncture each layer at a spread of depths and forces; the model is
judged against that distribution, not against one curve. Per speed and layer, the measured
punctures (the layers its repeats share, :mod:`.shared_punctures`) give a mean and a standard
deviation of the depth since contact and of the peak force; the simulation gives either its one
puncture (a nominal scene) or, with ``simulated_repeats`` N and a scene that states its spread
(``regions[].membrane.rupture_force_spread_n``, ``regions[].depth_spread_m``), N runs of the
same motion with ``variation.seed`` 1..N, each drawing its layers' rupture forces and depths: a
simulated study whose spread is set beside the measured one. A simulated layer is within the
repeats' spread when its mean depth is (``shared_punctures.within_spread``'s rule: two standard
deviations, or half the range, and the puncture window).

The scene's own puncture events give the simulated depths and forces (the depth since the
simulated contact, found by the detector the data's contact was found by, in the data's noise).
"""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

__all__ = ['run_simulated_repeats', 'spread_by_speed']


def run_simulated_repeats(plan, scene, count: int, *, store=None, workers=None, scheduler=None,
                          quiet=True) -> list[list]:
    """Per job of ``plan``: the results of ``count`` runs of its motion with ``variation.seed``
    1..count (nothing when the scene states no spread, or ``count`` < 2)."""
    from tissue_sim_ros.analysis.jobs import run_jobs
    from tissue_sim_ros.analysis.compare.trial_simulation import simulate
    from tissue_sim_ros.engine.scene.keys import set_key
    from tissue_sim_ros.engine.scene.variation import has_spread
    if count < 2 or not has_spread(scene.spec):
        return [[] for _ in plan.jobs]
    jobs = [replace(job, scene_spec=set_key(job.scene_spec, 'variation.seed', seed))
            for job in plan.jobs for seed in range(1, count + 1)]
    results = [store.get(job.key) if store is not None else None for job in jobs]
    todo = [i for i, r in enumerate(results) if r is None]

    def keep(position, result):
        results[todo[position]] = result
        if store is not None:
            store.put(jobs[todo[position]].key, result)
    run_jobs(simulate, [jobs[i] for i in todo], workers=workers, scheduler=scheduler, label='simulated repeats',
             on_result=keep, quiet=quiet)
    return [results[j * count:(j + 1) * count] for j in range(len(plan.jobs))]


def _events_since_contact(result, schedule, motion, scene_gap_m, noise_n):
    """(depth since the simulated contact [m], force [N], layer) of a run's puncture events."""
    from tissue_sim_ros.analysis.compare.simulated_curve import simulated_curve
    from tissue_sim_ros.analysis.compare.force_events import contact_in_noise
    if result.diverged:
        return []
    curve = simulated_curve(result, schedule, motion, scene_gap_m)
    index = contact_in_noise(curve.time_since_contact_s, curve.axial_force_n, curve.travel_since_contact_m,
                             noise_n=noise_n, record_time_s=motion.time_s - motion.time_s[motion.contact_index])
    shift = float(curve.travel_since_contact_m[index]) if index is not None else 0.0
    return [(float(t) - scene_gap_m - shift, float(f), int(layer))
            for t, f, layer in zip(result.puncture_travel_m, result.puncture_force_n, result.puncture_layer)]


def _stats(values) -> dict:
    values = np.asarray(values, dtype=float)
    if not values.size:
        return {'mean': math.nan, 'sd': math.nan, 'count': 0}
    return {'mean': float(values.mean()), 'sd': float(values.std(ddof=1)) if values.size >= 2 else 0.0,
            'count': int(values.size)}


def spread_by_speed(study: dict, repeats: list[list], scene_gap_m: float) -> dict:
    """Per speed (as ``study['speeds']``, by index): per layer the measured depth and force
    distributions beside the simulated ones (the nominal run's, or the simulated study's), and
    whether the simulated depth lies within the repeats' spread."""
    from tissue_sim_ros.analysis.compare.shared_punctures import within_spread
    from tissue_sim_ros.analysis.compare.force_events import Puncture, baseline_and_noise
    plan, comparisons = study['plan'], study['comparisons']
    out = {}
    for position, group in enumerate(study['speeds']):
        members = [i for i, c in enumerate(comparisons) if str(c.file) in group['files']]
        if not members:
            continue
        layers = study.get('layers', [None] * len(comparisons))[members[0]] or []
        job = plan.job_of_trial[members[0]]
        motion = plan.motions[plan.representative[job]]
        noise = baseline_and_noise(comparisons[members[0]].measured_n)[1]
        runs = repeats[job] if repeats and repeats[job] else [study['results'][job]]
        events = [_events_since_contact(r, plan.schedules[job], motion, scene_gap_m, noise) for r in runs]
        rows = []
        for k, layer in enumerate(layers):
            depths = [e[0] for run in events for e in run if e[2] == k]
            forces = [e[1] for run in events for e in run if e[2] == k]
            simulated = {'depth_m': _stats(depths), 'force_n': _stats(forces), 'runs': len(runs)}
            within = bool(depths) and within_spread(Puncture(0, 0.0, 0.0, 0.0, layer=k),
                                                    Puncture(0, float(np.mean(depths)), 0.0, 0.0), layers)
            rows.append({'layer': k, 'measured': layer.as_dict(), 'simulated': simulated, 'within_spread': within})
        out[position] = rows
    return out
