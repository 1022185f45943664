"""A flexible needle (needle.flexible): the rod against the clamped beam's closed form and the
large-deflection elastica (scipy's solve_bvp, independent of the rod), its derivatives against
finite differences; in the tissue, a bevel tip's path bends toward the bevel's point along a
near-constant curvature that grows as the rod softens and as the tissue stiffens (the directions
of Misra et al. 2010), a flip of the bevel half-way bends it back (an S), a conical tip stays on
the axis within the mesh's noise; a very stiff rod is the rigid needle, and the flexible needle's
compiled steps are its general path to the last bit."""
import math

import numpy as np
import pytest

from tissue_sim_ros.analysis.steering import arc_radius, insert_path, path_curvature
from tissue_sim_ros.bench.steering import PHANTOM, elastica_tip, needle_sets
from tissue_sim_ros.engine.needle import rod
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

AXIS = np.array([0.0, 0.0, 1.0])
SPEED = 0.01
DEPTH = 0.02


def clamped_tip(load_ratio, segments, length=0.08, bending=1.6e-3, axial=2.2e4):
    """(tip x, tip z, tip rotation) of a rod clamped at the origin along +z under a tip load
    F = load_ratio EI / L^2 along +x."""
    nodes = rod.straight_nodes([0.0, 0.0, 0.0], AXIS, length, segments)
    loads = np.zeros_like(nodes)
    loads[-1, 0] = load_ratio * bending / length ** 2
    iterations, residual = rod.static_solve(nodes, length / segments, bending, axial, AXIS, loads, 1,
                                            1e-9 * loads[-1, 0], 200)
    assert residual < 1e-3 * loads[-1, 0]            # (the stretching's round-off, 1e-8 N here)
    last = nodes[-1] - nodes[-2]
    return nodes[-1, 0], nodes[-1, 2], math.atan2(last[0], last[2])


@pytest.mark.parametrize('segments', [20, 40])
def test_a_clamped_rod_under_a_small_tip_load_deflects_f_l3_over_3_ei(segments):
    load_ratio = 1e-3                                      # F L^2 / EI: a tip rotation of 0.03 degrees
    x, _, angle = clamped_tip(load_ratio, segments)
    assert x == pytest.approx(load_ratio * 0.08 / 3.0, rel=0.01)
    assert angle == pytest.approx(load_ratio / 2.0, rel=0.01)     # F L^2 / (2 E I)


@pytest.mark.parametrize('load_ratio', [1.2, 4.0])
def test_the_rod_follows_the_large_deflection_elastica(load_ratio):
    """30.8 and 64.2 degrees of tip rotation: the tip where the elastica puts it within 2 %."""
    ex, ez, e_angle = elastica_tip(load_ratio, 0.08)
    rx, rz, r_angle = clamped_tip(load_ratio, 40)
    assert math.degrees(e_angle) > 30.0
    assert rx == pytest.approx(ex, rel=0.02) and rz == pytest.approx(ez, rel=0.02)
    assert r_angle == pytest.approx(e_angle, rel=0.02)


def test_the_rods_forces_and_stiffness_are_its_energys_derivatives():
    rng = np.random.default_rng(3)
    n, h, bending, axial = 5, 0.01, 0.7, 30.0
    nodes = rod.straight_nodes([0.0, 0.0, 0.0], AXIS, n * h * 1.02, n) + 1e-4 * rng.standard_normal((n + 1, 3))
    base_axis = np.array([0.1, 0.0, 1.0]) / math.hypot(0.1, 1.0)

    def gradient_band(x):
        g, band = np.zeros((n + 1, 3)), np.zeros((3 * (n + 1), rod.BANDS + 1))
        rod.assemble(x, h, bending, axial, base_axis, g, band)
        return g, band

    g, band = gradient_band(nodes)
    eps = 1e-7
    numeric = np.zeros_like(g)
    hessian = np.zeros((3 * (n + 1), 3 * (n + 1)))
    for i in range(3 * (n + 1)):
        step = np.zeros(3 * (n + 1))
        step[i] = eps
        up, down = nodes + step.reshape(-1, 3), nodes - step.reshape(-1, 3)
        numeric.reshape(-1)[i] = (rod.rod_energy(up, h, bending, axial, base_axis)
                                  - rod.rod_energy(down, h, bending, axial, base_axis)) / (2 * eps)
        hessian[:, i] = ((gradient_band(up)[0] - gradient_band(down)[0]) / (2 * eps)).reshape(-1)
    assert np.abs(numeric - g).max() < 1e-6 * np.abs(g).max()
    dense = np.zeros_like(hessian)
    for i in range(len(dense)):
        for d in range(rod.BANDS + 1):
            if i + d < len(dense):
                dense[i, i + d] = dense[i + d, i] = band[i, d]
    # every segment stretched here: the compressive geometric term the solve leaves out is absent
    assert np.abs(hessian - dense).max() < 1e-5 * np.abs(dense).max()
    rhs = rng.standard_normal(len(dense))
    spd = dense + np.eye(len(dense)) * np.abs(dense).max()
    packed = np.array([[spd[i, i + d] if i + d < len(spd) else 0.0 for d in range(rod.BANDS + 1)]
                       for i in range(len(spd))])
    solved = rhs.copy()
    assert rod.band_solve(packed, solved, 1)
    expected = np.zeros_like(rhs)
    expected[3:] = np.linalg.solve(spd[3:, 3:], rhs[3:])
    assert np.allclose(solved, expected, rtol=1e-10, atol=1e-14)


