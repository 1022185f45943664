"""Sharp tips (needle.tip): a cone's or bevel's contact grows with the indentation, so the curve
before the puncture is convex and sharper cones push less at the same depth (Sneddon's cone,
F = (2 / pi) E* tan(theta) d^2, against a flat punch's F proportional to d); a bevel's face pushes
the tissue aside after the puncture, so the tissue pushes the needle toward the sharp point, and
turning the bevel turns that force with it."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.insertion import run_insertion
from tissue_sim_ros.engine.scene.scene import Scene

COARSE_FAR = ['mesh.divisions=[6,6,5]']          # the default fine zone near the needle, coarser far away
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


@pytest.mark.parametrize('shape, integrator', [('flat', 'explicit'), ('conical', 'explicit'), ('bevel', 'explicit'),
                                               ('bevel', 'implicit')])
def test_the_compiled_inside_step_is_the_general_path_bit_for_bit(shape, integrator, monkeypatch):
    """Inside the tissue the needle's step runs as one compiled call (engine.needle_step); the
    general path runs the same kernels one by one from Python. An insertion through the capsule,
    a hold and the retraction give the same wrench at every tick and the same final tissue state
    either way, and the compiled call did run (on most steps)."""
    from tissue_sim_ros.engine.needle.interaction import NeedleTissue
    calls = []
    compiled_step = NeedleTissue._inserted_step

    def counted(self, *args):
        compiled_step(self, *args)
        # the explicit step sums the work over the nodes it pushed and leaves zeros behind
        calls.append(bool(self.applied_forces.any()))
    monkeypatch.setattr(NeedleTissue, '_inserted_step', counted)

    def run(compiled):
        scene = Scene.from_file(sets=COARSE_FAR + [f'needle.tip.shape={shape}', f'solver.integrator={integrator}'])
        scene.needle.compiled_inside = compiled
        scene.compiled_substeps = False      # (test_compiled_substep: the substep around it)
        speed = 0.005 if integrator == 'explicit' else 0.01          # (an implicit step costs more)
        result = run_insertion(scene, speed, scene.start_gap_m + 0.012, hold_s=0.1, tick=0.02)
        return result, scene.displacement.copy(), scene.simulation.input_work

    compiled, general = run(True), run(False)
    assert len(compiled[0].puncture_events) == 1 and {'inserted', 'retracting'} <= set(compiled[0].phase)
    # (the implicit integrators read the forces after the step: they stay)
    assert len(calls) > compiled[0].steps / 3 and (integrator != 'explicit' or not any(calls))
    assert np.array_equal(compiled[0].force, general[0].force)
    assert np.array_equal(compiled[0].torque, general[0].torque)
    assert compiled[0].phase == general[0].phase
    assert np.array_equal(compiled[1], general[1])
    # the work put in is summed in another order (a loop against numpy's dot)
    assert compiled[2] == pytest.approx(general[2], rel=1e-9)


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


@pytest.mark.parametrize('seed', [0, 1, 2, 3])
def test_the_near_surface_test_finds_what_testing_every_triangle_finds(seed):
    """near_surface_hit skips triangles whose rest box, grown by the largest displacement, misses
    the segment: on a dented, jittered box, rays from above (hits and misses, some along edges)
    give the same triangle, t and weights as first_surface_hit over every triangle."""
    from tissue_sim_ros.engine.mesh.tetmesh import surface_triangles
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    from tissue_sim_ros.engine.needle.kernels import cell_boxes, first_surface_hit, near_surface_hit
    rng = np.random.default_rng(seed)
    mesh = box_mesh(size=(0.04, 0.04, 0.02), divisions=(10, 10, 5))
    rest = mesh.rest_positions
    triangles = np.ascontiguousarray(surface_triangles(mesh.tetrahedra, rest), dtype=np.int64)
    boxes, nodes = cell_boxes(rest, triangles), np.unique(triangles)
    displacement = rng.normal(scale=3e-4, size=rest.shape)
    distance = np.linalg.norm(rest[:, :2] - 0.02, axis=1)
    displacement[:, 2] -= 0.004 * np.exp(-(distance / 0.006) ** 2)
    hits = 0
    for k in range(400):
        tilt = rng.uniform(-0.5, 0.5, size=2)
        direction = np.array([tilt[0], tilt[1], -1.0]) / np.linalg.norm([tilt[0], tilt[1], -1.0])
        origin = np.array([*rng.uniform(-0.005, 0.045, size=2), rng.uniform(0.012, 0.03)])
        if k % 10 == 0:                  # over a deformed surface node: rays along edges and corners
            node = rng.choice(nodes)
            origin[:2] = rest[node, :2] + displacement[node, :2]
        reach = rng.uniform(0.002, 0.03)
        every = first_surface_hit(rest, displacement, triangles, origin, direction, 0.0, reach)
        near = near_surface_hit(rest, displacement, triangles, boxes, nodes, origin, direction, 0.0, reach)
        assert every == near
        hits += every[0] >= 0
    assert 40 < hits < 360


@pytest.mark.parametrize('seed', [0, 1, 2])
def test_the_search_near_the_tip_finds_what_a_search_of_every_element_finds(seed):
    """cells_near skips elements whose rest box, grown by the largest displacement, is out of
    reach, and follow_rigid_samples tries a candidate only where its deformed box holds the point:
    on a dented, jittered box the candidates are exactly the elements whose deformed box is in
    reach (numpy over every element), and a point with no walk to start from is found in the
    element locate_point's search of every element finds (points inside, outside, on nodes)."""
    from tissue_sim_ros.engine.mesh.tetmesh import element_neighbours
    from tissue_sim_ros.engine.mesh.generators import box_mesh
    from tissue_sim_ros.engine.needle.kernels import cell_boxes, cells_near, follow_rigid_samples, locate_point
    rng = np.random.default_rng(seed)
    mesh = box_mesh(size=(0.04, 0.04, 0.02), divisions=(8, 8, 4))
    rest, tetrahedra = mesh.rest_positions, np.ascontiguousarray(mesh.tetrahedra, dtype=np.int64)
    n_elements = len(tetrahedra)
    displacement = rng.normal(scale=3e-4, size=rest.shape)
    distance = np.linalg.norm(rest[:, :2] - 0.02, axis=1)
    displacement[:, 2] -= 0.006 * np.exp(-(distance / 0.006) ** 2)       # a 6 mm dent: a large growth
    boxes, nodes = cell_boxes(rest, tetrahedra), np.arange(len(rest))
    neighbours = element_neighbours(tetrahedra, len(rest))
    deformed = (rest + displacement)[tetrahedra]                         # (k, 4, 3)
    candidates, near_boxes = np.zeros(n_elements, dtype=np.int64), np.zeros((n_elements, 6))
    found = inside = 0
    for k in range(300):
        point = rng.uniform([-0.004, -0.004, -0.004], [0.044, 0.044, 0.024])
        if k % 5 == 0:                                                   # at a deformed node
            point = rest[k % len(rest)] + displacement[k % len(rest)]
        reach = rng.uniform(0.0, 0.004)
        n = cells_near(rest, displacement, tetrahedra, boxes, nodes, point, reach, candidates, near_boxes)
        expected = np.flatnonzero(np.all((deformed.min(axis=1) <= point + reach)
                                         & (deformed.max(axis=1) >= point - reach), axis=1))
        assert list(candidates[:n]) == list(expected)
        np.testing.assert_array_equal(near_boxes[:n, :3], deformed[expected].min(axis=1))
        elements = np.full(1, -1, dtype=np.int64)                        # outside last step: a search
        found += follow_rigid_samples(rest, displacement, tetrahedra, neighbours, boxes, nodes, point, np.eye(3),
                                      np.zeros((1, 3)), elements, np.zeros((1, 3)), np.zeros((1, 4), dtype=np.int64),
                                      np.zeros((1, 4)), np.zeros(4), candidates, near_boxes)
        element, _ = locate_point(rest, displacement, tetrahedra, point, 1e-9)
        assert elements[0] == element
        inside += element >= 0
    assert found == inside and 100 < inside < 290
