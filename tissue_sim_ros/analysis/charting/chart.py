"""Speed against accuracy: ``tissue-sim chart --scene SCENE --out DIR``.

Every configuration runs the scene's insertion task: the insertion the scene is for when it
plans one (``needle.planned_travel_m`` from its own start pose, along its needle's axis: an
organ scene's path to its tumour), else the needle from 1 mm above the surface for ``travel``
(12 mm: through the first layer's puncture on the default scene); ``speed`` along the axis,
sampled every 20 ms, no retraction (:func:`insertion_task`). A configuration is the scene plus
``--set`` overrides along four axes:

* the model (linear, physically non-linear, geometric, full; the full model without viscosity,
  with other non-linearity thresholds, and with its element pass in float32), on each mesh
  level;
* the mesh refinement (``mesh.fine_size_m`` and ``mesh.divisions`` scaled: coarse, medium, the
  scene's, and in the full preset a finer one); a mesh file has no such keys: its scene's mesh
  is the one level (chart one mesh file against another with ``--set mesh.file=...``, meshes
  that ``tissue-sim mesh --cell-mm`` makes);
* the time step through the mass scaling (the full model on the scene's mesh, and the cheaper
  non-linear models at two smaller scalings), through the selective mass scaling (the full model
  at 2, 4 and 8: mass only where the shortest elements set the step), and the mass-proportional
  damping that the mass scaling multiplies (the full model at 400 and 1600 with lower damping
  rates);
* the integrator (implicit and quasi-static at a multiple of the explicit step; the full preset
  adds backward Euler at the explicit step, and at 4x without mass scaling).

**Error** (named ``force_nrmse``): the RMS difference of the axial force from the reference's
over the insertion's ticks, over the reference's force range. The reference is the converged
solution as far as the preset goes: the finest mesh, the full model, explicit, no mass scaling
(its row has error 0 by definition and is marked). ``reference_selective`` R > 1 gives the
reference selective mass scaling R (``solver.selective_mass_scaling``): on a mesher's organ with
viscosity the unscaled step is a Kelvin-Voigt limit of microseconds (0.57 us on the organ
example), and R = 8 lengthens it 61x for 131 % more mass at the nodes of the shortest elements.
That mass is not free: chart.md gives the reference's own estimated inertia error (0.011 on the
organ example, whose mesh is graded along the needle's path). Beside it: the peak force's
relative error and the first puncture's depth error [mm].

A second task, **plate compression**, has an analytic answer: a cube of the scene's material and
model on a frictionless floor, a frictionless plate pressing its top by 0.5 % and held (the
reaction settles); the error is the plate force's relative difference from E A strain (exact for
the linear model on linear tetrahedra; the non-linear models' own departure at 0.5 % strain is a
few 1e-3). It compares the integrators where all of them apply: every model x explicit, implicit
at 10x and quasi-static at 10x the explicit step, on 4^3 and 6^3 cubes (8^3 in the full preset).

**Cost**: wall seconds per simulated second in a worker with one numba thread (the simulation
alone, not the scene's set-up), tet-steps per second, and the share of one core the node would
take at 50 Hz: the cost (the physics at real time) plus TICK_OVERHEAD_S a tick (above 1, one
core cannot keep up).

Outputs in DIR: chart.csv (a row per configuration: ``model``, ``tetrahedra``, ``integrator``,
``time_step_s``, ``cost_s_per_sim_s``, ``error``, ``pareto``, ``reference``, ``overrides`` (the
``--set`` list that reproduces it) and more), chart.png (error against cost, log axes, the
Pareto front, one colour per model), chart.md, chart.json; runs.jsonl makes a rerun resume.
"""
from __future__ import annotations

import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from tissue_sim_ros.engine.scene.keys import override_text

__all__ = ['configurations', 'force_nrmse', 'insertion_task', 'make_job', 'read_reference', 'run_chart', 'simulate_job', 'main']

