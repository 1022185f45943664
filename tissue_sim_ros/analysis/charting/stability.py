"""Where each model and integrator stops being stable, and what happens when a run is pushed past
it: ``tissue-sim stability --scene SCENE --out DIR``.

1. **Largest stable step.** For each model (linear, physically non-linear, geometric, full; the
   scene's law and viscosity) and integrator, the scene's own loading is run at a time step
   chosen by the search: the needle, started at the tissue surface, pushed at ``speed`` for
   ``window_s``. Stable means the run ends with no watchdog stop and a finite wrench. Explicit:
   a bisection on log(dt) between 0.5x and 4x the solver's estimate (``critical_time_step``,
   mass scaling included), ``iterations`` halvings. Implicit and quasi-static (no limit in
   theory): the step multiplied by ``IMPLICIT_FACTORS`` until a run fails; the largest tried is a
   lower bound (``limit_reached``). The reason of the first failure above the result is kept:
   a run can fail for the model's sake (a small-strain model inverting elements under the tip)
   or the method's, not only the step's.
2. **Induced failures**, each on the scene's model unless it says otherwise: the step 2x and 4x
   over the estimate, a block compressed to 70 %, sliver elements (mean ratio below 0.05), a
   Poisson ratio of 0.499, a 50 mm/s needle, strong law coefficients. Outcomes: ``caught`` (the
   watchdog's reason, and ``steps_to_detect``: steps from the first step whose energy passed the
   watchdog's growth factor times the energy put in, the onset, to the stop), ``refused`` (at
   load, with the reason), ``survived``, or ``nan`` (a non-finite output that nothing caught: the
   goal is none).

Outputs in DIR: stability.csv, failures.csv, stability.png, stability.md, stability.json; every
finished job is appended to runs.jsonl, which a rerun with the same settings reuses (resume).
"""
from __future__ import annotations

import json
import math
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ['MODELS', 'FAILURE_CASES', 'run_stability', 'main']

#: model name -> the --set list that selects it on the scene (the law and viscosity: the scene's)
MODELS = {
    'linear': ['model.geometric=false', 'model.physical.law=none', 'model.viscosity_mu_pa_s=0',
               'model.viscosity_lambda_pa_s=0'],
    'physical': ['model.geometric=false', 'model.viscosity_mu_pa_s=0', 'model.viscosity_lambda_pa_s=0'],
    'geometric': ['model.geometric=true', 'model.physical.law=none', 'model.viscosity_mu_pa_s=0',
                  'model.viscosity_lambda_pa_s=0'],
    'full': ['model.geometric=true'],
}
INTEGRATORS = ('explicit', 'implicit', 'quasi_static')
IMPLICIT_FACTORS = (1.0, 4.0, 16.0, 64.0)
FAILURE_CASES = ('step_2x', 'step_4x', 'compression_70', 'sliver_elements', 'poisson_0499', 'needle_50mm_s',
                 'strong_law')
#: the loading's start: the needle tip this far above the surface [m]
START_GAP_M = 0.0002
#: the quick preset's mesh (the calibration's coarse scene)
QUICK_MESH = ['mesh.fine_size_m=0.003', 'mesh.divisions=[6,6,5]']
STRONG_LAW = ['model.physical.law=exponential', 'model.physical.mu_amplitude=5.0', 'model.physical.mu_rate=20.0',
              'model.physical.lambda_amplitude=2.0', 'model.physical.lambda_rate=20.0']


# -- one run ---------------------------------------------------------------------------------------
class _Watch:
    """Steps a run one at a time and notes the onset: the first step whose total energy passed
    the watchdog's growth factor times (initial energy + work put in), or was not finite."""

    def __init__(self, simulation):
        self.sim = simulation
        self.onset = None

    def after_step(self):
        sim = self.sim
        if self.onset is not None:
            return
        total = sim.kinetic_energy + sim.model.strain_energy(sim.displacement)[0]
        budget = (sim.reference_energy or 0.0) + max(sim.input_work, 0.0)
        if not (math.isfinite(total) and total <= sim.energy_growth_factor * budget + sim.energy_floor):
            self.onset = sim.step_count


def _needle_run(scene, duration_s, speed, watch):
    """Push the scene's needle along its axis at ``speed`` [m/s] for ``duration_s``, one step at
    a time so that ``watch`` sees each. Returns the wrench forces seen (k, 3)."""
    start, axis = scene.needle_pose[0].copy(), scene.needle.axis.copy()
    orientation = scene.needle_pose[1].copy()
    forces = []
    while scene.time < duration_s:
        dt = scene.dt
        scene.advance(dt, start + speed * min(scene.target_time + dt, duration_s) * axis, orientation,
                      max_steps=1)
        watch.after_step()
        forces.append(scene.reaction_wrench()[0])
    return np.array(forces)


