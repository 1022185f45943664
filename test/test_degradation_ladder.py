"""The degradation ladder's rungs: what a mass rung changes, and their order by error.

Truth: the damping force gamma_i = m_i rate_i a mass rung must keep (an invariant, exactly), the
critical step's square-root law, and the ladder probe's own errors, against the same probe with
the damping scaled along with the masses (as the rungs did before)."""
import math

import numpy as np
import pytest

from tissue_sim_ros.engine.ladder import DegradationLadder
from tissue_sim_ros.engine.ladder_probe import probe_errors
from tissue_sim_ros.engine.scene.scene import Scene


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


def test_the_rungs_are_ordered_by_error_and_the_mass_rungs_cost_little_with_the_damping_kept(monkeypatch):
    """On the default scene each rung's probe error is at least the one above's; the mass rungs
    (a quarter of the substeps at x16) stay within 2 % of the force range, and what x4 and x16
    add to the threshold rung's error is less than a tenth of what they added with the damping
    scaled along with the masses."""
    scene = Scene.from_file(None)
    scene.model.set_threads(1)
    ladder = DegradationLadder(scene)
    names = [rung.name for rung in ladder.rungs]
    assert names == ['as configured', 'non-linearity threshold 0.1', 'mass scaling x4, time step x2',
                     'mass scaling x16, time step x4', 'non-linearity threshold 0.5']
    kept = probe_errors(scene, ladder)
    print('damping force kept:', np.round(kept, 4))
    assert kept[0] == 0.0 and np.all(np.diff(kept) >= -1e-3)
    assert kept[3] < 0.02

    from tissue_sim_ros.engine.solver import explicit as solver
    original = solver.Simulation.rescale_masses

    def damping_scaled_along(self, mass_scaling):
        ratio = mass_scaling / self.mass_scaling
        original(self, mass_scaling)
        self.damping_rate *= ratio                                # the rate kept: the force scales
    monkeypatch.setattr(solver.Simulation, 'rescale_masses', damping_scaled_along)
    scaled = probe_errors(scene, ladder)
    print('damping scaled along:', np.round(scaled, 4))
    assert scaled[1] == pytest.approx(kept[1], abs=1e-12)          # the threshold rung is the same run
    assert math.isfinite(scaled[3]) and scaled[3] - scaled[1] > 10.0 * (kept[3] - kept[1])


def test_no_mass_rung_steps_longer_than_the_cap():
    """The default scene's x4 and x16 steps (2.5, 4.9 ms) are within the cap and offered; a coarse
    box's (17.8, 35.6 ms from 8.9) are not, and its ladder goes from threshold 0.1 to 0.5."""
    from tissue_sim_ros.engine.ladder import MAX_RUNG_TIME_STEP_S
    for sets, offered in ((None, {4.0, 16.0}), ({'generator': 'box', 'divisions': [6, 6, 4]}, set())):
        scene = Scene.from_file(None, mesh=sets) if sets else Scene.from_file(None)
        ladder = DegradationLadder(scene)
        factors = {rung.mass_factor for rung in ladder.rungs} - {1.0}
        print(f'{"box" if sets else "default"}: dt {scene.simulation.dt * 1e3:.2f} ms, rungs '
              f'{[rung.name for rung in ladder.rungs]}')
        assert factors == offered
        assert all(scene.simulation.dt * math.sqrt(f) <= MAX_RUNG_TIME_STEP_S for f in factors)
        assert ladder.rungs[-1].threshold == 0.5


def test_a_scene_set_up_at_a_higher_mass_scaling_equals_one_rescaled_at_run_time():
    """with_mass_scaling (the calibration's affordable-stiffness rule) and rescale_masses (the
    ladder's and predictions' rule) are one rule: the same masses and damping force. The step:
    the run-time one grows as sqrt(mass) (the elastic limit), the scene's own estimate faster
    (the Kelvin-Voigt limit grows with the mass itself), so the run-time step stays stable."""
    from tissue_sim_ros.engine.scene.keys import with_mass_scaling
    scene = Scene.from_file(None)
    scaling = scene.simulation.mass_scaling
    heavier = Scene(with_mass_scaling(scene.spec, 4.0 * scaling)).simulation
    sim = scene.simulation
    dt0 = sim.dt
    sim.rescale_masses(4.0 * scaling)
    np.testing.assert_allclose(heavier.mass, sim.mass, rtol=1e-12)
    np.testing.assert_allclose(heavier.damping_rate, sim.damping_rate, rtol=1e-12)
    assert sim.dt == pytest.approx(2.0 * dt0, rel=1e-12)
    assert sim.dt <= heavier.dt <= heavier.critical_time_step()