_NO_VISCOSITY = {'model.viscosity_mu_pa_s': 0.0, 'model.viscosity_lambda_pa_s': 0.0}
#: model name -> scene values (the law, the viscosity and the threshold: the scene's unless set)
MODELS = {
    'linear': {'model.geometric': False, 'model.physical.law': 'none', **_NO_VISCOSITY},
    'physical': {'model.geometric': False, **_NO_VISCOSITY},
    'geometric': {'model.geometric': True, 'model.physical.law': 'none', **_NO_VISCOSITY},
    'full': {'model.geometric': True},
    'full, no viscosity': {'model.geometric': True, **_NO_VISCOSITY},
    'full, threshold 0': {'model.geometric': True, 'model.nonlinearity_threshold': 0.0},
    'full, threshold 0.05': {'model.geometric': True, 'model.nonlinearity_threshold': 0.05},
    'full, threshold 0.1': {'model.geometric': True, 'model.nonlinearity_threshold': 0.1},
    'full, float32': {'model.geometric': True, 'model.precision': 'float32'},
}
#: mesh level -> scene values (the default scene's graded box: near-needle cell, far-field divisions)
MESHES = {
    'coarse': {'mesh.fine_size_m': 0.004, 'mesh.divisions': [5, 5, 4]},
    'medium': {'mesh.fine_size_m': 0.003, 'mesh.divisions': [6, 6, 5]},
    'scene': {},
    'fine': {'mesh.fine_size_m': 0.001, 'mesh.divisions': [12, 12, 10]},
}
MASS_SCALINGS = (25.0, 100.0, 1600.0)
#: cheaper models also run at smaller mass scalings on the scene's mesh: a model's own error and
#: the mass scaling's can cancel at one setting, and the recommendation should see both apart
CROSSED_MODELS = ('physical', 'geometric', 'full, no viscosity')
CROSSED_SCALINGS = (25.0, 100.0)
#: the mass-proportional damping grows with the mass scaling (gamma s m v): at 400 it is most of
#: the scene's error at 50/s (medium mesh: 0.13, 0.026 at 12.5/s, 0.088 at 2/s where the scaled
#: mass oscillates), so the full model also runs at lower damping rates
DAMPINGS = (6.25, 12.5, 25.0)
#: the full model at the scene's mass scaling with mass added only at the nodes of the elements
#: that set the explicit step (``solver.selective_mass_scaling``): on a mesher's organ a few small
#: or flat elements set the whole mesh's step, and this lengthens it for far less mass than the
#: uniform scaling
SELECTIVE_SCALINGS = (2.0, 4.0, 8.0)
#: (integrator, multiple of the scene's explicit step, mass scaling or None for the scene's)
INTEGRATOR_RUNS = (('implicit', 1.0, None), ('implicit', 4.0, None), ('implicit', 4.0, 1.0),
                   ('quasi_static', 4.0, None))
#: the quick preset leaves out the implicit run without mass scaling: beside the reference it is
#: the slowest row (144 s of 309 s on 2 cores), and the quasi-static row, which stays, shows the
#: same error without inertia (0.049 against its 0.052). It leaves out the implicit run at the
#: scene's own step too: that step and those masses are the explicit row's, each step a Newton
#: solve instead of one element pass, so it costs more by construction (on a 27000-element organ
#: the implicit run at 4x the step costs 152 s per simulated second, the explicit row 16)
QUICK_INTEGRATOR_RUNS = tuple(run for run in INTEGRATOR_RUNS if run not in (('implicit', 4.0, 1.0),
                                                                           ('implicit', 1.0, None)))
START_GAP_M = 0.001
#: the travel of a scene that plans no insertion [m]
DEFAULT_TRAVEL_M = 0.012
#: plate compression: (integrator, multiple of the cube's explicit step)
COMPRESSION_INTEGRATORS = (('explicit', 1.0), ('implicit', 10.0), ('quasi_static', 10.0))
COMPRESSION_STRAIN = 0.005
#: the node's own work per tick beside the physics [s]: node-bench's main thread, 6 % of a core at
#: 50 Hz (message building, the executor, recording and diagnostics)
TICK_OVERHEAD_S = 1.2e-3


def _model_family(name: str) -> str:
    return name.split(',')[0]


def insertion_task(scene_file=None, sets=(), travel=None) -> dict:
    """The insertion a chart scores (module docstring): {travel_m, start_gap_m (None: the scene's
    own start pose), planned}. ``travel``: given, it replaces the scene's plan (from 1 mm above
    the surface)."""
    from tissue_sim_ros.engine.scene.scene import read_scene_keys
    planned = read_scene_keys(scene_file, list(sets))[0]['needle']['planned_travel_m']
    if travel is None and planned is not None:
        return dict(travel_m=float(planned), start_gap_m=None, planned=True)
    return dict(travel_m=float(travel if travel is not None else DEFAULT_TRAVEL_M), start_gap_m=START_GAP_M,
                planned=False)


