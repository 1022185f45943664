"""Speed benchmark: force evaluation and full explicit step per model and mesh size.

Prints tet-steps per second (elements x steps / wall second) and the largest mesh that runs
one step in 20 ms, the paper's measure (50 Hz with 17000 / 2500 / 350 tetrahedra for the
linear / physically non-linear / full model on a 1 GHz Pentium III).
"""
import time

import numba
import numpy as np

from tissue_sim_ros.engine.material import Material
from tissue_sim_ros.engine.mesh import box_mesh
from tissue_sim_ros.engine.model import TensorMassModel
from tissue_sim_ros.engine.solver import Simulation

# divisions of a box of 6 nx ny nz tetrahedra: about 1e3, 1e4, 1e5, 5e5
SIZES = {'1e3': (8, 7, 3), '1e4': (15, 15, 8), '1e5': (32, 32, 16), '5e5': (56, 55, 28)}
PAPER_TETS_AT_50HZ = {'linear': 17000}


def _time_per_call(function, repeats=5, min_seconds=0.1, min_calls=3):
    """Best over ``repeats`` of the mean time per call in a >= min_seconds batch (seconds)."""
    function()                                  # warm (compiled at import via cache)
    best = float('inf')
    for _ in range(repeats):
        calls, start = 0, time.perf_counter()
        while calls < min_calls or time.perf_counter() - start < min_seconds:
            function()
            calls += 1
        best = min(best, (time.perf_counter() - start) / calls)
    return best


def bench_model(model, steps_per_call=10):
    """(force evaluation seconds, full step seconds) for one model on its mesh."""
    mesh = model.mesh
    rng = np.random.default_rng(0)
    u = rng.normal(scale=1e-4, size=(mesh.n_nodes, 3))
    v = rng.normal(scale=1e-4, size=(mesh.n_nodes, 3))
    out = np.empty_like(u)
    force_time = _time_per_call(lambda: model.internal_forces(u, v, out=out))
    bottom = np.flatnonzero(np.isclose(mesh.rest_positions[:, 2], mesh.rest_positions[:, 2].min()))
    sim = Simulation(model, damping=10.0, fixed=bottom)
    sim.displacement[:] = u * 0.01
    sim.displacement[bottom] = 0.0
    step_time = _time_per_call(lambda: sim.step(steps_per_call)) / steps_per_call
    return force_time, step_time


def run(sizes=None, models=None, material=None, stream=print):
    material = material or Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)
    sizes = sizes or list(SIZES)
    models = models or {'linear': {}}
    stream(f'threads: {numba.get_num_threads()} ({numba.config.THREADING_LAYER} layer); best of 5 batches')
    stream(f'{"model":<12} {"tets":>8} {"force [ms]":>11} {"step [ms]":>10} {"tet-steps/s":>12}')
    rows = []
    for name, options in models.items():
        for label in sizes:
            mesh = box_mesh(size=(0.1, 0.1, 0.05), divisions=SIZES[label])
            model = TensorMassModel(mesh, material, **options)
            force_time, step_time = bench_model(model)
            rate = mesh.n_elements / step_time
            rows.append((name, mesh.n_elements, force_time, step_time, rate))
            stream(f'{name:<12} {mesh.n_elements:>8} {force_time * 1e3:>11.3f} {step_time * 1e3:>10.3f} {rate:>12.3g}')
    stream('largest mesh at one step per 20 ms (rate at the largest size x 0.02 s), against the paper:')
    for name in models:
        rate = [r for r in rows if r[0] == name][-1][4]
        paper = PAPER_TETS_AT_50HZ.get(name)
        stream(f'  {name:<12} {rate * 0.02:>10.3g} tets' + (f'   (paper: {paper})' if paper else ''))
    return rows
