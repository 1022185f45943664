"""The needle's geometric kernels (engine/needle/kernels.py) against searches of every triangle and
every element."""

import numpy as np
import pytest


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