def _scene(scene_file, sets):
    from tissue_sim_ros.engine.scene.scene import Scene
    return Scene.from_file(scene_file, sets=sets, values={'needle.start_gap_m': START_GAP_M})


def _stable_at(scene, dt, window_s, speed):
    """(stable, reason): the loading at time step ``dt`` from rest."""
    from tissue_sim_ros.analysis.insertion import run_insertion
    from tissue_sim_ros.errors import SimulationDiverged
    scene.reset()
    scene.simulation.dt = dt
    try:
        forces = run_insertion(scene, speed, speed * window_s, retract=False).force
    except SimulationDiverged as exc:
        return False, exc.reason
    if not np.isfinite(forces).all():
        return False, 'non-finite wrench'
    return True, ''


def bisect_job(job: dict) -> dict:
    """The largest stable step of one model and integrator (module docstring, item 1)."""
    t0 = time.perf_counter()
    sets = list(job['sets']) + MODELS[job['model']] + [f"solver.integrator={job['integrator']}"]
    scene = _scene(job['scene_file'], sets)
    estimate = scene.simulation.critical_time_step()
    window, speed = job['window_s'], job['speed']
    trials, reasons = [], {}

    def trial(factor):
        ok, reason = _stable_at(scene, factor * estimate, window, speed)
        trials.append((factor, ok))
        if reason:
            reasons[factor] = reason
        return ok

    if job['integrator'] == 'explicit':
        lo, hi = 0.5, 4.0
        if trial(hi):
            best, limit_reached = hi, True
        elif not trial(lo):
            best, limit_reached = 0.0, False       # unstable at half the estimate: the reason says why
        else:
            for _ in range(job['iterations']):
                mid = math.sqrt(lo * hi)
                lo, hi = (mid, hi) if trial(mid) else (lo, mid)
            best, limit_reached = lo, False
    else:
        best, limit_reached = 0.0, True
        for factor in IMPLICIT_FACTORS:
            if not trial(factor):
                limit_reached = False
                break
            best = factor
    failed_above = [f for f, ok in trials if not ok and f > best]
    return dict(key=job['key'], kind='bisect', model=job['model'], integrator=job['integrator'],
                tetrahedra=int(scene.mesh.n_elements), estimated_dt_s=estimate,
                measured_max_dt_s=best * estimate, ratio=best, limit_reached=limit_reached,
                trials=[[f, bool(ok)] for f, ok in trials],
                reason=reasons[min(failed_above)] if failed_above else '', wall_s=time.perf_counter() - t0)


# -- induced failures --------------------------------------------------------------------------
def _with_slivers(mesh):
    """The mesh with its most central node moved toward the opposite face of one of its elements
    until that element's mean ratio is below 0.05 (a sliver), every element still positive."""
    import tissue_sim_ros as ts
    x = mesh.rest_positions
    centre = int(np.argmin(np.linalg.norm(x - x.mean(axis=0), axis=1)))
    element = int(np.flatnonzero((mesh.tetrahedra == centre).any(axis=1))[0])
    face = x[[n for n in mesh.tetrahedra[element] if n != centre]]
    normal = np.cross(face[1] - face[0], face[2] - face[0])
    normal /= np.linalg.norm(normal)
    distance = float(np.dot(face[0] - x[centre], normal))       # signed: along normal to the plane
    for fraction in np.linspace(0.9, 0.999, 100):
        moved = x.copy()
        moved[centre] += fraction * distance * normal
        sliver = ts.make_mesh(moved, mesh.tetrahedra, fix_orientation=False)
        if sliver.mean_ratio()[element] < 0.05:
            return sliver
    raise RuntimeError('no sliver below a mean ratio of 0.05')


