"""Several needles in one tissue: two needles 5 mm apart, each driven down during its window."""

import numpy as np

from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.scene.scene import Scene

MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
DOWN = np.array([0.0, 0.0, -1.0])
SPEED, TICK = 0.005, 0.02


def _run(needles, moves, seconds):
    """Drive each needle down at SPEED during its (start, end) window of ``moves`` [s]; per tick
    the forces of every needle (k, n, 3)."""
    scene = Scene.from_file(None, mesh=MESH, needles=needles)
    driver = SimulationDriver(scene)
    starts = [needle.position.copy() for needle in scene.needles]
    q = scene.needle.orientation.copy()
    forces = []
    for k in range(1, int(round(seconds / TICK)) + 1):
        t = k * TICK
        poses = [(p + DOWN * SPEED * min(max(t - a, 0.0), b - a), q) for p, (a, b) in zip(starts, moves)]
        driver.advance(TICK, *poses[0], others=poses[1:])
        forces.append(driver.forces.copy())
    return scene, np.array(forces)


TWO = [{'name': 'biopsy', 'initial_position_m': [0.0, 0.0, 0.159]},
       {'name': 'fixation', 'initial_position_m': [0.005, 0.0, 0.159]}]
