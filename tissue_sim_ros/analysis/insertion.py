"""A straight needle insertion and retraction on a scene, without ROS: the run, its CSV and plot.

The needle moves along its initial axis at constant speed by ``travel`` metres (insertion, from
its start pose), holds, then comes back (retraction), in ticks of ``tick`` seconds (the node's
50 Hz by default). ``travel_m`` in the CSV and the plot's abscissa is this travel of the tip from
its start pose, the abscissa of Okamura et al. (2004), whose liver sample was touched about 9 mm
after the start. The ``tissue-sim insert`` command is :mod:`.insert`; the chart and the
stability map run their insertions here too.
"""
import csv
import time
from dataclasses import dataclass

import numpy as np

CSV_HEADER = ('time_s', 'travel_m', 'tip_x_m', 'tip_y_m', 'tip_z_m', 'tip_deflection_m', 'force_x_n', 'force_y_n',
              'force_z_n', 'torque_x_nm', 'torque_y_nm', 'torque_z_nm', 'axial_force_n', 'phase')


@dataclass
class InsertionResult:
    time: np.ndarray          # (k,) s
    travel: np.ndarray        # (k,) m, tip travel from the start pose
    force: np.ndarray         # (k, 3) N, tissue on needle, world frame
    torque: np.ndarray        # (k, 3) N m, about the needle base origin, world frame
    axial_force: np.ndarray   # (k,) N, positive when the tissue resists insertion
    phase: list               # (k,) str
    retracting: np.ndarray    # (k,) bool, the retraction leg
    puncture_events: list
    wall_time: float
    steps: int
    time_step: float
    target_names: tuple = ()        # the scene's targets (engine.scene.targets)
    target_positions: np.ndarray = None   # (k, n_targets, 3) m, world frame, each tick
    target_tip_distance: np.ndarray = None  # (k, n_targets) m, needle tip to target
    target_lateral_miss: np.ndarray = None  # (k, n_targets) m, target to the needle's line
    target_positions_at_rest: np.ndarray = None  # (n_targets, 3) m, at the start (settled under gravity)
    inertia_error: float = None     # the mass scaling's estimated force NRMSE (solver.inertia_estimate)
    inertia_rms_n: float = 0.0      # the same in N
    tip: np.ndarray = None          # (k, 3) m, the tip's apex, world frame
    tip_deflection: np.ndarray = None   # (k,) m, the tip's distance from the base frame's axis

    @property
    def real_time_factor(self):
        return float(self.time[-1] / self.wall_time) if self.wall_time > 0 else float('inf')


def run_insertion(scene, speed, travel, *, hold_s=0.0, tick=0.02, retract=True, progress=None,
                  wall_limit_s=None):
    """Insert the scene's needle by ``travel`` [m] at ``speed`` [m/s] along its axis, hold
    ``hold_s`` [s] at the deepest point, then retract it; returns an InsertionResult sampled once
    per tick. ``progress``: a file to print a progress line to every simulated second (None:
    quiet). ``wall_limit_s``: raise WallTimeExceeded once a tick ends past that much wall time."""
    if not (speed > 0 and np.isfinite(speed)):
        raise ValueError(f'speed = {speed!r}: expected a finite speed > 0 m/s')
    if not (travel > 0 and np.isfinite(travel)):
        raise ValueError(f'travel = {travel!r}: expected a finite distance > 0 m')
    if not (hold_s >= 0 and np.isfinite(hold_s)):
        raise ValueError(f'hold_s = {hold_s!r}: expected a finite time >= 0 s')
    from tissue_sim_ros.engine.driver import SimulationDriver
    start = scene.needle_pose[0]
    axis = scene.needle.axis.copy()
    targets_at_start = scene.target_positions()
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
        if wall_limit_s is not None and time.perf_counter() - wall0 > wall_limit_s:
            from tissue_sim_ros.errors import WallTimeExceeded
            raise WallTimeExceeded(wall_limit_s, drv.time)
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
                            progress=None if progress is None and not n_targets and wall_limit_s is None
                            else report)
    return InsertionResult(samples.time, depths, samples.force, samples.torque,
                           -(samples.force @ axis), samples.phase, np.array(retracting),
                           list(scene.puncture_events), time.perf_counter() - wall0,
                           samples.substeps, scene.dt, tuple(scene.targets.names), target_positions,
                           target_distance, target_miss, targets_at_start,
                           driver.inertia.error, driver.inertia.rms_n, samples.tip, samples.tip_deflection)


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
            writer.writerow([f'{result.time[k]:.6f}', f'{result.travel[k]:.7f}',
                             *(f'{v:.9g}' for v in result.tip[k]), f'{result.tip_deflection[k]:.6g}',
                             *(f'{v:.6g}' for v in result.force[k]), *(f'{v:.6g}' for v in result.torque[k]),
                             f'{result.axial_force[k]:.6g}', result.phase[k], *targets])


def plot_insertion(result, path, *, title='needle insertion'):
    """Axial force against travel of a run, puncture events dashed."""
    from tissue_sim_ros.analysis.force_plot import plot_force_against_travel
    marks = [np.interp(event['time_s'], result.time, result.travel) for event in result.puncture_events]
    plot_force_against_travel(path, result.travel, result.axial_force, result.retracting, title=title,
                              marks_m=marks)
