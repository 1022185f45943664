"""Region selectors (engine/mesh/selectors.py): a point is in the same region by either formulation."""

import numpy as np

from support.foundations import block

from tissue_sim_ros.engine.mesh.selectors import RegionSelectors


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


def test_a_patch_selector_holds_exactly_the_surface_nodes_within_its_distance():
    point, distance = np.array([0.04, 0.013, 0.011]), 0.0105
    scene = block({'fixed': [{'surface_near_m': [*point, distance]}]}, divisions=(6, 6, 4), gravity=(0, 0, 0))
    x = scene.mesh.rest_positions
    triangles = scene.mesh.tetrahedra[:, [[0, 1, 2], [0, 1, 3], [0, 2, 3], [1, 2, 3]]].reshape(-1, 3)
    keys, counts = np.unique(np.sort(triangles, axis=1), axis=0, return_counts=True)
    surface = np.unique(keys[counts == 1])                   # faces of one element: the surface
    expected = surface[np.linalg.norm(x[surface] - point, axis=1) <= distance]
    held = np.flatnonzero((scene.simulation.dof_kind == 1).all(axis=1))
    assert len(expected) >= 3 and np.array_equal(held, expected)
    inside = np.flatnonzero(np.linalg.norm(x - point, axis=1) <= distance)
    assert len(inside) > len(expected)                       # interior nodes in reach are not held
