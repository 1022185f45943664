"""Layers are surfaces, the rupture force can follow a rate law, and the shaft's friction can hold
a constant pull: where a layer's plane is, not where the element faces lie, decides where the
needle meets it; the puncture force at two speeds is in the ratio (v1 / v2)^n; a constant term
next to the per-length ones gives the retraction its plateau."""
import numpy as np
import pytest

from test_needle import NU, axial, drive_down, push, small_scene, stiff_scene
from tissue_sim_ros.engine.mesh.selectors import RegionSelectors


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


def test_a_point_is_in_the_same_region_by_either_formulation():
    """region_at (per point, plain arithmetic: the needle's step) agrees with regions_of (arrays:
    the elements' materials) for every selector kind, later regions overriding earlier ones."""
    regions = [{'select': 'all'}, {'select': {'below_z_m': -0.01}}, {'select': {'above_z_m': 0.004}},
               {'select': {'box_m': [[-0.01, -0.01, -0.02], [0.0, 0.01, -0.005]]}},
               {'select': {'sphere_m': [0.005, 0.0, -0.01, 0.004]}}]
    rng = np.random.default_rng(3)
    points = rng.uniform(-0.02, 0.01, size=(4000, 3))
    by_arrays = RegionSelectors(regions).regions_of(points)
    by_points = np.array([RegionSelectors(regions).region_at(p, 0) for p in points])
    assert np.array_equal(by_arrays, by_points)
    assert set(by_arrays) == {0, 1, 2, 3, 4}
    # a tag selector between them: the element's tag decides, wherever the point is
    element_tags = rng.integers(1, 4, size=50)
    elements = rng.integers(0, 50, size=len(points))
    tagged = RegionSelectors(regions[:3] + [{'select': {'tag': 2}}] + regions[3:], element_tags)
    by_arrays = tagged.regions_of(points, element_tags[elements])
    assert np.array_equal(by_arrays, [tagged.region_at(p, e) for p, e in zip(points, elements)])
    assert set(by_arrays) == {0, 1, 2, 3, 4, 5}


@pytest.mark.parametrize('exponent', [0.25])
def test_the_rupture_force_follows_its_rate_law(exponent):
    """criterion 'force' with rate_exponent n: F_rupture = F0 (v / v0)^n (checked every step), so
    the puncture forces at 1 and 8 mm/s are in the ratio 8^n."""
    membrane = {'criterion': 'force', 'rupture_force_n': 0.1, 'rate_exponent': exponent,
                'reference_speed_m_s': 0.001}
    forces = {}
    for speed in (1e-3, 8e-3):
        scene = small_scene(region={'membrane': membrane})
        for _ in push(scene, 0.008, speed, tick=0.005):
            if scene.puncture_events:
                break
        event = scene.puncture_events[0]
        assert event['speed_m_s'] == pytest.approx(speed, rel=1e-6)
        forces[speed] = event['axial_force_n']
    ratio = forces[8e-3] / forces[1e-3]
    print(f'puncture at 1 mm/s {forces[1e-3]:.4f} N, at 8 mm/s {forces[8e-3]:.4f} N: ratio {ratio:.4f}, '
          f'law {8.0 ** exponent:.4f}')
    assert forces[1e-3] == pytest.approx(0.1, rel=0.02)
    assert ratio == pytest.approx(8.0 ** exponent, rel=0.03)


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
