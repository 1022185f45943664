"""A load-cell study made by the simulator: known parameters, several speeds, noise.

The truth a calibration must recover (tests, the calibration benchmarks): the scene's insertion
(:func:`~tissue_sim_ros.analysis.insertion.run_insertion`: in, a hold, out) at each speed,
``repeats`` trials each with white noise of ``noise_n`` on the force and the sample times
jittered by up to 1 ms, written as one CSV per trial (time in s, force in N, position in mm,
speed and repeat in the file name) with the data description that reads them.

:func:`write_layered_study` makes the repeats differ as real ones do: each trial is its own draw
of the scene's spread between repeats (``regions[].membrane.rupture_force_spread_n``,
``regions[].depth_spread_m``; trial k of the study, from 1, runs ``variation.seed`` 1000 seed + k:
draws of their own, not those of a simulated study's seeds 1..N), so each
layer punctures at its own force and depth in every repeat; the values drawn are written beside
the data (``truth.json``) with the nominal scene keys and what made the study (the scene file's
text, the keys set, speeds, travel, hold, repeats, noise, seed): a second call with the same
inputs finds them there, with every trial's file, and keeps the study instead of simulating it
again (a benchmark resumed).
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ['PHANTOM_MESHES', 'phantom_scene', 'write_layered_study', 'write_synthetic_study']

SPEC = ("files: ['trial_*.csv']\ntime: {column: time, unit: s}\nforce: {column: fz, unit: N}\n"
        "position: {column: pz, unit: mm}\n"
        "file_name: {pattern: 'trial_(?P<speed>[0-9.]+)_(?P<repeat>[0-9]+)', speed_unit: mm/s}\n")


#: the layered phantoms' meshes: 'test' (a 40 x 40 x 30 mm box of 8 x 8 x 3 mm cells, 1500
#: tetrahedra, about a second a run), 'bench' (a 40 x 40 x 40 mm box of 6.7 x 6.7 x 2 mm cells, 4320
#: tetrahedra: the study and Dask benchmarks) and 'graded' (the same box, x and y graded toward the
#: needle's axis: a 3.3 mm cell around it, 5.1 mm beside, 6.6 mm farther out; 2 mm in z; 5880
#: tetrahedra: the layered benchmark) and 'fine' (as 'graded' with a 1.65 mm cell around the axis
#: and 5 mm far out; 14520 tetrahedra, about 3.7x a run's cost: the tip's load spreads over fewer mm
#: of the layer below, so the layers' moduli act less alike). On 'bench' the force takes one of two paths
#: that part a few mm after contact, which one turning on the outer modulus within 2 %; on 'graded'
#: it follows the moduli smoothly. All put the elements' centroids off the planes every 3 (2) mm the
#: layers' boundaries lie on (z is uniform).
PHANTOM_MESHES = {
    'test': {'generator': 'box', 'size_m': [0.04, 0.04, 0.03], 'origin_m': [-0.02, -0.02, -0.03],
             'divisions': [5, 5, 10]},
    'bench': {'generator': 'box', 'size_m': [0.04, 0.04, 0.04], 'origin_m': [-0.02, -0.02, -0.04],
              'divisions': [6, 6, 20]},
    'graded': {'generator': 'graded_box', 'size_m': [0.04, 0.04, 0.04], 'origin_m': [-0.02, -0.02, -0.04],
               'divisions': [6, 6, 20], 'fine_size_m': 0.0033, 'focus_radius_m': 0.002, 'growth': 3.0,
               'grade_z': False},
    'fine': {'generator': 'graded_box', 'size_m': [0.04, 0.04, 0.04], 'origin_m': [-0.02, -0.02, -0.04],
             'divisions': [8, 8, 20], 'fine_size_m': 0.00165, 'focus_radius_m': 0.002, 'growth': 3.0,
             'grade_z': False},
}


def phantom_scene(layers: int = 2, mesh: str = 'test') -> dict:
    """The hidden truth of the layered phantoms (tests, the layered calibration benchmark): a two-
    or three-layer block, 4 and 3 (and 3.5) N rupture forces with 0.2 N of spread between repeats,
    the deeper boundaries 12 (and 18) mm down with 0.5 mm of spread (between the depths of the
    meshes' element centroids, so that a boundary's spread moves where the needle meets the layer,
    not which elements are in it), a relaxing tissue (a Prony
    term: the pause relaxes), a constant retraction pull per layer (a plateau with a step where
    the needle leaves the deep layer), an 18 gauge bevel starting 1 mm above the surface."""
    if layers not in (2, 3):
        raise ValueError(f'layers = {layers!r}: the phantoms have 2 or 3 layers')
    friction = {'insertion_static_n_per_m': 200.0, 'stick_band_m_per_s': 0.0005}
    regions = [
        {'name': 'outer', 'select': 'all', 'young_modulus_pa': 30000.0,
         'membrane': {'criterion': 'force', 'rupture_force_n': 4.0, 'rupture_force_spread_n': 0.2},
         'cutting_force_n': 0.2, 'friction': dict(friction, insertion_coulomb_n_per_m=100.0, retraction_constant_n=1.2)},
        {'name': 'deep', 'select': {'below_z_m': -0.012}, 'depth_spread_m': 0.0005, 'young_modulus_pa': 60000.0,
         'membrane': {'criterion': 'force', 'rupture_force_n': 3.0, 'rupture_force_spread_n': 0.2},
         'cutting_force_n': 0.3, 'friction': dict(friction, insertion_coulomb_n_per_m=150.0, retraction_constant_n=1.8)},
    ]
    if layers == 3:
        regions.append({'name': 'core', 'select': {'below_z_m': -0.018}, 'depth_spread_m': 0.0005,
                        'young_modulus_pa': 45000.0,
                        'membrane': {'criterion': 'force', 'rupture_force_n': 3.5, 'rupture_force_spread_n': 0.2},
                        'cutting_force_n': 0.4,
                        'friction': dict(friction, insertion_coulomb_n_per_m=120.0, retraction_constant_n=2.2)})
    return {'mesh': dict(PHANTOM_MESHES[mesh]), 'regions': regions,
            'model': {'geometric': True, 'viscosity_mu_pa_s': 5.0, 'nonlinearity_threshold': 0.02,
                      'relaxation': [{'relative_modulus': 0.7, 'time_constant_s': 2.0}]},
            'solver': {'time_step_safety': 0.65, 'damping_per_s': 50.0, 'mass_scaling': 400.0},
            'needle': {'diameter_m': 0.00127, 'tip': {'shape': 'bevel', 'bevel_angle_deg': 20.0},
                       'start_gap_m': 0.001}}


def _write_trial(path, run, rng, noise_n) -> None:
    t = np.arange(0.0, run.time[-1], 0.01) + rng.uniform(0.0, 0.001)
    force = np.interp(t, run.time, run.axial_force) + rng.normal(0.0, noise_n, t.size)
    rows = np.column_stack([t, force, 1e3 * np.interp(t, run.time, run.travel)])
    np.savetxt(path, rows, delimiter=',', fmt='%.6f', header='time,fz,pz', comments='')


def write_synthetic_study(directory, scene_sets, speeds_mm_s, *, travel_m=0.02, hold_s=0.5, repeats=2,
                          noise_n=0.005, seed=1, scene_file=None) -> Path:
    """Write the study into ``directory``; returns its data description's path."""
    from tissue_sim_ros.analysis.insertion import run_insertion
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    rng = np.random.default_rng(seed)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    for speed in speeds_mm_s:
        run = run_insertion(load_scene(scene_file, sets=scene_sets), speed * 1e-3, travel_m,
                            hold_s=hold_s, tick=0.01)
        for repeat in range(1, repeats + 1):
            _write_trial(directory / f'trial_{speed:g}_{repeat}.csv', run, rng, noise_n)
    spec = directory / 'spec.yaml'
    spec.write_text(SPEC)
    return spec


