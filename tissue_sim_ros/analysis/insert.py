"""``tissue-sim insert``: a straight insertion and retraction on a scene, without ROS.

Runs :func:`~tissue_sim_ros.analysis.insertion.run_insertion`, prints what happened (punctures,
targets, the peak force, the speed, the mass scaling's estimated inertia error) and writes into
``--out DIR``: ``insert.csv`` (a row per tick: time, tip travel, where the tip is and its
deflection from the base axis, wrench, axial force, phase, targets), ``insert.png`` (force
against travel), ``insert.md`` and ``insert.json`` (the
figures). On the packaged scene, which models the bovine liver of Okamura et al. (2004), it also
compares the run with that measurement (``insert_vs_bovine_liver.png``).
"""
import json
import sys
from pathlib import Path

import numpy as np

from tissue_sim_ros.analysis.charting.auto_keys import load_scene
from tissue_sim_ros.analysis.compare.compare import compare_with_reference
from tissue_sim_ros.analysis.insertion import plot_insertion, run_insertion, write_csv
from tissue_sim_ros.engine.scene.scene import merge
from tissue_sim_ros.engine.solver.inertia_estimate import inertia_line

__all__ = ['main']


#: the travel of an insertion whose scene plans none [mm]
DEFAULT_TRAVEL_MM = 35.0


def main(scene_file, speed_mm_s, out, *, travel_mm=None, depth_mm=None, hold_s=0.0, sets=(),
         tick=0.02, stream=None, overrides=None):
    """The `tissue-sim insert` command: run, print a summary, write the outputs (module docstring).
    ``travel_mm``: tip travel from the start pose, or ``depth_mm``: depth below the surface (the
    scene's start gap added), or neither: the scene's ``needle.planned_travel_m``, else
    DEFAULT_TRAVEL_MM; ``sets``: ``KEY=VALUE`` scene overrides."""
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # the speed of the run is the one a `solver.mass_scaling: auto` is chosen for (a --set wins)
    sections = merge({'solver': {'design_speed_m_s': speed_mm_s * 1e-3}}, overrides or {})
    scene = load_scene(scene_file, sets=sets, **sections)
    if travel_mm is not None and depth_mm is not None:
        raise ValueError('give one of travel_mm (tip travel) and depth_mm (depth below the surface)')
    if travel_mm is None and depth_mm is None:        # the insertion the scene is for, else 35 mm
        planned = scene.spec['needle']['planned_travel_m']
        travel_mm = DEFAULT_TRAVEL_MM if planned is None else planned * 1e3
    travel = travel_mm * 1e-3 if travel_mm is not None else scene.start_gap_m + depth_mm * 1e-3
    model = scene.model
    kind = ('full' if model.geometric and model.physical else 'geometric' if model.geometric
            else 'physical' if model.physical else 'linear') + ('+visc' if model.viscous else '')
    print(f'scene {scene_file or "(default liver sample)"}: {scene.mesh.n_elements} tetrahedra, '
          f'{kind} model, dt = {scene.dt * 1e3:.3f} ms (mass scaling {scene.simulation.mass_scaling:g})',
          file=stream)
    result = run_insertion(scene, speed_mm_s * 1e-3, travel, hold_s=hold_s, tick=tick, progress=stream)
    write_csv(result, out / 'insert.csv')
    plot_insertion(result, out / 'insert.png', title=f'insertion at {speed_mm_s:g} mm/s, {kind} model')
    if scene_file is None:              # the default scene models the bovine liver: compare with it
        comparison = compare_with_reference(result.time, result.travel, result.axial_force,
                                            plot=out / 'insert_vs_bovine_liver.png')
        e = comparison.errors
        travel_off = comparison.events.get('first_puncture_travel_error_m', float('nan'))
        force_off = comparison.events.get('first_puncture_force_error_n', float('nan'))
        puncture = (f'first puncture {1e3 * travel_off:+.2f} mm and {force_off:+.3f} N off'
                    if np.isfinite(travel_off) and np.isfinite(force_off)
                    else 'no puncture in this run to compare with the data\'s first')
        print(f'against the bovine-liver insertion (Okamura et al. 2004, 3 mm/s), by depth since '
              f'contact: NRMSE {e.get("nrmse", float("nan")):.3f} over the insertion, {puncture}; wrote '
              f'{out / "insert_vs_bovine_liver.png"}', file=stream)
    for event in result.puncture_events:
        print(f'puncture of {event["region"]} at travel {np.interp(event["time_s"], result.time, result.travel) * 1e3:.2f} mm, '
              f'axial force {event["axial_force_n"]:.3f} N', file=stream)
    for j, name in enumerate(result.target_names):
        closest = int(np.argmin(result.target_tip_distance[:, j]))
        moved = np.linalg.norm(result.target_positions[:, j] - result.target_positions_at_rest[j], axis=1)
        print(f'target {name}: the tip came within {result.target_tip_distance[closest, j] * 1e3:.2f} mm of it '
              f'(t = {result.time[closest]:.2f} s, lateral miss {result.target_lateral_miss[closest, j] * 1e3:.2f} mm); '
              f'the tissue carried it {moved.max() * 1e3:.2f} mm at most', file=stream)
    if scene.needle.rod is not None:
        k = int(np.argmax(result.tip_deflection))
        print(f'flexible needle: the tip deflected {result.tip_deflection[-1] * 1e3:.3f} mm from the base axis at '
              f'the end ({result.tip_deflection[k] * 1e3:.3f} mm at most, t = {result.time[k]:.2f} s)', file=stream)
    print(f'peak axial force {result.axial_force.max():.3f} N; simulated {result.time[-1]:.2f} s in '
          f'{result.wall_time:.2f} s wall: real-time factor {result.real_time_factor:.2f} '
          f'({result.steps} steps)', file=stream)
    print(inertia_line(scene.simulation.mass_scaling, result.inertia_error, result.inertia_rms_n,
                       scene.simulation.integrator, scene.simulation.selective_added_fraction), file=stream)
    if scene.simulation.integrator != 'explicit':
        print(scene.simulation.implicit_summary(), file=stream)
    write_summary(out, scene_file, speed_mm_s, kind, scene, result)
    print(f'wrote {out / "insert.csv"}, insert.png, insert.md and insert.json', file=stream)
    return result