def test_the_transported_frames_do_not_twist_about_the_centreline():
    """A rod bent in the x-z plane keeps the base frame's y (normal to the plane) in every frame,
    and the tip frame's quaternion turns it back into the frame."""
    from tissue_sim_ros.engine.needle.pose import rotation_matrix
    s = np.linspace(0.0, 0.05, 26)
    nodes = np.column_stack([0.02 * (1 - np.cos(s / 0.02)), np.zeros_like(s), 0.02 * np.sin(s / 0.02)])
    frames = np.zeros((25, 3, 3))
    rod.transport_frames(nodes, np.eye(3), frames)
    assert np.allclose(frames[:, :, 1], [0.0, 1.0, 0.0], atol=1e-12)
    assert np.allclose(np.einsum('kij,kil->kjl', frames, frames), np.eye(3), atol=1e-12)
    quaternions = np.zeros((25, 4))
    rod.frame_quaternions(frames, quaternions)
    assert np.allclose([rotation_matrix(q) for q in quaternions], frames, atol=1e-12)


def test_a_path_on_a_circle_tangent_at_the_entry_has_its_radius():
    """Points on a circle of 0.3 m leaving the entry along the axis, either way, any stretch of
    it: its radius, signed by the side; points on the axis: no bend."""
    t = np.linspace(0.02, 0.3, 40)
    assert arc_radius(0.3 * np.sin(t), 0.3 * (1 - np.cos(t))) == pytest.approx(0.3, rel=1e-12)
    assert arc_radius(0.3 * np.sin(t[20:]), -0.3 * (1 - np.cos(t[20:]))) == pytest.approx(-0.3, rel=1e-12)
    assert arc_radius(t, 0.0 * t) == math.inf


def test_the_flexible_keys_are_checked():
    with pytest.raises(SceneError, match=r'needle.inner_diameter_m = 0.002: expected less than needle.diameter_m'):
        Scene.from_file(sets=['needle.flexible=true', 'needle.inner_diameter_m=0.002'])
    with pytest.raises(SceneError, match=r'needle.rod_segments = 2.5: expected a whole number'):
        Scene.from_file(sets=['needle.flexible=true', 'needle.rod_segments=2.5'])


# -- in the tissue ------------------------------------------------------------------------------
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


@pytest.fixture(scope='module')
def nitinol():
    return own_bend(())


def test_a_bevel_tip_bends_toward_its_point_along_a_near_constant_curvature(nitinol):
    """The bevel's point at +x: the path bends toward +x, and the bevel's own bend (its half
    difference with the bevel turned 180 degrees) bends at a near-constant curvature over its last
    60 %: the arcs from the entry through each third of that stretch (Webster et al. 2006: a
    constant-curvature arc) have radii within 35 % of each other, and the arc through the whole
    stretch fits it within 15 % of its largest value."""
    bent, along, own = nitinol
    print(f'toward the bevel at {along[-1] * 1e3:.1f} mm: path {bent.lateral[-1] * 1e6:.0f} um, own bend '
          f'{own[-1] * 1e6:.0f} um')
    assert bent.lateral[-1] > 0.0 and own[-1] > 50e-6
    last = np.flatnonzero(along >= 0.4 * along[-1])
    radius = arc_radius(along[last], own[last])
    radii = [arc_radius(along[h], own[h]) for h in np.array_split(last, 3)]
    print(f'radius over the last 60 %: {radius:.3g} m; its thirds ' + ', '.join(f'{r:.3g}' for r in radii) + ' m')
    assert 0.0 < radius < 5.0                                     # toward the point
    assert max(radii) < 1.35 * min(radii)
    # and the arc fits the bend: within 15 % of the bend's largest value over the stretch
    arc = radius - np.sqrt(radius ** 2 - along[last] ** 2)
    assert np.abs(arc - own[last]).max() < 0.15 * own[-1]


def test_a_conical_tip_stays_on_the_axis_within_the_meshs_noise(nitinol):
    """A cone pushes the tissue aside evenly: its tip leaves the axis by the mesh's own bias, a
    fraction of the bevel's bend."""
    _, along, own = nitinol
    cone = bend(phantom(*needle_sets('20 G nitinol', 'conical')))[0]
    print(f'conical tip {cone.deflection[-1] * 1e6:.0f} um off the axis; the bevel {own[-1] * 1e6:.0f} um')
    assert cone.deflection[-1] < 0.3 * own[-1]


