"""The mass scaling's estimated inertia error (engine/solver/inertia_estimate.py) against a second
formulation, an analytic drift and a second simulation without mass scaling."""

import numpy as np
import pytest

from support.scenes import small_scene
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.solver.inertia_estimate import InertiaEstimate, inertia_line, weighted_body_force


def test_weighted_body_force_equals_numpy():
    rng = np.random.default_rng(3)
    n = 200
    mass, rate = rng.uniform(1e-6, 1e-4, n), rng.uniform(0.0, 50.0, n)
    velocity, previous, u = rng.normal(size=(n, 3)), rng.normal(size=(n, 3)), rng.normal(size=(n, 3))
    axis = np.array([0.0, 0.6, -0.8])
    expected = np.sum(mass[:, None] * ((velocity - previous) / 0.02 + rate[:, None] * velocity) * u)
    along = u @ axis
    kept = previous.copy()
    weighted, delta = weighted_body_force(mass, rate, velocity, kept, u, axis, 0.02)
    assert weighted == pytest.approx(expected, rel=1e-12)
    assert delta == along[np.argmax(np.abs(along))]
    assert np.array_equal(kept, velocity)          # the velocity is kept for the next advance


class _Drift:
    """Every node displaced by ``delta`` along the axis and moving at a constant ``v`` along it:
    a rigid translation, so all of the damping force reaches the needle (psi = 1 everywhere)."""

    def __init__(self, mass_scaling, n=50, v=0.003, rate=50.0, integrator='explicit', node_factor=1.0):
        self.mass_scaling = mass_scaling
        self.integrator = integrator
        self.mass = np.full(n, 2e-5 * mass_scaling) * node_factor
        self.added_mass = self.mass - 2e-5
        self.damping_rate = np.full(n, rate)
        self.axis = np.array([0.0, 0.0, -1.0])
        self.velocity = np.tile(v * self.axis, (n, 1))
        self.displacement = np.tile(1e-3 * self.axis, (n, 1))


@pytest.mark.parametrize('mass_scaling', [1.0, 4.0, 400.0])
def test_a_steady_drift_adds_the_scaled_damping_force(mass_scaling):
    sim = _Drift(mass_scaling)
    estimate = InertiaEstimate()
    t, tick = 0.0, 0.02
    for k in range(501):                       # 10 s, the force ramping 0 -> 1 N
        estimate.update(sim, tick if k else 0.0, sim.axis, k / 500)
        t += tick
    added = (1 - 1 / mass_scaling) * sim.damping_rate[0] * sim.mass.sum() * 0.003
    # the exponential average starts at 0: over 10 s with tau 0.1 s the rms is 1 % low
    assert estimate.rms_n == pytest.approx(added, rel=0.02, abs=1e-15)
    assert estimate.error == pytest.approx(added / 1.0, rel=0.02, abs=1e-15)
    if mass_scaling == 1.0:
        assert estimate.rms_n == 0.0


def test_selective_mass_scaling_adds_each_node_its_own_share():
    """Each node scaled by its own factor (selective mass scaling, no uniform one): the drift adds
    c v sum_i (s_i - 1) m_i, and the line every run prints names the added mass."""
    factors = np.where(np.arange(50) < 5, 9.0, 1.0)        # a tenth of the nodes at 9x
    sim = _Drift(1.0, node_factor=factors)
    estimate = InertiaEstimate()
    for k in range(501):
        estimate.update(sim, 0.02 if k else 0.0, sim.axis, k / 500)
    added = sim.damping_rate[0] * 0.003 * np.sum((factors - 1.0) * 2e-5)
    assert estimate.rms_n == pytest.approx(added, rel=0.02)
    line = inertia_line(1.0, estimate.error, estimate.rms_n, 'explicit', selective_fraction=0.8)
    assert line.startswith("mass scaling 1 and 80.00% more at the smallest elements' nodes: estimated inertia")


def test_a_quasi_static_run_has_no_inertia_to_scale():
    """The quasi-static integrator drops the masses: the same drift at mass scaling 400 adds
    nothing, and the line every run prints says so instead of an error estimate."""
    sim = _Drift(400.0, integrator='quasi_static')
    estimate = InertiaEstimate()
    for k in range(101):
        estimate.update(sim, 0.02 if k else 0.0, sim.axis, k / 100)
    assert estimate.rms_n == 0.0 and estimate.error is None
    assert inertia_line(400.0, estimate.error, estimate.rms_n, 'quasi_static').startswith('quasi-static: no inertia')
    assert 'mass scaling 400: estimated inertia error' in inertia_line(400.0, 0.01, 0.002, 'implicit')


