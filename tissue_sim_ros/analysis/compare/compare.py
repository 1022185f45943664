"""``tissue-sim compare``: the simulation on the measured motion of load-cell trials, and how far
it is from the measurement, next to the data's own repeat-to-repeat spread.

For each trial (one file of a study, :mod:`tissue_sim_ros.io.trials.data_spec`):

1. motion: the needle travel the trial measured (or its described stage motion), contact found
   in its force, the travel then being its gap (:mod:`~tissue_sim_ros.analysis.compare.measured_motion`);
   the simulation's contact is found in its force by the same detector with the data's noise
   level, and the two are compared from their contacts (the detector's lag cancels);
2. simulation: the scene's needle driven along that motion, contact at the same moment
   (:mod:`~tissue_sim_ros.analysis.compare.trial_simulation`). By default the repeats of one speed share
   one simulation, of their median repeat (by its deepest travel): the commanded motion of a
   condition; ``per_trial`` simulates every trial on its own motion;
3. alignment (``align``): ``contact`` compares at the same time since contact; ``xcorr`` then shifts
   the simulation by the lag (at most 0.5 s) that best correlates the two force signals;
   ``depth`` compares the insertion only, as force against travel since contact (data without a
   trustworthy clock: digitized curves);
4. errors, per trial and per phase (approach, loading before the first puncture, inserted after
   it, hold, retraction; phases from the data): RMSE [N], NRMSE (normalised by the data's force
   range over the trial), R², largest error, peak force error, first puncture depth and force
   errors (punctures found in both curves by one detector), retraction minimum error. The
   pointwise errors leave out 0.15 mm of travel (and 3 samples) around each puncture of either
   curve, where a one-sample timing difference of the drop would dominate them; the puncture is
   measured by its event errors, and ``nrmse_all_samples`` keeps every sample;
5. repeats: per speed the data's mean and spread on a grid since contact, and the noise floor:
   each repeat against the mean of the others, as an NRMSE, averaged. A model cannot be expected
   to come closer to a trial than the trial's own repeats do.

The simulations run in a process pool (or on a Dask cluster, ``scheduler``) with a progress
bar, and each is kept in ``DIR/simulations`` as it finishes: a second run with the same inputs
reuses them (resume). Outputs (:mod:`~tissue_sim_ros.analysis.compare.report`): compare.json,
compare.md, compare.csv, and PNGs of force against depth and against time.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.compare.shared_punctures import EVENT_WINDOW_M, within_spread
from tissue_sim_ros.analysis.compare.simulated_curve import SimulatedCurve, simulated_curve

__all__ = ['ALIGNMENTS', 'TrialComparison', 'SimulatedCurve', 'simulated_curve', 'compare_trial',
           'measured_layers', 'plan_simulations', 'compare_trials', 'compare_scenes', 'within_spread']

ALIGNMENTS = ('contact', 'xcorr', 'depth')
MAX_SHIFT_S = 0.5
#: the pointwise errors leave out EVENT_WINDOW_M of travel (shared_punctures's), and these samples,
#: around each puncture
EVENT_WINDOW_SAMPLES = 3


@dataclass
class TrialComparison:
    """One trial against its simulation, on the trial's samples."""

    file: str
    speed_m_s: float | None
    repeat: int | None
    time_since_contact_s: np.ndarray
    travel_since_contact_m: np.ndarray
    measured_n: np.ndarray
    simulated_n: np.ndarray          # NaN where not compared
    phases: np.ndarray
    errors: dict
    phase_errors: dict
    events: dict
    shift_s: float = 0.0
    measured_punctures: list = field(default_factory=list)
    simulated_punctures: list = field(default_factory=list)
    diverged: str = ''
    #: the scene's own puncture events (travel since contact [m], layer), the simulation's clock
    simulated_events: tuple = ()