def configurations(scene_dt: float, *, quick: bool, mesh_levels=True, reference_selective=1.0) -> list[dict]:
    """The grid (module docstring) as rows of (name fields, scene values); the first is the reference.
    ``scene_dt``: the scene's explicit step, which the implicit runs multiply; ``mesh_levels``:
    False for a mesh file (the scene's mesh the one level); ``reference_selective``: the
    reference's selective mass scaling (module docstring; 1: none)."""
    selective = {'solver.selective_mass_scaling': float(reference_selective)} if reference_selective > 1 else {}
    levels = (['coarse', 'medium', 'scene'] + ([] if quick else ['fine'])) if mesh_levels else ['scene']
    finest = levels[-1]
    rows = [dict(task='insertion', model='full', mesh=finest, integrator='explicit', mass_scaling=1.0, reference=True,
                 values={**MODELS['full'], **MESHES[finest], 'solver.mass_scaling': 1.0, **selective})]
    for model, model_values in MODELS.items():
        for level in levels:
            rows.append(dict(task='insertion', model=model, mesh=level, integrator='explicit', mass_scaling=None,
                             reference=False, values={**model_values, **MESHES[level]}))
    for model in ('full',) + CROSSED_MODELS:
        for scaling in MASS_SCALINGS if model == 'full' else CROSSED_SCALINGS:
            rows.append(dict(task='insertion', model=model, mesh='scene', integrator='explicit', mass_scaling=scaling,
                             reference=False, values={**MODELS[model], 'solver.mass_scaling': scaling}))
    for selective in SELECTIVE_SCALINGS:
        rows.append(dict(task='insertion', model='full', mesh='scene', integrator='explicit', mass_scaling=None,
                         reference=False,
                         values={**MODELS['full'], 'solver.selective_mass_scaling': selective}))
    for scaling in (400.0, 1600.0):
        for damping in DAMPINGS:
            rows.append(dict(task='insertion', model='full', mesh='scene', integrator='explicit', mass_scaling=scaling,
                             reference=False, values={**MODELS['full'], 'solver.mass_scaling': scaling,
                                                      'solver.damping_per_s': damping}))
    for integrator, multiple, scaling in QUICK_INTEGRATOR_RUNS if quick else INTEGRATOR_RUNS:
        values = {**MODELS['full'], 'solver.integrator': integrator, 'solver.time_step_s': multiple * scene_dt}
        if scaling is not None:
            values['solver.mass_scaling'] = scaling
        rows.append(dict(task='insertion', model='full', mesh='scene', integrator=integrator, mass_scaling=scaling,
                         reference=False, values=values))
    for model in ('linear', 'physical', 'geometric', 'full'):
        for divisions in (4, 6) if quick else (4, 6, 8):
            for integrator, multiple in COMPRESSION_INTEGRATORS:
                rows.append(dict(task='compression', model=model, mesh=f'{divisions}^3 cube', divisions=divisions,
                                 integrator=integrator, step_multiple=multiple, mass_scaling=None, reference=False,
                                 values={**MODELS[model], 'solver.integrator': integrator}))
    return rows


def simulate_job(job: dict) -> dict:
    """One configuration: its task's outputs and cost (module docstring)."""
    if job.get('task', 'insertion') == 'compression':
        return _compression_job(job)
    return _insertion_job(job)