def failure_job(job: dict) -> dict:
    """One induced failure (module docstring, item 2)."""
    from tissue_sim_ros.errors import SceneError, SimulationDiverged
    t0 = time.perf_counter()
    case, sets, speed, window = job['case'], list(job['sets']), job['speed'], job['window_s']
    row = dict(key=job['key'], kind='failure', case=case, model='full', integrator='explicit',
               outcome='survived', steps_to_detect='', reason='', steps=0, detail='')
    watch = None
    scene = _scene(job['scene_file'], sets)       # the scene as given loads (else: not this case's doing)
    if case == 'poisson_0499':
        sets += [f'regions[{k}].poisson_ratio=0.499' for k in range(len(scene.spec['regions']))]
    if case == 'strong_law':
        sets += STRONG_LAW
    try:
        if case in ('poisson_0499', 'strong_law'):
            scene = _scene(job['scene_file'], sets)
        if case in ('compression_70', 'sliver_elements'):
            from tissue_sim_ros.analysis.charting.compression import scene_block
            block = scene_block(scene, 0.7 if case == 'compression_70' else 0.2,
                                mesh_filter=_with_slivers if case == 'sliver_elements' else None)
            sim, top, steps = block.simulation, block.plate_nodes, block.steps
            mesh = sim.model.mesh
            row['detail'] = (f'block of {mesh.n_elements} tetrahedra, smallest mean ratio at rest '
                             f'{mesh.mean_ratio().min():.3g}, dt {sim.dt:.3g} s')
            watch = _Watch(sim)
            outputs = []
            for _ in range(steps):
                sim.step(1)
                watch.after_step()
                outputs.append(sim.reaction_force(top))
            deformed = mesh.mean_ratio(mesh.rest_positions + sim.displacement).min()
            row['detail'] += f', smallest mean ratio compressed {deformed:.3g}'
        else:
            sim = scene.simulation
            if case in ('step_2x', 'step_4x'):
                sim.dt = (2.0 if case == 'step_2x' else 4.0) * sim.critical_time_step()
            if case == 'needle_50mm_s':
                speed, window = 0.05, 0.4
            row['detail'] = f'dt {sim.dt:.3g} s, critical {sim.critical_time_step():.3g} s'
            watch = _Watch(sim)
            outputs = _needle_run(scene, window, speed, watch)
        row['steps'] = sim.step_count
        if not np.isfinite(np.asarray(outputs, dtype=float)).all():
            row.update(outcome='nan', reason='a non-finite output that the watchdog did not catch')
    except SimulationDiverged as exc:
        onset = exc.step if watch is None or watch.onset is None else watch.onset
        row.update(outcome='caught', reason=exc.reason, steps=exc.step, steps_to_detect=max(0, exc.step - onset))
    except (SceneError, ValueError) as exc:
        row.update(outcome='refused', reason=str(exc))
    row['wall_s'] = time.perf_counter() - t0
    return row


def _run_job(job: dict) -> dict:
    return bisect_job(job) if job['kind'] == 'bisect' else failure_job(job)


# -- the study ---------------------------------------------------------------------------------
def jobs_for(scene_file, sets, *, quick, speed, models=tuple(MODELS), integrators=INTEGRATORS,
             cases=FAILURE_CASES) -> list[dict]:
    sets = list(sets) + (QUICK_MESH if quick else [])
    window = 0.5 if quick else 1.0
    common = dict(scene_file=None if scene_file is None else str(scene_file), sets=sets, speed=speed,
                  window_s=window)
    jobs = [dict(common, kind='bisect', model=m, integrator=i, iterations=5 if quick else 7)
            for m in models for i in integrators]
    jobs += [dict(common, kind='failure', case=c) for c in cases]
    for job in jobs:
        job['key'] = json.dumps({k: v for k, v in job.items() if k != 'key'}, sort_keys=True)
    return jobs


def run_stability(scene_file=None, sets=(), *, quick=False, speed=0.005, out='out', workers=None,
                  scheduler=None, models=tuple(MODELS), integrators=INTEGRATORS, cases=FAILURE_CASES,
                  quiet=False) -> dict:
    """Run the study (module docstring) and write its outputs into ``out``; returns the report."""
    from tissue_sim_ros.analysis.jobs import run_logged
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    jobs = jobs_for(scene_file, sets, quick=quick, speed=speed, models=models, integrators=integrators,
                    cases=cases)
    t0 = time.perf_counter()
    rows = run_logged(_run_job, jobs, out / 'runs.jsonl', workers=workers, scheduler=scheduler,
                      label='stability runs', quiet=quiet)
    report = dict(scene=str(scene_file) if scene_file else 'packaged liver sample', sets=list(sets),
                  quick=quick, speed_m_s=speed, window_s=jobs[0]['window_s'] if jobs else None,
                  wall_s=time.perf_counter() - t0,
                  stability=[r for r in rows if r['kind'] == 'bisect'],
                  failures=[r for r in rows if r['kind'] == 'failure'])
    _write_outputs(out, report)
    return report


