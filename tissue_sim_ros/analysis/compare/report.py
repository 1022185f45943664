"""The outputs of ``tissue-sim compare`` in ``--out DIR``.

``compare.json`` (schema ``tissue_sim_ros/compare/1``; NaN written as null):

- ``trials``: one entry per data file: ``file``, ``speed_m_s``, ``repeat``, ``nrmse`` (the RMSE
  over the trial's measured axial-force range, 0.15 mm around each puncture left out: see
  :mod:`~tissue_sim_ros.analysis.compare.compare`), ``nrmse_all_samples`` (every sample), ``rmse_n``,
  ``r2``, ``max_error_n`` and
  ``max_error_time_since_contact_s``, ``bias_n`` (mean of simulated minus measured),
  ``samples_compared``, ``time_shift_s`` (align xcorr), ``phases`` (per phase: ``nrmse``,
  ``rmse_n``, ``r2``, ``count``), ``peak_force_error_n``, ``first_puncture_depth_error_m``,
  ``first_puncture_force_error_n``, ``retraction_minimum_error_n``, ``measured_punctures`` and
  ``simulated_punctures`` (``depth_m`` since contact, ``force_n``), ``diverged`` ('' or why);
- ``speeds``: per speed, ``speed_m_s``, ``trials``, ``nrmse_mean`` (the model),
  ``noise_floor_nrmse`` (the repeats against each other; null with one repeat), and
  ``punctures``: per layer the repeats share, ``measured`` (``depth_m``, ``depth_sd_m``,
  ``depth_min_m``, ``depth_max_m``, ``force_n``, ``force_sd_n``, ``found``, ``repeats``, ...),
  ``simulated`` (``depth_m`` and ``force_n`` as ``mean``, ``sd``, ``count``; ``runs``: the
  simulated repeats, 1 for the nominal scene) and ``within_spread``;
- ``summary``: ``trials``, ``simulations``, ``nrmse_mean`` (over the trials),
  ``noise_floor_nrmse`` (mean over the speeds that have repeats; null without), ``wall_s``;
- ``scene``, ``overrides``, ``align``, ``normaliser``, ``outputs``.

``compare.md``: the same in a table a person reads. ``compare.csv``: every data sample with
the simulation aligned to it (``file, speed_mm_s, repeat, time_since_contact_s,
depth_since_contact_m, phase, measured_n, simulated_n``). ``compare.png`` and
``compare_time.png``: per speed the data (each repeat thin, the mean and one standard deviation
as a band when there are repeats), the simulation line, punctures marked (circles: data,
crosses: simulation).
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

__all__ = ['SCHEMA', 'draw_measured', 'plot_comparison', 'report_dict', 'study_panels', 'write_report']

SCHEMA = 'tissue_sim_ros/compare/1'
NORMALISER = "each trial's measured axial-force range (max - min)"


def _clean(value):
    """JSON-ready: NaN/inf as None, numpy scalars as Python numbers."""
    if isinstance(value, dict):
        return {str(k): _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _trial_entry(c) -> dict:
    e, ev = c.errors, c.events
    index = e.get('max_abs_error_index')
    return {
        'file': str(c.file), 'speed_m_s': c.speed_m_s, 'repeat': c.repeat,
        'nrmse': e.get('nrmse'), 'nrmse_all_samples': e.get('nrmse_all_samples'),
        'rmse_n': e.get('rmse_n'), 'r2': e.get('r2'),
        'max_error_n': e.get('max_abs_error_n'),
        'max_error_time_since_contact_s': None if index is None else float(c.time_since_contact_s[index]),
        'bias_n': e.get('bias_n'), 'samples_compared': e.get('count', 0), 'time_shift_s': c.shift_s,
        'phases': {phase: {k: v.get(k) for k in ('nrmse', 'rmse_n', 'r2', 'count')}
                   for phase, v in c.phase_errors.items()},
        'peak_force_error_n': ev.get('peak_force_error_n'),
        'first_puncture_depth_error_m': ev.get('first_puncture_travel_error_m'),
        'first_puncture_force_error_n': ev.get('first_puncture_force_error_n'),
        'retraction_minimum_error_n': ev.get('retraction_minimum_error_n'),
        'measured_punctures': [{'depth_m': p.travel_m, 'force_n': p.force_n} for p in c.measured_punctures],
        'simulated_punctures': [{'depth_m': p.travel_m, 'force_n': p.force_n} for p in c.simulated_punctures],
        'diverged': c.diverged,
    }


def report_dict(study: dict, *, scene_label: str, overrides, align: str, outputs: dict) -> dict:
    trials = [_trial_entry(c) for c in study['comparisons']]
    nrmse = [t['nrmse'] for t in trials if t['nrmse'] is not None and math.isfinite(t['nrmse'])]
    floors = [s['noise_floor_nrmse'] for s in study['speeds'] if math.isfinite(s['noise_floor_nrmse'])]
    return _clean({
        'schema': SCHEMA, 'scene': scene_label, 'overrides': list(overrides), 'align': align,
        'normaliser': NORMALISER, 'trials': trials,
        'speeds': [dict({k: s[k] for k in ('speed_m_s', 'trials', 'nrmse_mean', 'noise_floor_nrmse')},
                        punctures=s.get('punctures', [])) for s in study['speeds']],
        'summary': {'trials': len(trials), 'simulations': len(study['plan'].jobs),
                    'failed_simulations': sum(bool(r.diverged) for r in study['results']),
                    'nrmse_mean': float(np.mean(nrmse)) if nrmse else float('nan'),
                    'noise_floor_nrmse': float(np.mean(floors)) if floors else float('nan'),
                    'wall_s': study['wall_s']},
        'outputs': outputs,
    })


def _markdown(report: dict) -> str:
    def f(value, scale=1.0, digits=3):
        return '–' if value is None else f'{value * scale:.{digits}g}'
    s = report['summary']
    lines = [f"# Comparison of {report['scene']} with {s['trials']} trial(s)", '',
             f"Alignment: {report['align']}; NRMSE normalised by {report['normaliser']}. "
             f"{s['simulations']} simulation(s) ({s['failed_simulations']} failed), "
             f"{s['wall_s']:.1f} s.", '',
             f"**Model NRMSE {f(s['nrmse_mean'])}** against the data's own repeat-to-repeat noise "
             f"floor **{f(s['noise_floor_nrmse'])}** (each repeat against the mean of the others).", '',
             '| speed [mm/s] | trials | model NRMSE | noise floor NRMSE |', '|---|---|---|---|']
    for sp in report['speeds']:
        lines.append(f"| {f(sp['speed_m_s'], 1e3)} | {sp['trials']} | {f(sp['nrmse_mean'])} | "
                     f"{f(sp['noise_floor_nrmse'])} |")
    layered = [(sp, row) for sp in report['speeds'] for row in sp.get('punctures') or []]
    if layered:
        lines += ['', '## Punctures: the repeats\' spread and the simulation\'s', '',
                  '| speed [mm/s] | layer | measured depth [mm] | simulated depth [mm] | measured force [N] | '
                  'simulated force [N] | within the spread |', '|---|---|---|---|---|---|---|']
        for sp, row in layered:
            m, sim = row['measured'], row['simulated']

            def both(mean, sd, scale=1.0, digits=2):
                return 'none' if mean is None else f'{mean * scale:.{digits}f} ± {(sd or 0.0) * scale:.{digits}f}'
            lines.append(f"| {f(sp['speed_m_s'], 1e3)} | {row['layer']} | {both(m['depth_m'], m['depth_sd_m'], 1e3)} "
                         f"({m['found']}/{m['repeats']}) | {both(sim['depth_m']['mean'], sim['depth_m']['sd'], 1e3)} "
                         f"({sim['runs']} run(s)) | {both(m['force_n'], m['force_sd_n'], digits=3)} | "
                         f"{both(sim['force_n']['mean'], sim['force_n']['sd'], digits=3)} | "
                         f"{'yes' if row['within_spread'] else 'no'} |")
    lines += ['', '| file | NRMSE | RMSE [N] | R² | peak error [N] | 1st puncture depth error [mm] | '
              'retraction min error [N] |', '|---|---|---|---|---|---|---|']
    for t in report['trials']:
        lines.append(f"| {Path(t['file']).name} | {f(t['nrmse'])} | {f(t['rmse_n'])} | {f(t['r2'])} | "
                     f"{f(t['peak_force_error_n'])} | {f(t['first_puncture_depth_error_m'], 1e3)} | "
                     f"{f(t['retraction_minimum_error_n'])} |" + (f" diverged: {t['diverged']}" if t['diverged'] else ''))
    return '\n'.join(lines) + '\n'


def _write_csv(path: Path, comparisons) -> None:
    with open(path, 'w', newline='') as handle:
        writer = csv.writer(handle)
        writer.writerow(['file', 'speed_mm_s', 'repeat', 'time_since_contact_s', 'depth_since_contact_m',
                         'phase', 'measured_n', 'simulated_n'])
        for c in comparisons:
            speed = '' if c.speed_m_s is None else f'{c.speed_m_s * 1e3:.6g}'
            repeat = '' if c.repeat is None else c.repeat
            for k in range(len(c.measured_n)):
                writer.writerow([Path(c.file).name, speed, repeat, f'{c.time_since_contact_s[k]:.6f}',
                                 f'{c.travel_since_contact_m[k]:.7f}', c.phases[k],
                                 f'{c.measured_n[k]:.6g}',
                                 '' if not math.isfinite(c.simulated_n[k]) else f'{c.simulated_n[k]:.6g}'])


def study_panels(study: dict) -> list[dict]:
    """One panel per speed of a study: its title, its trials' comparisons, its simulations."""
    from tissue_sim_ros.analysis.compare.simulated_curve import simulated_curve
    panels, plan, comparisons = [], study['plan'], study['comparisons']
    for group in study['speeds']:
        members = [i for i, c in enumerate(comparisons) if str(c.file) in group['files']]
        jobs = sorted({plan.job_of_trial[i] for i in members})
        speed = group['speed_m_s']
        title = (f"{'unknown speed' if speed is None else f'{speed * 1e3:g} mm/s'}: {len(members)} "
                 f"trial(s), model NRMSE {group['nrmse_mean']:.3f}"
                 + (f", noise floor {group['noise_floor_nrmse']:.3f}"
                    if math.isfinite(group['noise_floor_nrmse']) else ''))
        repeats = []
        for j in jobs:
            motion = plan.motions[plan.representative[j]]
            repeats += [simulated_curve(r, plan.schedules[j], motion, study.get('scene_gap_m', 0.0))
                        for r in (study.get('repeat_results') or [[]] * len(plan.jobs))[j] if not r.diverged]
        panels.append({'title': title, 'comparisons': [comparisons[i] for i in members],
                       'simulations': [(study['curves'][j], comparisons[plan.representative[j]]) for j in jobs],
                       'simulated_repeats': repeats})
    return panels


