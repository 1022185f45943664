"""Tests of tissue_sim_ros.engine.mesh.generators against independent truth: closed-form volumes,
areas and counts of a box, the divergence theorem, Euler's formula, and face/edge counts computed
here with plain Python sets (not with the module's numpy code); graded cells against their rule."""

import math
from collections import Counter

import numpy as np
import pytest

from support.meshes import DIVISIONS, ORIGIN, SIZE, cell_widths, face_counts, triangle_area_vectors
from tissue_sim_ros.engine.mesh.generators import box_mesh, graded_box_mesh
from tissue_sim_ros.errors import MeshError


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


# graded_box_mesh
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
