"""``tissue-sim calibrate``: scene parameters fitted to load-cell data, cross-validated across speeds.

1. The fitted trials (a data description, :mod:`tissue_sim_ros.io.trials.data_spec`) and the scene
   (with ``--set``); each ``--fit KEY=LOW:HIGH[:log]`` starts from the scene's value.
2. Affordable stiffness: a trial that would shrink the time step below the starting scene's keeps
   that step by raising the mass scaling (the critical step grows as its square root); its
   damping force stays the scene's (the rate falls as the mass scaling rises:
   ``engine.scene.keys.with_mass_scaling``, the rule the node's degradation ladder follows). The inertia
   error this brings is measured once, on the scene the search runs on: the fastest speed's
   simulation (the shortest, and the largest inertial forces: the worst case) at the starting
   mass scaling m0 and at m0 / 4, the damping force kept; the quasi-static error of mass scaling
   is linear in it (the inertial force m a scales with the mass), so e(m) = (4/3) d (m / m0), d the
   NRMSE between the two runs. The mass scaling is capped where
   e(m) reaches ``inertia_bound`` (default 0.02 of the force range); beyond that the step
   shrinks instead (slower, never less accurate). e at the optimum is reported.
3. The search (:mod:`~tissue_sim_ros.analysis.calibration.search`) on the objective
   (:mod:`~tissue_sim_ros.analysis.calibration.objective`); with ``coarse_sets`` (``--coarse-set``)
   the staged start runs on a cheaper scene (a coarser mesh, a simpler model), then on the scene
   as asked (:mod:`~tissue_sim_ros.analysis.calibration.fine`) the loading's keys are fitted
   again on the loading (``refit_steps`` Gauss-Newton steps, the simulations stopped at the
   first puncture) and ``fine_steps`` Gauss-Newton steps from that scene's own Jacobian
   finish there (that Jacobian, one parallel batch, also gives the standard errors): coarse to fine.
4. The result compared with every trial, fitted and held out (``--validate-spec``), by
   ``tissue-sim compare``'s machinery, beside the data's noise floor per speed and the baseline
   "reuse the nearest other speed's measured mean curve"; standard errors and correlations.
5. Outputs (:mod:`~tissue_sim_ros.analysis.calibration.report`).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.calibration.fine import REFIT_STEPS
from tissue_sim_ros.analysis.calibration.objective import calibrated_spec
from tissue_sim_ros.engine.scene.keys import with_mass_scaling

__all__ = ['INERTIA_BOUND', 'measure_inertia_error', 'calibrate', 'noise_floor',
           'parse_phase_weights', 'speed_folds', 'main']

INERTIA_BOUND = 0.02
#: the reduced mass scaling of the inertia check: m0 / this
INERTIA_CHECK_FACTOR = 4.0


def measure_inertia_error(objective, u0) -> dict:
    """The mass scaling's error at the start (see the module docstring, item 2)."""
    from dataclasses import replace

    from tissue_sim_ros.analysis.jobs import run_jobs
    from tissue_sim_ros.analysis.compare.trial_simulation import simulate
    jobs = objective.jobs_for(u0)
    fastest = int(np.argmin([job.times_s[-1] - job.times_s[0] for job in jobs]))
    job = jobs[fastest]
    m0 = float(job.scene_spec['solver']['mass_scaling'])
    lighter = with_mass_scaling(job.scene_spec, m0 / INERTIA_CHECK_FACTOR)
    plain = replace(job, keep_time_step_s=None, max_mass_scaling=None)
    heavy, light = run_jobs(simulate, [plain, replace(plain, scene_spec=lighter)], workers=objective.workers,
                            scheduler=objective.scheduler, quiet=True, pool=objective.pool)
    trial = objective.trials[objective.plan.representative[fastest]]
    scale = float(np.ptp(trial.axial_force_n)) or 1.0
    both = np.isfinite(heavy.axial_force_n) & np.isfinite(light.axial_force_n)
    if heavy.diverged or light.diverged or not both.any():
        return {'mass_scaling': m0, 'error_at_start': float('nan'),
                'note': f'the check did not finish: {heavy.diverged or light.diverged or "no samples"}'}
    difference = float(np.sqrt(np.mean((heavy.axial_force_n[both] - light.axial_force_n[both]) ** 2))) / scale
    error = difference * INERTIA_CHECK_FACTOR / (INERTIA_CHECK_FACTOR - 1.0)
    return {'mass_scaling': m0, 'error_at_start': error, 'difference_nrmse': difference,
            'checked_at': m0 / INERTIA_CHECK_FACTOR}


