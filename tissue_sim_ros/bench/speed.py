"""Speed benchmark: force evaluation and full explicit step per model and mesh size.

Prints tet-steps per second (elements x steps / wall second) and the largest mesh that runs
one step in 20 ms, the paper's measure (50 Hz with 17000 / 2500 / 350 tetrahedra for the
linear / physically non-linear / full model on a 1 GHz Pentium III).
"""
import functools
import time

import numpy as np

from tissue_sim_ros.engine.model.material import Material, MeanRatioLaw, Viscosity
from tissue_sim_ros.engine.mesh.generators import box_mesh
from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel
from tissue_sim_ros.engine.solver.explicit import Simulation

import numba  # noqa: E402  after the engine: its threading policy must come first

# divisions of a box of 6 nx ny nz tetrahedra: about 1e3, 1e4, 1e5, 5e5
SIZES = {'1e3': (8, 7, 3), '1e4': (15, 15, 8), '1e5': (32, 32, 16), '5e5': (56, 55, 28)}
PAPER_TETS_AT_50HZ = {'linear': 17000, 'physical': 2500, 'full': 350}

_LAW = MeanRatioLaw.exponential(lambda_amplitude=0.5, lambda_rate=8.0, mu_amplitude=1.5, mu_rate=12.0)
_VISCOSITY = Viscosity(lambda_v=5.0, mu_v=2.0)
MODELS = {
    'linear': dict(),
    'linear+visc': dict(viscosity=_VISCOSITY),
    'physical': dict(physical=_LAW),
    'physical+visc': dict(physical=_LAW, viscosity=_VISCOSITY),
    'geometric': dict(geometric=True),
    'geometric+visc': dict(geometric=True, viscosity=_VISCOSITY),
    'full': dict(geometric=True, physical=_LAW),
    'full+visc': dict(geometric=True, physical=_LAW, viscosity=_VISCOSITY),
    'full+thr0.02': dict(geometric=True, physical=_LAW, viscosity=_VISCOSITY, nonlinearity_threshold=0.02),
}


def needle_dent(mesh, depth=0.005, radius=0.005):
    """A needle-like local deformation: the top surface pushed down by ``depth`` under a point,
    decaying as a Gaussian of ``radius`` with distance and with depth into the block."""
    x = mesh.rest_positions
    top = x[:, 2].max()
    centre = np.array([x[:, 0].mean(), x[:, 1].mean(), top])
    distance = np.linalg.norm(x - centre, axis=1)
    u = np.zeros_like(x)
    u[:, 2] = -depth * np.exp(-(distance / radius) ** 2)
    return u


def _best_per_call(functions, repeats=5, min_seconds=0.1, min_calls=3):
    """Best over ``repeats`` of the mean time per call in a >= min_seconds batch (seconds), for
    each function. The functions' batches alternate within each repeat, so that what drifts on a
    shared machine (timings in separate processes here differ by 20-30 %) falls on all of them."""
    for function in functions:
        function()                              # warm (compiled at import via cache)
    best = [float('inf')] * len(functions)
    for repeat in range(repeats):
        order = list(enumerate(functions))
        for k, function in (order if repeat % 2 == 0 else order[::-1]):     # none always goes first
            calls, start = 0, time.perf_counter()
            while calls < min_calls or time.perf_counter() - start < min_seconds:
                function()
                calls += 1
            best[k] = min(best[k], (time.perf_counter() - start) / calls)
    return best


def _timed_simulation(model, u):
    """A Simulation holding the dent, fixed at the bottom, on a tiny step that keeps the dent in
    place while timing (stability is not what is measured here)."""
    rest = model.mesh.rest_positions
    bottom = np.flatnonzero(np.isclose(rest[:, 2], rest[:, 2].min()))
    sim = Simulation(model, damping=10.0, fixed=bottom, dt=1e-9)
    sim.displacement[:] = u
    sim.displacement[bottom] = 0.0
    return sim