def _compression_job(job: dict) -> dict:
    """The plate compression of the scene's material and model, error against E A strain."""
    from tissue_sim_ros.analysis.charting.compression import scene_block
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.errors import SimulationDiverged
    row = {k: job[k] for k in ('key', 'task', 'model', 'mesh', 'integrator', 'reference')}
    row['values'] = dict(job['values'])
    scene = Scene.from_file(job['scene_file'], sets=job['sets'], values=job['values'])
    explicit = scene_block(scene, COMPRESSION_STRAIN, divisions=job['divisions'], integrator='explicit')
    dt = explicit.simulation.dt * job['step_multiple']
    block = scene_block(scene, COMPRESSION_STRAIN, divisions=job['divisions'], dt=dt)
    sim = block.simulation
    row.update(tetrahedra=int(sim.model.mesh.n_elements), time_step_s=float(sim.dt),
               mass_scaling=float(sim.mass_scaling))
    t0 = time.perf_counter()
    try:
        sim.step(block.steps)
    except SimulationDiverged as exc:
        return dict(row, failure=f'diverged: {exc.reason}')
    wall = time.perf_counter() - t0
    reaction = float(sim.reaction_force(block.plate_nodes)[2])
    return dict(row, failure='', wall_s=wall, sim_time_s=float(sim.time), steps=block.steps,
                cost_s_per_sim_s=wall / sim.time, tet_steps_per_s=sim.model.mesh.n_elements * block.steps / wall,
                error=abs(reaction / block.expected_reaction - 1.0), reaction_n=reaction,
                peak_force_error=None, puncture_depth_error_mm=None)


def _insertion_job(job: dict) -> dict:
    """One configuration's insertion: the axial force per tick, the punctures, and the cost."""
    from tissue_sim_ros.analysis.insertion import run_insertion
    from tissue_sim_ros.engine.scene.scene import Scene
    from tissue_sim_ros.errors import SceneError, SimulationDiverged, WallTimeExceeded
    row = {k: job[k] for k in ('key', 'model', 'mesh', 'integrator', 'reference')}
    row['task'] = 'insertion'
    row['mass_scaling'] = job.get('mass_scaling')
    row['values'] = dict(job['values'])
    task = insertion_task(job['scene_file'], job['sets'], job['travel'])
    gap = {} if task['start_gap_m'] is None else {'needle.start_gap_m': task['start_gap_m']}
    try:
        scene = Scene.from_file(job['scene_file'], sets=job['sets'], values={**job['values'], **gap})
    except (SceneError, ValueError) as exc:
        return dict(row, failure=f'refused: {exc}')
    row.update(tetrahedra=int(scene.mesh.n_elements), time_step_s=float(scene.dt),
               mass_scaling=float(scene.spec['solver']['mass_scaling']),
               damping_per_s=float(scene.spec['solver']['damping_per_s']))
    try:
        result = run_insertion(scene, job['speed'], task['travel_m'], retract=False,
                               wall_limit_s=job.get('wall_limit_s'))
    except SimulationDiverged as exc:
        return dict(row, failure=f'diverged: {exc.reason}')
    except WallTimeExceeded as exc:
        return dict(row, failure=str(exc))
    sim_time = float(result.time[-1])
    row.update(failure='', wall_s=result.wall_time, sim_time_s=sim_time, steps=int(result.steps),
               cost_s_per_sim_s=result.wall_time / sim_time,
               tet_steps_per_s=scene.mesh.n_elements * result.steps / result.wall_time,
               axial_force=result.axial_force.tolist(), inertia_error_estimate=result.inertia_error,
               puncture_depth_m=(result.puncture_events[0]['tip_depth_m'] if result.puncture_events else None))
    return row


def force_nrmse(force, reference) -> float:
    """The chart's error: RMS of (force - reference) over the ticks / the reference's range."""
    force, reference = np.asarray(force, dtype=float), np.asarray(reference, dtype=float)
    span = float(reference.max() - reference.min()) or 1.0
    return float(np.sqrt(np.mean((force - reference) ** 2)) / span)


def read_reference(out) -> np.ndarray:
    """The reference's axial force per tick [N] from a chart's output directory."""
    return np.asarray(json.loads((Path(out) / 'chart.json').read_text())['reference_axial_force_n'])


def _errors(rows: list[dict]) -> None:
    """Each row's errors against the reference row (module docstring), in place."""
    rows = [r for r in rows if r['task'] == 'insertion']
    reference = next(r for r in rows if r['reference'])
    if reference.get('failure'):
        raise RuntimeError(f"the reference configuration failed: {reference['failure']}")
    ref = np.asarray(reference['axial_force'])
    for r in rows:
        if r.get('failure'):
            r.update(error=None, peak_force_error=None, puncture_depth_error_mm=None)
            continue
        r['core_share_at_50hz'] = r['cost_s_per_sim_s'] + 50.0 * TICK_OVERHEAD_S
        force = np.asarray(r['axial_force'])
        r['error'] = force_nrmse(force, ref)
        r['peak_force_error'] = float(force.max() / ref.max() - 1.0)
        both = r['puncture_depth_m'] is not None and reference['puncture_depth_m'] is not None
        r['puncture_depth_error_mm'] = (1e3 * (r['puncture_depth_m'] - reference['puncture_depth_m'])
                                        if both else None)