def noise_floor(objective, evaluation) -> float:
    """The fitted trials' noise floor: the mean over speeds of their repeats' NRMSE against each
    other (compare's), NaN without repeats."""
    from tissue_sim_ros.analysis.compare.compare import speed_groups
    floors = [g['noise_floor_nrmse'] for g in speed_groups(objective.trials, objective.plan.motions,
                                                            evaluation.comparisons)]
    return float(np.nanmean(floors)) if np.isfinite(floors).any() else float('nan')


def _whole_scene(spec, where: str, centroids=None) -> None:
    """Check scene keys as a scene would (every key, every list, the combinations, and with the
    mesh's element ``centroids`` that every element has a region), without building the scene; a
    SceneError starting with ``where``."""
    from tissue_sim_ros.engine.mesh.selectors import RegionSelectors
    from tissue_sim_ros.engine.scene.build import check_combinations
    from tissue_sim_ros.engine.scene.checks import apply_schema
    from tissue_sim_ros.engine.scene.schema import SCHEMA
    from tissue_sim_ros.errors import SceneError
    try:
        checked = apply_schema('', spec, SCHEMA)
        check_combinations(checked)
    except SceneError as exc:
        raise SceneError(f'{where}: {exc}') from None
    if centroids is not None and checked['mesh']['generator'] != 'file':
        orphans = int(np.sum(RegionSelectors(checked['regions']).element_regions(centroids) < 0))
        if orphans:
            raise SceneError(f'{where}: {orphans} elements would belong to no region (the first region must '
                             'select all, or the regions together cover the mesh)')


def _start(keys, spec, log, centroids=None) -> np.ndarray:
    """The unit coordinates of the scene's values; a key that cannot take its bounds is refused
    here, before the first evaluation: each bound set alone, and every key at its lower and at
    its upper bound at once, must make a scene the schema and its combinations accept (a
    relaxation term's part of the modulus, whose sum must stay below 1; relaxation with an
    implicit integrator)."""
    from tissue_sim_ros.analysis.calibration.parameters import read_key
    from tissue_sim_ros.engine.scene.keys import set_key, set_keys
    u = []
    for side in ('low', 'high'):
        corner = {k.key: getattr(k, side) for k in keys}
        where = f"--fit with every key at its {'lower' if side == 'low' else 'upper'} bound"
        _whole_scene(set_keys(spec, corner) if len(keys) > 1 else spec, where, centroids)
    for k in keys:
        value = read_key(spec, k.key)
        for bound in (k.low, k.high):
            where = f'--fit {k.key}={k.low:g}:{k.high:g}'
            _whole_scene(set_key(spec, k.key, bound, where=where), f'{where} (at {bound:g})', centroids)
        if not k.low <= value <= k.high:
            log(f'warning: {k.key} = {value:g} in the scene is outside --fit {k.low:g}:{k.high:g}; '
                'starting at the nearest bound')
        u.append(k.unit(value))
    return np.array(u)


