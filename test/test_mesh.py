"""Tests of tissue_sim_ros.engine.mesh.tetmesh and mesh_generators against independent truth:
closed-form volumes, areas and counts of a box, the divergence theorem, Euler's formula, a
hand-evaluated mean ratio, and face/edge counts computed here with plain Python sets (not with
the module's numpy code). Files: test_mesh_io.py."""
from collections import Counter
import math

import numpy as np
import pytest

from tissue_sim_ros.engine.mesh.tetmesh import (MeshOrientationWarning, TetMesh, make_mesh, mean_ratio,
                                                signed_volumes, surface_triangles)
from tissue_sim_ros.errors import MeshError
from tissue_sim_ros.engine.mesh.generators import box_mesh, graded_box_mesh

UNIT_CORNER = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
# Regular tetrahedron with edge 2 sqrt(2), positively oriented (checked in a test below).
REGULAR = np.array([[1.0, 1.0, 1.0], [-1.0, -1.0, 1.0], [-1.0, 1.0, -1.0], [1.0, -1.0, -1.0]])
ONE_TET = np.array([[0, 1, 2, 3]])


def random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def face_counts(tetrahedra) -> Counter:
    """How many elements hold each face (as a frozenset of nodes), by brute force."""
    counts = Counter()
    for a, b, c, d in tetrahedra.tolist():
        for face in ((b, c, d), (a, c, d), (a, b, d), (a, b, c)):
            counts[frozenset(face)] += 1
    return counts


def oriented_set(triangles) -> set:
    """Triangles as tuples rotated to start at their smallest node (keeps the orientation)."""
    out = set()
    for t in triangles.tolist():
        k = t.index(min(t))
        out.add(tuple(t[k:] + t[:k]))
    return out


def triangle_area_vectors(positions, triangles) -> np.ndarray:
    p = positions[triangles]
    return 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def cell_widths(coordinates) -> np.ndarray:
    return np.diff(np.unique(coordinates))


# ------------------------------------------------------------------------------------------
# box_mesh
# ------------------------------------------------------------------------------------------

SIZE = (0.03, 0.05, 0.02)
DIVISIONS = (3, 4, 2)
ORIGIN = (0.2, -0.1, 0.05)


@pytest.fixture(scope='module')
def box():
    return box_mesh(SIZE, DIVISIONS, ORIGIN)


