"""A load-cell study made by the simulator: known parameters, several speeds, noise.

The truth a calibration must recover (tests, the calibration benchmark): the scene's insertion
(:func:`~tissue_sim_ros.analysis.insertion.run_insertion`: in, a hold, out) at each speed,
``repeats`` trials each with white noise of ``noise_n`` on the force and the sample times
jittered by up to 1 ms, written as one CSV per trial (time in s, force in N, position in mm,
speed and repeat in the file name) with the data description that reads them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ['write_synthetic_study']

SPEC = ("files: ['trial_*.csv']\ntime: {column: time, unit: s}\nforce: {column: fz, unit: N}\n"
        "position: {column: pz, unit: mm}\n"
        "file_name: {pattern: 'trial_(?P<speed>[0-9.]+)_(?P<repeat>[0-9]+)', speed_unit: mm/s}\n")


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
            t = np.arange(0.0, run.time[-1], 0.01) + rng.uniform(0.0, 0.001)
            force = np.interp(t, run.time, run.axial_force) + rng.normal(0.0, noise_n, t.size)
            rows = np.column_stack([t, force, 1e3 * np.interp(t, run.time, run.travel)])
            np.savetxt(directory / f'trial_{speed:g}_{repeat}.csv', rows, delimiter=',', fmt='%.6f',
                       header='time,fz,pz', comments='')
    spec = directory / 'spec.yaml'
    spec.write_text(SPEC)
    return spec
