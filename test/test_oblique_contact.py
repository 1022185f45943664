"""A needle meeting a surface at an angle to its normal: the contact starts without an impulse
and the capsule ruptures at its rupture force, for a flat end and a bevel. (Pulling every point
the end had crossed onto it at first contact made 85 N on the organ example at 25 degrees.)"""
import numpy as np
import pytest

from tissue_sim_ros.engine.scene.scene import Scene

RUPTURE_N = 0.3
TILT_DEG = 30.0


def insert(tip, tilt_deg):
    axis = np.array([np.sin(np.radians(tilt_deg)), 0.0, -np.cos(np.radians(tilt_deg))])
    angle = np.arctan2(axis[0], axis[2])                     # +z turned onto the axis about y
    length = 0.1
    spec = {'mesh': {'generator': 'box', 'size_m': [0.024, 0.024, 0.012], 'origin_m': [-0.012, -0.012, -0.012],
                     'divisions': [12, 12, 6]},
            'regions': [{'name': 'capsule', 'young_modulus_pa': 5000.0, 'poisson_ratio': 0.45,
                         'membrane': {'criterion': 'force', 'rupture_force_n': RUPTURE_N}}],
            'solver': {'mass_scaling': 100.0},
            'needle': {'diameter_m': 0.00127, 'length_m': length, 'tip': {'shape': tip},
                       'initial_position_m': list(-axis * (length + 0.0005)),
                       'initial_orientation_xyzw': [0.0, float(np.sin(angle / 2)), 0.0, float(np.cos(angle / 2))]}}
    scene = Scene(spec)
    start, orientation = scene.initial_needle_pose
    forces, depths = [], []
    for k in range(1, 301):                                     # 6 mm at 5 mm/s, 20 ms ticks
        scene.advance(0.02, start + axis * 1e-4 * k, orientation)
        forces.append(-float(scene.reaction_wrench()[0] @ axis))
        depths.append(scene.needle.tip_depth())
        if scene.puncture_events:
            break
    return np.array(forces), np.array(depths), scene.puncture_events


@pytest.mark.parametrize('tip', ['flat', 'bevel'])
def test_an_oblique_contact_loads_the_capsule_smoothly_up_to_its_rupture_force(tip):
    forces, depths, events = insert(tip, TILT_DEG)
    assert len(events) == 1
    event = events[0]
    assert event['axial_force_n'] == pytest.approx(RUPTURE_N, rel=0.15)
    assert event['tip_depth_m'] > 0.0005                       # not at first contact
    touching = forces[depths > 0]
    assert np.max(np.diff(touching[:-1])) < 0.2 * RUPTURE_N    # no jump before the rupture
