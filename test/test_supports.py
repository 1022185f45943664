"""Supports where anatomy has them: a block on an elastic foundation settles under gravity to the
analytic column, too few supports are refused at load naming the key, a surface-patch selector
holds exactly the surface nodes within its distance, and a target at a region's centroid moves
with the tissue."""
import numpy as np
import pytest

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

E, RHO, G = 5000.0, 1000.0, 9.81
SIZE = (0.04, 0.04, 0.02)
K_N, K_T = 2.0e5, 1.0e5


def block(boundary, model=None, regions=None, targets=(), divisions=(4, 4, 4), gravity=(0.0, 0.0, -G)):
    spec = {'mesh': {'generator': 'box', 'size_m': list(SIZE), 'origin_m': [0.0, 0.0, 0.0],
                     'divisions': list(divisions)},
            'regions': regions or [{'name': 'tissue', 'young_modulus_pa': E, 'poisson_ratio': 0.0,
                                    'density_kg_per_m3': RHO}],
            'model': model or {'geometric': False, 'inversion_safeguard': False},
            'boundary': boundary, 'solver': {'gravity_m_s2': list(gravity)},
            'targets': list(targets),
            'needle': {'initial_position_m': [0.02, 0.02, 0.2]}}
    return Scene(spec)


ON_FOUNDATION = {'fixed': [], 'springs': [{'select': {'below_z_m': 1e-9}, 'normal_n_per_m3': K_N,
                                           'tangential_n_per_m3': K_T}]}


def column(z):
    """Downward displacement of a column of height H on a Winkler foundation k_n under its own
    weight, Poisson ratio 0 (uniaxial stress): rho g H / k_n + rho g (H z - z^2 / 2) / E."""
    h = SIZE[2]
    return RHO * G * h / K_N + RHO * G * (h * z - z * z / 2.0) / E


def test_a_block_on_a_foundation_settles_to_the_analytic_column():
    scene = block(ON_FOUNDATION)
    x, u = scene.mesh.rest_positions, scene.simulation.displacement
    bottom = np.isclose(x[:, 2], 0.0)
    # the foundation carries the weight: its area-weighted settlement is W / (k_n A), exactly
    rows = scene.simulation.support_rows
    stiffness_zz = scene.simulation.support_stiffness[rows[bottom], 2]
    weight = RHO * G * np.prod(SIZE)
    assert -np.sum(stiffness_zz * u[bottom, 2]) == pytest.approx(weight, rel=1e-9)
    assert -np.sum(stiffness_zz * u[bottom, 2]) / np.sum(stiffness_zz) == pytest.approx(column(0.0), rel=1e-9)
    # the top moves by the foundation's settlement plus the column's own compression (lumped
    # gravity on linear elements: 1.4e-4 off at four layers, 2e-5 at eight)
    top = np.isclose(x[:, 2], SIZE[2])
    assert -u[top, 2].mean() == pytest.approx(column(SIZE[2]), rel=0.002)
    # no Poisson effect and no sliding: what moves sideways is the Kuhn split's own skew (1 %)
    assert np.abs(u[:, :2]).max() < 0.02 * column(SIZE[2])
    # the state is the one a reset returns to, and the tissue stays there
    scene.advance(0.05, *scene.initial_needle_pose)
    assert np.abs(scene.simulation.displacement - u).max() < 0.01 * column(SIZE[2])
    scene.reset()
    assert np.array_equal(scene.simulation.displacement, u)


def test_the_full_model_settles_near_the_linear_one():
    linear = block(ON_FOUNDATION).simulation.displacement
    full = block(ON_FOUNDATION, model={'geometric': True}).simulation.displacement
    # 2 % strain at most: the geometric non-linearity moves the sag by about that fraction
    assert np.abs(full - linear).max() < 0.03 * np.abs(linear).max()


def test_supports_that_cannot_stop_rigid_motion_are_refused_naming_the_key():
    corner = [0.0, 0.0, 0.0, 1e-4]
    with pytest.raises(SceneError, match=r'boundary\.fixed.*holds 1 node.*free to move rigidly'):
        block({'fixed': [{'surface_near_m': corner}]})
    with pytest.raises(SceneError, match=r'rotation'):          # two nodes: a hinge
        block({'fixed': [{'surface_near_m': corner}, {'surface_near_m': [0.04, 0.0, 0.0, 1e-4]}]})
    sliding = {'fixed': [], 'springs': [dict(ON_FOUNDATION['springs'][0], tangential_n_per_m3=0.0)]}
    with pytest.raises(SceneError, match=r'translation along x.*translation along y'):
        block(sliding)
    three = block({'fixed': [{'surface_near_m': corner}, {'surface_near_m': [0.04, 0.0, 0.0, 1e-4]},
                             {'surface_near_m': [0.0, 0.04, 0.0, 1e-4]}]}, gravity=(0.0, 0.0, 0.0))
    assert int((three.simulation.dof_kind == 1).all(axis=1).sum()) == 3


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


def test_a_target_at_a_region_centroid_moves_with_the_tissue():
    regions = [{'name': 'tissue', 'young_modulus_pa': E, 'poisson_ratio': 0.0, 'density_kg_per_m3': RHO},
               {'name': 'lump', 'select': {'box_m': [[0.01, 0.01, 0.005], [0.03, 0.03, 0.015]]},
                'young_modulus_pa': E, 'poisson_ratio': 0.0, 'density_kg_per_m3': RHO}]
    scene = block(ON_FOUNDATION, regions=regions, targets=[{'name': 'centre', 'region': 'lump'}],
                  divisions=(4, 4, 4))
    x, tets = scene.mesh.rest_positions, scene.mesh.tetrahedra
    centroids = x[tets].mean(axis=1)
    lump = np.all((centroids >= [0.01, 0.01, 0.005]) & (centroids <= [0.03, 0.03, 0.015]), axis=1)
    volumes = scene.mesh.volumes()[lump]
    expected = (centroids[lump] * volumes[:, None]).sum(axis=0) / volumes.sum()
    assert np.allclose(scene.targets.rest[0], expected, atol=1e-12)
    moved = scene.target_positions()[0] - scene.targets.rest[0]
    assert -moved[2] == pytest.approx(column(expected[2]), rel=0.02)