def write_summary(out: Path, scene_file, speed_mm_s, kind, scene, result) -> dict:
    """insert.json (the run's figures, for scripts) and insert.md (the same for a person)."""
    figures = {
        'scene': str(scene_file) if scene_file else 'packaged liver sample',
        'speed_mm_s': speed_mm_s, 'model': kind, 'tetrahedra': int(scene.mesh.n_elements),
        'time_step_s': float(scene.dt), 'mass_scaling': float(scene.simulation.mass_scaling),
        'peak_axial_force_n': float(result.axial_force.max()),
        'punctures': [{'region': e['region'], 'travel_m': float(np.interp(e['time_s'], result.time, result.travel)),
                       'axial_force_n': float(e['axial_force_n'])} for e in result.puncture_events],
        'simulated_s': float(result.time[-1]), 'wall_s': float(result.wall_time),
        'real_time_factor': float(result.real_time_factor), 'steps': int(result.steps),
        'inertia_error_estimate': result.inertia_error,
        'final_tip_m': [float(v) for v in result.tip[-1]],
        'final_tip_deflection_m': float(result.tip_deflection[-1]),
        'max_tip_deflection_m': float(result.tip_deflection.max()),
    }
    (out / 'insert.json').write_text(json.dumps(figures, indent=1))
    lines = [f"# Insertion at {speed_mm_s:g} mm/s: {figures['scene']}", '',
             f"{figures['tetrahedra']} tetrahedra, {kind} model, time step {figures['time_step_s'] * 1e3:.3f} ms, "
             f"mass scaling {figures['mass_scaling']:g}.", '',
             f"Peak axial force {figures['peak_axial_force_n']:.3f} N; simulated {figures['simulated_s']:.2f} s in "
             f"{figures['wall_s']:.2f} s (real-time factor {figures['real_time_factor']:.2f}).", '',
             f"Tip deflection from the base axis: {figures['final_tip_deflection_m'] * 1e3:.3f} mm at the end, "
             f"{figures['max_tip_deflection_m'] * 1e3:.3f} mm at most.", '',
             '| puncture of | travel [mm] | axial force [N] |', '|---|---|---|']
    lines += [f"| {p['region']} | {p['travel_m'] * 1e3:.2f} | {p['axial_force_n']:.3f} |" for p in figures['punctures']]
    lines += ['', '![force against travel](insert.png)', '']
    (out / 'insert.md').write_text('\n'.join(lines))
    return figures