def compare_trial(trial, motion, curve: SimulatedCurve, align: str = 'contact', *, measured_punctures=None,
                  layers=None) -> TrialComparison:
    """The errors of ``curve`` against ``trial`` (see the module docstring). ``measured_punctures``:
    the trial's punctures as its repeats share them (:func:`measured_layers`; None: detected in this
    trial alone); ``layers``: the repeats' layers (their depths' spread), which say whether a
    simulated puncture lies within the spread."""
    from tissue_sim_ros.analysis.compare.alignment import best_time_shift, resample
    from tissue_sim_ros.analysis.compare.force_events import detect_punctures, segment_phases
    from tissue_sim_ros.analysis.compare.force_metrics import curve_errors, event_errors, per_phase_errors
    from tissue_sim_ros.analysis.compare.shared_punctures import pair_punctures
    if align not in ALIGNMENTS:
        raise ValueError(f'align = {align!r}: expected one of {", ".join(ALIGNMENTS)}')
    force = np.asarray(trial.axial_force_n, dtype=float)
    since = motion.time_s - motion.time_s[motion.contact_index]
    travel = motion.travel_m - motion.gap_m
    data_punctures = detect_punctures(travel, force) if measured_punctures is None else list(measured_punctures)
    phases = segment_phases(motion.time_s, motion.travel_m, force, contact=motion.contact_index,
                            first_puncture=data_punctures[0].index if data_punctures else None)
    shift = 0.0
    if curve.diverged:
        simulated = np.full_like(force, np.nan)
    else:
        curve = _at_its_contact(curve, since, force)
        if align == 'depth':
            simulated = _on_travel(curve, travel, phases)
        else:
            if align == 'xcorr':
                shift = best_time_shift(since, force, curve.time_since_contact_s, curve.axial_force_n,
                                        max_shift_s=MAX_SHIFT_S)
            simulated = resample(curve.time_since_contact_s - shift, curve.axial_force_n, since)
    compared = np.isfinite(simulated)
    kept = np.flatnonzero(compared)                  # punctures indexed on the trial's samples
    sim_punctures = _labelled([replace(p, index=int(kept[p.index]))
                               for p in _simulated_punctures(travel[kept], simulated[kept], curve)], curve) \
        if kept.size > 2 else []
    pairs = pair_punctures(data_punctures, sim_punctures)
    events = event_errors(data_punctures, sim_punctures, measured_force_n=force[compared],
                          measured_phases=phases[compared], simulated_force_n=simulated[compared],
                          simulated_phases=phases[compared], pairs=pairs) if compared.any() else {}
    within = [(m, p) for m, p in pairs if within_spread(m, p, layers)]
    if compared.any():
        events['punctures_within_spread'] = len(within)
    pointwise = np.where(away_from_events(travel, data_punctures + sim_punctures, between=within), simulated,
                         np.nan)
    normaliser = float(np.ptp(force)) or None
    errors = curve_errors(force, pointwise, normaliser=normaliser) \
        if np.isfinite(pointwise).any() else {'nrmse': float('nan'), 'rmse_n': float('nan'), 'count': 0}
    if compared.any():
        errors['nrmse_all_samples'] = curve_errors(force, simulated, normaliser=normaliser)['nrmse']
    per_phase = per_phase_errors(force, pointwise, phases, normaliser=errors.get('normaliser_n')) \
        if np.isfinite(pointwise).any() else {}
    return TrialComparison(trial.file, trial.speed_m_s, trial.repeat, since, travel, force, simulated,
                           phases, errors, per_phase, events, shift, data_punctures, sim_punctures,
                           curve.diverged, curve.puncture_events)


def away_from_events(travel, punctures, between=()) -> np.ndarray:
    """Samples farther than EVENT_WINDOW_M of travel (and EVENT_WINDOW_SAMPLES samples) from
    every puncture of either curve, and not between the two punctures of a pair in ``between``
    ((measured, simulated) pairs whose simulated one lies within the repeats' spread): the
    pointwise errors leave those out. A puncture drops the force by most of its value within a
    sample; a timing difference of one sample there would otherwise dominate the whole curve's
    RMSE, and a simulated puncture where the repeats themselves puncture is no miss of the
    samples between. Events are measured as events: their depth and force errors."""
    travel = np.asarray(travel, dtype=float)
    keep = np.ones(len(travel), dtype=bool)
    for p in punctures:
        near = np.abs(travel - p.travel_m) <= EVENT_WINDOW_M
        near[max(0, p.index - EVENT_WINDOW_SAMPLES):p.index + EVENT_WINDOW_SAMPLES + 1] = True
        keep &= ~near
    for measured, simulated in between:
        first, last = sorted((measured.index, simulated.index))
        keep[first:last + 1] = False
    return keep


#: a simulated curve's puncture is the scene's event within this much travel of it
EVENT_MATCH_M = 0.001


