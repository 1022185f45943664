"""The least model a scene needs: ``tissue-sim recommend --scene SCENE
--tolerance 0.05 [--rate-hz 50] --out DIR``.

Runs the chart's grid (:mod:`.chart`, into DIR/chart, resumable; ``--quick`` for its preset) and
picks the cheapest configuration whose force error against the chart's reference is within the
tolerance and whose cost lets the node keep real time on this machine:

    cost_s_per_sim_s + rate_hz * TICK_OVERHEAD_S <= CORE_BUDGET

(one core's worth for the physics on one thread, CORE_BUDGET of it, less the node's own work per
tick, measured by node-bench: the main thread's 6 % of a core at 50 Hz, 1.2 ms a tick). The
non-linearity threshold, the mesh, the mass scaling and the integrator are chosen with the model,
so the threshold follows from the tolerance instead of being set by hand. The chosen scene is run
again from the written file and its error measured afresh against the same reference.

Outputs in DIR: recommended.yaml (a complete scene every command accepts), recommend.json
(``candidates``: configurations evaluated, ``predicted_error`` (the chart's), ``measured_error``
(afresh), ``cost_s_per_sim_s``, ``overrides``, and what was asked), recommend.csv (every
configuration with its verdict), recommend.png (the chart with the tolerance and the choice),
recommend.md.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.charting.chart import TICK_OVERHEAD_S   # the node's own work per tick

__all__ = ['TICK_OVERHEAD_S', 'CORE_BUDGET', 'auto_spec', 'choose', 'recommend', 'main']

CORE_BUDGET = 0.8


def choose(rows: list[dict], tolerance: float, rate_hz: float, budget: float = CORE_BUDGET) -> tuple[dict, dict]:
    """(the chosen row, verdicts): the cheapest finished row within ``tolerance`` that keeps real
    time at ``rate_hz``; failing that, the most accurate one that keeps real time; failing that,
    the cheapest within tolerance. Verdicts: per row index, (within tolerance, keeps real time)."""
    verdicts = {}
    for k, r in enumerate(rows):
        if r.get('failure') or r.get('error') is None:
            continue
        verdicts[k] = (r['error'] <= tolerance,
                       r['cost_s_per_sim_s'] + rate_hz * TICK_OVERHEAD_S <= budget)
    both = [k for k, (ok, fast) in verdicts.items() if ok and fast]
    fast = [k for k, (_, f) in verdicts.items() if f]
    accurate = [k for k, (ok, _) in verdicts.items() if ok]
    if both:
        k = min(both, key=lambda i: rows[i]['cost_s_per_sim_s'])
    elif fast:
        k = min(fast, key=lambda i: rows[i]['error'])
    elif accurate:
        k = min(accurate, key=lambda i: rows[i]['cost_s_per_sim_s'])
    else:
        raise RuntimeError('no configuration of the chart finished')
    return rows[k], verdicts


def recommend(scene_file=None, sets=(), *, tolerance=0.05, rate_hz=50.0, quick=False, speed=0.005, travel=None,
              out='out', workers=None, scheduler=None, jobs=None, quiet=False, budget=CORE_BUDGET,
              reference_selective=1.0, row_limit_s=None) -> dict:
    """The study (module docstring); returns recommend.json's content. ``jobs``: a subset of the
    chart's; ``budget``: the share of a core the physics may take (CORE_BUDGET); ``row_limit_s``:
    the chart's (:func:`.chart.jobs_for`)."""
    from tissue_sim_ros.analysis.charting import chart
    from tissue_sim_ros.engine.scene.keys import override_text
    from tissue_sim_ros.engine.scene.scene import Scene, scene_yaml
    if not (np.isfinite(tolerance) and tolerance > 0):
        raise ValueError(f'tolerance = {tolerance!r}: expected a force NRMSE > 0 (e.g. 0.05)')
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise ValueError(f'rate_hz = {rate_hz!r}: expected a rate > 0 Hz')
    out = Path(out)
    report = chart.run_chart(scene_file, sets, quick=quick, speed=speed, travel=travel, out=out / 'chart',
                             workers=workers, scheduler=scheduler, jobs=jobs, quiet=quiet,
                             reference_selective=reference_selective, row_limit_s=row_limit_s)
    rows = [r for r in report['rows'] if r['task'] == 'insertion']
    chosen, verdicts = choose(rows, tolerance, rate_hz, budget)
    base = Scene.from_file(scene_file, sets=list(sets))
    spec = Scene.from_file(scene_file, sets=list(sets), values=chosen['values']).spec
    overrides = [override_text(k, v) for k, v in chosen['values'].items()]
    header = [f'The least model within a force NRMSE of {tolerance:g} at {rate_hz:g} Hz: tissue-sim recommend',
              f"({chosen['model']}, {chosen['mesh']} mesh, {chosen['integrator']}, mass scaling "
              f"{chosen['mass_scaling']:g}; predicted error {chosen['error']:.4f}, cost "
              f"{chosen['cost_s_per_sim_s']:.3g} s per simulated s).",
              f"Starting scene: {scene_file or 'the packaged default'}"
              + (f" with {' '.join('--set ' + s for s in sets)}" if sets else ''),
              f"Changes: {' '.join('--set ' + s for s in overrides) or 'none'}"]
    out.mkdir(parents=True, exist_ok=True)
    path = out / 'recommended.yaml'
    path.write_text(scene_yaml(spec, base.base_dir, header))
    # the chosen scene afresh, from the file, against the chart's reference
    fresh = chart.simulate_job(chart.make_job(dict(model=chosen['model'], mesh=chosen['mesh'],
                                                   integrator=chosen['integrator'], reference=False, values={}),
                                              path, speed=speed, travel=travel))
    reference = chart.read_reference(out / 'chart')
    measured = chart.force_nrmse(fresh['axial_force'], reference) if not fresh.get('failure') else None
    result = dict(tolerance=tolerance, rate_hz=rate_hz, candidates=len(rows),
                  within_tolerance=sum(ok for ok, _ in verdicts.values()),
                  real_time=sum(fast for _, fast in verdicts.values()),
                  tolerance_met=chosen['error'] <= tolerance,
                  keeps_real_time=chosen['cost_s_per_sim_s'] + rate_hz * TICK_OVERHEAD_S <= budget,
                  predicted_error=chosen['error'], measured_error=measured,
                  cost_s_per_sim_s=chosen['cost_s_per_sim_s'], overrides=overrides,
                  chosen={k: chosen[k] for k in ('model', 'mesh', 'integrator', 'tetrahedra', 'time_step_s',
                                                 'mass_scaling', 'peak_force_error', 'puncture_depth_error_mm')},
                  rule=f'cost_s_per_sim_s + rate_hz x {TICK_OVERHEAD_S:g} s <= {budget:g}; the cheapest '
                       'within tolerance',
                  error_metric=report['error_metric'], scene=report['scene'], sets=list(sets))
    (out / 'recommend.json').write_text(json.dumps(result, indent=1))
    _write_table(out / 'recommend.csv', rows, verdicts, chosen)
    _plot(out / 'recommend.png', rows, chosen, tolerance, rate_hz, budget)
    (out / 'recommend.md').write_text(_markdown(result))
    return result


