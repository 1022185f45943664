"""The ladder's errors measured on the scene (engine/ladder_probe.py): the rungs are ordered by
error, and the mass rungs cost little with the damping kept."""

import math

import numpy as np
import pytest

from tissue_sim_ros.engine.ladder import DegradationLadder
from tissue_sim_ros.engine.ladder_probe import probe_errors
from tissue_sim_ros.engine.scene.scene import Scene


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
