"""A straight needle insertion and retraction on a scene, without ROS; CSV, plot, data comparison.

The needle moves along its initial axis at constant speed by ``travel`` metres (insertion, from
its start pose), holds, then comes back (retraction), in ticks of ``tick`` seconds (the node's
50 Hz by default). ``depth_m`` in the CSV and the plot's abscissa is this travel of the tip from
its start pose, the abscissa of Okamura et al. (2004), whose liver sample was touched about 9 mm
after the start (the command takes ``--travel-mm`` for it, or ``--depth-mm`` below the surface).
"""
import csv
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

CSV_HEADER = ('time_s', 'depth_m', 'force_x_n', 'force_y_n', 'force_z_n', 'torque_x_nm', 'torque_y_nm',
              'torque_z_nm', 'axial_force_n', 'phase')


@dataclass
class InsertionResult:
    time: np.ndarray          # (k,) s
    depth: np.ndarray         # (k,) m, tip travel from the start pose
    force: np.ndarray         # (k, 3) N, tissue on needle, world frame
    torque: np.ndarray        # (k, 3) N m, about the needle base origin, world frame
    axial_force: np.ndarray   # (k,) N, positive when the tissue resists insertion
    phase: list               # (k,) str
    retracting: np.ndarray    # (k,) bool, the retraction leg
    puncture_events: list
    wall_time: float
    steps: int
    time_step: float
    target_names: tuple = ()        # the scene's targets (engine.targets)
    target_positions: np.ndarray = None   # (k, n_targets, 3) m, world frame, each tick
    target_tip_distance: np.ndarray = None  # (k, n_targets) m, needle tip to target
    target_lateral_miss: np.ndarray = None  # (k, n_targets) m, target to the needle's line
    target_positions_at_rest: np.ndarray = None  # (n_targets, 3) m
    inertia_error: float = None     # the mass scaling's estimated force NRMSE (engine.inertia_estimate)
    inertia_rms_n: float = 0.0      # the same in N

    @property
    def real_time_factor(self):
        return float(self.time[-1] / self.wall_time) if self.wall_time > 0 else float('inf')


def run_insertion(scene, speed, travel, *, hold_s=0.0, tick=0.02, retract=True, progress=None):
    """Insert the scene's needle by ``travel`` [m] at ``speed`` [m/s] along its axis, hold
    ``hold_s`` [s] at the deepest point, then retract it; returns an InsertionResult sampled once
    per tick. ``progress``: a file to print a progress line to every simulated second (None:
    quiet)."""
    if not (speed > 0 and np.isfinite(speed)):
        raise ValueError(f'speed = {speed!r}: expected a finite speed > 0 m/s')
    if not (travel > 0 and np.isfinite(travel)):
        raise ValueError(f'travel = {travel!r}: expected a finite distance > 0 m')
    if not (hold_s >= 0 and np.isfinite(hold_s)):
        raise ValueError(f'hold_s = {hold_s!r}: expected a finite time >= 0 s')
    from tissue_sim_ros.engine.driver import SimulationDriver
    start = scene.needle_pose[0]
    axis = scene.needle.axis.copy()
    legs = [(0.0, travel, travel / speed)] + ([(travel, travel, hold_s)] if hold_s > 0 else []) + \
        ([(travel, 0.0, travel / speed)] if retract else [])
    times, depths, retracting, t = [], [], [], 0.0
    for begin, end, duration in legs:
        n_ticks = max(1, int(np.ceil(duration / tick - 1e-9)))
        for k in range(1, n_ticks + 1):
            t += duration / n_ticks
            times.append(t)
            depths.append(begin + (end - begin) * k / n_ticks)
            retracting.append(end < begin)
    depths = np.array(depths)
    driver = SimulationDriver(scene, wrench_frame='world', on_divergence='raise')
    wall0, next_report = time.perf_counter(), [1.0]
    n_targets = len(scene.targets)
    target_positions = np.zeros((len(times), n_targets, 3))
    target_distance = np.zeros((len(times), n_targets))
    target_miss = np.zeros((len(times), n_targets))

    def report(k, drv):
        if n_targets:
            target_positions[k] = scene.target_positions()
            target_distance[k], target_miss[k], _ = scene.targets_relative_to_needle()
        if progress is not None and drv.time >= next_report[0]:
            elapsed = time.perf_counter() - wall0
            print(f'  t = {drv.time:6.2f} s  travel {depths[k] * 1e3:6.2f} mm  axial '
                  f'{-float(np.dot(drv.force, axis)):7.3f} N  {drv.scene.phase:<10}  real-time factor '
                  f'{drv.time / elapsed:5.2f}', file=progress, flush=True)
            next_report[0] += 1.0

    samples = driver.follow(times, start + depths[:, None] * axis,
                            progress=None if progress is None and not n_targets else report)
    return InsertionResult(samples.time, depths, samples.force, samples.torque,
                           -(samples.force @ axis), samples.phase, np.array(retracting),
                           list(scene.puncture_events), time.perf_counter() - wall0,
                           samples.substeps, scene.dt, tuple(scene.targets.names), target_positions,
                           target_distance, target_miss, scene.targets.rest.copy(),
                           driver.inertia.error, driver.inertia.rms_n)


def target_columns(names) -> list[str]:
    """The CSV columns of each target: its position now, its displacement from rest, the needle
    tip's distance to it and the lateral miss of the needle's line [m]."""
    return [f'target/{name}/{column}' for name in names
            for column in ('x_m', 'y_m', 'z_m', 'displacement_m', 'tip_distance_m', 'lateral_miss_m')]