def _pareto(rows: list[dict]) -> None:
    """pareto = no other finished, non-reference row is at most as costly and as wrong, and
    better in one."""
    for task in {r.get('task', 'insertion') for r in rows}:
        _pareto_of([r for r in rows if r.get('task', 'insertion') == task])


def _pareto_of(rows: list[dict]) -> None:
    candidates = [r for r in rows if not r['reference'] and r.get('error') is not None]
    for r in rows:
        r['pareto'] = r in candidates and not any(
            o is not r and o['cost_s_per_sim_s'] <= r['cost_s_per_sim_s'] and o['error'] <= r['error']
            and (o['cost_s_per_sim_s'] < r['cost_s_per_sim_s'] or o['error'] < r['error']) for o in candidates)


def make_job(config: dict, scene_file=None, sets=(), *, speed=0.005, travel=None) -> dict:
    """A job for simulate_job: a configuration (``model``, ``mesh``, ``integrator``, ``reference``,
    ``values``: {key path: value}) on the scene and task (``travel`` None: :func:`insertion_task`'s)."""
    job = dict(config, scene_file=None if scene_file is None else str(scene_file), sets=list(sets), speed=speed,
               travel=travel)
    job['key'] = json.dumps(job, sort_keys=True)
    return job


def jobs_for(scene_file, sets, *, quick, speed, travel, reference_selective=1.0, row_limit_s=None) -> list[dict]:
    """The grid's jobs on the scene. ``row_limit_s``: the wall time after which an insertion row
    other than the reference stops (its failure says so); outside the job's key, so a chart run
    with a limit resumes one without, and a stopped row stays stopped (delete its line from
    runs.jsonl to run it again)."""
    from tissue_sim_ros.engine.scene.scene import Scene
    scene = Scene.from_file(scene_file, sets=list(sets))
    jobs = [make_job(config, scene_file, sets, speed=speed, travel=travel)
            for config in configurations(scene.dt, quick=quick, mesh_levels=scene.spec['mesh']['generator'] != 'file',
                                         reference_selective=reference_selective)]
    for job in jobs:
        if row_limit_s is not None and not job['reference']:
            job['wall_limit_s'] = float(row_limit_s)
    return jobs


def run_chart(scene_file=None, sets=(), *, quick=False, speed=0.005, travel=None, out='out', workers=None,
              scheduler=None, jobs=None, quiet=False, reference_selective=1.0, row_limit_s=None) -> dict:
    """Run the grid (or ``jobs``, a subset of jobs_for's) and write the outputs; returns the report."""
    from tissue_sim_ros.analysis.jobs import run_logged
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    if jobs is None:
        jobs = jobs_for(scene_file, sets, quick=quick, speed=speed, travel=travel,
                        reference_selective=reference_selective, row_limit_s=row_limit_s)
    # the costly ones first, so the pool's last minutes are not one long run
    order = sorted(range(len(jobs)), key=lambda i: (jobs[i]['mesh'] != 'fine', not jobs[i]['reference'],
                                                    jobs[i].get('task') == 'compression',
                                                    jobs[i]['integrator'] == 'explicit'))
    t0 = time.perf_counter()
    done = run_logged(simulate_job, [jobs[i] for i in order], out / 'runs.jsonl', workers=workers,
                      scheduler=scheduler, label='chart configurations', quiet=quiet)
    rows = [None] * len(jobs)
    for i, row in zip(order, done):
        rows[i] = dict(row)
        rows[i].setdefault('task', 'insertion')
    _errors(rows)
    _pareto(rows)
    report = dict(scene=str(scene_file) if scene_file else 'packaged liver sample', sets=list(sets), quick=quick,
                  task=dict(speed_m_s=speed, tick_s=0.02, **insertion_task(scene_file, sets, travel)),
                  error_metric='force_nrmse: RMS difference of the axial force from the reference over the '
                               "insertion's ticks / the reference's force range",
                  compression_error_metric=f'|plate force / (E A strain) - 1| at {COMPRESSION_STRAIN:g} strain, held',
                  wall_s=time.perf_counter() - t0,
                  rows=[{k: v for k, v in r.items() if k not in ('axial_force', 'key')} for r in rows],
                  reference_axial_force_n=next(r for r in rows if r['reference'] and r['task'] == 'insertion')['axial_force'])
    _write_outputs(out, report, rows)
    return report


