"""The degradation ladder (engine/ladder.py): no mass rung steps longer than the cap."""

import math

from tissue_sim_ros.engine.ladder import DegradationLadder
from tissue_sim_ros.engine.scene.scene import Scene


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
