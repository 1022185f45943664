"""``tissue-sim inspect``: what a data description reads from its files, before a long run.

No simulation: the trials as ``compare`` and ``calibrate`` will read them, so a wrong unit, sign,
column or file-name pattern shows in seconds, not after a calibration. Per trial: the file, its
speed and repeat (from the file name or the description), samples, rate, duration, the force and
travel ranges in SI, where contact was found (the travel then: the gap), the deepest travel, the
pause, whether it retracts, its punctures (depth since contact, peak force) and pre-drops; per
speed: the layers its repeats share (depth and peak force as mean and standard deviation) and the
noise floor (each repeat against the mean of the others, as compare reports it). The units and
signs the description applies are listed first.

Outputs in ``--out DIR``: ``inspect.csv`` (a row per trial), ``inspect.json``, ``inspect.md`` and
``inspect.png`` (per speed, every repeat's force against travel since contact, punctures as
circles and pre-drops as triangles).
"""
from __future__ import annotations

import csv
import json
import math
import sys
from pathlib import Path

import numpy as np

__all__ = ['inspect_trials', 'main']


def _units(spec) -> dict:
    values = spec.values
    out = {}
    for section in ('time', 'force', 'torque', 'position'):
        given = values.get(section)
        if given:
            out[section] = {k: given[k] for k in ('column', 'columns', 'unit', 'sign', 'rate_hz', 'reduce')
                            if k in given and given[k] is not None}
    for section in ('motion', 'file_name', 'mcap'):
        if values.get(section):
            out[section] = {k: v for k, v in values[section].items() if v is not None}
    return out


def inspect_trials(trials) -> dict:
    """Per trial and per speed, what the module docstring lists (JSON-ready)."""
    from tissue_sim_ros.analysis.compare.compare import measured_layers
    from tissue_sim_ros.analysis.compare.force_events import PRE_DROP, depth_bounds, detect_drops
    from tissue_sim_ros.analysis.compare.measured_motion import measured_motion, trial_travel
    from tissue_sim_ros.analysis.compare.repeat_statistics import ForceCurve, noise_floor_nrmse
    rows, motions, usable = [], [], []
    for trial in trials:
        row = {'file': Path(trial.file).name, 'speed_mm_s': None if trial.speed_m_s is None else trial.speed_m_s * 1e3,
               'repeat': trial.repeat, 'samples': trial.n_samples, 'rate_hz': trial.sample_rate_hz,
               'duration_s': trial.duration_s, 'force_min_n': float(np.min(trial.axial_force_n)),
               'force_max_n': float(np.max(trial.axial_force_n)), 'nan_rows_dropped': trial.nan_rows_dropped}
        try:
            travel = trial_travel(trial)
            motion = measured_motion(trial)
        except ValueError as exc:
            row['problem'] = str(exc)
            rows.append(row)
            continue
        start, end = depth_bounds(travel)
        since = travel - motion.gap_m
        row.update(travel_max_mm=float(np.max(travel)) * 1e3, contact_s=float(motion.time_s[motion.contact_index]),
                   gap_mm=motion.gap_m * 1e3, depth_max_mm=float(np.max(since)) * 1e3,
                   hold_s=float(trial.time_s[end] - trial.time_s[start]), retracts=bool(end < len(travel) - 2))
        drops = detect_drops(since, trial.axial_force_n)
        row['punctures'] = [{'depth_mm': p.travel_m * 1e3, 'force_n': p.force_n, 'drop_n': p.drop_n}
                            for p in drops if p.kind != PRE_DROP]
        row['pre_drops'] = [{'depth_mm': p.travel_m * 1e3, 'force_n': p.force_n, 'drop_n': p.drop_n}
                            for p in drops if p.kind == PRE_DROP]
        rows.append(row)
        motions.append(motion)
        usable.append(trial)
    speeds = []
    if usable:
        _, layer_lists = measured_layers(usable, motions)
        groups: dict = {}
        for trial, motion, layers in zip(usable, motions, layer_lists):
            key = None if trial.speed_m_s is None else round(trial.speed_m_s, 9)
            groups.setdefault(key, {'trials': [], 'motions': [], 'layers': layers})
            groups[key]['trials'].append(trial)
            groups[key]['motions'].append(motion)
        for speed, group in sorted(groups.items(), key=lambda kv: (kv[0] is None, kv[0] or 0.0)):
            curves = [ForceCurve(m.time_s, t.axial_force_n, m.travel_m, m.contact_index)
                      for t, m in zip(group['trials'], group['motions'])]
            speeds.append({'speed_mm_s': None if speed is None else speed * 1e3, 'repeats': len(curves),
                           'noise_floor_nrmse': noise_floor_nrmse(curves) if len(curves) >= 2 else math.nan,
                           'layers': [layer.as_dict() for layer in group['layers']]})
    return {'trials': rows, 'speeds': speeds}


