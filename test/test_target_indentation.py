"""A target in the tissue under the needle moves as a static solve of the same indentation says.

The needle indents the surface (before any puncture) on the linear model and is held until the
tissue has settled. At equilibrium every free node satisfies K u = f, and f is zero except where
the needle acts; so prescribing the nodes that carry a force (read off K u itself) and the fixed
boundary at their settled displacement, a static solve with scipy (K_ff u_f = -K_fc u_c, no
needle, no solver of ours) must give every other node, and the target with them, where the
needle left them.
"""
import numpy as np

from conftest import static_solve
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.scene.scene import Scene

MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
LINEAR = {'geometric': False, 'physical': {'law': 'none'}, 'viscosity_mu_pa_s': 0.0,
          'viscosity_lambda_pa_s': 0.0, 'nonlinearity_threshold': 0.0}


def test_a_target_under_the_needle_moves_as_the_static_solve_of_the_indentation():
    scene = Scene.from_file(None, mesh=MESH, model=LINEAR,
                            targets=[{'name': 'tumour', 'position_m': [0.001, 0.0, -0.008]}])
    driver = SimulationDriver(scene)
    start, q = scene.needle_pose
    axis = scene.needle.axis
    for k in range(1, 61):                     # 12 mm at 10 mm/s: the tip 3 mm into the surface
        driver.advance(0.02, start + 0.0002 * k * axis, q)
    for _ in range(150):                       # held 3 s: settled
        driver.advance(0.02)
    assert scene.phase == 'contact' and not scene.puncture_events
    u = scene.displacement.copy()
    assert np.abs(scene.simulation.velocity).max() < 1e-4 * np.abs(u).max() / 0.02
    model = scene.model
    residual = (model.stiffness_matrix() @ u.ravel()).reshape(-1, 3)
    fixed = np.flatnonzero((scene.simulation.dof_kind != 0).any(axis=1))
    loaded = np.flatnonzero(np.linalg.norm(residual, axis=1) > 1e-6 * np.abs(residual).max())
    held = np.union1d(fixed, loaded)
    assert 0 < len(np.setdiff1d(loaded, fixed)) < 60, 'the needle should load a few nodes only'
    dofs = (3 * held[:, None] + np.arange(3)).ravel()
    static = static_solve(model, dofs, u[held].ravel())
    target = scene.target_positions()[0] - scene.targets.rest[0]
    static_target = scene.targets.positions(static)[0] - scene.targets.rest[0]
    assert target[2] < -2e-4, f'the target should move down by a fraction of a millimetre: {target}'
    np.testing.assert_allclose(target, static_target, rtol=0, atol=0.01 * abs(target[2]))
