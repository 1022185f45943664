"""Sharp tips (engine/needle/tip.py): a cone's or bevel's contact grows with the indentation, so the
curve before the puncture is convex and sharper cones push less at the same depth (Sneddon's
cone, F = (2 / pi) E* tan(theta) d^2, against a flat punch's F proportional to d); a bevel's face
pushes the tissue aside after the puncture, so the tissue pushes the needle toward the sharp
point, and turning the bevel turns that force with it."""

import numpy as np
import pytest

from support.scenes import COARSE_FAR
from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.engine.scene.scene import Scene

NO_PUNCTURE = ['regions[0].membrane.rupture_force_n=100']
INDENT_M = 0.0075


def pre_puncture(tip_sets):
    """(indentation since contact [m], axial force [N]) of the default scene's needle with this
    tip, pushed INDENT_M into a capsule that does not rupture, at 3 mm/s."""
    scene = Scene.from_file(sets=COARSE_FAR + NO_PUNCTURE + tip_sets)
    run = run_insertion(scene, 0.003, scene.start_gap_m + INDENT_M, retract=False, tick=0.02)
    inside = run.travel > scene.start_gap_m
    return run.travel[inside] - scene.start_gap_m, run.axial_force[inside]


def test_sharp_tips_curve_up_before_the_puncture_and_sharper_cones_push_less():
    curves = {name: pre_puncture(sets) for name, sets in (
        ('cone 15', ['needle.tip.shape=conical', 'needle.tip.half_angle_deg=15']),
        ('cone 30', ['needle.tip.shape=conical', 'needle.tip.half_angle_deg=30']),
        ('cone 60', ['needle.tip.shape=conical', 'needle.tip.half_angle_deg=60']),
        ('bevel 20', ['needle.tip.shape=bevel', 'needle.tip.bevel_angle_deg=20']),
        ('flat', ['needle.tip.shape=flat']))}
    fits, ends = {}, {}
    for name, (depth, force) in curves.items():
        fits[name] = np.polyfit(depth, force, 2)             # a2, a1, a0
        ends[name] = float(np.interp(INDENT_M * 0.98, depth, force))
        print(f'{name}: a2 {fits[name][0]:.0f} N/m^2, a1 {fits[name][1]:.1f} N/m, F({INDENT_M * 0.98 * 1e3:.2f} mm) '
              f'{ends[name]:.3f} N')
    for name in ('cone 15', 'cone 30', 'cone 60', 'bevel 20'):
        assert fits[name][0] > 0.0, name                     # convex: the loaded area grows
    assert fits['cone 15'][0] < fits['cone 30'][0]           # Sneddon: a2 grows with tan(theta)
    assert ends['cone 15'] < ends['cone 30'] < ends['cone 60'] < ends['flat']


def lateral_after_puncture(orientation_deg):
    """Mean force on the needle in its own frame (x, y) [N] from 4 to 10 mm past the capsule's
    puncture, and the mean torque about the base (world) with the mean force (world)."""
    scene = Scene.from_file(sets=COARSE_FAR + ['regions[0].membrane.rupture_force_n=0.5',
                                               f'needle.tip.bevel_orientation_deg={orientation_deg}'])
    run = run_insertion(scene, 0.003, scene.start_gap_m + 0.018, retract=False, tick=0.02)
    puncture = scene.puncture_events[0]['tip_depth_m'] + scene.start_gap_m
    window = (run.travel > puncture + 0.004) & (run.travel < puncture + 0.010)
    rotation = scene.needle.rotation
    force_world = run.force[window].mean(axis=0)
    return (rotation.T @ force_world)[:2], run.torque[window].mean(axis=0), force_world, scene.needle.axis


