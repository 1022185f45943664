"""What ``tissue-sim calibrate`` writes into ``--out DIR``.

- ``calibrated.yaml``: the complete scene at the optimum (every key, the mass scaling it ran
  with), the fitted values with their standard errors, the data and the command in comments;
  every command that takes ``--scene`` accepts it.
- ``calibrate.json``: ``parameters`` (per fitted key: ``value``, ``stderr``, ``start``, ``low``,
  ``high``, ``log``, ``phase``), ``correlation`` (``keys`` and ``matrix``), ``fit``
  (``nrmse_mean`` and ``nrmse_mean_start`` over the fitted trials, ``speeds``), ``validation``
  (the same over the held-out trials, when given), ``cross_validation`` (with leave-one-speed-out:
  ``nrmse_mean`` and per speed its prediction by the calibration without it, as the ``speeds`` rows
  with that calibration's ``parameters`` and ``report``), ``speeds`` (per speed and role: model NRMSE
  at the start and at the optimum, the data's noise floor, the nearest other speed's mean curve
  as a prediction), ``inertia`` (the mass scaling's measured error), ``finish`` (per step of the
  fine finish: ``objective_before``, ``predicted`` by its linear model, ``objective`` run), ``warnings``,
  ``evaluations`` (every one the search made, within ``max_evaluations``, across resumes:
  ``replayed_evaluations`` of them replayed an earlier run's simulations; ``partial_evaluations``
  ran the simulations only as far as a stage of the search needed), ``evaluations_logged`` (lines of
  evaluations.jsonl, each evaluation once), ``simulations``, ``wall_s`` (this run) and
  ``wall_s_all_runs`` (with the earlier ``runs`` of an interrupted study), ``stages`` (per stage of
  the staged start: its keys, its residuals' objective and every residual's, before and after),
  ``stopped_at_start`` (the start was within the noise floor), ``noise_floor_nrmse``,
  ``weakest_direction`` (the least-determined combination of keys probed: per key ``value``,
  ``minus``, ``plus``; ``nrmse`` and ``objective`` at the minus end, the optimum and the plus end,
  ``worse_t`` per end, ``noise_floor``, ``told_apart``; null with one key); per key in
  ``parameters`` also ``moved``, ``why_not_moved`` (at a bound, insensitive, correlated, at its
  optimum) and ``pushed_past`` (the bound it ended at with the fit pushing past it: warned),
  ``repeat_draws`` (with ``--per-repeat``: per fitted trial its ``file`` and per region its matched
  ``rupture_force_offset_n`` and ``depth_offset_m``; per region the offsets' ``mean`` and
  ``spread``, the spread written into calibrated.yaml; the fit's NRMSE is then each repeat's
  against its own draws, the held-out trials' against the mean repeat), ``outputs``.
- ``calibrate.md``: the same for a person; ``calibrate.csv``: one row per speed and role (fit,
  held out, left out);
  ``evaluations.jsonl``: every evaluation of the search (written as it ran);
  ``calibrate_<role>_<speed>.png``: per speed the data (trials, mean and one standard
  deviation, punctures) against depth and against time since contact, the starting and the
  calibrated scene (punctures marked), and their NRMSEs beside the noise floor and the nearest
  other speed's data.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

__all__ = ['speed_label', 'write_report']


def _number(value):
    value = float(value)
    return value if math.isfinite(value) else None


def _plain(value):
    """JSON-ready: numbers as floats (NaN as None), containers walked."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, (bool, str)) or value is None:
        return value
    if isinstance(value, (int, np.integer)):
        return int(value)
    return _number(value)


def speed_label(speed) -> str:
    return 'unknown speed' if speed is None else f'{speed * 1e3:g} mm/s'


def _studies(trials, scene, **options):
    from tissue_sim_ros.analysis.compare.compare import compare_trials
    return compare_trials(trials, scene, quiet=True, **options) if trials else None


def _study_of(evaluation, objective) -> dict:
    """The fitted trials' comparisons as compare's study (the search already simulated them)."""
    from tissue_sim_ros.analysis.compare.compare import speed_groups
    return {'comparisons': evaluation.comparisons,
            'speeds': speed_groups(objective.trials, objective.plan.motions, evaluation.comparisons)}


