"""Tests of tissue_sim_ros.engine.mesh.tetmesh against independent truth: closed-form volumes, a
hand-evaluated mean ratio, heights, the element holding each face against a brute-force set
count, and the validation and orientation repair of make_mesh."""

import math

import numpy as np
import pytest

from support.meshes import ONE_TET, REGULAR, UNIT_CORNER, oriented_set, random_rotation, triangle_area_vectors
from tissue_sim_ros.engine.mesh.generators import box_mesh, graded_box_mesh
from tissue_sim_ros.engine.mesh.tetmesh import (MeshOrientationWarning, TetMesh, face_elements,
                                                make_mesh, mean_ratio, signed_volumes, surface_triangles)
from tissue_sim_ros.errors import MeshError


# volumes, mean ratio, heights, surface of one element
def test_signed_volumes_of_the_unit_corner_and_its_mirror():
    assert signed_volumes(UNIT_CORNER, ONE_TET)[0] == pytest.approx(1 / 6, rel=1e-15)
    assert signed_volumes(UNIT_CORNER, [[0, 2, 1, 3]])[0] == pytest.approx(-1 / 6, rel=1e-15)


def test_mean_ratio_is_one_for_a_regular_tetrahedron():
    lengths = [np.linalg.norm(REGULAR[i] - REGULAR[j]) for i in range(4) for j in range(i)]
    np.testing.assert_allclose(lengths, 2 * math.sqrt(2), rtol=1e-15)  # it is regular
    assert signed_volumes(REGULAR, ONE_TET)[0] > 0
    assert mean_ratio(REGULAR, ONE_TET)[0] == pytest.approx(1.0, abs=1e-12)


def test_mean_ratio_of_the_unit_corner_by_hand():
    # V = 1/6, so 3V = 1/2; edges: three of length 1 and three of length sqrt 2, sum l^2 = 9
    expected = 12 * 0.5 ** (2 / 3) / 9
    assert mean_ratio(UNIT_CORNER, ONE_TET)[0] == pytest.approx(expected, rel=1e-14)
    assert expected == pytest.approx(0.8399473665, rel=1e-9)


def test_mean_ratio_is_invariant_under_rigid_motion_and_scaling():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(4, 3))
    reference = mean_ratio(points, ONE_TET)[0]
    assert 0.05 < reference < 1
    for _ in range(5):
        moved = 7.3 * points @ random_rotation(rng).T + rng.normal(size=3) * 10
        assert mean_ratio(moved, ONE_TET)[0] == pytest.approx(reference, rel=1e-12)


def test_mean_ratio_tends_to_zero_as_the_element_flattens():
    heights = [1.0, 1e-1, 1e-2, 1e-4, 1e-6]
    values = []
    for h in heights:
        points = UNIT_CORNER.copy()
        points[3, 2] = h
        values.append(mean_ratio(points, ONE_TET)[0])
    assert all(a > b for a, b in zip(values, values[1:]))
    assert values[-1] < 1e-3
    # 3V = h/2, so the numerator scales as h^(2/3), while sum l^2 = 1 + 1 + h^2 + 2 + 2 (1 + h^2)
    assert values[-1] == pytest.approx(12 * (0.5e-6) ** (2 / 3) / 6, rel=1e-9)


def test_mesh_mean_ratio_at_deformed_positions(box):
    rng = np.random.default_rng(5)
    rotated = box.rest_positions @ random_rotation(rng).T + 3.0
    np.testing.assert_allclose(box.mean_ratio(rotated), box.mean_ratio(), rtol=1e-12)
    stretched = box.rest_positions * np.array([2.0, 1.0, 1.0])
    assert not np.allclose(box.mean_ratio(stretched), box.mean_ratio())
    with pytest.raises(MeshError, match='positions'):
        box.mean_ratio(box.rest_positions[:-1])


def test_characteristic_length_of_the_unit_corner_and_a_regular_tetrahedron():
    corner = make_mesh(UNIT_CORNER, ONE_TET)
    # largest face: the one opposite the origin, area sqrt(3)/2; h = 3 (1/6) / (sqrt(3)/2)
    assert corner.characteristic_lengths()[0] == pytest.approx(1 / math.sqrt(3), rel=1e-14)
    regular = make_mesh(REGULAR, ONE_TET)
    edge = 2 * math.sqrt(2)
    assert regular.characteristic_lengths()[0] == pytest.approx(edge * math.sqrt(2 / 3),
                                                                rel=1e-14)
    # per element: the unit corner beside a copy scaled by 2
    pair = make_mesh(np.vstack([UNIT_CORNER, 2 * UNIT_CORNER + 5]), [[0, 1, 2, 3], [4, 5, 6, 7]])
    np.testing.assert_allclose(pair.characteristic_lengths(), [1, 2] / np.sqrt(3), rtol=1e-14)


