"""The mass scaling's estimated inertia error against the error it really adds::

    tissue-sim bench inertia [--scene S] [--set KEY=VALUE]...
        [--speed-mm-s 5] [--travel-mm 17] [--scalings 25 100 400 1600] [--jobs N] --out DIR

An insertion like the chart's (from 1 mm above the surface, in at constant speed; 17 mm here, where
the chart goes 12), once per mass scaling and once without (the reference: the same mesh, model and
step rule, only the masses differ, so the difference is what the scaling adds). Each scaled run's
force NRMSE against the reference is set beside the estimate the run printed
(engine.solver.inertia_estimate), and the reference's first puncture beside the run's. The runs are
the chart's jobs (chart.simulate_job, in parallel, resumable from DIR/runs.jsonl); DIR gets the
chart's outputs for them (chart.csv with ``error`` and ``inertia_error_estimate`` per row) and
inertia.csv, inertia.png (estimate against measured), inertia.md and inertia.json. The reference is
the costly run: without mass scaling the default scene's viscosity holds the step at 7.6 us, about 4
minutes of one core for the 3.4 s of the default task.
"""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

from tissue_sim_ros.errors import InputError

__all__ = ['SCALINGS', 'run_bench', 'main']

SCALINGS = (25.0, 100.0, 400.0, 1600.0)


def _config(scaling: float) -> dict:
    return dict(task='insertion', model='scene', mesh='scene', integrator='explicit', mass_scaling=scaling,
                reference=scaling == 1.0, values={'solver.mass_scaling': scaling})


def run_bench(scene_file=None, sets=(), *, scalings=SCALINGS, speed=0.005, travel=0.017, out='out',
              workers=None, quiet=False) -> dict:
    """Run the reference and the scaled insertions; write and return the comparison."""
    from tissue_sim_ros.analysis.charting.chart import make_job, run_chart
    out = Path(out)
    jobs = [make_job(_config(s), scene_file, sets, speed=speed, travel=travel) for s in (1.0,) + tuple(scalings)]
    report = run_chart(scene_file, sets, speed=speed, travel=travel, out=out, workers=workers, jobs=jobs, quiet=quiet)
    reference = next(r for r in report['rows'] if r['reference'])
    rows = []
    for r in report['rows']:
        if r['reference']:
            continue
        shift = r.get('puncture_depth_error_mm')
        rows.append(dict(mass_scaling=r['mass_scaling'], time_step_s=r.get('time_step_s'), failure=r.get('failure', ''),
                         measured_error=r.get('error'), estimated_error=r.get('inertia_error_estimate'),
                         ratio=(r['inertia_error_estimate'] / r['error']
                                if r.get('error') and r.get('inertia_error_estimate') is not None else None),
                         puncture_shift_mm=shift,
                         puncture_shift_s=None if shift is None else shift * 1e-3 / speed))
    result = dict(scene=report['scene'], sets=list(sets), speed_m_s=speed, travel_m=travel,
                  reference_time_step_s=reference.get('time_step_s'),
                  reference_cost_s_per_sim_s=reference.get('cost_s_per_sim_s'),
                  wall_s=report['wall_s'], rows=rows)
    _write(out, result)
    return result


def _write(out: Path, result: dict) -> None:
    columns = ('mass_scaling', 'time_step_s', 'measured_error', 'estimated_error', 'ratio', 'puncture_shift_mm',
               'puncture_shift_s', 'failure')
    with (out / 'inertia.csv').open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(columns)
        for r in result['rows']:
            w.writerow(['' if r[c] is None else (f'{r[c]:.6g}' if isinstance(r[c], float) else r[c]) for c in columns])
    (out / 'inertia.json').write_text(json.dumps(result, indent=1))
    (out / 'inertia.md').write_text(_markdown(result))
    _plot(out / 'inertia.png', result)


def _markdown(result: dict) -> str:
    lines = [f"# Mass scaling: estimated against measured error ({result['scene']})", '',
             f"Insertion from 1 mm above the surface, {result['travel_m'] * 1e3:g} mm at {result['speed_m_s'] * 1e3:g} "
             f"mm/s; measured = force NRMSE against the same scene without mass scaling (step "
             f"{result['reference_time_step_s'] * 1e6:.1f} us). {result['wall_s']:.0f} s of wall time.", '',
             '| mass scaling | dt [ms] | measured | estimated | estimated / measured | puncture moved [mm] |',
             '|---|---|---|---|---|---|']
    for r in result['rows']:
        if r['failure']:
            lines.append(f"| {r['mass_scaling']:g} | | failed: {r['failure']} | | | |")
            continue
        ratio = '' if r['ratio'] is None else f"{r['ratio']:.2f}"
        shift = '' if r['puncture_shift_mm'] is None else f"{r['puncture_shift_mm']:+.2f}"
        estimate = '' if r['estimated_error'] is None else f"{r['estimated_error']:.4f}"
        lines.append(f"| {r['mass_scaling']:g} | {r['time_step_s'] * 1e3:.3f} | {r['measured_error']:.4f} | {estimate} "
                     f"| {ratio} | {shift} |")
    return '\n'.join(lines) + '\n'


def _plot(path: Path, result: dict) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    rows = [r for r in result['rows'] if not r['failure'] and r['estimated_error'] and r['measured_error']]
    fig, ax = plt.subplots(figsize=(5.5, 5))
    if rows:
        measured = [r['measured_error'] for r in rows]
        ax.scatter(measured, [r['estimated_error'] for r in rows], color='C0', zorder=3)
        for r in rows:
            ax.annotate(f"{r['mass_scaling']:g}x", (r['measured_error'], r['estimated_error']), fontsize=8,
                        textcoords='offset points', xytext=(4, -10))
        low, high = min(measured) / 2, max(measured) * 2
        ax.plot([low, high], [low, high], color='black', lw=1, label='estimate = measured')
        ax.fill_between([low, high], [low / 1.25, high / 1.25], [low * 1.25, high * 1.25], color='grey', alpha=0.2,
                        label='within 25 %')
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.set_xlabel('measured force NRMSE (against no mass scaling)')
    ax.set_ylabel('estimated by the run (inertia_error_estimate)')
    ax.set_title('error that mass scaling adds', fontsize=10)
    ax.grid(alpha=0.3, which='both')
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(*, scene=None, sets=(), speed_mm_s=5.0, travel_mm=17.0, scalings=SCALINGS, jobs=None,
         out='out/bench_inertia') -> dict:
    """``tissue-sim bench inertia``: run the benchmark, print its markdown."""
    if any(not s > 1.0 for s in scalings):
        raise InputError(f'--scalings {list(scalings)}: each must be above 1 (1 is the reference, always run)')
    result = run_bench(scene, sets, scalings=scalings, speed=speed_mm_s * 1e-3, travel=travel_mm * 1e-3,
                       out=out, workers=jobs)
    print((Path(out) / 'inertia.md').read_text())
    print(f'wrote {out}/inertia.csv, inertia.png, inertia.md, inertia.json (and the chart\'s outputs)',
          file=sys.stderr)
    return result


if __name__ == '__main__':
    sys.exit('this benchmark runs as: tissue-sim bench inertia (tissue-sim bench --help)')