def _clean(value):
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def _plot(path, trials, report) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    from tissue_sim_ros.analysis.compare.measured_motion import measured_motion
    speeds = report['speeds'] or [{'speed_mm_s': None}]
    fig, axes = plt.subplots(1, len(speeds), figsize=(5.5 * len(speeds), 4.2), squeeze=False)
    rows = {row['file']: row for row in report['trials']}
    for ax, group in zip(axes[0], speeds):
        for trial in trials:
            speed = None if trial.speed_m_s is None else round(trial.speed_m_s * 1e3, 6)
            row = rows[Path(trial.file).name]
            if 'problem' in row or (group['speed_mm_s'] is not None and round(group['speed_mm_s'], 6) != speed):
                continue
            motion = measured_motion(trial)
            ax.plot((motion.travel_m - motion.gap_m) * 1e3, trial.axial_force_n, lw=0.6)
            ax.plot([p['depth_mm'] for p in row['punctures']], [p['force_n'] for p in row['punctures']], 'o',
                    mfc='none', color='0.2', ms=5)
            ax.plot([p['depth_mm'] for p in row['pre_drops']], [p['force_n'] for p in row['pre_drops']], 'v',
                    color='C1', ms=6)
        for layer in group.get('layers', []):
            ax.axvspan(layer['depth_min_m'] * 1e3, max(layer['depth_max_m'], layer['depth_min_m'] + 1e-5) * 1e3,
                       color='C0', alpha=0.15)
        speed = group['speed_mm_s']
        ax.set_title(f"{'unknown speed' if speed is None else f'{speed:g} mm/s'}: {group.get('repeats', 0)} "
                     'trial(s); circles punctures, triangles pre-drops, bands layers', fontsize=8)
        ax.set_xlabel('travel since contact [mm]')
        ax.set_ylabel('axial force [N]')
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def _markdown(report) -> str:
    def f(value, digits=3):
        return 'n/a' if value is None else f'{value:.{digits}g}'
    lines = [f"# What {report['data_spec']} reads", '', f"{len(report['trials'])} file(s).", '', '## Units and signs', '']
    lines += [f'- `{section}`: {values}' for section, values in report['units'].items()]
    lines += ['', '## Trials', '', '| file | speed [mm/s] | repeat | samples | rate [Hz] | force [N] | gap [mm] | '
              'depth [mm] | pause [s] | retracts | punctures (depth mm, N) | pre-drops |',
              '|---|---|---|---|---|---|---|---|---|---|---|---|']
    for row in report['trials']:
        if 'problem' in row:
            lines.append(f"| {row['file']} | {f(row['speed_mm_s'])} | {row['repeat']} | {row['samples']} | | | | | | | "
                         f"{row['problem']} | |")
            continue
        punctures = ', '.join(f"{p['depth_mm']:.2f}/{p['force_n']:.2f}" for p in row['punctures']) or 'none'
        lines.append(f"| {row['file']} | {f(row['speed_mm_s'])} | {row['repeat']} | {row['samples']} | "
                     f"{f(row['rate_hz'])} | {f(row['force_min_n'])} to {f(row['force_max_n'])} | {f(row['gap_mm'])} | "
                     f"{f(row['depth_max_mm'])} | {f(row['hold_s'])} | {'yes' if row['retracts'] else 'no'} | "
                     f"{punctures} | {len(row['pre_drops'])} |")
    lines += ['', '## Speeds', '', '| speed [mm/s] | repeats | noise floor NRMSE | layers (depth mm, peak N: mean +- s.d.) |',
              '|---|---|---|---|']
    for group in report['speeds']:
        layers = '; '.join(f"{l['depth_m'] * 1e3:.2f} +- {l['depth_sd_m'] * 1e3:.2f}, {l['force_n']:.2f} +- "
                           f"{l['force_sd_n']:.2f} ({l['found']}/{l['repeats']})" for l in group['layers']) or 'none'
        lines.append(f"| {f(group['speed_mm_s'])} | {group['repeats']} | {f(group['noise_floor_nrmse'])} | {layers} |")
    return '\n'.join(lines) + '\n'


def main(*, data_spec, out='out/inspect', stream=None) -> dict:
    """The ``tissue-sim inspect`` command."""
    from tissue_sim_ros.io.trials.data_spec import DataSpec, load_trials
    stream = sys.stdout if stream is None else stream
    spec = DataSpec.from_file(data_spec)
    trials = load_trials(spec)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    report = _clean(dict(inspect_trials(trials), data_spec=str(data_spec), units=_units(spec)))
    report['outputs'] = {name: str(out / name) for name in ('inspect.csv', 'inspect.json', 'inspect.md', 'inspect.png')}
    (out / 'inspect.json').write_text(json.dumps(report, indent=2))
    (out / 'inspect.md').write_text(_markdown(report))
    columns = ['file', 'speed_mm_s', 'repeat', 'samples', 'rate_hz', 'duration_s', 'force_min_n', 'force_max_n',
               'travel_max_mm', 'contact_s', 'gap_mm', 'depth_max_mm', 'hold_s', 'retracts', 'punctures', 'pre_drops',
               'problem']
    with (out / 'inspect.csv').open('w', newline='') as handle:
        writer = csv.DictWriter(handle, fieldnames=columns, extrasaction='ignore')
        writer.writeheader()
        for row in report['trials']:
            writer.writerow(dict(row, punctures=len(row.get('punctures', [])), pre_drops=len(row.get('pre_drops', []))))
    _plot(out / 'inspect.png', trials, report)
    print(_markdown(report), file=stream, end='')
    print(f"wrote {', '.join(report['outputs'].values())}", file=stream)
    return report
