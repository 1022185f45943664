"""Inversion safeguard of the St Venant-Kirchhoff path: exact where it is not triggered,
continuous at the clamp, restoring for inverted elements, and a 70 % compression that stays
bounded."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from tissue_sim_ros.engine.model.kernels import STRETCH_CLAMP


def test_untriggered_elements_are_exact_st_venant_kirchhoff(jittered_block, liver):
    u = np.random.default_rng(3).normal(scale=5e-4, size=(jittered_block.n_nodes, 3))   # strains ~ 5 %
    guarded = ts.TensorMassModel(jittered_block, liver, geometric=True)
    plain = ts.TensorMassModel(jittered_block, liver, geometric=True, inversion_safeguard=False)
    assert np.array_equal(guarded.internal_forces(u), plain.internal_forces(u))
    assert guarded.safeguarded_count == 0


def test_elements_set_aside_but_not_compressed_keep_st_venant_kirchhoff(jittered_block, liver):
    """A homogeneous shear of 0.8: |H|_F is past the cheap bound, so every element takes the
    exact test (smallest stretch 0.68 > STRETCH_CLAMP: not set aside, not changed); with the
    physically non-linear law and viscosity the forces equal the unguarded model's to round-off."""
    mesh = jittered_block
    shear = np.eye(3)
    shear[0, 1] = 0.8
    u = mesh.rest_positions @ (shear - np.eye(3)).T
    v = np.random.default_rng(5).normal(scale=0.01, size=u.shape)
    options = dict(geometric=True, physical=ts.MeanRatioLaw.exponential(0.5, 8.0, 1.5, 12.0),
                   viscosity=ts.Viscosity(lambda_v=1.0, mu_v=2.0))
    guarded = ts.TensorMassModel(mesh, liver, **options)
    plain = ts.TensorMassModel(mesh, liver, inversion_safeguard=False, **options)
    expected = plain.internal_forces(u, v)
    difference = np.abs(guarded.internal_forces(u, v) - expected).max() / np.abs(expected).max()
    assert np.sqrt(np.linalg.eigvalsh(shear.T @ shear).min()) > STRETCH_CLAMP
    assert difference < 1e-13
    assert guarded.safeguarded_count == 0


def test_safeguard_takes_exactly_the_elements_below_the_clamp_or_inverted(jittered_block, liver):
    """Homogeneous random deformations near the clamp: the force loop's test (Sylvester's
    criterion on F^T F - clamp^2 I, and det F) must pick out every element whose smallest singular
    value (numpy's SVD) is below STRETCH_CLAMP or whose det F <= 0, and no other."""
    mesh = jittered_block
    model = ts.TensorMassModel(mesh, liver, geometric=True)
    rng = np.random.default_rng(11)
    seen = set()
    for _ in range(40):
        f = np.eye(3) + rng.normal(scale=0.35, size=(3, 3))
        below = np.linalg.svd(f, compute_uv=False).min() < STRETCH_CLAMP or np.linalg.det(f) <= 0
        model.internal_forces(mesh.rest_positions @ (f - np.eye(3)).T)
        assert model.safeguarded_count == (mesh.n_elements if below else 0), f
        seen.add(bool(below))
    assert seen == {True, False}


def _uniaxial_force(model, mesh, stretch, lateral=1.0):
    u = mesh.rest_positions @ (np.diag([stretch, lateral, lateral]) - np.eye(3)).T
    force = model.internal_forces(u)
    x_max = np.isclose(mesh.rest_positions[:, 0], mesh.rest_positions[:, 0].max())
    return -force[x_max, 0].sum()


def test_stress_continuous_at_clamp_and_monotone_below(liver):
    mesh = ts.box_mesh(size=(0.01, 0.01, 0.01), divisions=(2, 2, 2))
    model = ts.TensorMassModel(mesh, liver, geometric=True)
    eps = 1e-7
    above = _uniaxial_force(model, mesh, STRETCH_CLAMP + eps)
    below = _uniaxial_force(model, mesh, STRETCH_CLAMP - eps)
    assert below == pytest.approx(above, rel=1e-5)
    stretches = np.linspace(STRETCH_CLAMP, -0.5, 12)             # through zero into inversion
    forces = [_uniaxial_force(model, mesh, s) for s in stretches]
    assert np.all(np.diff(forces) < 0)                            # ever more compressive: pushes back
    plain = ts.TensorMassModel(mesh, liver, geometric=True, inversion_safeguard=False)
    unguarded = [_uniaxial_force(plain, mesh, s) for s in stretches]
    assert unguarded[-1] > 0                                      # plain StVK pushes an inverted block further in
    assert model.safeguarded_count == mesh.n_elements


def test_inverted_element_is_pushed_back_out(liver):
    rest = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 1.0]]) * 0.01
    mesh = ts.make_mesh(rest, np.array([[0, 1, 2, 3]]))
    model = ts.TensorMassModel(mesh, liver, geometric=True)
    u = np.zeros((4, 3))
    u[3, 2] = -0.015                                              # apex pushed through its base
    force = model.internal_forces(u)
    assert force[3, 2] > 0 and model.safeguarded_count == 1


def _compress_seventy_percent(liver, safeguard):
    size = 0.02
    mesh = ts.box_mesh(size=(size, size, size), divisions=(3, 3, 3))
    model = ts.TensorMassModel(mesh, liver, geometric=True, inversion_safeguard=safeguard)
    x = mesh.rest_positions
    top = np.flatnonzero(np.isclose(x[:, 2], size))
    sim = ts.Simulation(model, damping=100.0, time_step_safety=0.2)   # compression shortens the step
    sim.fix(np.flatnonzero(np.isclose(x[:, 2], 0.0)), axes='z')
    sim.fix(np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1)), axes='xy')
    sim.fix(np.flatnonzero(np.all(np.isclose(x, [size, 0, 0]), axis=1)), axes='y')
    ramp = 0.4
    sim.prescribe(top, lambda t: np.array([0.0, 0.0, -0.7 * size * min(t / ramp, 1.0)]), axes='z')
    sim.step(int(0.5 / sim.dt))
    return sim, model, top


def test_seventy_percent_compression_stays_bounded(liver):
    """With the safeguard the run ends finite and bounded (the watchdog's energy check passes
    every 50 steps) and reports how many elements it had to treat; plain StVK is stopped."""
    sim, model, top = _compress_seventy_percent(liver, safeguard=True)
    reaction = sim.reaction_force(top)[2]
    inverted = model.strain_energy(sim.displacement)[1]
    assert np.isfinite(sim.displacement).all() and np.isfinite(reaction)
    assert reaction > 0.0
    assert sim.max_safeguarded_elements > 0
    assert inverted < 0.05 * model.mesh.n_elements
    print(f'70 % compression: reaction {reaction:.3f} N, {sim.safeguarded_elements} of '
          f'{model.mesh.n_elements} elements safeguarded, {inverted} inverted and held, dt {sim.dt:.3g} s')
    with pytest.raises(ts.SimulationDiverged) as plain:
        _compress_seventy_percent(liver, safeguard=False)
    print(f'plain St Venant-Kirchhoff: {plain.value.reason} at step {plain.value.step}')
