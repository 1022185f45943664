"""The needle inside the tissue (engine/needle/inside.py): cutting plus Karnopp friction, constant
friction terms, the lateral force and torque of a sideways motion, and the layers the tip meets
where their planes are."""

import numpy as np
import pytest

from support.scenes import NU, axial, drive_down, push, small_scene, stiff_scene


def second_puncture_travel(fine, plane):
    """Travel [m] at the second puncture: a capsule, then a layer under the plane z = ``plane``
    (the same material: only the layer's place differs between runs)."""
    regions = [{'name': 'upper', 'young_modulus_pa': 16000.0, 'poisson_ratio': NU, 'cutting_force_n': 0.2,
                'membrane': {'criterion': 'force', 'rupture_force_n': 0.3}},
               {'name': 'lower', 'select': {'below_z_m': plane}, 'young_modulus_pa': 16000.0, 'poisson_ratio': NU,
                'membrane': {'criterion': 'force', 'rupture_force_n': 0.5}, 'cutting_force_n': 0.3}]
    scene = small_scene(fine=fine, regions=regions, model={'geometric': True},
                        mesh={'size_m': [0.03, 0.03, 0.03], 'origin_m': [-0.015, -0.015, -0.03]})
    for _ in push(scene, 0.016, 3e-3, tick=0.01):
        if len(scene.puncture_events) >= 2:
            break
    assert [e['region'] for e in scene.puncture_events] == ['upper', 'lower']
    return scene.puncture_events[1]['time_s'] * 3e-3


@pytest.mark.parametrize('fine', [0.002, 0.001])
def test_moving_a_layer_plane_moves_its_puncture_by_as_much(fine):
    """Regions selected elements by centroid: a plane 0.7 mm lower moved the layer by 1.9 mm on
    the default mesh. Now the tip's material point decides (the plane in rest coordinates)."""
    moved = second_puncture_travel(fine, -0.0067) - second_puncture_travel(fine, -0.006)
    print(f'{fine * 1e3:.1f} mm cells: the plane 0.7 mm lower moved the second puncture {moved * 1e3:.3f} mm')
    assert moved == pytest.approx(0.0007, abs=0.00025)


def test_constant_friction_terms_give_a_plateau_both_ways():
    """Stiff tissue (the shaft's points do not move): axial force = cutting + C0_ins + L (C + b v)
    inserting and -(C0_ret + L (C + b v)) retracting, L the inserted length."""
    friction = {'insertion_coulomb_n_per_m': 10.57, 'insertion_viscous_n_s_per_m2': 212.31,
                'retraction_coulomb_n_per_m': 11.96, 'retraction_viscous_n_s_per_m2': 239.08,
                'insertion_constant_n': 0.4, 'retraction_constant_n': 1.1}
    cutting, speed = 0.5, 3e-3
    scene = stiff_scene(cutting, friction)
    drive_down(scene, 0.0105, speed, tick=0.01)
    inserted = scene.tip_depth
    expected = cutting + 0.4 + inserted * (10.57 + 212.31 * speed)
    print(f'inserting, {inserted * 1e3:.2f} mm in: {axial(scene):.4f} N against {expected:.4f} N')
    assert axial(scene) == pytest.approx(expected, rel=0.02)
    p, q = scene.needle_pose
    for k in (1, 2):
        scene.advance(0.01, p + np.array([0.0, 0.0, k * speed * 0.01]), q)
    expected_back = -(1.1 + scene.tip_depth * (11.96 + 239.08 * speed))
    print(f'retracting: {axial(scene):.4f} N against {expected_back:.4f} N')
    assert axial(scene) == pytest.approx(expected_back, rel=0.02)


def test_stiff_tissue_force_is_cutting_plus_karnopp_friction_and_retraction_pulls():
    friction = {'insertion_static_n_per_m': 18.45, 'insertion_coulomb_n_per_m': 10.57,
                'insertion_viscous_n_s_per_m2': 212.31, 'retraction_static_n_per_m': 18.23,
                'retraction_coulomb_n_per_m': 11.96, 'retraction_viscous_n_s_per_m2': 239.08}
    cutting, speed = 0.94, 3e-3
    scene = stiff_scene(cutting, friction)
    drive_down(scene, 0.0105, speed, tick=0.01)
    assert scene.phase == 'inserted'
    inserted = scene.tip_depth
    expected = cutting + inserted * (10.57 + 212.31 * speed)
    print(f'inserted {inserted * 1e3:.3f} mm: axial {axial(scene):.5f} N, cutting + friction {expected:.5f} N')
    assert axial(scene) == pytest.approx(expected, rel=0.02)
    p, q = scene.needle_pose
    scene.advance(0.01, p + np.array([0.0, 0.0, speed * 0.01]), q)
    scene.advance(0.01, p + np.array([0.0, 0.0, 2 * speed * 0.01]), q)
    assert scene.phase == 'retracting'
    expected_back = -scene.tip_depth * (11.96 + 239.08 * speed)
    print(f'retracting: axial {axial(scene):.5f} N, friction law {expected_back:.5f} N')
    assert axial(scene) == pytest.approx(expected_back, rel=0.02)


def test_sideways_motion_gives_a_lateral_force_and_a_consistent_torque():
    scene = small_scene(region={'membrane': {'criterion': 'force', 'rupture_force_n': 0.05}})
    drive_down(scene, 0.008, 3e-3)
    p, q = scene.needle_pose
    for k in range(1, 21):
        scene.advance(0.02, p + np.array([1e-3 * k / 20, 0.0, 0.0]), q)
    force, torque = scene.reaction_wrench('world')
    needle = scene.needle
    assert force[0] < -1e-3 and abs(force[0]) > 5 * abs(force[1])     # pushes back against +x
    lever = np.linalg.norm(torque) / np.linalg.norm(force[:2])
    entry = needle.geometry.length_m - scene.tip_depth
    print(f'lateral force {force[0]:.4f} N, torque {torque}, lever {lever * 1e3:.2f} mm')
    assert entry - 1e-3 <= lever <= needle.geometry.length_m + 1e-3      # acts along the inserted part
    assert abs(np.dot(torque, needle.axis)) < 1e-6 * np.linalg.norm(torque)
    assert np.dot(np.cross(needle.axis, force), torque) > 0           # lever arm along the axis, from the base


def test_two_layers_give_two_punctures():
    regions = [{'name': 'muscle', 'young_modulus_pa': 30000.0, 'poisson_ratio': NU,
                'membrane': {'criterion': 'force', 'rupture_force_n': 0.3}, 'cutting_force_n': 0.1},
               {'name': 'skin', 'select': {'above_z_m': -0.004}, 'young_modulus_pa': 60000.0, 'poisson_ratio': NU,
                'membrane': {'criterion': 'force', 'rupture_force_n': 0.2}, 'cutting_force_n': 0.1}]
    scene = small_scene(regions=regions, model={'geometric': True})
    drive_down(scene, 0.015, 5e-3)
    names = [e['region'] for e in scene.puncture_events]
    print(scene.puncture_events)
    assert names == ['skin', 'muscle']
