"""Targets carried by the tissue (engine/scene/targets.py): exact under an affine displacement, the
tip distance and lateral miss against their definitions, refusals by name, and a target under the
needle moving as a static solve of the same indentation says."""

import numpy as np
import pytest

from support.foundations import E, ON_FOUNDATION, RHO, block, column
from support.solvers import static_solve
from tissue_sim_ros.engine.driver import SimulationDriver
from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.errors import SceneError

MESH = {'generator': 'graded_box', 'divisions': [8, 8, 6], 'fine_size_m': 0.002, 'focus_radius_m': 0.006}
LINEAR = {'geometric': False, 'physical': {'law': 'none'}, 'viscosity_mu_pa_s': 0.0,
          'viscosity_lambda_pa_s': 0.0, 'nonlinearity_threshold': 0.0}


def test_a_target_under_the_needle_moves_as_the_static_solve_of_the_indentation():
    scene = Scene.from_file(None, mesh=MESH, model=LINEAR,
                            targets=[{'name': 'tumour', 'position_m': [0.001, 0.0, -0.008]}])
    driver = SimulationDriver(scene)
    start, q = scene.needle_pose
    axis = scene.needle.axis
    for k in range(1, 61):                     # 12 mm at 10 mm/s: the tip 3 mm into the surface
        driver.advance(0.02, start + 0.0002 * k * axis, q)
    for _ in range(150):                       # held 3 s: settled
        driver.advance(0.02)
    assert scene.phase == 'contact' and not scene.puncture_events
    u = scene.displacement.copy()
    assert np.abs(scene.simulation.velocity).max() < 1e-4 * np.abs(u).max() / 0.02
    model = scene.model
    residual = (model.stiffness_matrix() @ u.ravel()).reshape(-1, 3)
    fixed = np.flatnonzero((scene.simulation.dof_kind != 0).any(axis=1))
    loaded = np.flatnonzero(np.linalg.norm(residual, axis=1) > 1e-6 * np.abs(residual).max())
    held = np.union1d(fixed, loaded)
    assert 0 < len(np.setdiff1d(loaded, fixed)) < 60, 'the needle should load a few nodes only'
    dofs = (3 * held[:, None] + np.arange(3)).ravel()
    static = static_solve(model, dofs, u[held].ravel())
    target = scene.target_positions()[0] - scene.targets.rest[0]
    static_target = scene.targets.positions(static)[0] - scene.targets.rest[0]
    assert target[2] < -2e-4, f'the target should move down by a fraction of a millimetre: {target}'
    np.testing.assert_allclose(target, static_target, rtol=0, atol=0.01 * abs(target[2]))


COARSE = ['mesh.fine_size_m=0.003', 'mesh.divisions=[6,6,5]']
TARGETS = 'targets=[{name: tumour, position_m: [0.002, 0.0, -0.015]}, {name: fiducial, position_m: [0.012, -0.007, -0.031]}]'


@pytest.fixture(scope='module')
def scene():
    return Scene.from_file(None, sets=COARSE + [TARGETS])


def test_targets_follow_an_affine_displacement_exactly(scene):
    """u = (F - I) X at every node: linear interpolation reproduces it, so each target sits at F X."""
    rng = np.random.default_rng(2)
    gradient = 0.05 * rng.normal(size=(3, 3))
    shift = rng.normal(scale=1e-3, size=3)
    x = scene.mesh.rest_positions
    displacement = x @ gradient.T + shift
    positions = scene.targets.positions(displacement)
    expected = scene.targets.rest + scene.targets.rest @ gradient.T + shift
    assert scene.targets.names == ['tumour', 'fiducial']
    assert np.abs(positions - expected).max() < 1e-14
    np.testing.assert_array_equal(scene.target_positions(), scene.targets.rest)    # at rest


def test_tip_distance_and_lateral_miss(scene):
    tip, axis = scene.needle.tip, scene.needle.axis
    distance, miss, ahead = scene.targets_relative_to_needle()
    offset = scene.targets.rest - tip
    assert distance == pytest.approx(np.linalg.norm(offset, axis=1), abs=1e-15)
    assert miss == pytest.approx(np.linalg.norm(np.cross(offset, axis), axis=1), abs=1e-15)
    assert ahead == pytest.approx(offset @ axis, abs=1e-15)
    assert np.all(ahead > 0)          # both below the tip, which points into the tissue


@pytest.mark.parametrize('targets, words', [
    ('[{name: t, position_m: [0.0, 0.0, 0.05]}]', ['targets[0].position_m', 'outside the tissue mesh']),
    ('[{name: t, position_m: [0.0, 0.0, -0.01]}, {name: t, position_m: [0.0, 0.0, -0.02]}]',
     ['targets[1].name', 'another target']),
    ('[{name: t}]', ['targets[0]: give one of position_m', 'and region']),
    ('[{position_m: [0.0, 0.0, -0.01]}]', ['targets[0].name']),
])
def test_bad_targets_refused_by_name(targets, words):
    with pytest.raises(SceneError) as caught:
        Scene.from_file(None, sets=COARSE + [f'targets={targets}'])
    for word in words:
        assert word in str(caught.value)


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