def _speed_rows(study_start, study_final, role, baseline) -> list[dict]:
    rows = []
    for start, final in zip(study_start['speeds'], study_final['speeds']):
        speed = final['speed_m_s']
        near = baseline.get(None if speed is None else round(speed, 9), {})
        rows.append({'role': role, 'speed_m_s': speed, 'trials': final['trials'],
                     'nrmse_start': _number(start['nrmse_mean']), 'nrmse_calibrated': _number(final['nrmse_mean']),
                     'noise_floor_nrmse': _number(final['noise_floor_nrmse']),
                     'nearest_speed_m_s': near.get('nearest_speed_m_s'),
                     'nearest_speed_nrmse': _number(near.get('nrmse', float('nan')))})
    return rows


def _nearest_baseline(trials) -> dict:
    from tissue_sim_ros.analysis.compare.measured_motion import measured_motion
    from tissue_sim_ros.analysis.compare.repeat_statistics import ForceCurve, nearest_speed_baseline
    groups: dict = {}
    for trial in trials:
        if trial.speed_m_s is None:
            continue
        motion = measured_motion(trial)
        groups.setdefault(round(trial.speed_m_s, 9), []).append(
            ForceCurve(motion.time_s, trial.axial_force_n, motion.travel_m, motion.contact_index))
    return nearest_speed_baseline(groups) if len(groups) >= 2 else {}


def _nan(value) -> float:
    return float('nan') if value is None else float(value)


def _mean(comparisons) -> float:
    scores = [c.errors.get('nrmse', np.nan) for c in comparisons]
    return _number(np.nanmean(scores)) if np.isfinite(scores).any() else None


def _weakest_text(weakest: dict) -> str:
    """The probed least-determined combination in words: each key's range over the probe."""
    def change(entry, end):
        return f"{100 * (entry[end] / entry['value'] - 1):+.0f} %" if entry['value'] else f'{entry[end]:.4g}'
    keys = ', '.join(f"{key} {entry['minus']:.4g} to {entry['plus']:.4g} ({change(entry, 'minus')} to "
                     f"{change(entry, 'plus')})" for key, entry in weakest['keys'].items())
    low, at, high = weakest['nrmse']
    minus, plus = weakest['worse_t']
    objective = ' / '.join(f'{value:.4g}' for value in weakest['objective'])
    worse = (f'; the ends worse by {minus:.1f} and {plus:.1f} standard errors of the objective over the trials'
             if weakest['told_apart'] is not None else '')
    return f'{keys}: fit NRMSE {low:.4f} / {at:.4f} / {high:.4f}, objective {objective} (the optimum between{worse})'


def _moved_text(entry) -> str:
    if not entry.get('moved'):
        return 'no: ' + (entry.get('why_not_moved') or '')
    return f"yes, to its {entry['pushed_past']} bound" if entry.get('pushed_past') else 'yes'