def calibrate(trials, scene, keys, *, coarse_scene=None, align='contact', gap_m=None, tick_s=0.01,
              phase_weights=None, inertia_bound=INERTIA_BOUND, staged=True, global_search=False,
              generations=5, stage_evaluations=6, joint_evaluations=20, max_evaluations=150,
              refit_steps=REFIT_STEPS, fine_steps=3, out=None, workers=None, scheduler=None, quiet=False,
              log=None, per_repeat=False) -> dict:
    """Fit ``keys`` (FittedKey) of ``scene`` to ``trials``; everything the report needs."""
    from tqdm import tqdm

    from tissue_sim_ros.analysis.calibration.evaluation_log import logged_runs
    from tissue_sim_ros.analysis.calibration.objective import Budget, Objective
    from tissue_sim_ros.analysis.calibration.repeat_draws import MATCH_ROUNDS, absorb_means, match_repeat_draws
    from tissue_sim_ros.analysis.calibration.fine import fine_finish, refit_loading
    from tissue_sim_ros.analysis.calibration.search import WEAK_EVALUATIONS, search, uncertainty, weakest_direction, \
        why_not_moved
    from tissue_sim_ros.analysis.compare.trial_simulation import ResultStore
    log = log or (lambda text: print(text, file=sys.stderr))
    wall0 = time.perf_counter()
    reserve = len(keys) + WEAK_EVALUATIONS
    matching = MATCH_ROUNDS + 1 if per_repeat else 0     # the rounds, and the search's start moved by them
    if max_evaluations is not None and max_evaluations < reserve + 2 + matching:
        raise ValueError(f'--max-evaluations {max_evaluations}: expected at least {reserve + 2 + matching} for '
                         f'{len(keys)} key(s) (the start, a step, the Jacobian of the standard errors at the result, '
                         'the probe of what the data determines least'
                         + (f' and {matching} matching each repeat\'s draws)' if matching else ')'))
    budget = Budget(max_evaluations, reserve=reserve)
    out = Path(out) if out is not None else None
    store = ResultStore(out / 'simulations') if out is not None else None
    log_path = out / 'evaluations.jsonl' if out is not None else None
    earlier_runs = logged_runs(log_path)
    search_scene = coarse_scene or scene
    u0 = _start(keys, scene.spec, log, scene.mesh.rest_positions[scene.mesh.tetrahedra].mean(axis=1))
    from tissue_sim_ros.analysis.jobs import WorkerPool
    pool = WorkerPool(workers if scheduler is None else 1)
    options = dict(align=align, gap_m=gap_m, tick_s=tick_s, phase_weights=phase_weights, store=store,
                   log_path=log_path, workers=workers, scheduler=scheduler, pool=pool)

    def inertia_for(a_scene):
        inertia = measure_inertia_error(Objective(trials, a_scene, keys, **options), u0)
        m0, e0 = inertia['mass_scaling'], inertia['error_at_start']
        cap = m0 * max(1.0, inertia_bound / e0) if np.isfinite(e0) and e0 > 0 else m0
        return dict(inertia, cap=cap, bound=inertia_bound)

    offsets = None

    def objective_for(a_scene, inertia):
        nonlocal offsets
        made = Objective(trials, a_scene, keys, keep_time_step_s=a_scene.dt, max_mass_scaling=inertia['cap'],
                         per_repeat=per_repeat, **options)
        made.budget = budget
        if per_repeat and offsets is None:
            offsets = match_repeat_draws(made, u0)
            log(f'each repeat\'s draws matched to its punctures in {MATCH_ROUNDS} rounds: '
                f'{_spread_text(made.spec_for(u0), offsets)}')
        elif per_repeat:
            made.set_repeat_offsets(offsets)
        return made

    bar = tqdm(desc='calibration', unit='eval', file=sys.stderr, disable=quiet, dynamic_ncols=True)

    def progress(objective):
        def seen(evaluation):
            bar.update(1)
            bar.set_postfix_str(f'best NRMSE {objective.best.nrmse_mean:.4f}, '
                                f'{objective.simulations_run} sims', refresh=False)
        objective.on_evaluation = seen
        return objective

    with bar, pool:
        inertia = inertia_for(search_scene)
        objective = objective_for(search_scene, inertia)
        used_objectives = [progress(objective)]
        u_search = u0
        if per_repeat:                            # the fitted keys take the repeats' mean draw
            u_search, absorbed = absorb_means(keys, u0, objective.spec_for(u0), offsets)
            if absorbed != offsets:
                offsets = absorbed
                objective.set_repeat_offsets(offsets)
        start = objective.evaluate(u0)
        floor = noise_floor(objective, start)

        def enough(evaluation):
            return bool(np.isfinite(floor) and evaluation.nrmse_mean <= floor)
        stages: list = []
        # with a coarse scene the joint refinement is the fine finish's, on the scene as asked
        u = search(objective, u_search, staged=staged, global_search=global_search, generations=generations,
                   stage_evaluations=stage_evaluations, joint_evaluations=joint_evaluations,
                   joint=coarse_scene is None or not staged, log=log, record=stages,
                   enough=enough if coarse_scene is None else None)
        at_optimum, J, finish = objective, None, []
        stopped_at_start = any(entry.get('stopped') == 'already optimal' for entry in stages)
        if stopped_at_start:
            J = next(entry.pop('jacobian') for entry in stages if entry.get('stopped') == 'already optimal')
        if coarse_scene is not None and not stopped_at_start:
            log('fine stage: on the scene as asked')
            objective = objective_for(scene, inertia)
            used_objectives.append(progress(objective))
            start = objective.evaluate(u0)         # the report's starting scene
            u = refit_loading(objective, u, steps=refit_steps, log=log)
            at_optimum = objective
            if fine_steps:
                u, J, finish = fine_finish(objective, u, steps=fine_steps, noise_floor=noise_floor(objective, start),
                                           log=log)
        best = objective.evaluate(u)
        for used in used_objectives:
            used.for_search = False              # the reserve: the Jacobian of the standard errors
        spread = uncertainty(at_optimum, u, J)
        spread['jacobian'] = ('the scene as asked, before the fine finish\'s steps' if J is not None else
                              'the scene as asked, at the optimum')
        spread['moved'] = why_not_moved(at_optimum, u0, u, spread['jacobian_matrix'], spread['correlation'])
        spread['weakest'] = weakest_direction(at_optimum, u, spread['jacobian_matrix'], floor)
    evaluations = [e for o in used_objectives for e in o.evaluations]
    failed = [e for e in evaluations if e.failures]
    partial = sum(e.phases is not None for e in evaluations)
    simulations = sum(o.simulations_run for o in used_objectives)
    used = max((r.mass_scaling for r in best.results if np.isfinite(r.mass_scaling)), default=inertia['mass_scaling'])
    inertia['mass_scaling_at_optimum'] = used
    inertia['error_at_optimum'] = inertia['error_at_start'] * used / inertia['mass_scaling']
    wall = time.perf_counter() - wall0
    earlier = sum(run['elapsed_s'] for run in earlier_runs.values())
    return {'keys': keys, 'u0': u0, 'u': u, 'start': start, 'best': best, 'uncertainty': spread,
            'inertia': inertia, 'objective': objective, 'evaluations': budget.used,
            'replayed_evaluations': budget.replayed, 'max_evaluations': max_evaluations,
            'partial_evaluations': partial, 'failed': failed, 'simulations': simulations,
            'search_wall_s': wall, 'wall_s_all_runs': earlier + wall, 'runs': len(earlier_runs) + 1,
            'evaluations_logged': sum(run['evaluations'] for run in logged_runs(log_path).values()),
            'finish': finish, 'stages': stages, 'noise_floor_nrmse': floor, 'stopped_at_start': stopped_at_start,
            'evaluations_in_memory': len(evaluations), 'repeat_offsets': offsets}