def test_characteristic_lengths_of_kuhn_elements_in_cubes():
    # Kuhn element of a cube of side a: V = a^3/6, largest faces a^2 sqrt(2)/2, so h = a/sqrt 2
    mesh = box_mesh((0.02, 0.02, 0.04), (2, 2, 4))
    np.testing.assert_allclose(mesh.characteristic_lengths(), 0.01 / math.sqrt(2), rtol=1e-12)


def test_surface_extraction_for_very_large_node_counts_matches(box):
    # beyond ~1.6e6 nodes face keys no longer fit one int64 and a lexicographic sort is used
    from tissue_sim_ros.engine.mesh.tetmesh import _faces_seen_once
    faces = box.tetrahedra[:, [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]]].reshape(-1, 3)
    np.testing.assert_array_equal(_faces_seen_once(faces, 10 ** 7),
                                  _faces_seen_once(faces, box.n_nodes))
    assert len(_faces_seen_once(faces, 10 ** 7)) == len(box.surface_triangles())


@pytest.mark.parametrize('order', [[0, 1, 2, 3], [0, 2, 1, 3]])
def test_surface_of_one_element_points_outward(order):
    triangles = surface_triangles(np.array([order]), UNIT_CORNER)
    assert len(triangles) == 4
    centre = UNIT_CORNER.mean(axis=0)
    area_vectors = triangle_area_vectors(UNIT_CORNER, triangles)
    face_centres = UNIT_CORNER[triangles].mean(axis=1)
    assert (np.einsum('ij,ij->i', face_centres - centre, area_vectors) > 0).all()


# make_mesh validation and orientation repair
def small_box():
    return box_mesh((1.0, 1.0, 1.0), (2, 2, 2))


def test_make_mesh_repairs_inverted_elements():
    reference = small_box()
    tets = np.array(reference.tetrahedra)
    inverted = [3, 10, 47]
    tets[inverted] = tets[inverted][:, [0, 2, 1, 3]]  # negative orientation
    assert (signed_volumes(reference.rest_positions, tets)[inverted] < 0).all()
    with pytest.warns(MeshOrientationWarning) as record:
        repaired = make_mesh(reference.rest_positions, tets)
    assert len(record) == 1 and '3 negatively oriented elements' in str(record[0].message)
    assert '[3, 10, 47]' in str(record[0].message)
    assert record[0].filename == __file__  # attributed to the caller of make_mesh
    assert repaired.flipped_elements.tolist() == inverted
    assert (repaired.volumes() > 0).all()
    np.testing.assert_allclose(repaired.volumes(), reference.volumes(), rtol=1e-14)
    # repaired rows: columns 2 and 3 of the input swapped; all other rows untouched
    np.testing.assert_array_equal(repaired.tetrahedra[inverted], tets[inverted][:, [0, 1, 3, 2]])
    untouched = np.setdiff1d(np.arange(len(tets)), inverted)
    np.testing.assert_array_equal(repaired.tetrahedra[untouched], reference.tetrahedra[untouched])
    # same elements (as node sets), same outward surface, same quality
    assert ({frozenset(t) for t in repaired.surface_triangles().tolist()}
            == {frozenset(t) for t in reference.surface_triangles().tolist()})
    assert oriented_set(repaired.surface_triangles()) == oriented_set(reference.surface_triangles())
    np.testing.assert_allclose(repaired.mean_ratio(), reference.mean_ratio(), rtol=1e-14)


def test_make_mesh_refuses_inverted_elements_without_fix_orientation():
    reference = small_box()
    tets = np.array(reference.tetrahedra)
    tets[7] = tets[7][[1, 0, 2, 3]]
    with pytest.raises(MeshError) as info:
        make_mesh(reference.rest_positions, tets, fix_orientation=False)
    assert 'tetrahedra' in str(info.value) and '[7]' in str(info.value)