def _write_outputs(out: Path, report: dict) -> None:
    import csv
    with (out / 'stability.csv').open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['model', 'integrator', 'tetrahedra', 'estimated_dt_s', 'measured_max_dt_s', 'ratio',
                    'limit_reached', 'failure_above'])
        for r in report['stability']:
            w.writerow([r['model'], r['integrator'], r['tetrahedra'], f"{r['estimated_dt_s']:.6g}",
                        f"{r['measured_max_dt_s']:.6g}", f"{r['ratio']:.4g}", r['limit_reached'], r['reason']])
    with (out / 'failures.csv').open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(['case', 'model', 'integrator', 'outcome', 'steps_to_detect', 'reason', 'steps', 'detail'])
        for r in report['failures']:
            w.writerow([r['case'], r['model'], r['integrator'], r['outcome'], r['steps_to_detect'], r['reason'],
                        r['steps'], r['detail']])
    (out / 'stability.json').write_text(json.dumps(report, indent=1))
    _plot(out / 'stability.png', report)
    (out / 'stability.md').write_text(_markdown(report))


def _markdown(report: dict) -> str:
    explicit = [r for r in report['stability'] if r['integrator'] == 'explicit']
    within = [r for r in explicit if not r['limit_reached'] and abs(r['ratio'] - 1.0) <= 0.25]
    lines = [f"# Stability: {report['scene']}", '',
             f"Loading: the needle from the surface at {report['speed_m_s'] * 1e3:g} mm/s for "
             f"{report['window_s']:g} s{' (quick: coarse mesh)' if report['quick'] else ''}; "
             f"{report['wall_s']:.0f} s of wall time.", '',
             '| model | integrator | estimated dt [s] | measured largest stable dt [s] | ratio | what failed above it |',
             '|---|---|---|---|---|---|']
    for r in report['stability']:
        bound = '>= ' if r['limit_reached'] else ''
        lines.append(f"| {r['model']} | {r['integrator']} | {r['estimated_dt_s']:.4g} | "
                     f"{bound}{r['measured_max_dt_s']:.4g} | {bound}{r['ratio']:.3g} | {r['reason']} |")
    lines += ['', f'Explicit models with the measured step within 25 % of the estimate: {len(within)} of '
                  f'{len(explicit)}.', '', '| case | outcome | steps to detect | reason |', '|---|---|---|---|']
    for r in report['failures']:
        lines.append(f"| {r['case']} | {r['outcome']} | {r['steps_to_detect']} | {r['reason'] or r['detail']} |")
    return '\n'.join(lines) + '\n'


def _plot(path: Path, report: dict) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.8), gridspec_kw=dict(width_ratios=[1.2, 1]))
    rows = report['stability']
    labels = [f"{r['model']}\n{r['integrator'].replace('_', '-')}" for r in rows]
    x = np.arange(len(rows))
    left.bar(x - 0.2, [r['estimated_dt_s'] for r in rows], 0.4, label='estimated critical step')
    left.bar(x + 0.2, [r['measured_max_dt_s'] for r in rows], 0.4,
             color=['C1' if not r['limit_reached'] else 'C2' for r in rows],
             label='measured largest stable (green: search limit, a lower bound)')
    left.set_yscale('log')
    left.set_xticks(x, labels, fontsize=7, rotation=40, ha='right')
    left.set_ylabel('time step [s]')
    left.legend(fontsize=7)
    left.set_title('time step: estimated and measured')
    colours = dict(survived='#8fd18f', caught='#f4c06b', refused='#c8c8c8', nan='#e36a6a')
    failures = report['failures']
    for k, r in enumerate(failures):
        right.add_patch(plt.Rectangle((0, len(failures) - 1 - k), 1, 1, facecolor=colours[r['outcome']],
                                      edgecolor='white'))
        text = r['outcome'] + (f", {r['steps_to_detect']} steps" if r['outcome'] == 'caught' else '')
        right.text(0.02, len(failures) - 0.5 - k, f"{r['case']}: {text}", va='center', fontsize=8)
        right.text(0.02, len(failures) - 0.8 - k, (r['reason'] or r['detail'])[:80], va='center', fontsize=6)
    right.set_xlim(0, 1)
    right.set_ylim(0, max(1, len(failures)))
    right.axis('off')
    right.set_title('induced failures')
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main(scene_file=None, sets=(), quick=False, speed_mm_s=5.0, out='out', workers=None, scheduler=None) -> int:
    report = run_stability(scene_file, sets, quick=quick, speed=speed_mm_s * 1e-3, out=out, workers=workers,
                           scheduler=scheduler)
    print((Path(out) / 'stability.md').read_text())
    print(f'wrote {out}/stability.csv, failures.csv, stability.png, stability.md, stability.json', file=sys.stderr)
    bad = [r['case'] for r in report['failures'] if r['outcome'] == 'nan']
    return 1 if bad else 0
