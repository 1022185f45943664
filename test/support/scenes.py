"""Small needle scenes: a 30 x 30 x 20 mm sample with the tip just above it, a rigid-like one, the
needle pushed down tick by tick, and two layers whose rupture force and depth vary per run."""

import math

import numpy as np

from tissue_sim_ros.engine.scene.scene import Scene

DOWN = [1.0, 0.0, 0.0, 0.0]          # needle axis (+z of its frame) along world -z
E, NU = 16000.0, 0.45

COARSE_FAR = ['mesh.divisions=[6,6,5]']          # the default fine zone near the needle, coarser far away

#: two layers on a small box: the outer one's rupture force drawn per run (0.1 N spread), the deep
#: one under a plane 11 mm down drawn 0.5 mm deep per run
TWO_LAYERS = {
    'mesh': {'generator': 'box', 'divisions': [4, 4, 3]},
    'regions': [{'name': 'outer', 'select': 'all', 'membrane': {'criterion': 'force', 'rupture_force_n': 0.8,
                                                                'rupture_force_spread_n': 0.1}},
                {'name': 'deep', 'select': {'below_z_m': -0.011}, 'depth_spread_m': 0.0005, 'young_modulus_pa': 9000.0,
                 'membrane': {'criterion': 'force', 'rupture_force_n': 1.0}}],
    'solver': {'mass_scaling': 400.0},
    'needle': {'diameter_m': 0.00127, 'tip': {'shape': 'bevel'}, 'start_gap_m': 0.001},
}



def small_scene(**options):
    """A 30 x 30 x 20 mm sample (top at z = 0), needle tip ``gap`` above the centre."""
    return Scene(small_spec(**options))


def small_spec(*, fine=0.002, region=None, regions=None, model=None, solver=None, mesh=None, gap=0.0005):
    """The keys of :func:`small_scene`."""
    return {'mesh': {'size_m': [0.03, 0.03, 0.02], 'origin_m': [-0.015, -0.015, -0.02], 'divisions': [6, 6, 4],
                     'fine_size_m': fine, 'focus_radius_m': 0.002, 'grade_z': True, **(mesh or {})},
            'model': {'geometric': False, 'physical': {'law': 'none'}, 'viscosity_mu_pa_s': 0.0, **(model or {})},
            'needle': {'initial_position_m': [0.0, 0.0, 0.15 + gap], 'length_m': 0.15,
                       'initial_orientation_xyzw': DOWN},
            'solver': {'mass_scaling': 400.0, 'damping_per_s': 50.0, **(solver or {})},
            'regions': regions or [{'name': 'tissue', 'young_modulus_pa': E, 'poisson_ratio': NU,
                                    'membrane': {'criterion': 'force', 'rupture_force_n': 100.0}, **(region or {})}]}


def push(scene, travel, speed, *, tick=0.02):
    """Move the needle down by ``travel`` at ``speed``; yields after each tick."""
    p, q = scene.needle_pose
    n = max(1, math.ceil(travel / (speed * tick)))
    for k in range(1, n + 1):
        scene.advance(travel / n / speed, p + np.array([0.0, 0.0, -travel * k / n]), q)
        yield


def stiff_scene(cutting_n, friction):
    """A rigid-like tissue (the shaft's points do not move; huge masses keep the step usable) with a
    0.5 N membrane: the axial force is the needle's own laws, cutting and friction."""
    return small_scene(fine=0.003, regions=[{'name': 'stiff', 'young_modulus_pa': 2e9, 'poisson_ratio': 0.3,
                                             'membrane': {'criterion': 'force', 'rupture_force_n': 0.5},
                                             'cutting_force_n': cutting_n, 'friction': friction}],
                       solver={'mass_scaling': 1e6})


def drive_down(scene, travel, speed, *, tick=0.02):
    """push() to the end, when only the final state matters."""
    for _ in push(scene, travel, speed, tick=tick):
        continue


def axial(scene):
    return -float(np.dot(scene.reaction_wrench()[0], scene.needle.axis))