@pytest.mark.parametrize('turned', [90.0])
def test_a_bevel_pushes_the_needle_toward_its_point_and_the_force_turns_with_it(turned):
    """The default scene's bevel with its point toward the needle frame's +x, then turned 180
    and ``turned`` degrees: the difference of opposite bevels is the tip's own lateral force
    (the mesh's own bias cancels), toward the point; turned, it turns."""
    f0, torque, force_world, axis = lateral_after_puncture(0.0)
    f180, *_ = lateral_after_puncture(180.0)
    f_turned, *_ = lateral_after_puncture(turned)
    f_opposite, *_ = lateral_after_puncture(turned + 180.0)
    print(f'lateral force in the needle frame [N]: 0 deg {f0}, 180 deg {f180}, {turned:.0f} deg {f_turned}, '
          f'{turned + 180:.0f} deg {f_opposite}')
    assert f0[0] > 0.0 > f180[0]                              # the sign flips with the bevel
    own = 0.5 * (f0 - f180)
    assert own[0] > 0.02 and abs(own[1]) < 0.3 * own[0]
    own_turned = 0.5 * (f_turned - f_opposite)
    direction = np.array([np.cos(np.radians(turned)), np.sin(np.radians(turned))])
    assert own_turned @ direction > 0.8 * np.linalg.norm(own_turned)
    assert np.linalg.norm(own_turned) == pytest.approx(np.linalg.norm(own), rel=0.35)
    # the moment about the base: the lateral force acts along the inserted part, far from the base
    lateral = force_world - (force_world @ axis) * axis
    assert np.dot(np.cross(axis, lateral), torque) > 0.0


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_engaging_samples_finds_the_hits_a_ray_test_of_every_triangle_finds(seed):
    """engage_samples tries, per sample, only the near triangles whose box across the axis holds
    it: the same hits (triangle, barycentric weights) as the ray test against the whole deformed
    surface, on a dented, jittered box under a tilted tip."""
    from tissue_sim_ros.engine.mesh.tetmesh import surface_triangles
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    from tissue_sim_ros.engine.needle.kernels import cell_boxes, first_surface_hit
    from tissue_sim_ros.engine.needle.tip import engage_samples
    rng = np.random.default_rng(seed)
    mesh = box_mesh(size=(0.04, 0.04, 0.02), divisions=(12, 12, 6))
    rest = mesh.rest_positions
    triangles = surface_triangles(mesh.tetrahedra, rest)
    centre = np.array([0.02, 0.02, 0.02])
    distance = np.linalg.norm(rest[:, :2] - centre[:2], axis=1)
    displacement = rng.normal(scale=2e-4, size=rest.shape)
    displacement[:, 2] -= 0.003 * np.exp(-(distance / 0.004) ** 2)
    tilt = rng.uniform(-0.35, 0.35, size=2)                          # up to 20 degrees
    axis = np.array([tilt[0], tilt[1], -1.0]) / np.linalg.norm([tilt[0], tilt[1], -1.0])
    rotation = np.linalg.qr(np.column_stack([axis, rng.normal(size=(3, 2))]))[0][:, [1, 2, 0]]
    rotation[:, 2] = axis                        # the needle frame's z along the axis
    tip = centre + rng.normal(scale=5e-4, size=3) - np.array([0, 0, 0.0045])   # 1.5 mm past the dent
    offsets = np.column_stack([rng.uniform(-0.0015, 0.0015, (60, 2)), rng.uniform(-0.003, 0.0, 60)])
    back, reach = 0.004, 0.005
    n = len(triangles)
    engaged, new = np.zeros(60, dtype=np.bool_), np.zeros(60, dtype=np.bool_)
    nodes, weights = np.full((60, 4), -1, dtype=np.int64), np.zeros((60, 4))
    count = engage_samples(rest, displacement, triangles, cell_boxes(rest, triangles), np.unique(triangles), tip,
                           rotation, axis, offsets, engaged, new, back,
                           reach + back, np.zeros(n, dtype=np.int64), np.zeros((n, 6)), np.zeros((n, 4)),
                           np.zeros((n, 3), dtype=triangles.dtype), np.zeros(n, dtype=np.int64), nodes, weights)
    expected = 0
    for s in range(60):
        origin = tip + rotation @ offsets[s] - back * axis
        hit, t, w0, w1, w2 = first_surface_hit(rest, displacement, triangles, origin, axis, 0.0, back)
        assert engaged[s] == (hit >= 0)
        if hit >= 0:
            expected += 1
            assert list(nodes[s, :3]) == list(triangles[hit])
            np.testing.assert_allclose(weights[s, :3], [w0, w1, w2], atol=1e-12)   # origin's round-off
    assert count == expected and count > 10 and new.sum() == count