def draw_measured(ax, comparisons, by: str, *, label: str | None = None) -> None:
    """The measured trials on ``ax`` against depth (``by='depth'``, mm) or time since contact (s):
    each thin (the first labelled ``label``), its punctures as circles, and with repeats their mean
    and one standard deviation as a band (the figures of compare and calibrate draw the data so)."""
    from tissue_sim_ros.analysis.compare.repeat_statistics import ForceCurve, mean_and_spread
    scale = 1e3 if by == 'depth' else 1.0
    for n, c in enumerate(comparisons):
        x = (c.travel_since_contact_m if by == 'depth' else c.time_since_contact_s) * scale
        ax.plot(x, c.measured_n, color='0.7', lw=0.6, label=label if n == 0 else None)
        ax.plot(x[[p.index for p in c.measured_punctures]], [p.force_n for p in c.measured_punctures],
                'o', mfc='none', color='0.35', ms=5)
    if len(comparisons) >= 2:
        curves = [ForceCurve(c.time_since_contact_s, c.measured_n,
                             c.travel_since_contact_m if by == 'depth' else None,
                             int(np.argmin(np.abs(c.time_since_contact_s)))) for c in comparisons]
        grid, mean, std, _ = mean_and_spread(curves, by='travel_since_contact' if by == 'depth'
                                             else 'time_since_contact')
        ax.fill_between(grid * scale, mean - std, mean + std, color='C0', alpha=0.25,
                        label='data: mean ± 1 s.d.')
        ax.plot(grid * scale, mean, color='C0', lw=1.2)


