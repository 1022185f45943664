"""Supports where anatomy has them (engine/solver/supports.py, built by engine/scene/build.py): a
block on an elastic foundation settles under gravity to the analytic column, the full model near
the linear one, and supports that cannot stop rigid motion are refused at load naming the key."""
import numpy as np
import pytest

from support.foundations import G, ON_FOUNDATION, RHO, SIZE, block, column
from tissue_sim_ros.errors import SceneError


def test_a_block_on_a_foundation_settles_to_the_analytic_column():
    scene = block(ON_FOUNDATION)
    x, u = scene.mesh.rest_positions, scene.simulation.displacement
    bottom = np.isclose(x[:, 2], 0.0)
    # the foundation carries the weight: its area-weighted settlement is W / (k_n A), exactly
    rows = scene.simulation.support_rows
    stiffness_zz = scene.simulation.support_stiffness[rows[bottom], 2]
    weight = RHO * G * np.prod(SIZE)
    assert -np.sum(stiffness_zz * u[bottom, 2]) == pytest.approx(weight, rel=1e-9)
    assert -np.sum(stiffness_zz * u[bottom, 2]) / np.sum(stiffness_zz) == pytest.approx(column(0.0), rel=1e-9)
    # the top moves by the foundation's settlement plus the column's own compression (lumped
    # gravity on linear elements: 1.4e-4 off at four layers, 2e-5 at eight)
    top = np.isclose(x[:, 2], SIZE[2])
    assert -u[top, 2].mean() == pytest.approx(column(SIZE[2]), rel=0.002)
    # no Poisson effect and no sliding: what moves sideways is the Kuhn split's own skew (1 %)
    assert np.abs(u[:, :2]).max() < 0.02 * column(SIZE[2])
    # the state is the one a reset returns to, and the tissue stays there
    scene.advance(0.05, *scene.initial_needle_pose)
    assert np.abs(scene.simulation.displacement - u).max() < 0.01 * column(SIZE[2])
    scene.reset()
    assert np.array_equal(scene.simulation.displacement, u)


def test_the_full_model_settles_near_the_linear_one():
    linear = block(ON_FOUNDATION).simulation.displacement
    full = block(ON_FOUNDATION, model={'geometric': True}).simulation.displacement
    # 2 % strain at most: the geometric non-linearity moves the sag by about that fraction
    assert np.abs(full - linear).max() < 0.03 * np.abs(linear).max()


def test_the_settled_state_is_the_equilibrium_of_the_model_it_names():
    """With a non-linearity threshold in the middle of the sag's gradients (2 % at the bottom of
    the column, 0 at its top) the state found balances the loads with the model's forces, its
    threshold kept, or set aside (every element non-linear) where that stalled, as it says; the
    threshold is the scene's again afterwards."""
    from tissue_sim_ros.engine.solver.settle import settle
    scene = block(ON_FOUNDATION, model={'geometric': True, 'nonlinearity_threshold': 0.01})
    sim = scene.simulation
    free = sim.dof_kind == 0

    def residual(u, threshold):
        sim.model.set_nonlinearity_threshold(threshold)
        force = sim.model.internal_forces(u, out=np.empty_like(u))
        sim.add_support_forces(u, force)
        force += sim.body_forces
        return np.linalg.norm(force * free) / np.linalg.norm(sim.body_forces * free)
    u, info = settle(sim, tolerance=1e-10)
    assert sim.model.nonlinearity_threshold == 0.01
    named, other = (0.0, 0.01) if info['threshold_set_aside'] else (0.01, 0.0)
    assert residual(u, named) < 1e-9
    assert residual(u, other) > 1e-6          # the threshold matters here: the two differ


def test_a_float32_model_settles_to_its_round_off_near_the_float64_one():
    """A float32 element pass cannot bring the residual to 1e-9 of the loads (its forces' round-off
    is larger): it settles to FLOAT32_TOLERANCE, within float32's reach of the float64 state."""
    from tissue_sim_ros.engine.solver.settle import FLOAT32_TOLERANCE, settle
    double = block(ON_FOUNDATION, model={'geometric': True})
    single = block(ON_FOUNDATION, model={'geometric': True, 'precision': 'float32'})
    u, info = settle(single.simulation)
    assert info['residual'] <= FLOAT32_TOLERANCE
    reference = double.simulation.displacement
    assert np.abs(u - reference).max() < 2 * FLOAT32_TOLERANCE * np.abs(reference).max()


def test_supports_that_cannot_stop_rigid_motion_are_refused_naming_the_key():
    corner = [0.0, 0.0, 0.0, 1e-4]
    with pytest.raises(SceneError, match=r'boundary\.fixed.*holds 1 node.*free to move rigidly'):
        block({'fixed': [{'surface_near_m': corner}]})
    with pytest.raises(SceneError, match=r'rotation'):          # two nodes: a hinge
        block({'fixed': [{'surface_near_m': corner}, {'surface_near_m': [0.04, 0.0, 0.0, 1e-4]}]})
    sliding = {'fixed': [], 'springs': [dict(ON_FOUNDATION['springs'][0], tangential_n_per_m3=0.0)]}
    with pytest.raises(SceneError, match=r'translation along x.*translation along y'):
        block(sliding)
    three = block({'fixed': [{'surface_near_m': corner}, {'surface_near_m': [0.04, 0.0, 0.0, 1e-4]},
                             {'surface_near_m': [0.0, 0.04, 0.0, 1e-4]}]}, gravity=(0.0, 0.0, 0.0))
    assert int((three.simulation.dof_kind == 1).all(axis=1).sum()) == 3