def _warnings(fit, rows, spread) -> list[str]:
    out = [f'{a} and {b} are correlated at {rho:+.3f}: the data cannot tell them apart; fix one or '
           'add data where they differ' for a, b, rho in spread['correlated_pairs']]
    weakest = spread.get('weakest')
    if weakest and weakest['told_apart'] is False:
        out.append(f'the data cannot tell these values apart: {_weakest_text(weakest)}, the repeats not agreeing '
                   'that both ends fit worse; fix some of them or add data where they differ')
    out += [f'{key} does not change the fitted curves (zero sensitivity): its value is the start'
            for key in spread['insensitive']]
    out += [f"{key} ended at its {entry['pushed_past']} bound with the fit pushing past it: the other keys make "
            'up for it; widen its --fit bounds and calibrate again' for key, entry in spread.get('moved', {}).items()
            if entry.get('pushed_past')]
    from tissue_sim_ros.analysis.calibration.fine import linear_model_warning
    nonlinear = linear_model_warning(fit.get('finish', []))
    if nonlinear:
        out.append(nonlinear)
    failed = fit['failed']
    if failed:
        out.append(f'{len(failed)} evaluation(s) failed and scored as misses (first: {failed[0].failures[0][:160]})')
    inertia = fit['inertia']
    if (inertia.get('error_at_optimum') or 0) > inertia['bound']:
        out.append(f"mass scaling {inertia['mass_scaling_at_optimum']:g} brings an inertia error of "
                   f"{inertia['error_at_optimum']:.3f} of the force range, above the bound {inertia['bound']}")
    for row in rows:
        if row['nrmse_calibrated'] is None or row['nearest_speed_nrmse'] is None \
                or not row['nrmse_calibrated'] > row['nearest_speed_nrmse']:
            continue
        other = f"the measured {speed_label(row['nearest_speed_m_s'])} curve ({row['nearest_speed_nrmse']:.3f})"
        if row['role'] in ('held out', 'left out'):
            out.append(f"{'held-out' if row['role'] == 'held out' else 'left out (calibrated without it)'} "
                       f"{speed_label(row['speed_m_s'])}: the model (NRMSE {row['nrmse_calibrated']:.3f}) "
                       f"predicts worse than reusing {other}")
        else:   # a curve it was fitted to: another speed's data is closer than the fit
            out.append(f"fitted {speed_label(row['speed_m_s'])}: the calibrated model (NRMSE "
                       f"{row['nrmse_calibrated']:.3f}) is farther from the data than {other}: the search "
                       'may have stopped short, or the scene cannot take the data\'s shape')
    return out


def _calibrated_yaml(path, spec, report, *, scene_file, sets, data_spec, base_dir) -> None:
    from tissue_sim_ros.engine.scene.scene import scene_yaml
    lines = ['A scene calibrated by tissue-sim calibrate (every key; `tissue-sim scene-keys` explains them).',
             f'data: {data_spec}; starting scene: {scene_file or "the packaged default"}'
             + (f' with {" ".join("--set " + s for s in sets)}' if sets else ''),
             f"fit NRMSE {report['fit']['nrmse_mean']:.4f} (start {report['fit']['nrmse_mean_start']:.4f})",
             f"fitted values (standard error from the Jacobian of {report['jacobian']}; a lower bound):"]
    lines += [f"  {key} = {p['value']:.6g} +- {p['stderr']:.2g}" for key, p in report['parameters'].items()]
    path.write_text(scene_yaml(spec, base_dir, lines))


