"""A coarse scene with a target under the needle, and a straight descent as a candidate path."""

import numpy as np

from tissue_sim_ros.engine.scene.scene import Scene

COARSE = {'generator': 'box', 'divisions': [6, 6, 4]}
TUMOUR = [{'name': 'tumour', 'position_m': [0.002, 0.0, -0.012]}]
TICK = 0.02
SPEED = 0.005


def _scene():
    return Scene.from_file(None, mesh=COARSE, targets=TUMOUR)


def _down(scene, start_s, seconds, t0=0.0):
    """A straight path down the needle axis at SPEED, a pose per tick, from the pose the needle
    reaches after ``start_s`` of the same motion."""
    p0, q = scene.initial_needle_pose
    axis = scene.needle.axis
    t = np.arange(0.0, seconds + 1e-9, TICK)
    positions = p0 + ((start_s + t) * SPEED)[:, None] * axis
    return t0 + t, positions, np.tile(q, (t.size, 1))
