"""A flexible needle in a small phantom (bench.steering.PHANTOM): scenes, insertions and the
bevel's own bend, shared by the steering and rod-coupling tests."""
import numpy as np

from tissue_sim_ros.analysis.steering import insert_path, path_curvature
from tissue_sim_ros.bench.steering import PHANTOM, needle_sets
from tissue_sim_ros.engine.scene.scene import Scene

#: insertion speed [m/s] and depth below the surface [m] of the phantom's runs
SPEED = 0.01
DEPTH = 0.02


def phantom(*sets):
    return Scene.from_file(sets=PHANTOM + list(sets))


def bend(scene, depth=DEPTH, roll_at=None):
    """The path of the scene's needle inserted ``depth`` below the surface, its bend toward the
    needle frame's +x (where the bevel's point is at 0 degrees)."""
    point = scene.needle.rotation[:, 0].copy()             # before any roll
    path = insert_path(scene, scene.start_gap_m + depth, SPEED,
                       roll_at_m=None if roll_at is None else scene.start_gap_m + roll_at)
    return path, path_curvature(path, direction=point)


def own_bend(sets):
    """(0-degree bend, half the difference of the 0 and 180-degree bevels' lateral paths: the
    bevel's own bend, the mesh's bias cancelled) along the 0-degree path's depth."""
    a = bend(phantom(*needle_sets('20 G nitinol', 'bevel', 0.0), *sets))[1]
    b = bend(phantom(*needle_sets('20 G nitinol', 'bevel', 180.0), *sets))[1]
    along = a.along[a.along <= b.along[-1]]
    return a, along, 0.5 * (a.lateral[:len(along)] - np.interp(along, b.along, b.lateral))