_CSV_COLUMNS = ('task', 'model', 'mesh', 'tetrahedra', 'integrator', 'time_step_s', 'mass_scaling', 'damping_per_s',
                'cost_s_per_sim_s',
                'tet_steps_per_s', 'core_share_at_50hz', 'error', 'inertia_error_estimate', 'peak_force_error',
                'puncture_depth_error_mm', 'pareto', 'reference',
                'failure', 'overrides')


def _cell(value):
    if value is None:
        return ''
    if isinstance(value, float):
        return f'{value:.6g}'
    return value


def _overrides_text(values: dict) -> str:
    """The ``--set`` options that reproduce a row's scene values."""
    return ' '.join(f'--set {shlex.quote(override_text(k, v))}' for k, v in values.items())


def _write_outputs(out: Path, report: dict, rows: list[dict]) -> None:
    import csv
    with (out / 'chart.csv').open('w', newline='') as f:
        w = csv.writer(f)
        w.writerow(_CSV_COLUMNS)
        for r in rows:
            w.writerow([_overrides_text(r['values']) if c == 'overrides' else _cell(r.get(c))
                        for c in _CSV_COLUMNS])
    (out / 'chart.json').write_text(json.dumps(report, indent=1))
    _plot(out / 'chart.png', rows)
    (out / 'chart.md').write_text(_markdown(report, rows))


def _reference_line(rows: list[dict]) -> str:
    """What the reference is, with its own estimated inertia error (its selective mass scaling's)."""
    ref = next(r for r in rows if r['reference'] and r['task'] == 'insertion')
    selective = ref['values'].get('solver.selective_mass_scaling')
    estimate = ref.get('inertia_error_estimate')
    return ('Reference: the full model, explicit, no mass scaling'
            + (f', selective mass scaling {selective:g}' if selective else '')
            + ('' if estimate is None else f'; its estimated inertia error {estimate:.4f}') + '.')


def _scaling_cell(row: dict) -> str:
    """The mass scaling, and the selective one where the row has it."""
    selective = row['values'].get('solver.selective_mass_scaling', 1.0)
    return f"{row['mass_scaling']:g}" + (f', selective {selective:g}' if selective > 1 else '')


def _markdown(report: dict, rows: list[dict]) -> str:
    task = report['task']
    lines = [f"# Speed against accuracy: {report['scene']}", '',
             f"Cost: wall seconds per simulated second, one thread. {report['wall_s']:.0f} s of wall time"
             f"{' (quick preset)' if report['quick'] else ''}.", '',
             f"## Needle insertion: "
             + (f"the scene's planned insertion from its start pose, " if task['planned'] else
                f"from {task['start_gap_m'] * 1e3:g} mm above the surface, ")
             + f"{task['travel_m'] * 1e3:g} mm at {task['speed_m_s'] * 1e3:g} mm/s", '',
             f"Error: {report['error_metric']}.", '', _reference_line(rows), '',
             '| model | mesh | tetrahedra | integrator | mass scaling | damping [1/s] | dt [s] | cost [s/s] | error | '
             'peak | puncture [mm] | Pareto |', '|---|---|---|---|---|---|---|---|---|---|---|---|']
    insertion = [r for r in rows if r['task'] == 'insertion']
    for r in sorted((r for r in insertion if not r.get('failure')), key=lambda r: r['cost_s_per_sim_s']):
        puncture = '' if r['puncture_depth_error_mm'] is None else f"{r['puncture_depth_error_mm']:+.2f}"
        lines.append(f"| {r['model']} | {r['mesh']} | {r['tetrahedra']} | {r['integrator']} | {_scaling_cell(r)} "
                     f"| {_cell(r.get('damping_per_s'))} | {r['time_step_s']:.3g} "
                     f"| {r['cost_s_per_sim_s']:.3g} | {'reference' if r['reference'] else format(r['error'], '.4f')} "
                     f"| {r['peak_force_error']:+.3f} | {puncture} | {'yes' if r['pareto'] else ''} |")
    compression = [r for r in rows if r['task'] == 'compression']
    if compression:
        lines += ['', '## Plate compression', '', f"Error: {report['compression_error_metric']}.", '',
                  '| model | cube | tetrahedra | integrator | dt [s] | cost [s/s] | error | Pareto |',
                  '|---|---|---|---|---|---|---|---|']
        for r in sorted((r for r in compression if not r.get('failure')), key=lambda r: r['cost_s_per_sim_s']):
            lines.append(f"| {r['model']} | {r['mesh']} | {r['tetrahedra']} | {r['integrator']} | {r['time_step_s']:.3g} "
                         f"| {r['cost_s_per_sim_s']:.3g} | {r['error']:.2e} | {'yes' if r['pareto'] else ''} |")
    failed = [r for r in rows if r.get('failure')]
    if failed:
        lines += ['', 'Failed:', ''] + [f"- {r['task']}: {r['model']}, {r['mesh']}, {r['integrator']}: {r['failure']}"
                                        for r in failed]
    return '\n'.join(lines) + '\n'


