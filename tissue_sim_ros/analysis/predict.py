"""``tissue-sim predict``: what a candidate needle path would do, without ROS.

The same prediction the node answers on ``plan/candidate`` (engine.prediction), from the scene at
rest: the path is a CSV of the needle base's poses, one per row, with the header
``t, x, y, z, qx, qy, qz, qw`` (seconds, metres, a quaternion x, y, z, w; ``t_s``, ``x_m``... and
any other columns are accepted and ignored), its first pose the scene's initial needle pose
(``config/candidate_path.csv`` is a 10 s example on the default scene). Writes into ``--out``:
``predict.csv`` (one row per pose: time from start, the prediction's columns, the phase),
``predict.png`` (force, tip depth and target displacements against time), ``predict.md``
and ``predict.json`` (figures and the speed: wall time and real-time factor; with
``--max-error``, the ladder's rung it ran on and that rung's measured error). The wrench is in
the needle frame by default, as the node's (``--wrench-frame world`` for the world frame).
"""
from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np

from tissue_sim_ros.errors import DataError

__all__ = ['PATH_COLUMNS', 'read_path_csv', 'write_prediction', 'main']

#: The path CSV's columns; each may also carry its unit (``t_s``, ``x_m``).
PATH_COLUMNS = ('t', 'x', 'y', 'z', 'qx', 'qy', 'qz', 'qw')
_UNIT_SUFFIX = {'t': '_s', 'x': '_m', 'y': '_m', 'z': '_m'}


def read_path_csv(path):
    """(stamps (k,) [s], positions (k, 3) [m], quaternions (k, 4)) of a path CSV; a missing
    column or a value that is not a number raises DataError naming the file, line and column."""
    path = Path(path)
    with open(path, newline='') as f:
        numbered = [(n, line) for n, line in enumerate(f, start=1)
                    if line.strip() and not line.lstrip().startswith('#')]
    if not numbered:
        raise DataError(path, f'empty; expected a header {", ".join(PATH_COLUMNS)} and one row per pose')
    rows = list(csv.reader(line for _, line in numbered))
    header = [name.strip().lower() for name in rows[0]]
    index = {}
    for name in PATH_COLUMNS:
        for alias in (name, name + _UNIT_SUFFIX.get(name, '')):
            if alias in header:
                index[name] = header.index(alias)
                break
        else:
            raise DataError(path, f'no column {name!r} in the header {rows[0]}; expected '
                                  f'{", ".join(PATH_COLUMNS)}')
    values = np.empty((len(rows) - 1, len(PATH_COLUMNS)))
    for k, row in enumerate(rows[1:]):
        for j, name in enumerate(PATH_COLUMNS):
            try:
                values[k, j] = float(row[index[name]])
            except (IndexError, ValueError):
                cell = row[index[name]] if index[name] < len(row) else '(missing)'
                raise DataError(path, f'{cell!r}: expected a number', column=name,
                                row=numbered[k + 1][0]) from None
    return values[:, 0], values[:, 1:4], values[:, 4:8]


def write_prediction(prediction, out: Path, *, title: str, wrench_frame: str = 'needle') -> None:
    """predict.csv and predict.png of a Prediction."""
    with open(out / 'predict.csv', 'w', newline='') as f:
        writer = csv.writer(f)
        writer.writerow(['time_from_start_s', *prediction.columns, 'phase'])
        for k, t in enumerate(prediction.time_from_start_s):
            writer.writerow([f'{t:.6f}', *(f'{v:.7g}' for v in prediction.values[k]), prediction.phase[k]])
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    t = prediction.time_from_start_s
    targets = [c for c in prediction.columns if c.startswith('target/')]
    fig, axes = plt.subplots(2 + bool(targets), 1, figsize=(7, 6 + 2 * bool(targets)), sharex=True)
    for j, axis in enumerate('xyz'):
        axes[0].plot(t, prediction.column(f'force_{axis}_n'), label=f'force {axis}')
    axes[0].set_ylabel(f'force on the needle [N]\n({wrench_frame} frame)')
    axes[0].legend(fontsize=8)
    axes[0].set_title(title)
    axes[1].plot(t, prediction.column('tip_depth_m') * 1e3, color='k')
    axes[1].set_ylabel('tip depth [mm]')
    for name in targets:
        axes[2].plot(t, prediction.column(name) * 1e3, label=name.split('/')[1])
    if targets:
        axes[2].set_ylabel('target displacement [mm]')
        axes[2].legend(fontsize=8)
    axes[-1].set_xlabel('time from the first pose [s]')
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out / 'predict.png', dpi=120)
    plt.close(fig)


