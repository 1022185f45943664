"""Explicit solver (engine/solver/explicit.py): discrete energy conservation, dissipation, the
stability limit, the watchdog, a quasi-static plate compression against the analytic reaction,
and a mass rung that keeps the damping force."""

import numpy as np
import pytest

import tissue_sim_ros as ts
from support.meshes import _bottom
from tissue_sim_ros.engine.scene.scene import Scene

# Half-step kinetic plus strain energy of a stable leapfrog mode swings up to 2 / (1 - (dt/dt_crit)^2)
# times its amplitude energy (2 from the half-step velocity, the rest from the discrete dispersion).
SWING_AT_0_9 = 2.0 / (1.0 - 0.9 ** 2)


def _perturbed(sim, amplitude=1e-3, seed=0):
    rng = np.random.default_rng(seed)
    free = sim.dof_kind == 0
    sim.displacement[free] = rng.normal(scale=amplitude, size=free.sum())
    return sim


def _leapfrog_invariant_trace(sim, n_steps):
    """H_n = 1/2 v_{n+1/2}.M v_{n-1/2} + 1/2 u_n.K u_n: exactly conserved by undamped symplectic
    Euler on a linear system (a discrete energy; see the solver docstring)."""
    values = np.empty(n_steps)
    for n in range(n_steps):
        u_before = sim.displacement.copy()
        v_before = sim.velocity.copy()
        sim.step()
        kinetic = 0.5 * np.sum(sim.mass[:, None] * sim.velocity * v_before)
        values[n] = kinetic + sim.model.strain_energy(u_before)[0]
    return values


def test_undamped_energy_conserved_over_1e4_steps(small_model):
    sim = _perturbed(ts.Simulation(small_model, fixed=_bottom(small_model.mesh), time_step_safety=0.9))
    initial = small_model.strain_energy(sim.displacement)[0]
    invariant = _leapfrog_invariant_trace(sim, 10_000)
    assert np.abs(invariant / invariant[0] - 1.0).max() < 1e-9
    kinetic, strain = sim.energy()
    assert kinetic + strain < SWING_AT_0_9 * initial    # the ordinary energy stays bounded too
    assert sim.step_count == 10_000


def test_damped_energy_decreases_monotonically(small_model):
    sim = _perturbed(ts.Simulation(small_model, fixed=_bottom(small_model.mesh), damping=20.0,
                                   time_step_safety=0.9))
    invariant = _leapfrog_invariant_trace(sim, 3000)
    assert np.all(np.diff(invariant) < 0.0)
    assert invariant[-1] < 1e-3 * invariant[0]


def test_run_below_limit_bounded_and_above_limit_caught(small_model):
    fixed = _bottom(small_model.mesh)
    stable = _perturbed(ts.Simulation(small_model, fixed=fixed, time_step_safety=0.9))
    initial = small_model.strain_energy(stable.displacement)[0]
    stable.step(5000)
    assert sum(stable.energy()) < SWING_AT_0_9 * initial

    unstable = _perturbed(ts.Simulation(small_model, fixed=fixed, time_step_safety=3.0))
    with pytest.raises(ts.SimulationDiverged) as caught:
        unstable.step(5000)
    error = caught.value
    assert error.step < 5000
    assert error.time_step == pytest.approx(3.0 * error.critical_time_step)
    assert 'energy grew' in str(error) or 'NaN' in str(error)
    assert f'step {error.step}' in str(error) and '3.00x' in str(error)


def test_watchdog_reports_non_finite(small_model):
    sim = ts.Simulation(small_model, fixed=_bottom(small_model.mesh))
    sim.external_forces[-1, 0] = np.nan
    with pytest.raises(ts.SimulationDiverged, match='NaN or infinite') as caught:
        sim.step(10)
    assert caught.value.step == 1


def test_watchdog_catches_a_finite_blow_up_at_once(small_model):
    """A displacement of more than 100 body sizes is reported at the step it appears, not at the
    next energy check (a blow-up can pass 1e38 m, inf in float32, between two checks)."""
    sim = ts.Simulation(small_model, fixed=_bottom(small_model.mesh), check_interval=50)
    free = int(np.flatnonzero(sim.dof_kind[:, 0] == 0)[0])
    sim.displacement[free, 0] = 1e3 * sim.displacement_limit
    with pytest.raises(ts.SimulationDiverged, match='100 body sizes') as caught:
        sim.step(10)
    assert caught.value.step == 1


def test_watchdog_reports_inverted_elements(small_model):
    sim = ts.Simulation(small_model, fixed=_bottom(small_model.mesh), check_interval=1)
    top = np.flatnonzero(np.isclose(small_model.mesh.rest_positions[:, 2], 0.03))
    sim.prescribe(top, lambda t: np.array([0.0, 0.0, -0.05]), axes='z')    # pushed through the bottom
    with pytest.raises(ts.SimulationDiverged, match='inverted'):
        sim.step(5)


def test_quasi_static_plate_compression_matches_E_A_strain(liver):
    size = (0.02, 0.02, 0.02)
    mesh = ts.box_mesh(size=size, divisions=(3, 3, 3))
    model = ts.TensorMassModel(mesh, liver)
    x = mesh.rest_positions
    bottom = np.flatnonzero(np.isclose(x[:, 2], 0.0))
    top = np.flatnonzero(np.isclose(x[:, 2], size[2]))
    origin = np.flatnonzero(np.all(np.isclose(x, 0.0), axis=1))
    corner = np.flatnonzero(np.all(np.isclose(x, [size[0], 0.0, 0.0]), axis=1))
    sim = ts.Simulation(model, damping=200.0)
    sim.fix(bottom, axes='z')
    sim.fix(origin, axes='xy')
    sim.fix(corner, axes='y')
    strain, ramp = 0.02, 0.05
    sim.prescribe(top, lambda t: np.array([0.0, 0.0, -strain * size[2] * min(t / ramp, 1.0)]), axes='z')
    sim.step(int(0.3 / sim.dt))
    reaction = sim.reaction_force(top)
    assert reaction[2] == pytest.approx(liver.young_modulus * size[0] * size[1] * strain, rel=2e-3)


def test_bad_arguments_named(small_model):
    with pytest.raises(ValueError, match='dt'):
        ts.Simulation(small_model, dt=-1.0)
    with pytest.raises(ValueError, match='damping'):
        ts.Simulation(small_model, damping=float('nan'))
    with pytest.raises(ValueError, match='fixed'):
        ts.Simulation(small_model, fixed=[10**6])
    with pytest.raises(ValueError, match='axes'):
        ts.Simulation(small_model).fix([0], axes='w')


def test_a_mass_rung_keeps_the_damping_force_and_lengthens_the_step_by_the_square_root():
    scene = Scene.from_file(None)
    sim = scene.simulation
    mass, gamma, dt, scaling = sim.mass.copy(), sim.mass * sim.damping_rate, sim.dt, sim.mass_scaling
    sim.rescale_masses(16.0 * scaling)
    np.testing.assert_allclose(sim.mass, 16.0 * mass, rtol=1e-12)
    np.testing.assert_allclose(sim.mass * sim.damping_rate, gamma, rtol=1e-12)
    assert sim.dt == pytest.approx(4.0 * dt, rel=1e-12)
    sim.rescale_masses(scaling)                                   # and back, exactly
    np.testing.assert_allclose(sim.mass * sim.damping_rate, gamma, rtol=1e-12)
    assert sim.dt == pytest.approx(dt, rel=1e-12)