def test_box_mesh_counts_numbering_and_element_order(box):
    nx, ny, nz = DIVISIONS
    assert box.n_nodes == (nx + 1) * (ny + 1) * (nz + 1)
    assert box.n_elements == 6 * nx * ny * nz
    assert box.tetrahedra.dtype == np.int64 and box.rest_positions.dtype == np.float64
    assert box.element_tags.dtype == np.int32 and not box.element_tags.any()
    assert box.flipped_elements.size == 0
    # node index i + (nx+1) (j + (ny+1) k) sits at origin + (i, j, k) * cell size
    cell = np.array(SIZE) / np.array(DIVISIONS)
    for i, j, k in [(0, 0, 0), (3, 0, 0), (1, 2, 1), (3, 4, 2), (0, 4, 1)]:
        node = i + (nx + 1) * (j + (ny + 1) * k)
        np.testing.assert_allclose(box.rest_positions[node],
                                   np.array(ORIGIN) + cell * (i, j, k), rtol=0, atol=1e-15)
    # elements 6h .. 6h+5 fill hexahedron h = i + nx (j + ny k): their centroids lie inside it
    centroids = box.rest_positions[box.tetrahedra].mean(axis=1)
    hex_index = np.arange(box.n_elements) // 6
    ijk = np.stack([hex_index % nx, (hex_index // nx) % ny, hex_index // (nx * ny)], axis=1)
    local = (centroids - np.array(ORIGIN)) / cell - ijk
    assert ((local > 0) & (local < 1)).all()


def test_box_mesh_volumes_are_positive_equal_and_sum_to_the_box(box):
    volumes = box.volumes()
    hexahedron = np.prod(np.array(SIZE) / np.array(DIVISIONS))
    assert (volumes > 0).all()
    np.testing.assert_allclose(volumes, hexahedron / 6, rtol=1e-12)
    assert math.isclose(volumes.sum(), np.prod(SIZE), rel_tol=1e-12)
    # independent check of the module's volume formula with numpy's determinant
    p = box.rest_positions[box.tetrahedra]
    np.testing.assert_allclose(np.linalg.det(p[:, 1:] - p[:, :1]) / 6, volumes, rtol=1e-12)


def test_box_mesh_is_conforming_and_its_surface_is_the_box(box):
    nx, ny, nz = DIVISIONS
    counts = face_counts(box.tetrahedra)
    assert set(counts.values()) == {1, 2}  # each internal face shared by exactly two elements
    boundary = {face for face, count in counts.items() if count == 1}
    assert len(boundary) == 4 * (nx * ny + ny * nz + nz * nx)  # two triangles per square
    triangles = box.surface_triangles()
    assert {frozenset(t) for t in triangles.tolist()} == boundary
    assert len(triangles) == len(boundary)
    area = np.linalg.norm(triangle_area_vectors(box.rest_positions, triangles), axis=1).sum()
    a, b, c = SIZE
    assert math.isclose(area, 2 * (a * b + b * c + c * a), rel_tol=1e-12)


def test_box_surface_is_closed_and_outward(box):
    triangles = box.surface_triangles()
    positions = box.rest_positions
    # closed and consistently oriented: each directed edge once, and its reverse once
    directed = Counter()
    for a, b, c in triangles.tolist():
        directed.update([(a, b), (b, c), (c, a)])
    assert set(directed.values()) == {1}
    assert all((b, a) in directed for a, b in directed)
    # divergence theorem: V = (1/3) sum over the surface of x . n dA
    area_vectors = triangle_area_vectors(positions, triangles)
    centroids = positions[triangles].mean(axis=1)
    enclosed = np.einsum('ij,ij->', centroids, area_vectors) / 3
    assert math.isclose(enclosed, np.prod(SIZE), rel_tol=1e-12)
    # every normal points away from the box centre
    centre = np.array(ORIGIN) + 0.5 * np.array(SIZE)
    assert (np.einsum('ij,ij->i', centroids - centre, area_vectors) > 0).all()


def test_box_mesh_edges_and_euler_characteristic(box):
    nx, ny, nz = DIVISIONS
    edges = box.edges()
    axis_edges = nx * (ny + 1) * (nz + 1) + (nx + 1) * ny * (nz + 1) + (nx + 1) * (ny + 1) * nz
    face_diagonals = nx * ny * (nz + 1) + nx * (ny + 1) * nz + (nx + 1) * ny * nz
    body_diagonals = nx * ny * nz
    assert len(edges) == axis_edges + face_diagonals + body_diagonals
    assert (edges[:, 0] < edges[:, 1]).all()
    order = np.lexsort((edges[:, 1], edges[:, 0]))
    assert (order == np.arange(len(edges))).all()
    brute = {tuple(sorted(pair)) for t in box.tetrahedra.tolist()
             for pair in ((t[0], t[1]), (t[0], t[2]), (t[0], t[3]),
                          (t[1], t[2]), (t[1], t[3]), (t[2], t[3]))}
    assert set(map(tuple, edges.tolist())) == brute
    faces = len(face_counts(box.tetrahedra))
    assert box.n_nodes - len(edges) + faces - box.n_elements == 1  # a ball


def test_box_surface_nodes(box):
    nx, ny, nz = DIVISIONS
    nodes = box.surface_nodes()
    assert len(nodes) == box.n_nodes - (nx - 1) * (ny - 1) * (nz - 1)
    assert (np.diff(nodes) > 0).all()
    p = box.rest_positions[nodes]
    low, high = np.array(ORIGIN), np.array(ORIGIN) + SIZE
    on_face = np.isclose(p, low, rtol=0, atol=1e-15) | np.isclose(p, high, rtol=0, atol=1e-15)
    assert on_face.any(axis=1).all()


def test_box_mesh_arrays_are_read_only_and_cached(box):
    for array in (box.rest_positions, box.tetrahedra, box.element_tags, box.flipped_elements,
                  box.volumes(), box.surface_triangles(), box.edges()):
        assert array.flags.c_contiguous
        with pytest.raises(ValueError):
            array[0] = 0
    assert box.surface_triangles() is box.surface_triangles()


def test_box_mesh_of_half_a_million_elements_builds():
    mesh = box_mesh((0.1, 0.1, 0.05), (44, 44, 43))  # 499 488 elements (timing: benchmarks)
    assert mesh.n_elements == 6 * 44 * 44 * 43
    assert math.isclose(mesh.volumes().sum(), 0.1 * 0.1 * 0.05, rel_tol=1e-12)


@pytest.mark.parametrize('kwargs, field, value', [
    ({'size': (0.1, -0.1, 0.05)}, 'size', '-0.1'),
    ({'size': (0.1, 0.0, 0.05)}, 'size', '0.0'),
    ({'size': (0.1, float('nan'), 0.05)}, 'size', 'nan'),
    ({'size': (0.1, 0.1)}, 'size', '0.1'),
    ({'divisions': (4, 0, 4)}, 'divisions', '0'),
    ({'divisions': (4, 2.5, 4)}, 'divisions', '2.5'),
    ({'origin': (0.0, float('inf'), 0.0)}, 'origin', 'inf'),
])
def test_box_mesh_refuses_bad_parameters(kwargs, field, value):
    with pytest.raises(MeshError) as info:
        box_mesh(**kwargs)
    assert field in str(info.value) and value in str(info.value)


# ------------------------------------------------------------------------------------------
# volumes, mean ratio, heights, surface of one element
# ------------------------------------------------------------------------------------------

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


# ------------------------------------------------------------------------------------------
# make_mesh validation and orientation repair
# ------------------------------------------------------------------------------------------

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


# ------------------------------------------------------------------------------------------
# graded_box_mesh
# ------------------------------------------------------------------------------------------

GRADED_SIZE = (0.04, 0.03, 0.01)
GRADED_ORIGIN = (-0.01, 0.0, 0.02)
FOCUS = (0.004, 0.021)
FINE = 0.0005
GROWTH = 1.3
COARSE = (0.004, 0.003, 0.0025)  # size / divisions
GRADED_DIVISIONS = (10, 10, 4)


@pytest.fixture(scope='module')
def graded():
    return graded_box_mesh(GRADED_SIZE, GRADED_DIVISIONS, GRADED_ORIGIN, focus=FOCUS,
                           focus_radius=0.001, growth=GROWTH, fine_size=FINE)


def test_graded_box_mesh_is_conforming_positive_and_fills_the_box(graded):
    volumes = graded.volumes()
    assert (volumes > 0).all()
    assert math.isclose(volumes.sum(), np.prod(GRADED_SIZE), rel_tol=1e-12)
    counts = face_counts(graded.tetrahedra)
    assert set(counts.values()) == {1, 2}
    boundary = {face for face, count in counts.items() if count == 1}
    assert {frozenset(t) for t in graded.surface_triangles().tolist()} == boundary
    area = np.linalg.norm(triangle_area_vectors(graded.rest_positions,
                                                graded.surface_triangles()), axis=1).sum()
    a, b, c = GRADED_SIZE
    assert math.isclose(area, 2 * (a * b + b * c + c * a), rel_tol=1e-12)
    # each element is a sixth of the hexahedron around it
    x, y, z = (np.unique(graded.rest_positions[:, a]) for a in range(3))
    nx, ny = len(x) - 1, len(y) - 1
    assert graded.n_elements == 6 * nx * ny * (len(z) - 1)
    hexahedra = np.multiply.outer(np.multiply.outer(np.diff(z), np.diff(y)), np.diff(x)).ravel()
    np.testing.assert_allclose(volumes, np.repeat(hexahedra, 6) / 6, rtol=1e-12)


@pytest.mark.parametrize('axis', [0, 1])
def test_graded_box_mesh_cells_are_finest_at_the_focus_and_grow_gently(graded, axis):
    nodes = np.unique(graded.rest_positions[:, axis])
    widths = np.diff(nodes)
    assert nodes[0] == GRADED_ORIGIN[axis] and nodes[-1] == GRADED_ORIGIN[axis] + GRADED_SIZE[axis]
    at_focus = np.searchsorted(nodes, FOCUS[axis]) - 1  # the cell that contains the focus
    assert widths[at_focus] <= widths.min() * (1 + 1e-9)
    assert FINE * (1 - 1 / len(widths)) <= widths.min() <= FINE * (1 + 1e-12)
    ratios = widths[1:] / widths[:-1]
    assert np.maximum(ratios, 1 / ratios).max() <= GROWTH * (1 + 1e-9)
    assert widths.max() <= COARSE[axis] * (1 + 1e-12)
    assert widths.max() > 0.9 * COARSE[axis]  # graded up to the far-field width
    # widths never shrink moving away from the focus
    left, right = widths[:at_focus + 1], widths[at_focus:]
    assert (np.diff(left) <= 1e-15).all() and (np.diff(right) >= -1e-15).all()


def test_graded_box_mesh_keeps_z_uniform_or_grades_it_toward_the_top(graded):
    np.testing.assert_allclose(cell_widths(graded.rest_positions[:, 2]), COARSE[2], rtol=1e-12)
    top_graded = graded_box_mesh(GRADED_SIZE, GRADED_DIVISIONS, GRADED_ORIGIN, focus=FOCUS,
                                 focus_radius=0.0, growth=GROWTH, fine_size=FINE, grade_z=True)
    widths = cell_widths(top_graded.rest_positions[:, 2])
    assert widths[-1] == widths.min() and widths[-1] <= FINE
    assert (np.diff(widths) <= 1e-15).all()  # growing downward, away from the top face
    assert math.isclose(top_graded.volumes().sum(), np.prod(GRADED_SIZE), rel_tol=1e-12)


def test_graded_box_mesh_with_growth_one_is_uniform():
    mesh = graded_box_mesh((0.01, 0.01, 0.01), (2, 2, 2), focus=(0.003, 0.004),
                           focus_radius=0.0, growth=1.0, fine_size=0.001)
    for axis in (0, 1):
        np.testing.assert_allclose(cell_widths(mesh.rest_positions[:, axis]), 0.001, rtol=1e-12)


@pytest.mark.parametrize('kwargs, field', [
    ({'growth': 0.9}, 'growth'),
    ({'growth': float('nan')}, 'growth'),
    ({'focus': (0.5, 0.0)}, 'focus'),
    ({'focus': (0.01,)}, 'focus'),
    ({'focus_radius': -0.001}, 'focus_radius'),
    ({'fine_size': 0.0}, 'fine_size'),
    ({'fine_size': 0.02}, 'fine_size'),  # coarser than size / divisions
])
def test_graded_box_mesh_refuses_bad_parameters(kwargs, field):
    arguments = dict(focus=(0.01, 0.01), focus_radius=0.001, growth=1.2, fine_size=0.001)
    arguments.update(kwargs)
    with pytest.raises(MeshError) as info:
        graded_box_mesh((0.02, 0.02, 0.01), (4, 4, 2), **arguments)
    assert str(info.value).startswith(field)