def _plot(out, study_start, study_final, role, rows) -> dict:
    """Per speed: the data against depth and against time since contact (each repeat, the mean and
    one standard deviation as a band, its punctures as circles), the starting and the calibrated
    simulations (their punctures as crosses), and the NRMSEs beside the noise floor and the nearest
    other speed's data."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from tissue_sim_ros.analysis.compare.report import draw_measured
    written = {}
    for group in study_final['speeds']:
        speed = group['speed_m_s']
        row = next((r for r in rows if r['role'] == role and r['speed_m_s'] == speed), {})
        members = [i for i, c in enumerate(study_final['comparisons']) if str(c.file) in group['files']]
        comparisons = [study_final['comparisons'][i] for i in members]
        fig, axes = plt.subplots(1, 3, figsize=(16, 4.4), gridspec_kw={'width_ratios': [3, 3, 1.3]})
        for ax, by in zip(axes[:2], ('depth', 'time')):
            def x_of(c):
                return c.travel_since_contact_m * 1e3 if by == 'depth' else c.time_since_contact_s
            draw_measured(ax, comparisons, by, label='repeats')
            for study, style, colour, label in ((study_start, '--', 'C1', 'starting scene'),
                                                (study_final, '-', 'C3', 'calibrated')):
                c = study['comparisons'][members[0]]
                ax.plot(x_of(c), c.simulated_n, style, color=colour, lw=1.2, label=label)
                ax.plot(x_of(c)[[p.index for p in c.simulated_punctures]], [p.force_n for p in c.simulated_punctures],
                        'x', color=colour, ms=7)
            ax.set_xlabel('depth since contact [mm]' if by == 'depth' else 'time since contact [s]')
            ax.set_ylabel('axial force [N]')
            ax.grid(alpha=0.3)
            ax.legend(fontsize=7, loc='best')
        bars = [('start', row.get('nrmse_start')), ('calibrated', row.get('nrmse_calibrated')),
                ('noise floor', row.get('noise_floor_nrmse')), ('nearest\nspeed', row.get('nearest_speed_nrmse'))]
        axes[2].bar([b[0] for b in bars], [b[1] or 0.0 for b in bars], color=['C1', 'C3', '0.5', 'C2'])
        for k, (_, value) in enumerate(bars):
            axes[2].text(k, value or 0.0, 'n/a' if value is None else f'{value:.3f}', ha='center', va='bottom',
                         fontsize=7)
        axes[2].set_ylabel('NRMSE')
        axes[2].tick_params(axis='x', labelsize=7)
        fig.suptitle(f'{role}: {speed_label(speed)}, {len(members)} trial(s): punctures as circles (data) and '
                     'crosses (simulations)', fontsize=9)
        fig.tight_layout()
        name = f"calibrate_{role.replace(' ', '_')}_{'unknown' if speed is None else f'{speed * 1e3:g}mm_s'}.png"
        fig.savefig(out / name, dpi=100)
        plt.close(fig)
        written[name] = str(out / name)
    return written


def _markdown(report) -> str:
    def f(value, digits=4):
        return 'n/a' if value is None else f'{value:.{digits}f}'
    budget = '' if report.get('max_evaluations') is None else f" of {report['max_evaluations']}"
    lines = ['# Calibration', '', f"Data: {report['data_spec']}" + (f"; held out: {report['validate_spec']}"
                                                                  if report['validate_spec'] else ''),
             f"Scene: {report['scene']}; {report['evaluations']}{budget} evaluations "
             f"({report.get('replayed_evaluations', 0)} replayed from an earlier run's simulations), "
             f"{report['simulations']} simulations, {report['wall_s']:.1f} s"
             + (f" ({report['wall_s_all_runs']:.1f} s over {report['runs']} runs)" if report.get('runs', 1) > 1 else ''),
             '']
    if report.get('stopped_at_start'):
        lines += ['**The start was already as close to the data as its repeats are to each other (NRMSE within '
                  'the noise floor): nothing to fit; the search ended there.**', '']
    lines += ['| key | start | calibrated | standard error | bounds | moved |', '|---|---|---|---|---|---|']
    lines += [f"| `{k}` | {p['start']:.6g} | {p['value']:.6g} | {p['stderr']:.2g} | {p['low']:g} to {p['high']:g}"
              f"{' (log)' if p['log'] else ''} | {_moved_text(p)} |"
              for k, p in report['parameters'].items()]
    stages = [st for st in report.get('stages', []) if 'objective_before' in st]
    if stages:
        lines += ['', '## Staged start', '', '| stage | keys | residuals | its objective | every residual |',
                  '|---|---|---|---|---|']
        def g(value):
            return 'not reached (evaluations spent)' if value is None else f'{value:.4g}'
        lines += [f"| {st['stage']} | {', '.join(f'`{k}`' for k in st['keys'])} | {st['residuals']} | "
                  f"{g(st['objective_before'])} -> {g(st.get('objective_after'))} | {g(st['whole_before'])} -> "
                  f"{g(st.get('whole_after'))} |" for st in stages]
    lines += ['', f"Standard errors from the Jacobian of {report['jacobian']} (a lower bound: neighbouring "
                  'force samples are correlated).']
    weakest = report.get('weakest_direction')
    if weakest:
        verdict = {True: 'the data tells them apart.', False: 'the data cannot tell these values apart.',
                   None: 'one trial: no repeats to judge by.'}[weakest['told_apart']]
        lines += ['', 'What the data determines least (the combination along the Jacobian\'s least singular '
                  f'value, stepped either way and run): {_weakest_text(weakest)}: {verdict}']
    draws = report.get('repeat_draws')
    if draws:
        lines += ['', 'Each repeat simulated with its own rupture forces and layer depths, matched to its punctures '
                  'at the start (the fit\'s NRMSE: each repeat against its own; held out: the mean repeat). '
                  'Their spread, written into calibrated.yaml: ' + '; '.join(
                      f"{name} {v['rupture_force_spread_n']:.3g} N, {v['depth_spread_m'] * 1e3:.3g} mm"
                      for name, v in draws['spread'].items()) + '.' if draws['spread'] else
                  'Each repeat simulated on its own motion; no puncture to match its draws to.']
    lines += ['', '| role | speed | trials | NRMSE start | NRMSE calibrated | noise floor | nearest other speed\'s data |',
              '|---|---|---|---|---|---|---|']
    lines += [f"| {r['role']} | {speed_label(r['speed_m_s'])} | {r['trials']} | {f(r['nrmse_start'])} | "
              f"{f(r['nrmse_calibrated'])} | {f(r['noise_floor_nrmse'])} | {f(r['nearest_speed_nrmse'])} |"
              for r in report['speeds']]
    if report.get('cross_validation'):
        lines += ['', '## Leave one speed out', '', 'Each speed predicted by a calibration that did not see it '
                  '(its outputs in `leave_out_<speed>/`):', '',
                  '| speed | trials | NRMSE start | NRMSE predicted | noise floor | nearest other speed\'s data |',
                  '|---|---|---|---|---|---|']
        lines += [f"| {speed_label(r['speed_m_s'])} | {r['trials']} | {f(r['nrmse_start'])} | "
                  f"{f(r['nrmse_calibrated'])} | "
                  f"{f(r['noise_floor_nrmse'])} | {f(r['nearest_speed_nrmse'])} |"
                  for r in report['cross_validation']['speeds']]
    inertia = report['inertia']
    lines += ['', f"Mass scaling: {inertia['mass_scaling_at_optimum']:g} at the optimum; its inertia error "
              f"{f(_number(inertia.get('error_at_optimum', float('nan'))), 3)} of the force range (bound "
              f"{inertia['bound']}; measured {f(_number(inertia.get('error_at_start', float('nan'))), 3)} at "
              f"{inertia['mass_scaling']:g})."]
    if report['warnings']:
        lines += ['', '## Warnings', ''] + [f'- {w}' for w in report['warnings']]
    return '\n'.join(lines) + '\n'


def _repeat_draws(fit, spec) -> dict:
    """Each fitted repeat's matched offsets by region name, their means and spreads."""
    from tissue_sim_ros.analysis.calibration.repeat_draws import means, spreads
    offsets = fit['repeat_offsets']
    names = [region['name'] for region in spec['regions']]

    def by_name(values, force_key, depth_key):
        return {names[r]: {force_key: float(force), depth_key: float(depth)} for r, (force, depth) in values.items()}
    return {'trials': [{'file': str(trial.file), 'regions': by_name(own, 'rupture_force_offset_n', 'depth_offset_m')}
                       for trial, own in zip(fit['objective'].trials, offsets)],
            'mean': by_name(means(offsets), 'rupture_force_offset_n', 'depth_offset_m'),
            'spread': by_name(spreads(offsets), 'rupture_force_spread_n', 'depth_spread_m')}