def bench_models(models, steps_per_call=10):
    """[(force evaluation s, full step s, non-linear fraction, forces)] for models on one mesh,
    on a needle dent, timed in alternating batches (_best_per_call)."""
    u = needle_dent(models[0].mesh)
    v = 0.01 * u
    outs = [np.empty_like(u) for _ in models]
    force_times = _best_per_call([functools.partial(model.internal_forces, u, v, out=out)
                                  for model, out in zip(models, outs)])
    fractions = [model.nonlinear_fraction for model in models]
    sims = [_timed_simulation(model, u) for model in models]
    step_times = _best_per_call([functools.partial(sim.step, steps_per_call) for sim in sims])
    return [(force, step / steps_per_call, fraction, out)
            for force, step, fraction, out in zip(force_times, step_times, fractions, outs)]


def run(sizes=None, models=None, material=None, stream=print, precisions=('float64',)):
    """Print and return rows (model, tetrahedra, force s, step s, tet-steps/s, precision). With
    several precisions each model is timed in each, paired in one process, and the line after
    says how much faster the step is and how far the forces are from the first precision's."""
    material = material or Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)
    precisions = list(dict.fromkeys(precisions))        # each once, in the order given
    sizes = sizes or list(SIZES)
    models = {name: MODELS[name] for name in (models or MODELS)}
    paired = len(precisions) > 1
    stream(f'threads: {numba.get_num_threads()} ({numba.config.THREADING_LAYER} layer); best of 5 batches; '
           f'element pass in {", ".join(precisions)}' + (' (timed in alternating batches, paired)' if paired else ''))
    stream('displacement: a needle-like dent, 5 mm deep, 5 mm Gaussian radius, at the top centre')
    stream(f'{"model":<15} {"tets":>8} {"force [ms]":>11} {"step [ms]":>10} {"tet-steps/s":>12} {"non-linear":>11}'
           + (' precision' if paired else ''))
    rows = []
    for label in sizes:
        mesh = box_mesh(size=(0.1, 0.1, 0.05), divisions=SIZES[label])
        for name, options in models.items():
            built = [TensorMassModel(mesh, material, precision=precision, **options) for precision in precisions]
            results = bench_models(built)
            for precision, (force_time, step_time, fraction, _) in zip(precisions, results):
                rate = mesh.n_elements / step_time
                rows.append((name, mesh.n_elements, force_time, step_time, rate, precision))
                stream(f'{name:<15} {mesh.n_elements:>8} {force_time * 1e3:>11.3f} {step_time * 1e3:>10.3f} '
                       f'{rate:>12.3g} {fraction:>10.1%}' + (f' {precision}' if paired else ''))
            first_step, first_forces = results[0][1], results[0][3]
            for precision, (_, step_time, _, forces) in zip(precisions[1:], results[1:]):
                difference = np.abs(forces - first_forces).max() / np.abs(first_forces).max()
                stream(f'  {precision}: step {first_step / step_time:.2f}x as fast as {precisions[0]}, forces '
                       f'within {difference:.1e} of the largest')
    stream('largest mesh at one step per 20 ms (rate at the largest size x 0.02 s), against the paper:')
    width = 23 if paired else 15
    for precision in precisions:
        for name in models:
            rate = [r for r in rows if r[0] == name and r[5] == precision][-1][4]
            paper = PAPER_TETS_AT_50HZ.get(name)
            label = f'{name} {precision}' if paired else name
            stream(f'  {label:<{width}} {rate * 0.02:>10.3g} tets' + (f'   (paper: {paper})' if paper else ''))
    linear = {r[1]: r[3] for r in rows if r[0] == 'linear' and r[5] == precisions[0]}
    for name in ('full', 'full+visc'):
        ratios = [f'{r[3] / linear[r[1]]:.2f}' for r in rows
                  if r[0] == name and r[5] == precisions[0] and r[1] in linear]
        if ratios:
            stream(f'cost of {name} / linear per step{f" ({precisions[0]})" if paired else ""}, by size: '
                   f'{", ".join(ratios)}   (paper: 49)')
    return rows