def test_the_curvature_grows_as_the_rod_softens_and_as_the_tissue_stiffens(nitinol):
    """Misra et al. (2010): a stiffer rod (steel, 3.3 times the bending stiffness) bends less; a
    stiffer tissue (2.7 times the modulus, and a cutting force as much higher: a stiffer gel is
    also tougher) bends it more."""
    _, along, own = nitinol
    _, steel_along, steel = own_bend(('needle.young_modulus_pa=200e9',))
    _, stiff_along, stiff = own_bend(('regions[0].young_modulus_pa=60000', 'regions[0].cutting_force_n=1.33'))
    at = along[-1]
    bends = [float(np.interp(at, a, o)) for a, o in ((along, own), (steel_along, steel), (stiff_along, stiff))]
    print('own bend at {:.1f} mm: nitinol {:.0f} um, steel {:.0f} um, stiffer tissue {:.0f} um'.format(
        at * 1e3, *(1e6 * b for b in bends)))
    assert bends[1] < 0.8 * bends[0] < 0.8 * bends[2]


def test_turning_the_bevel_half_way_bends_the_path_back(nitinol):
    """The input pose's roll turns the bevel: 180 degrees half-way, the path that bent toward +x
    turns toward -x (an S), where the same insertion without the turn goes on toward +x; up to the
    turn the two are the same run, to the last bit."""
    straight = nitinol[0]
    flipped = bend(phantom(*needle_sets('20 G nitinol')), DEPTH, roll_at=0.5 * DEPTH)[1]
    turn = int(np.argmax(flipped.along >= 0.5 * DEPTH - 0.006))        # (the capsule takes ~4 mm)
    peak = int(np.argmax(flipped.lateral))
    print(f'flipped half-way: {flipped.lateral[peak] * 1e6:.0f} um toward the first bevel at '
          f'{flipped.along[peak] * 1e3:.1f} mm, {flipped.lateral[-1] * 1e6:.0f} um at {flipped.along[-1] * 1e3:.1f} '
          f'mm; without the turn {straight.lateral[-1] * 1e6:.0f} um')
    assert np.array_equal(flipped.lateral[:turn], straight.lateral[:turn])
    assert flipped.lateral[peak] > 10e-6 and flipped.along[peak] < 0.7 * flipped.along[-1]
    assert flipped.lateral[-1] < flipped.lateral[peak] - 50e-6
    assert flipped.lateral[-1] < straight.lateral[-1] - 150e-6
    later = flipped.along >= 0.7 * flipped.along[-1]
    assert np.polyfit(flipped.along[later], flipped.lateral[later], 1)[0] < 0.0     # heading for -x


def test_a_very_stiff_rod_is_the_rigid_needle():
    """The rod and the shaft's points solved together reduce to the rigid needle's projection when
    the rod cannot bend: the same wrench, within 1 % of its largest value, through the capsule and in."""
    def wrench(*sets):
        scene = phantom(*sets)
        path = insert_path(scene, scene.start_gap_m + 0.008, SPEED)
        return path.force, scene.needle.tip_deflection()
    rigid, _ = wrench('needle.tip.shape=bevel')
    stiff, deflection = wrench('needle.flexible=true', 'needle.young_modulus_pa=1e16')
    assert deflection < 1e-9
    assert np.abs(stiff - rigid).max() < 0.01 * np.abs(rigid).max()


def test_the_flexible_needles_compiled_steps_are_its_general_path_bit_for_bit():
    """The compiled slices and the one-call inside step run the same kernels in the same order
    as the Python calls: the same wrench and shape to the last bit, and they did run."""
    def run(compiled):
        scene = phantom(*needle_sets('20 G nitinol'))
        scene.compiled_substeps = scene.needle.compiled_inside = compiled
        path = insert_path(scene, scene.start_gap_m + 0.006, SPEED)
        return path.force, path.tip, scene.needle.shape(), scene
    compiled, general = run(True), run(False)
    assert compiled[3]._compiled.counts.get(('inside', 0), 0) > 100
    for a, b in zip(compiled[:3], general[:3]):
        assert np.array_equal(a, b)


def test_the_rod_keeps_its_length_in_the_tissue():
    """The rod's segments keep their rest length but for the tube's elastic strain under the axial
    load, at most the axial force over EA (no drift with the steps)."""
    scene = phantom(*needle_sets('20 G nitinol'))
    path = insert_path(scene, scene.start_gap_m + 0.012, SPEED)
    strain = np.linalg.norm(np.diff(scene.needle.shape(), axis=0), axis=1) / scene.needle.rod.h - 1.0
    axial = float(np.abs(path.force[-1] @ path.axis))
    print(f'strain {strain.min():.3g} .. {strain.max():.3g}; axial force over EA {axial / scene.needle.rod.axial:.3g}')
    assert scene.needle.n_points > 3 and axial > 0.1
    assert np.abs(strain).max() <= 1.2 * axial / scene.needle.rod.axial