def _figures(prediction) -> dict:
    force = prediction.values[:, 0:3]
    figures = {
        'points': len(prediction.time_from_start_s),
        'simulated_s': prediction.simulated_s,
        'wall_s': prediction.wall_s,
        'real_time_factor': prediction.real_time_factor,
        'substeps': prediction.substeps,
        'peak_force_n': float(np.linalg.norm(force, axis=1).max()),
        'final_tip_depth_m': float(prediction.column('tip_depth_m')[-1]),
        'final_phase': prediction.phase[-1],
        'target_peak_displacement_m': {c.split('/')[1]: float(prediction.column(c).max())
                                       for c in prediction.columns if c.startswith('target/')},
    }
    return figures


def _rung(scene, max_error) -> dict:
    """Set ``scene`` to its ladder's cheapest rung within ``max_error`` (the probe's errors,
    measured once per scene and cached); its name and error."""
    from tissue_sim_ros.engine.ladder import DegradationLadder
    from tissue_sim_ros.engine.ladder_probe import cached_probe_errors
    ladder = DegradationLadder(scene)
    ladder.predicted_errors = cached_probe_errors(scene, DegradationLadder)
    level = ladder.cheapest_within(max_error)
    ladder.set_level(level)
    return {'rung': ladder.rung.name, 'rung_error': float(ladder.predicted_errors[level])}


def main(scene_file, path_file, out, *, sets=(), wrench_frame='needle', max_error=0.0, stream=None):
    """The command: read the path, predict from the scene at rest, write the four outputs, print
    the figures (the speed among them). ``wrench_frame``: 'needle' (the node's default
    wrench.frame_id) or 'world'. ``max_error`` > 0: on the cheapest degradation-ladder rung whose
    measured error against the scene as configured is within it, as the node's
    ``prediction.max_error`` (the rung and its error in the outputs). Returns the Prediction."""
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.engine.prediction import check_path, predict
    stream = sys.stdout if stream is None else stream
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    stamps, positions, orientations = read_path_csv(path_file)
    scene = load_scene(scene_file, sets=sets)
    needle = scene.needle
    path = check_path(stamps, positions, orientations, max_jump_m=needle.geometry.max_jump_m,
                      start_pose=scene.needle_pose, length_m=needle.geometry.length_m,
                      max_duration_s=float('inf'), field_name=str(path_file))
    print(f'scene {scene_file or "(default liver sample)"}: {scene.mesh.n_elements} tetrahedra, '
          f'dt = {scene.dt * 1e3:.3f} ms; path {path_file}: {len(path)} poses over {path.duration_s:g} s',
          file=stream)
    rung = _rung(scene, max_error) if max_error > 0 else None
    if rung is not None:
        print(f"on the ladder's rung '{rung['rung']}' (measured error {rung['rung_error']:.4f} of the "
              f'force range against the scene as configured, within {max_error:g})', file=stream)
    prediction = predict(scene, path, wrench_frame=wrench_frame)
    figures = dict(_figures(prediction), **(rung or {}))
    write_prediction(prediction, out, title=f'prediction of {Path(path_file).name}', wrench_frame=wrench_frame)
    summary = {'scene': str(scene_file) if scene_file else 'default (config/liver_sample.yaml)',
               'path': str(path_file), 'sets': list(sets), 'wrench_frame': wrench_frame,
               'tetrahedra': int(scene.mesh.n_elements), 'columns': prediction.columns, **figures}
    (out / 'predict.json').write_text(json.dumps(summary, indent=2))
    lines = [f'# Prediction of {Path(path_file).name}', '',
             f'Scene: {scene_file or "the default liver sample"} ({scene.mesh.n_elements} tetrahedra)'
             + (f', with {", ".join(sets)}' if sets else '') + f'. Force and torque in the {wrench_frame} '
             'frame (as the node answers with wrench.frame_id = ' + ('needle' if wrench_frame == 'needle'
                                                                    else 'its frame_id') + ').', '',
             '| figure | value |', '|---|---|',
             f'| poses | {figures["points"]} over {figures["simulated_s"]:g} s |',
             f'| peak force | {figures["peak_force_n"]:.4g} N |',
             f'| final tip depth | {figures["final_tip_depth_m"] * 1e3:.3g} mm ({figures["final_phase"]}) |',
             *(f'| target {name}: largest displacement | {value * 1e3:.3g} mm |'
               for name, value in figures['target_peak_displacement_m'].items()),
             f'| answered in | {figures["wall_s"]:.3g} s wall, {figures["real_time_factor"]:.3g}x real time |',
             *([f'| settings | the ladder\'s rung {figures["rung"]} (error {figures["rung_error"]:.4f}) |']
               if 'rung' in figures else []),
             '', 'Files: predict.csv (one row per pose), predict.png, predict.json.', '']
    (out / 'predict.md').write_text('\n'.join(lines))
    for line in lines[6:-3]:
        print('  ' + line.strip('|').replace(' | ', ': ').strip(), file=stream)
    print(f'wrote {out / "predict.csv"}, .png, .md and .json', file=stream)
    return prediction