def write_report(out: Path, fit, *, held_out, start_scene, final_scene, scene_file, sets, data_spec,
                 validate_spec, align, gap_m, tick_s, workers=None, scheduler=None, cross_validation=None) -> dict:
    """Write every output (see the module docstring); the report dict. ``cross_validation``: per
    speed, its prediction by the calibration without it (the held-out row of that fold's report,
    with its ``parameters`` and ``report``)."""
    from tissue_sim_ros.analysis.calibration.objective import calibrated_spec
    from tissue_sim_ros.analysis.compare.trial_simulation import ResultStore
    out.mkdir(parents=True, exist_ok=True)
    options = dict(align=align, gap_m=gap_m, tick_s=tick_s, store=ResultStore(out / 'simulations'),
                   workers=workers, scheduler=scheduler)
    baseline = _nearest_baseline(list(fit['objective'].trials) + list(held_out))
    objective = fit['objective']
    studies = {'fit': (_study_of(fit['start'], objective), _study_of(fit['best'], objective))}
    if held_out:
        studies['held out'] = (_studies(held_out, start_scene, **options), _studies(held_out, final_scene, **options))
    rows = [row for role, pair in studies.items() for row in _speed_rows(*pair, role, baseline)]
    spread = fit['uncertainty']
    keys = fit['keys']
    moved = spread.get('moved', {})
    parameters = {k.key: {'value': k.value(x), 'stderr': float(se), 'start': k.value(x0), 'low': k.low,
                          'high': k.high, 'log': k.log, 'phase': k.phase,
                          'moved': moved.get(k.key, {}).get('moved'), 'why_not_moved': moved.get(k.key, {}).get('why'),
                          'pushed_past': moved.get(k.key, {}).get('pushed_past')}
                  for k, x, x0, se in zip(keys, fit['u'], fit['u0'], spread['stderr'])}
    report = {'data_spec': str(data_spec), 'validate_spec': str(validate_spec) if validate_spec else None,
              'scene': str(scene_file or 'the packaged default'), 'sets': list(sets), 'align': align,
              'parameters': parameters,
              'correlation': {'keys': [k.key for k in keys], 'matrix': np.round(spread['correlation'], 4).tolist()},
              'jacobian': spread['jacobian'],
              'fit': {'nrmse_mean': _mean(studies['fit'][1]['comparisons']),
                      'nrmse_mean_start': _mean(studies['fit'][0]['comparisons']),
                      'speeds': [r for r in rows if r['role'] == 'fit']},
              'speeds': rows,
              'inertia': {k: (_number(v) if isinstance(v, float) else v) for k, v in fit['inertia'].items()},
              'finish': fit.get('finish', []),
              'evaluations': fit['evaluations'], 'max_evaluations': fit.get('max_evaluations'),
              'replayed_evaluations': fit.get('replayed_evaluations', 0),
              'evaluations_logged': fit.get('evaluations_logged'), 'partial_evaluations': fit['partial_evaluations'],
              'simulations': fit['simulations'], 'wall_s': fit['search_wall_s'],
              'runs': fit.get('runs', 1), 'wall_s_all_runs': fit.get('wall_s_all_runs', fit['search_wall_s']),
              'stages': _plain(fit.get('stages', [])), 'stopped_at_start': fit.get('stopped_at_start', False),
              'noise_floor_nrmse': _number(fit.get('noise_floor_nrmse', float('nan'))),
              'weakest_direction': spread.get('weakest')}
    if fit.get('repeat_offsets'):
        report['repeat_draws'] = _repeat_draws(fit, final_scene.spec)
    if held_out:
        report['validation'] = {'nrmse_mean': _mean(studies['held out'][1]['comparisons']),
                                'nrmse_mean_start': _mean(studies['held out'][0]['comparisons']),
                                'speeds': [r for r in rows if r['role'] == 'held out']}
    if cross_validation:
        report['cross_validation'] = {'method': 'leave one speed out',
                                      'nrmse_mean': _number(np.nanmean([_nan(r['nrmse_calibrated'])
                                                                        for r in cross_validation])),
                                      'speeds': cross_validation}
    rows = rows + list(cross_validation or [])   # the CSV and the warnings; report['speeds'] keeps its roles
    report['warnings'] = _warnings(fit, rows, spread)
    outputs = {name: str(out / name) for name in ('calibrated.yaml', 'calibrate.json', 'calibrate.md',
                                                  'calibrate.csv', 'evaluations.jsonl')}
    for role, (start, final) in studies.items():
        outputs.update(_plot(out, start, final, role, report['speeds']))
    report['outputs'] = outputs
    _calibrated_yaml(out / 'calibrated.yaml', calibrated_spec(fit), report, scene_file=scene_file, sets=sets,
                     data_spec=data_spec, base_dir=start_scene.base_dir)
    (out / 'calibrate.json').write_text(json.dumps(report, indent=2, default=float))
    (out / 'calibrate.md').write_text(_markdown(report))
    with (out / 'calibrate.csv').open('w', newline='') as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]), extrasaction='ignore')
        writer.writeheader()
        writer.writerows(rows)
    return report