def write_csv(result, path):
    with open(path, 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(CSV_HEADER + tuple(target_columns(result.target_names)))
        for k in range(len(result.time)):
            targets = []
            for j in range(len(result.target_names)):
                position = result.target_positions[k, j]
                targets += [*(f'{v:.7g}' for v in position),
                            f'{np.linalg.norm(position - result.target_positions_at_rest[j]):.6g}',
                            f'{result.target_tip_distance[k, j]:.6g}', f'{result.target_lateral_miss[k, j]:.6g}']
            writer.writerow([f'{result.time[k]:.6f}', f'{result.depth[k]:.7f}',
                             *(f'{v:.6g}' for v in result.force[k]), *(f'{v:.6g}' for v in result.torque[k]),
                             f'{result.axial_force[k]:.6g}', result.phase[k], *targets])


def plot_insertion(result, path, *, title='needle insertion'):
    """Axial force against travel of a run, puncture events dashed."""
    from tissue_sim_ros.analysis.force_plot import plot_force_against_travel
    marks = [np.interp(event['time_s'], result.time, result.depth) for event in result.puncture_events]
    plot_force_against_travel(path, result.depth, result.axial_force, result.retracting, title=title,
                              marks_m=marks)


def main(scene_file, speed_mm_s, out, *, travel_mm=None, depth_mm=None, hold_s=0.0, sets=(),
         tick=0.02, stream=None, overrides=None):
    """The `tissue-sim insert` command: run, print a summary, write insertion.csv and .png.
    ``travel_mm``: tip travel from the start pose, or ``depth_mm``: depth below the surface (the
    scene's start gap added); ``sets``: ``KEY=VALUE`` scene overrides."""
    from tissue_sim_ros.engine.scene.scene import Scene
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    # the speed of the run is the one a `solver.mass_scaling: auto` is chosen for
    sets = [f'solver.design_speed_m_s={speed_mm_s * 1e-3!r}'] + list(sets)
    scene = Scene.from_file(scene_file, sets=sets, **(overrides or {}))
    if (travel_mm is None) == (depth_mm is None):
        raise ValueError('give one of travel_mm (tip travel) and depth_mm (depth below the surface)')
    travel = travel_mm * 1e-3 if travel_mm is not None else scene.start_gap_m + depth_mm * 1e-3
    model = scene.model
    kind = ('full' if model.geometric and model.physical else 'geometric' if model.geometric
            else 'physical' if model.physical else 'linear') + ('+visc' if model.viscous else '')
    print(f'scene {scene_file or "(default liver sample)"}: {scene.mesh.n_elements} tetrahedra, '
          f'{kind} model, dt = {scene.dt * 1e3:.3f} ms (mass scaling {scene.simulation.mass_scaling:g})',
          file=stream)
    result = run_insertion(scene, speed_mm_s * 1e-3, travel, hold_s=hold_s, tick=tick, progress=stream)
    write_csv(result, out / 'insertion.csv')
    plot_insertion(result, out / 'insertion.png', title=f'insertion at {speed_mm_s:g} mm/s, {kind} model')
    if scene_file is None:              # the default scene models the bovine liver: compare with it
        from tissue_sim_ros.analysis.compare.compare import compare_with_reference
        comparison = compare_with_reference(result.time, result.depth, result.axial_force,
                                            plot=out / 'insertion_vs_bovine_liver.png')
        e = comparison.errors
        travel_off = comparison.events.get('first_puncture_travel_error_m', float('nan'))
        force_off = comparison.events.get('first_puncture_force_error_n', float('nan'))
        puncture = (f'first puncture {1e3 * travel_off:+.2f} mm and {force_off:+.3f} N off'
                    if np.isfinite(travel_off) and np.isfinite(force_off)
                    else 'no puncture in this run to compare with the data\'s first')
        print(f'against the bovine-liver insertion (Okamura et al. 2004, 3 mm/s), by depth since '
              f'contact: NRMSE {e.get("nrmse", float("nan")):.3f} over the insertion, {puncture}; wrote '
              f'{out / "insertion_vs_bovine_liver.png"}', file=stream)
    for event in result.puncture_events:
        print(f'puncture of {event["region"]} at travel {np.interp(event["time_s"], result.time, result.depth) * 1e3:.2f} mm, '
              f'axial force {event["axial_force_n"]:.3f} N', file=stream)
    for j, name in enumerate(result.target_names):
        closest = int(np.argmin(result.target_tip_distance[:, j]))
        moved = np.linalg.norm(result.target_positions[:, j] - result.target_positions_at_rest[j], axis=1)
        print(f'target {name}: the tip came within {result.target_tip_distance[closest, j] * 1e3:.2f} mm of it '
              f'(t = {result.time[closest]:.2f} s, lateral miss {result.target_lateral_miss[closest, j] * 1e3:.2f} mm); '
              f'the tissue carried it {moved.max() * 1e3:.2f} mm at most', file=stream)
    print(f'peak axial force {result.axial_force.max():.3f} N; simulated {result.time[-1]:.2f} s in '
          f'{result.wall_time:.2f} s wall: real-time factor {result.real_time_factor:.2f} '
          f'({result.steps} steps)', file=stream)
    from tissue_sim_ros.engine.solver.inertia_estimate import inertia_line
    print(inertia_line(scene.simulation.mass_scaling, result.inertia_error, result.inertia_rms_n,
                       scene.simulation.integrator), file=stream)
    if scene.simulation.integrator != 'explicit':
        print(scene.simulation.implicit_summary(), file=stream)
    print(f'wrote {out / "insertion.csv"} and {out / "insertion.png"}', file=stream)
    return result