def _simulated_punctures(travel, force, curve: SimulatedCurve) -> list:
    """The simulated curve's punctures: the drops a measured puncture needs, and any other drop
    within EVENT_MATCH_M of a membrane the scene ruptured. The engine says that one is a puncture;
    the drop fraction only keeps noise out of measured data (where a small puncture may pass it in
    one repeat and not the next: the repeats' majority makes it a layer), and a simulation has no
    noise."""
    from tissue_sim_ros.analysis.compare.force_events import PUNCTURE, detect_drops, detect_punctures
    found = detect_punctures(travel, force)
    indices = {p.index for p in found}
    ruptures = [at for at, _ in curve.puncture_events]
    found += [p for p in detect_drops(travel, force, min_drop_fraction=0.0)
              if p.kind == PUNCTURE and p.index not in indices
              and any(abs(at - p.travel_m) <= EVENT_MATCH_M for at in ruptures)]
    return sorted(found, key=lambda p: p.index)


def _labelled(punctures, curve: SimulatedCurve) -> list:
    """The punctures found in the simulated force, each with the layer of a scene's puncture event
    within EVENT_MATCH_M of it: the outermost such layer not given to an earlier puncture (two
    layers that rupture together show as one drop: it is the outer one's); -1 where none."""
    taken, out = set(), []
    for p in punctures:
        near = sorted(layer for travel, layer in curve.puncture_events
                      if abs(travel - p.travel_m) <= EVENT_MATCH_M and layer not in taken)
        layer = near[0] if near else -1
        taken.add(layer)
        out.append(replace(p, layer=layer))
    return out


def measured_layers(trials, motions) -> tuple[list, list]:
    """Per trial: its punctures as the repeats of its speed share them, and that speed's layers
    (:mod:`~tissue_sim_ros.analysis.compare.shared_punctures`; travel since contact)."""
    from tissue_sim_ros.analysis.compare.shared_punctures import shared_punctures
    groups: dict = {}
    for index, trial in enumerate(trials):
        key = index if trial.speed_m_s is None else round(trial.speed_m_s, 9)
        groups.setdefault(key, []).append(index)
    punctures, layers = [None] * len(trials), [None] * len(trials)
    for members in groups.values():
        shared = shared_punctures([motions[i].travel_m - motions[i].gap_m for i in members],
                                  [trials[i].axial_force_n for i in members])
        for position, i in enumerate(members):
            punctures[i] = shared.punctures_of(position)
            layers[i] = shared.layers
    return punctures, layers


def _at_its_contact(curve: SimulatedCurve, since_contact_s, measured_force) -> SimulatedCurve:
    """The simulated curve with its time and travel counted from its own contact, found by the
    detector that found the data's, as it finds it in the data's record (its sample times
    ``since_contact_s``, from the data's contact, and its noise: :func:`~.force_events.
    contact_in_noise`): a threshold detector finds a contact late by an amount that depends on
    the noise, the record and the curve's onset; the same rule on the same record makes that lag
    the same on both curves, so it cancels."""
    from tissue_sim_ros.analysis.compare.force_events import baseline_and_noise, contact_in_noise
    _, noise = baseline_and_noise(measured_force)
    index = contact_in_noise(curve.time_since_contact_s, curve.axial_force_n, curve.travel_since_contact_m,
                             noise_n=noise, record_time_s=since_contact_s)
    if index is None:
        return curve
    shift = float(curve.travel_since_contact_m[index])
    return SimulatedCurve(curve.time_since_contact_s - curve.time_since_contact_s[index],
                          curve.travel_since_contact_m - shift, curve.axial_force_n, curve.diverged,
                          tuple((travel - shift, layer) for travel, layer in curve.puncture_events))


def _on_travel(curve: SimulatedCurve, travel, phases) -> np.ndarray:
    """The simulated force at the data's travel since contact, on the insertion only."""
    inserting = np.isin(phases, ('approach', 'loading', 'inserted'))
    deepest = int(np.argmax(curve.travel_since_contact_m))
    sim_travel = curve.travel_since_contact_m[:deepest + 1]
    order = np.argsort(sim_travel, kind='stable')
    out = np.full(len(travel), np.nan)
    inside = inserting & (travel >= sim_travel.min()) & (travel <= sim_travel.max())
    out[inside] = np.interp(travel[inside], sim_travel[order], curve.axial_force_n[:deepest + 1][order])
    return out


