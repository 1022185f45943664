"""What a compiled substep decides after the needle's step (engine/compiled/outcomes.py): its
watchdog's energy limit is Simulation's own."""
import numpy as np

from support.scenes import COARSE_FAR
from tissue_sim_ros.engine.compiled import outcomes
from tissue_sim_ros.engine.scene.scene import Scene


def test_the_compiled_watchdog_limit_is_the_simulations():
    """The compiled substep's energy limit is Simulation._energy_limit: a kinetic energy 1e-12
    below it passes, 1e-12 above it trips, for work put in below and above zero."""
    scene = Scene.from_file(sets=COARSE_FAR)
    sim = scene.simulation
    scene.advance(0.01, *scene.needle_pose)
    needle = scene.needle
    for work_in, step_work in ((-2e-3, 1e-4), (0.0, 0.0), (3e-2, -1e-3), (5.0, 2e-3)):
        sim.input_work = work_in + step_work
        limit = sim._energy_limit()
        watch = np.array([sim.energy_limit_factor(), sim.reference_energy, sim.energy_floor])
        for kinetic, passes in ((limit * (1 - 1e-12), True), (limit * (1 + 1e-12), False)):
            energy = np.array([work_in])
            moved = [a.copy() for a in (needle.position, needle.axis, needle.position, needle.axis, needle.tip)]
            assert outcomes.move_and_watch(0.5, step_work, kinetic, 0, needle.position, np.zeros(3), energy,
                                           watch, moved[0], moved[1], moved[2], moved[3],
                                           needle.geometry.length_m, moved[4]) == passes
            assert energy[0] == sim.input_work
        assert not outcomes.move_and_watch(0.5, step_work, 0.0, 1, needle.position, np.zeros(3),
                                           np.array([work_in]), watch, *moved[:4],
                                           needle.geometry.length_m, moved[4])