def plot_comparison(path, panels: list[dict], by: str, *, simulation_label: str = 'simulation') -> None:
    """Force against depth (``by='depth'``) or time since contact, a panel per entry of ``panels``
    (``title``; ``comparisons``: the trials; ``simulations``: (SimulatedCurve, the comparison
    whose simulated punctures it shows)): each trial thin, with repeats their mean and one
    standard deviation as a band, the simulation line, punctures marked (circles: data, crosses:
    simulation), and a simulated study's repeats thin (``simulated_repeats``, when given)."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels), 4.2), squeeze=False)
    scale = 1e3 if by == 'depth' else 1.0

    def x_of(c, indices=None):
        x = c.travel_since_contact_m if by == 'depth' else c.time_since_contact_s
        return x * scale if indices is None else x[indices] * scale
    for ax, panel in zip(axes[0], panels):
        draw_measured(ax, panel['comparisons'], by)
        for n, curve in enumerate(panel.get('simulated_repeats', [])):
            x = curve.travel_since_contact_m if by == 'depth' else curve.time_since_contact_s
            ax.plot(x * scale, curve.axial_force_n, color='C3', lw=0.5, alpha=0.35,
                    label='simulated repeats (their spread drawn)' if n == 0 else None)
        for n, (curve, shown) in enumerate(panel['simulations']):
            x = curve.travel_since_contact_m if by == 'depth' else curve.time_since_contact_s
            ax.plot(x * scale, curve.axial_force_n, color='C3', lw=1.3, label=simulation_label if n == 0 else None)
            ax.plot(x_of(shown, [p.index for p in shown.simulated_punctures]),
                    [p.force_n for p in shown.simulated_punctures], 'x', color='C3', ms=7)
        ax.set_title(panel['title'], fontsize=9)
        ax.set_xlabel('depth since contact [mm]' if by == 'depth' else 'time since contact [s]')
        ax.set_ylabel('axial force [N]')
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8, loc='upper left')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_report(out, study: dict, *, scene_label: str, overrides=(), align: str = 'contact') -> dict:
    """Write every output into ``out``; the report dict."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    names = ('compare.json', 'compare.md', 'compare.csv', 'compare.png', 'compare_time.png')
    outputs = {name: str(out / name) for name in names}
    report = report_dict(study, scene_label=scene_label, overrides=overrides, align=align, outputs=outputs)
    (out / 'compare.json').write_text(json.dumps(report, indent=2))
    (out / 'compare.md').write_text(_markdown(report))
    _write_csv(out / 'compare.csv', study['comparisons'])
    panels = study_panels(study)
    plot_comparison(out / 'compare.png', panels, 'depth')
    plot_comparison(out / 'compare_time.png', panels, 'time')
    return report