@dataclass
class Plan:
    """Simulations to run and which one each trial is compared with."""

    jobs: list
    schedules: list
    motions: list                    # per trial
    job_of_trial: list               # per trial, an index into jobs
    representative: list             # per job, the trial index whose motion it runs


def plan_simulations(trials, scene, *, gap_m: float | None = None, per_trial: bool = False,
                     tick_s: float = 0.01) -> Plan:
    """The simulation jobs of a study: one per speed (its median repeat's motion) or per trial."""
    from tissue_sim_ros.analysis.compare.measured_motion import END_HOLD_S, measured_motion, schedule_for_scene
    from tissue_sim_ros.analysis.compare.trial_simulation import SimulationJob
    motions = [measured_motion(trial, gap_m=gap_m) for trial in trials]
    groups: dict = {}
    for index, trial in enumerate(trials):
        key = index if per_trial or trial.speed_m_s is None else round(trial.speed_m_s, 9)
        groups.setdefault(key, []).append(index)
    start, axis = scene.needle_pose[0], scene.needle.axis.copy()
    jobs, schedules, job_of_trial, representative = [], [], [0] * len(trials), []
    for members in groups.values():
        deepest = [float(np.max(motions[i].travel_m - motions[i].gap_m)) for i in members]
        chosen = members[int(np.argsort(deepest)[len(members) // 2])]
        # held long enough to reach the end of every repeat it is compared with, each on the
        # clock of its own contact (a repeat recorded longer than the median one, jitter)
        after_contact = [float(motions[i].time_s[-1] - motions[i].time_s[motions[i].contact_index]) for i in members]
        longer = max(after_contact) - after_contact[members.index(chosen)]
        schedule = schedule_for_scene(motions[chosen], start, axis, scene.start_gap_m, tick_s,
                                      hold_s=END_HOLD_S + longer)
        for i in members:
            job_of_trial[i] = len(jobs)
        representative.append(chosen)
        schedules.append(schedule)
        jobs.append(SimulationJob(scene.spec, str(scene.base_dir), schedule.times_s, schedule.positions))
    return Plan(jobs, schedules, motions, job_of_trial, representative)


def run_plans(plans, *, store=None, workers=None, scheduler=None, quiet=False) -> list[list]:
    """Per plan, the results of its jobs: from ``store`` (a ResultStore) where there, else run
    (and put there as each finishes); every plan's jobs in one parallel batch."""
    from tissue_sim_ros.analysis.jobs import run_jobs
    from tissue_sim_ros.analysis.compare.trial_simulation import simulate
    jobs = [job for plan in plans for job in plan.jobs]
    results = [store.get(job.key) if store is not None else None for job in jobs]
    todo = [i for i, result in enumerate(results) if result is None]

    def keep(position, result):
        results[todo[position]] = result
        if store is not None:
            store.put(jobs[todo[position]].key, result)
    run_jobs(simulate, [jobs[i] for i in todo], workers=workers, scheduler=scheduler,
             label='simulations', on_result=keep, quiet=quiet)
    ends = np.cumsum([0] + [len(plan.jobs) for plan in plans])
    return [results[a:b] for a, b in zip(ends[:-1], ends[1:])]


def run_plan(plan: Plan, *, store=None, workers=None, scheduler=None, quiet=False) -> list:
    """The results of the plan's jobs (:func:`run_plans`)."""
    return run_plans([plan], store=store, workers=workers, scheduler=scheduler, quiet=quiet)[0]


def compare_trials(trials, scene, *, align: str = 'contact', gap_m: float | None = None,
                   per_trial: bool = False, tick_s: float = 0.01, store=None, workers=None,
                   scheduler=None, quiet: bool = False, simulated_repeats: int = 0) -> dict:
    """Everything the report needs: the comparisons, the plan, the results, the repeats' floors
    by speed, each speed's punctures measured and simulated (with ``simulated_repeats`` runs of a
    scene that states its spread: :mod:`.puncture_spread`), and what it cost."""
    return compare_scenes(trials, [scene], align=align, gap_m=gap_m, per_trial=per_trial, tick_s=tick_s,
                          store=store, workers=workers, scheduler=scheduler, quiet=quiet,
                          simulated_repeats=simulated_repeats)[0]


def compare_scenes(trials, scenes, *, align: str = 'contact', gap_m: float | None = None,
                   per_trial: bool = False, tick_s: float = 0.01, store=None, workers=None,
                   scheduler=None, quiet: bool = False, simulated_repeats: int = 0) -> list[dict]:
    """:func:`compare_trials` for each of ``scenes``, their simulations in one parallel batch (a
    scan over one value: the cores work on every scene at once, not one scene's jobs at a time)."""
    from tissue_sim_ros.analysis.compare.puncture_spread import run_simulated_repeats, spread_by_speed
    wall0 = time.perf_counter()
    plans = [plan_simulations(trials, scene, gap_m=gap_m, per_trial=per_trial, tick_s=tick_s) for scene in scenes]
    all_results = run_plans(plans, store=store, workers=workers, scheduler=scheduler, quiet=quiet)
    punctures, layers = measured_layers(trials, plans[0].motions)
    studies = []
    for scene, plan, results in zip(scenes, plans, all_results):
        curves = [simulated_curve(results[j], plan.schedules[j], plan.motions[plan.representative[j]],
                                  scene.start_gap_m) for j in range(len(plan.jobs))]
        comparisons = [compare_trial(trial, plan.motions[i], curves[plan.job_of_trial[i]], align,
                                     measured_punctures=punctures[i], layers=layers[i])
                       for i, trial in enumerate(trials)]
        study = {'comparisons': comparisons, 'plan': plan, 'results': results, 'curves': curves, 'layers': layers,
                 'speeds': speed_groups(trials, plan.motions, comparisons), 'scene_gap_m': scene.start_gap_m}
        repeats = run_simulated_repeats(plan, scene, simulated_repeats, store=store, workers=workers,
                                        scheduler=scheduler, quiet=quiet)
        study['repeat_results'] = repeats
        for position, rows in spread_by_speed(study, repeats, scene.start_gap_m).items():
            study['speeds'][position]['punctures'] = rows
        study['wall_s'] = time.perf_counter() - wall0
        studies.append(study)
    return studies


def speed_groups(trials, motions, comparisons) -> list[dict]:
    """Per speed: its trials, the model's mean NRMSE, the data's noise floor and mean spread."""
    from tissue_sim_ros.analysis.compare.repeat_statistics import ForceCurve, noise_floor_nrmse
    groups: dict = {}
    for trial, motion, comparison in zip(trials, motions, comparisons):
        key = None if trial.speed_m_s is None else round(trial.speed_m_s, 9)
        groups.setdefault(key, []).append((trial, motion, comparison))
    out = []
    for speed, members in sorted(groups.items(), key=lambda kv: (kv[0] is None, kv[0] or 0.0)):
        curves = [ForceCurve(m.time_s, t.axial_force_n, m.travel_m, m.contact_index) for t, m, _ in members]
        floor = noise_floor_nrmse(curves) if len(curves) >= 2 else float('nan')
        nrmse = [c.errors.get('nrmse', np.nan) for _, _, c in members]
        out.append({'speed_m_s': speed, 'trials': len(members),
                    'nrmse_mean': float(np.nanmean(nrmse)) if np.isfinite(nrmse).any() else float('nan'),
                    'noise_floor_nrmse': float(floor),
                    'files': [str(t.file) for t, _, _ in members]})
    return out


def data_spec_from_options(files, options: dict):
    """A data description from files named on the command line and column options (the keys
    of a data description, dotted: {'time.column': 'time', 'force.unit': 'mN', ...})."""
    from tissue_sim_ros.io.trials.data_spec import DataSpec
    spec: dict = {'files': [str(Path(f).absolute()) for f in files]}
    for dotted, value in options.items():
        if value is None:
            continue
        section, key = dotted.split('.', 1) if '.' in dotted else (dotted, None)
        if key is None:
            spec[section] = value
        else:
            spec.setdefault(section, {})[key] = value
    return DataSpec.from_dict(spec, base_dir='.', source='command line')


def main(*, data_spec=None, files=(), options=None, scene_file=None, sets=(), align='contact',
         gap_mm=None, max_depth_mm=None, per_trial=False, tick_ms=10.0, workers=None, scheduler=None, out='out/compare',
         simulated_repeats=0, stream=None) -> dict:
    """The ``tissue-sim compare`` command: load the trials, compare, write the report."""
    import sys

    from tissue_sim_ros.analysis.compare.report import write_report
    from tissue_sim_ros.analysis.compare.trial_simulation import ResultStore
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    stream = sys.stdout if stream is None else stream
    spec = DataSpec.from_file(data_spec) if data_spec else data_spec_from_options(files, options or {})
    trials = load_trials(spec)
    if max_depth_mm is not None:
        from tissue_sim_ros.analysis.compare.measured_motion import within_depth
        trials = [within_depth(t, max_depth_mm * 1e-3, gap_m=None if gap_mm is None else gap_mm * 1e-3)
                  for t in trials]
    scene = load_scene(scene_file, sets=sets)
    print(f'compare: {len(trials)} trial(s) from {spec.source}; scene {scene_file or "(default)"}'
          f'{" with " + ", ".join(sets) if sets else ""}: {scene.mesh.n_elements} tetrahedra', file=stream)
    out = Path(out)
    study = compare_trials(trials, scene, align=align, gap_m=None if gap_mm is None else gap_mm * 1e-3,
                           per_trial=per_trial, tick_s=tick_ms * 1e-3,
                           store=ResultStore(out / 'simulations'), workers=workers, scheduler=scheduler,
                           simulated_repeats=simulated_repeats)
    report = write_report(out, study, scene_label=str(scene_file or 'the default scene'),
                          overrides=sets, align=align)
    s = report['summary']

    def fmt(value):
        return 'n/a' if value is None else f'{value:.4f}'
    print(f"model NRMSE {fmt(s['nrmse_mean'])} (mean of {s['trials']} trials) against the data's "
          f"noise floor {fmt(s['noise_floor_nrmse'])}; {s['simulations']} simulation(s), "
          f"{s['failed_simulations']} failed, {s['wall_s']:.1f} s", file=stream)
    for group in report['speeds']:
        speed = 'unknown' if group['speed_m_s'] is None else f"{group['speed_m_s'] * 1e3:g} mm/s"
        print(f"  {speed:>12}: {group['trials']} trial(s), model NRMSE {fmt(group['nrmse_mean'])}, "
              f"noise floor {fmt(group['noise_floor_nrmse'])}", file=stream)
        for row in group.get('punctures') or []:
            m, sim = row['measured'], row['simulated']
            print(f"    layer {row['layer']}: measured {1e3 * m['depth_m']:.2f} +- {1e3 * m['depth_sd_m']:.2f} mm, "
                  f"{m['force_n']:.3f} +- {m['force_sd_n']:.3f} N ({m['found']} of {m['repeats']}); simulated "
                  + ('none' if not sim['depth_m']['count'] else
                     f"{1e3 * sim['depth_m']['mean']:.2f} +- {1e3 * (sim['depth_m']['sd'] or 0):.2f} mm, "
                     f"{sim['force_n']['mean']:.3f} +- {sim['force_n']['sd'] or 0:.3f} N ({sim['runs']} run(s))")
                  + ('' if row['within_spread'] else ', outside the repeats\' spread'), file=stream)
    print(f"wrote {', '.join(report['outputs'].values())}", file=stream)
    return report


def compare_with_reference(time_s, travel_m, axial_force_n, *, study=None, plot=None,
                           title='', label='simulation'):
    """A simulated insertion (time [s], tip travel [m] from any origin, axial force [N]) against
    a study's first trial, by depth since each curve's own contact, the insertion only (the
    motions may differ in speed and depth). ``study``: its data description (default: the
    bovine liver of the default scene). Writes ``plot`` (force against depth) when given.
    Returns the TrialComparison."""
    from tissue_sim_ros.analysis.compare.report import plot_comparison
    from tissue_sim_ros.analysis.compare.measured_motion import measured_motion
    from tissue_sim_ros.analysis.compare.reference_data import study_path
    from tissue_sim_ros.io.trials.data_spec import load_trials
    trial = load_trials(study or study_path())[0]
    motion = measured_motion(trial)
    curve = SimulatedCurve(np.asarray(time_s, dtype=float), np.asarray(travel_m, dtype=float),
                           np.asarray(axial_force_n, dtype=float))
    comparison = compare_trial(trial, motion, curve, align='depth')
    if plot is not None:
        shown = _at_its_contact(curve, motion.time_s - motion.time_s[motion.contact_index], trial.axial_force_n)
        plot_comparison(plot, [{'title': title or f'{Path(trial.file).name}: NRMSE '
                                f'{comparison.errors.get("nrmse", float("nan")):.3f} (insertion)',
                                'comparisons': [comparison], 'simulations': [(shown, comparison)]}],
                        'depth', simulation_label=label)
    return comparison