def auto_spec(spec: dict, base_dir='.', *, quiet=False) -> dict:
    """The scene keys ``model: auto`` stands for: ``spec`` (auto on) with the recommendation's
    choices, from the per-user cache (``recommendations/<hash of the keys>.yaml``), else found now
    by the quick chart (minutes, said on stderr) and cached. The recommendation is for this
    machine: its costs decided it."""
    import yaml

    from tissue_sim_ros.engine.scene.scene import scene_yaml
    from tissue_sim_ros.system.user_cache import scene_cache_entry, write_whole
    tolerance = spec['model']['auto_tolerance']
    base = json.loads(json.dumps(spec))
    base['model']['auto'] = False
    text = scene_yaml(base, base_dir)
    where, key = scene_cache_entry('recommendations', text)
    cache = Path(where)
    cached = cache / f'{key}.yaml'
    if cached.exists():
        return yaml.safe_load(cached.read_text())
    cache.mkdir(parents=True, exist_ok=True)
    scene_file = cache / f'{key}-scene.yaml'
    scene_file.write_text(text)
    if not quiet:
        print(f'tissue_sim_ros: model: auto: finding the least model within {tolerance:g} for this scene '
              f'(the quick chart, a few minutes, once; cached in {cache})', file=sys.stderr, flush=True)
    recommend(scene_file, (), tolerance=tolerance, quick=True, out=cache / f'{key}-study', quiet=quiet)
    chosen = yaml.safe_load((cache / f'{key}-study' / 'recommended.yaml').read_text())
    write_whole(cached, yaml.safe_dump(chosen, sort_keys=False))
    return chosen


