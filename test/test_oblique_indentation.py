"""The needle on curved anatomy: a sphere indented along its surface normal at the pole and at 30
and 60 degrees from it gives the same force-depth curve, rotated, within the mesh's
discretisation error, measured here as the spread between two mesh levels of the straight
indentation. The sphere is the project's own unstructured mesh (tissue-sim mesh), held by the
surface cap opposite the indentation (rotated with it), so the only difference between the three
is how the elements lie under the needle."""
import numpy as np
import pytest
import trimesh

from tissue_sim_ros.engine.scene.scene import Scene
from tissue_sim_ros.meshing.volume import mesh_surface

R = 0.015
DEPTH, SPEED, TICK = 0.003, 0.004, 0.01
ANGLES = (0.0, 30.0, 60.0)


@pytest.fixture(scope='module')
def spheres(tmp_path_factory):
    folder = tmp_path_factory.mktemp('spheres')
    trimesh.creation.icosphere(subdivisions=3, radius=R * 1e3).export(folder / 'ball.stl')
    meshes = {}
    for name, cell in (('coarse', 0.003), ('fine', 0.0022)):
        meshes[name] = folder / f'{name}.vtu'
        mesh_surface(folder / 'ball.stl', meshes[name], units='mm', cell_m=cell, epsilon=2e-3, threads=1,
                     echo=lambda *a: None)
    return meshes


def quaternion_to(axis):
    """(x, y, z, w) turning +z onto ``axis`` (a unit vector in the x-z plane): about y."""
    angle = np.arctan2(axis[0], axis[2])
    return [0.0, float(np.sin(angle / 2)), 0.0, float(np.cos(angle / 2))]


def indent(mesh_file, angle_deg):
    """(depth (k,), force on the needle (k, 3)) indenting the sphere along -n at polar angle
    ``angle_deg`` (in the x-z plane) with a flat end that does not puncture."""
    n = np.array([np.sin(np.radians(angle_deg)), 0.0, np.cos(np.radians(angle_deg))])
    axis = -n
    length = 0.1
    spec = {'mesh': {'generator': 'file', 'file': str(mesh_file)},
            'regions': [{'name': 'ball', 'young_modulus_pa': 5000.0, 'poisson_ratio': 0.45,
                         'membrane': {'criterion': 'force', 'rupture_force_n': 100.0}}],
            'model': {'geometric': True, 'inversion_safeguard': True},
            'boundary': {'fixed': [{'surface_near_m': [*(-R * n), 0.006]}]},
            'solver': {'mass_scaling': 100.0, 'damping_per_s': 200.0},
            'needle': {'diameter_m': 0.003, 'length_m': length, 'tip': {'shape': 'flat'},
                       'initial_position_m': list(n * (R + 0.0005) - length * axis),
                       'initial_orientation_xyzw': quaternion_to(axis), 'max_jump_m': 0.01}}
    scene = Scene(spec)
    start, orientation = scene.initial_needle_pose
    depths, forces = [], []
    travel = DEPTH + 0.0005
    ticks = int(round(travel / SPEED / TICK))
    for k in range(1, ticks + 1):
        scene.advance(TICK, start + axis * travel * k / ticks, orientation)
        depths.append(scene.needle.tip_depth())
        forces.append(scene.reaction_wrench()[0].copy())
    assert scene.phase == 'contact'
    return np.array(depths), np.array(forces), n


def axial_curve(depths, forces, n, grid):
    """The force pushing the needle back along the normal, at the grid's depths."""
    return np.interp(grid, depths, forces @ n)


def test_oblique_indentations_match_the_straight_one_rotated_within_the_discretisation_error(spheres):
    grid = np.linspace(0.0005, DEPTH, 11)
    straight = {level: axial_curve(*indent(path, 0.0), grid) for level, path in spheres.items()}
    discretisation = np.max(np.abs(straight['coarse'] - straight['fine'])) / straight['fine'][-1]
    assert straight['fine'][-1] > 0.01 and np.all(np.diff(straight['fine']) > 0)
    for angle in ANGLES[1:]:
        depths, forces, n = indent(spheres['fine'], angle)
        curve = axial_curve(depths, forces, n, grid)
        difference = np.max(np.abs(curve - straight['fine'])) / straight['fine'][-1]
        lateral = np.linalg.norm(forces - np.outer(forces @ n, n), axis=1)
        print(f'{angle:.0f} deg: force-depth curve within {difference:.3f} of the straight one; '
              f'mesh levels apart by {discretisation:.3f}; lateral force {lateral.max():.4f} N')
        assert difference <= max(discretisation, 0.02)
        assert lateral.max() < 0.1 * straight['fine'][-1]