def test_a_puncture_moved_by_the_added_force_counts_its_drop():
    """A membrane that ruptures at 3 N under a force ramping at 0.5 N/s, dropping 1 N: the scaled
    run carries the drift's added force A (0.06 N at mass scaling 400) on top, so it ruptures
    A / (0.5 N/s) earlier. The estimate equals the rms difference of the two force histories,
    integrated on a 1 ms grid, within 5 %; the added force alone (A) is less than half of it."""
    sim = _Drift(400.0)
    added = (1 - 1 / 400.0) * sim.damping_rate[0] * sim.mass.sum() * 0.003
    rate, rupture, drop, duration, tick = 0.5, 3.0, 1.0, 10.0, 0.02

    def force(t, offset):      # ramp until the force with the offset reaches the rupture, then flat
        return np.where(rate * t + offset < rupture, rate * t, rupture - drop) + offset

    estimate = InertiaEstimate()
    for k in range(round(duration / tick) + 1):
        t = k * tick
        scaled = float(force(t, added))
        estimate.update(sim, tick if k else 0.0, sim.axis, scaled, int(rate * t + added >= rupture))
    fine = np.linspace(0.0, duration, 10001)
    exact = np.sqrt(np.mean((force(fine, added) - force(fine, 0.0)) ** 2))
    assert estimate.puncture_shifts_s == [pytest.approx(added / rate, rel=0.02)]
    assert exact > 1.9 * added
    assert estimate.rms_n == pytest.approx(exact, rel=0.05)


def _push(mass_scaling, *, speed=0.01, travel=0.003, tick=0.02, **solver):
    scene = small_scene(solver={'mass_scaling': mass_scaling, **solver})
    driver = SimulationDriver(scene)
    n = round(travel / speed / tick)
    p, q = scene.needle_pose
    samples = driver.follow(np.arange(1, n + 1) * tick, p + np.outer(np.arange(1, n + 1) / n * travel, scene.needle.axis))
    return -(samples.force @ scene.needle.axis), driver.inertia


def test_the_estimate_matches_the_error_measured_against_no_mass_scaling():
    """The small sample pushed 3 mm at 10 mm/s, mass scaling 25 and 100 against 1: the estimate
    is at least 0.6 of the measured force NRMSE, and within 40 % of it where the inertia error is the
    force's (measured 0.0016 and 0.0129, estimated 0.0037 and 0.0141). At 25 the error is near
    what the contact's start leaves in a run without mass scaling too, and the first-order
    estimate is within a factor 2.5 above it. The plain momentum balance, all of the body force
    on the needle, read 0.0137 and 0.054: the walls carry most of it."""
    unscaled, none = _push(1.0)
    assert none.rms_n == 0.0
    for scaling, above in ((25.0, 2.5), (100.0, 1.4)):
        force, estimate = _push(scaling)
        measured = np.sqrt(np.mean((force - unscaled) ** 2)) / np.ptp(unscaled)
        assert measured > 1e-3
        assert 0.6 * measured <= estimate.error <= above * measured, scaling


def test_the_estimate_follows_selective_mass_scaling_too():
    """The same push with no uniform scaling and the step raised 10-fold by selective mass
    scaling (on this sample graded around the needle's path it adds most of its mass where the
    needle pushes: x93 in all): the estimate is within 40 % of the measured error (0.0259,
    estimated 0.0220)."""
    unscaled, _ = _push(1.0)
    force, estimate = _push(1.0, selective_mass_scaling=10.0)
    measured = np.sqrt(np.mean((force - unscaled) ** 2)) / np.ptp(unscaled)
    assert measured > 1e-3
    assert 0.6 * measured <= estimate.error <= 1.4 * measured


def test_a_reset_restarts_the_estimate():
    scene = small_scene(solver={'mass_scaling': 100.0})
    driver = SimulationDriver(scene)
    p, q = scene.needle_pose
    driver.follow([0.1, 0.2], [p + 0.001 * scene.needle.axis, p + 0.002 * scene.needle.axis])
    assert driver.inertia.error > 0
    driver.reset()
    assert driver.inertia.error is None and driver.inertia.rms_n == 0.0