def _spread_text(spec, offsets) -> str:
    """Each region's matched offsets as standard deviations over the repeats."""
    from tissue_sim_ros.analysis.calibration.repeat_draws import spreads
    return '; '.join(f"{spec['regions'][k]['name']}: rupture force s.d. {force:.3g} N, depth s.d. {depth * 1e3:.3g} mm"
                     for k, (force, depth) in spreads(offsets).items()) or 'no puncture matched'


def parse_phase_weights(texts) -> dict:
    from tissue_sim_ros.analysis.compare.force_events import PHASES
    weights = {}
    for text in texts or ():
        phase, _, value = text.partition('=')
        if phase not in PHASES:
            raise ValueError(f'--phase-weight {text!r}: unknown phase {phase!r}; expected one of {", ".join(PHASES)}')
        try:
            weights[phase] = float(value)
        except ValueError:
            raise ValueError(f'--phase-weight {text!r}: the weight {value!r} is not a number') from None
        if not (np.isfinite(weights[phase]) and weights[phase] >= 0):
            raise ValueError(f'--phase-weight {text!r}: expected a finite weight >= 0')
    return weights


def speed_folds(trials) -> list[tuple]:
    """Leave-one-speed-out folds: per speed (ascending), (speed [m/s], the other speeds' trials,
    that speed's trials). Every trial needs its speed (the data description's file-name pattern)."""
    unknown = [str(t.file) for t in trials if t.speed_m_s is None]
    if unknown:
        raise ValueError(f'--leave-one-speed-out: no speed for {unknown[0]} (and {len(unknown) - 1} more); '
                         "give the speed in the data description (file_name.pattern's speed group)")
    speeds = sorted({round(t.speed_m_s, 9) for t in trials})
    if len(speeds) < 2:
        raise ValueError(f'--leave-one-speed-out: the trials have {len(speeds)} speed(s); expected at least 2')
    return [(speed, [t for t in trials if round(t.speed_m_s, 9) != speed],
             [t for t in trials if round(t.speed_m_s, 9) == speed]) for speed in speeds]


