"""The paper's precomputed non-linear form (engine/model/reference.py) against the deformation
gradient form of the kernels, on random elements at strains of order one."""

import numpy as np

import tissue_sim_ros as ts
from tissue_sim_ros.engine.model.reference import picinbono_forces


def test_picinbono_form_equals_deformation_gradient_form_on_random_elements():
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(25):
        mesh = ts.make_mesh(rng.normal(size=(4, 3)), np.array([[0, 1, 2, 3]]))
        material = ts.Material(young_modulus=rng.uniform(1e3, 1e5), poisson_ratio=rng.uniform(0.0, 0.49),
                               density=1000.0)
        model = ts.TensorMassModel(mesh, material, geometric=True, inversion_safeguard=False)
        size = np.abs(mesh.rest_positions).max()
        u = rng.normal(scale=0.5 * size, size=(4, 3))                 # strains of order 1
        kernel = model.internal_forces(u)
        reference = picinbono_forces(model.tetrahedra, model.shape_gradients, model.volume_lambda,
                                     model.volume_mu, u)
        worst = max(worst, np.abs(kernel - reference).max() / np.abs(reference).max())
    assert worst < 1e-12
    print(f'Picinbono K/c/d form vs P = F S kernel: worst relative difference {worst:.2e}')