def _one_layered_trial(task):
    """One trial of a layered study, in a worker: (scene file, sets, speed [m/s], travel [m], hold
    [s]) -> (the run, the values its seed drew)."""
    from tissue_sim_ros.analysis.charting.auto_keys import load_scene
    from tissue_sim_ros.analysis.insertion import run_insertion
    scene_file, sets, speed, travel, hold = task
    scene = load_scene(scene_file, sets=sets)
    return run_insertion(scene, speed, travel, hold_s=hold, tick=0.01), dict(scene.drawn)


def write_layered_study(directory, scene_sets, speeds_mm_s, *, scene_file=None, travel_m=0.026, hold_s=5.0,
                        repeats=5, noise_n=0.005, seed=1, workers=None) -> Path:
    """Write a study whose repeats each draw the scene's spread (module docstring) into
    ``directory``, its simulations over ``workers`` processes; returns its data description's
    path. ``truth.json`` beside it: the scene keys, and per file the values its run drew."""
    from tissue_sim_ros.analysis.jobs import run_jobs
    rng = np.random.default_rng(seed)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    trials = [(speed, repeat) for speed in speeds_mm_s for repeat in range(1, repeats + 1)]
    made_with = {'scene': None if scene_file is None else Path(scene_file).read_text(), 'sets': list(scene_sets),
                 'speeds_mm_s': [float(speed) for speed in speeds_mm_s], 'travel_m': float(travel_m),
                 'hold_s': float(hold_s), 'repeats': int(repeats), 'noise_n': float(noise_n), 'seed': int(seed)}
    spec = directory / 'spec.yaml'
    if _made_with(directory) == made_with and spec.is_file():
        return spec
    (directory / 'truth.json').unlink(missing_ok=True)
    tasks = [(None if scene_file is None else str(scene_file), list(scene_sets) + [f'variation.seed={1000 * seed + k}'],
              speed * 1e-3, travel_m, hold_s) for k, (speed, _) in enumerate(trials, 1)]
    runs = run_jobs(_one_layered_trial, tasks, workers=workers, label='synthetic trials', quiet=True)
    truth = {'scene_file': None if scene_file is None else str(scene_file), 'sets': list(scene_sets),
             'noise_n': noise_n, 'trials': {}, 'made_with': made_with}
    for (speed, repeat), (run, drawn) in zip(trials, runs):
        name = f'trial_{speed:g}_{repeat}.csv'
        _write_trial(directory / name, run, rng, noise_n)
        truth['trials'][name] = {'drawn': {k: float(v) for k, v in drawn.items()},
                                 'punctures': [{'region': e['region'], 'tip_depth_m': float(e['tip_depth_m']),
                                                'axial_force_n': float(e['axial_force_n'])}
                                               for e in run.puncture_events]}
    spec.write_text(SPEC)
    (directory / 'truth.json').write_text(json.dumps(truth, indent=2))    # last: it marks the study whole
    return spec


def _made_with(directory: Path):
    """What made the study in ``directory`` (its ``truth.json``'s record), None when it has none or
    a trial file it names is missing."""
    try:
        truth = json.loads((directory / 'truth.json').read_text())
    except (OSError, ValueError):
        return None
    if not all((directory / name).is_file() for name in truth.get('trials', {})):
        return None
    return truth.get('made_with')