def _fit_and_report(trials, held_out, out, *, scene, coarse, keys, scene_file, sets, data_spec, validate_spec,
                    align, gap_m, tick_s, cross_validation=None, stream, **search) -> dict:
    """One calibration of ``trials`` (``held_out`` predicted), its outputs in ``out``."""
    from tissue_sim_ros.analysis.calibration.report import write_report
    from tissue_sim_ros.engine.scene.scene import Scene
    fit = calibrate(trials, scene, keys, coarse_scene=coarse, align=align, gap_m=gap_m, tick_s=tick_s, out=out,
                    log=lambda text: print(text, file=stream), **search)
    final = Scene(calibrated_spec(fit), base_dir=scene.base_dir)
    return write_report(Path(out), fit, held_out=held_out, start_scene=scene, final_scene=final,
                        scene_file=scene_file, sets=sets, data_spec=data_spec, validate_spec=validate_spec,
                        align=align, gap_m=gap_m, tick_s=tick_s, workers=search.get('workers'),
                        scheduler=search.get('scheduler'), cross_validation=cross_validation)


def main(*, data_spec, fits, validate_spec=None, leave_one_speed_out=False, scene_file=None, sets=(), coarse_sets=(),
         align='contact', gap_mm=None, max_depth_mm=None, tick_ms=10.0, phase_weights=(), inertia_bound=INERTIA_BOUND,
         global_search=False, max_evaluations=150, refit_steps=REFIT_STEPS, fine_steps=3, workers=None, scheduler=None,
         out='out/calibrate', stream=None, per_repeat=False) -> dict:
    """The ``tissue-sim calibrate`` command; with ``leave_one_speed_out`` first one calibration per
    speed without it (each in ``out/leave_out_<speed>``), whose predictions of it the report
    gives as the cross-validation."""
    from tissue_sim_ros.analysis.calibration.parameters import parse_fit
    from tissue_sim_ros.analysis.calibration.report import speed_label
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    stream = sys.stdout if stream is None else stream
    keys = [parse_fit(text) for text in fits]
    if not keys:
        raise ValueError('calibrate: give at least one --fit KEY=LOW:HIGH[:log]')
    if leave_one_speed_out and validate_spec:
        raise ValueError('calibrate: --leave-one-speed-out and --validate-spec are two ways to hold data out; give one')
    weights = parse_phase_weights(phase_weights)
    spec = DataSpec.from_file(data_spec)
    trials = load_trials(spec)
    held_out = load_trials(DataSpec.from_file(validate_spec)) if validate_spec else []
    if max_depth_mm is not None:
        from tissue_sim_ros.analysis.compare.measured_motion import within_depth
        gap = None if gap_mm is None else gap_mm * 1e-3
        trials = [within_depth(t, max_depth_mm * 1e-3, gap_m=gap) for t in trials]
        held_out = [within_depth(t, max_depth_mm * 1e-3, gap_m=gap) for t in held_out]
    folds = speed_folds(trials) if leave_one_speed_out else []
    scene = load_scene(scene_file, sets=sets)
    coarse = load_scene(scene_file, sets=list(sets) + list(coarse_sets)) if coarse_sets else None
    print(f'calibrate: {len(keys)} key(s) on {len(trials)} trial(s) from {spec.source}'
          f'{f", {len(held_out)} held out" if held_out else ""}'
          f'{f", cross-validated leaving out each of {len(folds)} speeds" if folds else ""}; '
          f'scene {scene_file or "(default)"}: {scene.mesh.n_elements} tetrahedra'
          f'{f", searching on {coarse.mesh.n_elements}" if coarse else ""}', file=stream)
    options = dict(scene=scene, coarse=coarse, keys=keys, scene_file=scene_file, sets=sets, align=align,
                   gap_m=None if gap_mm is None else gap_mm * 1e-3, tick_s=tick_ms * 1e-3, stream=stream,
                   phase_weights=weights, inertia_bound=inertia_bound, global_search=global_search,
                   max_evaluations=max_evaluations, refit_steps=refit_steps, fine_steps=fine_steps, workers=workers,
                   scheduler=scheduler, per_repeat=per_repeat)
    cross_validation = []
    for speed, fitted, left in folds:
        label = speed_label(speed)
        print(f'cross-validation: calibrating without {label}', file=stream)
        fold = _fit_and_report(fitted, left, Path(out) / f"leave_out_{label.replace(' ', '').replace('/', '_')}",
                               data_spec=data_spec, validate_spec=f'{data_spec} ({label})', **options)
        row = dict(fold['validation']['speeds'][0], role='left out',
                   parameters={k: p['value'] for k, p in fold['parameters'].items()},
                   report=fold['outputs']['calibrate.json'])
        print(f'cross-validation: {label} predicted at NRMSE {row["nrmse_calibrated"]:.4f} (noise floor '
              f'{row["noise_floor_nrmse"] or float("nan"):.4f}, the nearest other speed\'s data '
              f'{row["nearest_speed_nrmse"] or float("nan"):.4f})', file=stream)
        cross_validation.append(row)
    report = _fit_and_report(trials, held_out, Path(out), data_spec=data_spec, validate_spec=validate_spec,
                             cross_validation=cross_validation or None, **options)
    for key, entry in report['parameters'].items():
        why = '' if entry.get('moved') or not entry.get('why_not_moved') else f"; did not move: {entry['why_not_moved']}"
        print(f"  {key} = {entry['value']:.6g} +- {entry['stderr']:.2g} (start {entry['start']:.6g}{why})", file=stream)
    for warning in report['warnings']:
        print(f'  warning: {warning}', file=stream)
    print(f"fit NRMSE {report['fit']['nrmse_mean']:.4f} (start {report['fit']['nrmse_mean_start']:.4f})"
          + (f"; held out {report['validation']['nrmse_mean']:.4f}" if report.get('validation') else '')
          + (f"; leave-one-speed-out {report['cross_validation']['nrmse_mean']:.4f}"
             if report.get('cross_validation') else '')
          + f"; {report['evaluations']}{'' if max_evaluations is None else f' of {max_evaluations}'} evaluations"
          f"{'' if not report.get('replayed_evaluations') else ' (' + str(report['replayed_evaluations']) + ' replayed)'}, "
          f"{report['simulations']} simulations, {report['wall_s']:.1f} s"
          + (f" ({report['wall_s_all_runs']:.1f} s over {report['runs']} runs)" if report.get('runs', 1) > 1 else ''),
          file=stream)
    print(f"wrote {', '.join(report['outputs'].values())}", file=stream)
    return report