def test_make_mesh_refuses_degenerate_elements_with_their_indices():
    points = np.vstack([UNIT_CORNER, [[1.0, 1.0, 0.0]], [[0.5, 0.5, 1e-13]]])
    flat = [[0, 1, 2, 4]]  # four points in the plane z = 0
    sliver = [[0, 1, 2, 5]]  # |V| = 1e-13 / 6 <= 1e-12 (sqrt 2)^3
    with pytest.raises(MeshError) as info:
        make_mesh(points, np.array([[0, 1, 2, 3]] + flat + [[1, 4, 2, 3]] + sliver))
    message = str(info.value)
    assert 'degenerate' in message and '[1, 3]' in message
    # just above the threshold: accepted
    points[5, 2] = 1e-10
    assert make_mesh(points, np.array(sliver)).volumes()[0] == pytest.approx(1e-10 / 6)


@pytest.mark.parametrize('positions, tetrahedra, tags, field, detail', [
    (np.vstack([UNIT_CORNER, [[np.nan, 0, 0]]]), ONE_TET, None, 'rest_positions', '[4]'),
    (UNIT_CORNER[:, :2], ONE_TET, None, 'rest_positions', '(4, 2)'),
    (UNIT_CORNER, [[0, 1, 2, 4]], None, 'tetrahedra', '4'),
    (UNIT_CORNER, [[0, 1, 2, 3], [0, 1, -1, 3]], None, 'tetrahedra', '[1]'),
    (UNIT_CORNER, [[0, 1, 2, 2]], None, 'tetrahedra', 'repeat'),
    (UNIT_CORNER, [[0, 1, 2]], None, 'tetrahedra', '(1, 3)'),
    (UNIT_CORNER, np.zeros((0, 4), dtype=int), None, 'tetrahedra', 'at least one'),
    (UNIT_CORNER, [[0.0, 1.0, 2.0, 3.0]], None, 'tetrahedra', 'float64'),
    (UNIT_CORNER, ONE_TET, [1, 2], 'element_tags', '(2,)'),
    (UNIT_CORNER, ONE_TET, [1.5], 'element_tags', '1.5'),
])
def test_make_mesh_refuses_bad_input_naming_the_field(positions, tetrahedra, tags, field, detail):
    with pytest.raises(MeshError) as info:
        make_mesh(positions, tetrahedra, tags)
    assert field in str(info.value) and detail in str(info.value)


def test_make_mesh_copies_its_input_and_keeps_unused_nodes():
    points = np.vstack([UNIT_CORNER, [[5.0, 5.0, 5.0]]])  # node 4 is used by no element
    tets = ONE_TET.copy()
    mesh = make_mesh(points, tets, [9])
    points[0] = 100.0
    tets[0, 0] = 4
    assert mesh.rest_positions[0].tolist() == [0.0, 0.0, 0.0]
    assert mesh.tetrahedra.tolist() == [[0, 1, 2, 3]]
    assert mesh.n_nodes == 5 and mesh.element_tags.tolist() == [9]
    assert mesh.surface_nodes().tolist() == [0, 1, 2, 3]
    assert isinstance(mesh, TetMesh) and 'n_elements=1' in repr(mesh)


@pytest.mark.parametrize('n_nodes', [None, 2 ** 21])  # 2**63 > 2**62: the row-compare fallback
def test_face_elements_finds_the_element_holding_each_face(n_nodes):
    """Truth by brute force with Python sets: each boundary triangle lies in exactly one element,
    each interior face in two (the lower index is returned); a non-face is refused by row."""
    mesh = graded_box_mesh((0.02, 0.02, 0.01), (3, 3, 2), focus_radius=0.002, growth=1.3)
    triangles = mesh.surface_triangles()
    holders = {}
    for e, tet in enumerate(mesh.tetrahedra.tolist()):
        for face in ((tet[1], tet[2], tet[3]), (tet[0], tet[2], tet[3]), (tet[0], tet[1], tet[3]),
                     (tet[0], tet[1], tet[2])):
            holders.setdefault(frozenset(face), []).append(e)
    expected = [holders[frozenset(t)] for t in triangles.tolist()]
    assert all(len(h) == 1 for h in expected)
    found = face_elements(mesh.tetrahedra, triangles, n_nodes)
    assert found.tolist() == [h[0] for h in expected]
    interior = [(sorted(f), h) for f, h in holders.items() if len(h) == 2][:50]
    rows = np.array([f for f, _ in interior])[:, ::-1]  # any vertex order
    assert face_elements(mesh.tetrahedra, rows, n_nodes).tolist() == [min(h) for _, h in interior]
    not_a_face = np.vstack([triangles[:3], [[0, 1, mesh.n_nodes - 1]]])
    with pytest.raises(MeshError, match=r'triangles: rows \[3\]'):
        face_elements(mesh.tetrahedra, not_a_face, n_nodes)