def _write_table(path: Path, rows, verdicts, chosen) -> None:
    import csv
    with path.open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['model', 'mesh', 'integrator', 'mass_scaling', 'cost_s_per_sim_s', 'error', 'within_tolerance',
                    'keeps_real_time', 'chosen', 'failure'])
        for k, r in enumerate(rows):
            ok, fast = verdicts.get(k, ('', ''))
            w.writerow([r['model'], r['mesh'], r['integrator'], r.get('mass_scaling', ''),
                        '' if r.get('cost_s_per_sim_s') is None else f"{r['cost_s_per_sim_s']:.6g}",
                        '' if r.get('error') is None else f"{r['error']:.6g}", ok, fast, r is chosen,
                        r.get('failure', '')])


def _plot(path: Path, rows, chosen, tolerance, rate_hz, budget) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, ax = plt.subplots(figsize=(7, 5))
    done = [r for r in rows if not r.get('failure') and not r['reference']]
    ax.scatter([r['cost_s_per_sim_s'] for r in done], [max(r['error'], 1e-5) for r in done], color='C0', s=24,
               label='configurations (the chart)')
    ax.axhline(tolerance, color='C2', ls='--', label=f'tolerance {tolerance:g}')
    if np.isfinite(budget):
        ax.axvline(budget - rate_hz * TICK_OVERHEAD_S, color='C3', ls='--', label=f'real time at {rate_hz:g} Hz')
    ax.scatter([chosen['cost_s_per_sim_s']], [max(chosen['error'], 1e-5)], s=160, facecolor='none',
               edgecolor='black', lw=2, label=f"chosen: {chosen['model']}, {chosen['mesh']}, {chosen['integrator']}")
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.set_xlabel('cost [wall s per simulated s, one thread]')
    ax.set_ylabel('force NRMSE against the reference')
    ax.set_title('the least model within the tolerance')
    ax.grid(alpha=0.3, which='both')
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _markdown(r: dict) -> str:
    c = r['chosen']
    measured = 'failed' if r['measured_error'] is None else f"{r['measured_error']:.4f}"
    lines = [f"# Recommendation: {r['scene']}", '',
             f"Tolerance {r['tolerance']:g} ({r['error_metric']}), {r['rate_hz']:g} Hz. {r['candidates']} "
             f"configurations evaluated, {r['within_tolerance']} within the tolerance, {r['real_time']} fast "
             f"enough ({r['rule']}).", '',
             f"Chosen: **{c['model']}**, {c['mesh']} mesh ({c['tetrahedra']} tetrahedra), {c['integrator']}, "
             f"time step {c['time_step_s']:.3g} s, mass scaling {c['mass_scaling']:g}: predicted error "
             f"{r['predicted_error']:.4f}, measured afresh {measured}, cost {r['cost_s_per_sim_s']:.3g} s per "
             'simulated s.', '',
             f"Changes: `{' '.join('--set ' + s for s in r['overrides']) or 'none'}`"]
    if not r['tolerance_met']:
        lines += ['', '**No configuration fast enough is within the tolerance**: this is the most accurate one '
                      'that keeps real time.']
    if not r['keeps_real_time']:
        lines += ['', '**This configuration does not keep real time on this machine.**']
    return '\n'.join(lines) + '\n'


def main(scene_file=None, sets=(), tolerance=0.05, rate_hz=50.0, quick=False, speed_mm_s=5.0, travel_mm=None,
         out='out', workers=None, scheduler=None, reference_selective=1.0, row_limit_min=None) -> int:
    recommend(scene_file, sets, tolerance=tolerance, rate_hz=rate_hz, quick=quick, speed=speed_mm_s * 1e-3,
              travel=None if travel_mm is None else travel_mm * 1e-3, out=out, workers=workers, scheduler=scheduler,
              reference_selective=reference_selective,
              row_limit_s=None if row_limit_min is None else 60.0 * row_limit_min)
    print((Path(out) / 'recommend.md').read_text())
    print(f'wrote {out}/recommended.yaml, recommend.json, recommend.csv, recommend.png, recommend.md', file=sys.stderr)
    return 0