def _plot(path: Path, rows: list[dict]) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    tasks = [t for t in ('insertion', 'compression') if any(r['task'] == t for r in rows)]
    fig, axes = plt.subplots(1, len(tasks), figsize=(8 * len(tasks), 5.5), squeeze=False)
    families = list(dict.fromkeys(_model_family(r['model']) for r in rows))
    for ax, task in zip(axes[0], tasks):
        _plot_task(ax, [r for r in rows if r['task'] == task], families, task)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _plot_task(ax, rows: list[dict], families: list[str], task: str) -> None:
    markers = dict(explicit='o', implicit='s', quasi_static='^')
    finished = [r for r in rows if not r.get('failure') and not r['reference']]
    for k, family in enumerate(families):
        for integrator, marker in markers.items():
            sel = [r for r in finished if _model_family(r['model']) == family and r['integrator'] == integrator]
            if sel:
                ax.scatter([r['cost_s_per_sim_s'] for r in sel], [max(r['error'], 1e-6) for r in sel],
                           color=f'C{k}', marker=marker, s=36,
                           label=f'{family}' + ('' if integrator == 'explicit' else f', {integrator.replace("_", "-")}'))
    front = sorted((r for r in finished if r['pareto']), key=lambda r: r['cost_s_per_sim_s'])
    if front:
        ax.step([r['cost_s_per_sim_s'] for r in front], [max(r['error'], 1e-6) for r in front], where='post',
                color='black', lw=1, label='Pareto front')
    reference = [r for r in rows if r['reference'] and not r.get('failure')]
    if reference:
        ax.axvline(reference[0]['cost_s_per_sim_s'], color='grey', ls=':', lw=1,
                   label=f"reference's cost ({reference[0]['tetrahedra']} tetrahedra)")
    ax.axvline(1.0, color='red', ls='--', lw=0.8, label='real time on one core')
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.set_xlabel('cost [wall s per simulated s, one thread]')
    if task == 'insertion':
        ax.set_ylabel('force NRMSE against the reference')
        ax.set_title('needle insertion')
    else:
        ax.set_ylabel('|plate force / (E A strain) - 1|')
        ax.set_title('plate compression (analytic reference)')
    ax.grid(alpha=0.3, which='both')
    ax.legend(fontsize=7, loc='best')


def main(scene_file=None, sets=(), quick=False, speed_mm_s=5.0, travel_mm=None, out='out', workers=None,
         scheduler=None, reference_selective=1.0, row_limit_min=None) -> int:
    run_chart(scene_file, sets, quick=quick, speed=speed_mm_s * 1e-3,
              travel=None if travel_mm is None else travel_mm * 1e-3, out=out,
              workers=workers, scheduler=scheduler, reference_selective=reference_selective,
              row_limit_s=None if row_limit_min is None else 60.0 * row_limit_min)
    print((Path(out) / 'chart.md').read_text())
    print(f'wrote {out}/chart.csv, chart.png, chart.md, chart.json', file=sys.stderr)
    return 0
