"""tissue-sim bench: models in two precisions timed paired in one process, with the forces compared."""

import re

import numpy as np

from tissue_sim_ros.bench import speed as bench
from tissue_sim_ros.engine.mesh.generators import box_mesh
from tissue_sim_ros.engine.model.material import Material
from tissue_sim_ros.engine.model.tensor_mass import TensorMassModel


def test_paired_precisions_time_both_and_compare_their_forces_to_the_element_truth():
    """bench_models on float64 and float32 of the full model with viscosity: the forces it timed
    are the model's own (a fresh float64 evaluation, to the last bit), float32's differ from them
    by float32 rounding (above 1e-12, below 1e-6 of the largest), and the line run() prints says
    the same difference."""
    mesh = box_mesh(size=(0.1, 0.1, 0.05), divisions=bench.SIZES['1e3'])
    material = Material(young_modulus=5e3, poisson_ratio=0.45, density=1060.0)
    models = [TensorMassModel(mesh, material, precision=p, **bench.MODELS['full+visc']) for p in ('float64', 'float32')]
    results = bench.bench_models(models, steps_per_call=2)
    u = bench.needle_dent(mesh)
    exact = TensorMassModel(mesh, material, **bench.MODELS['full+visc']).internal_forces(u, 0.01 * u)
    (force64, step64, fraction64, forces64), (force32, step32, fraction32, forces32) = results
    assert np.array_equal(forces64, exact)
    difference = np.abs(forces32 - exact).max() / np.abs(exact).max()
    assert 1e-12 < difference < 1e-6
    assert fraction64 == fraction32 == 1.0
    assert min(force64, step64, force32, step32) > 0

    lines = []
    rows = bench.run(sizes=['1e3'], models=['full+visc'], precisions=('float64', 'float32'), stream=lines.append)
    assert [(r[0], r[1], r[5]) for r in rows] == [('full+visc', mesh.n_elements, 'float64'),
                                                   ('full+visc', mesh.n_elements, 'float32')]
    (line,) = [line for line in lines if 'as fast as float64' in line]
    printed = float(re.search(r'forces within ([0-9.e+-]+) of the largest', line).group(1))
    assert printed == float(f'{difference:.1e}')


def test_a_precision_given_twice_is_timed_once():
    lines = []
    rows = bench.run(sizes=['1e3'], models=['linear'], precisions=['float32', 'float32'], stream=lines.append)
    assert [r[5] for r in rows] == ['float32']
    assert not any('as fast as' in line for line in lines)
