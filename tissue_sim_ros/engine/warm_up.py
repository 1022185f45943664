"""Compile the needle's numba kernels once per process, before the first tick.

Without this a fresh clone compiles each kernel at its first use: seconds in which the node falls
behind its robot at first contact.
"""
import numpy as np

from tissue_sim_ros.engine.compiled import cache as compile_cache

_WARM = []

# The warm-up tissue is linear (small strain, elastic): the needle's kernels do not depend on the
# model, and the linear element pass is compiled anyway (the critical time step's Lanczos runs it),
# so the warm-up adds no element-pass variant to a first start (a geometric warm-up model would
# add one, seconds of every first start).
WARM_UP_SCENE = {
    'mesh': {'size_m': [0.01, 0.01, 0.006], 'origin_m': [-0.005, -0.005, -0.006], 'divisions': [3, 3, 2]},
    'needle': {'initial_position_m': [0.0, 0.0, 0.1505], 'length_m': 0.15,
               'initial_orientation_xyzw': [1.0, 0.0, 0.0, 0.0]},
    'regions': [{'name': 'warm-up', 'young_modulus_pa': 2e4, 'cutting_force_n': 0.05,
                 'membrane': {'criterion': 'force', 'rupture_force_n': 0.02},
                 'friction': {'insertion_coulomb_n_per_m': 1.0}}],
    'model': {'geometric': False},
}


def warm_up(flexible=False):
    """Compile (or load from numba's cache) the kernels of every needle phase once per process,
    on a tiny scene driven through contact, puncture, cutting with friction and retraction.
    Otherwise a fresh clone compiles each at its first use: seconds in which the node falls
    behind its robot at first contact (and may then refuse the robot's next pose as a jump).
    On a first start this is what the second compile process runs (engine.compiled.cache).
    ``flexible``: also a flexible needle's (engine.needle.rod_step), once per process: a scene
    with one asks for them, so a scene without one does not compile them."""
    if not _WARM:
        _WARM.append(True)
        compile_cache.wait_for_helper()
        _drive({})
    if flexible and len(_WARM) == 1:
        _WARM.append(True)
        _drive({'flexible': True, 'inner_diameter_m': 0.0006, 'young_modulus_pa': 60e9, 'rod_segments': 30})


def _drive(needle):
    """The warm-up scene's needle with the keys ``needle``, flat then bevelled, in and out."""
    from tissue_sim_ros.engine.scene.scene import Scene
    for tip in ({'shape': 'flat'}, {'shape': 'bevel'}):     # the bonded end; a sharp tip's kernels
        scene = Scene({**WARM_UP_SCENE, 'needle': {**WARM_UP_SCENE['needle'], **needle, 'tip': tip}})
        position, orientation = scene.needle_pose
        for depth in (0.0015, 0.003, 0.0045, 0.003):     # down through the membrane, then back up
            scene.advance(0.05, position - np.array([0.0, 0.0, depth]), orientation)
            scene.reaction_wrench('needle')
