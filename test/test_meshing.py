"""tissue-sim mesh: volumes against the analytic sphere, inclusions tagged with their volumes,
repairs and refusals (an open boundary, a self-intersection, millimetres read as metres),
grading toward a focus, and the quality measures against the regular tetrahedron."""
import json

import numpy as np
import pytest
import trimesh

from tissue_sim_ros.cli.app import main as cli
from tissue_sim_ros.engine.mesh.files import load_mesh
from tissue_sim_ros.errors import MeshError
from tissue_sim_ros.meshing.quality import dihedral_angles, quality_report
from tissue_sim_ros.meshing.surface import read_surface
from tissue_sim_ros.meshing.volume import mesh_surface

R_MM, INNER_MM = 20.0, 8.0


def sphere_file(path, radius_mm, centre=(0.0, 0.0, 0.0), drop=()):
    ball = trimesh.creation.icosphere(subdivisions=4, radius=radius_mm)
    faces = np.delete(np.asarray(ball.faces), list(drop), axis=0)
    trimesh.Trimesh(np.asarray(ball.vertices) + centre, faces, process=False).export(path)
    return path


def ball_volume(radius_mm):
    return 4.0 / 3.0 * np.pi * (radius_mm * 1e-3) ** 3


def test_a_sphere_with_an_inclusion_meshes_to_their_volumes_through_the_command(tmp_path):
    outer = sphere_file(tmp_path / 'ball.stl', R_MM, drop=[7])        # a segmentation's missing triangle
    inner = sphere_file(tmp_path / 'lump.stl', INNER_MM, centre=(4.0, 0.0, 0.0))
    out = tmp_path / 'ball.vtu'
    assert cli(['mesh', str(outer), '--out', str(out), '--units', 'mm', '--cell-mm', '5',
                '--inclusion', f'lump={inner}', '--threads', '2']) == 0
    report = json.loads(out.with_suffix('.quality.json').read_text())
    mesh = load_mesh(out)
    volumes = mesh.volumes()
    assert volumes.sum() == pytest.approx(ball_volume(R_MM), rel=0.01)
    assert volumes[mesh.element_tags == 2].sum() == pytest.approx(ball_volume(INNER_MM), rel=0.01)
    assert set(np.unique(mesh.element_tags)) == {1, 2} and report['tags'] == {'organ': 1, 'lump': 2}
    assert report['regions']['2']['volume_m3'] == pytest.approx(volumes[mesh.element_tags == 2].sum())
    assert any('closed 1 small holes' in r for r in report['repairs']['organ'])
    centroids = mesh.rest_positions[mesh.tetrahedra].mean(axis=1)
    tagged = np.linalg.norm(centroids - [0.004, 0.0, 0.0], axis=1) < INNER_MM * 1e-3
    assert np.mean(tagged == (mesh.element_tags == 2)) > 0.99
    assert report['dihedral_deg']['min'] > 5.0 and report['slivers'] == 0


def test_a_surface_with_an_opening_is_refused_with_its_reason(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=R_MM)
    cap = np.flatnonzero(np.asarray(ball.triangles_center)[:, 2] > 0.9 * R_MM)
    path = sphere_file(tmp_path / 'cut.stl', R_MM, drop=cap)
    with pytest.raises(MeshError, match=r'not closed: an open boundary of \d+ edges'):
        read_surface(path, 'mm')


def test_millimetres_read_as_metres_are_caught(tmp_path):
    path = sphere_file(tmp_path / 'organ.stl', 80.0)
    with pytest.raises(MeshError, match=r'larger than any organ.*more likely in mm: give --units mm'):
        read_surface(path)
    assert read_surface(path, 'mm').diagonal == pytest.approx(0.16 * np.sqrt(3), rel=0.01)
    with pytest.raises(MeshError, match=r'smaller than an organ'):
        read_surface(path, 'mm', scale=1e-3)


def test_a_surface_that_crosses_itself_is_refused(tmp_path):
    one = trimesh.creation.icosphere(subdivisions=2, radius=R_MM)
    two = trimesh.creation.icosphere(subdivisions=2, radius=R_MM)
    vertices = np.concatenate([one.vertices, np.asarray(two.vertices) + [R_MM, 0.0, 0.0]])
    faces = np.concatenate([one.faces, np.asarray(two.faces) + len(one.vertices)])
    trimesh.Trimesh(vertices, faces, process=False).export(tmp_path / 'two.stl')
    with pytest.raises(MeshError, match='intersects itself'):
        read_surface(tmp_path / 'two.stl', 'mm')


def test_grading_makes_the_elements_fine_near_the_focus(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=30.0)
    ball.export(tmp_path / 'ball.stl')
    report = mesh_surface(tmp_path / 'ball.stl', tmp_path / 'graded.vtu', units='mm', cell_m=0.01, fine_m=0.0025,
                          focus=(0, 0, 0), radius_m=0.004, epsilon=3e-3, threads=2, echo=lambda *a: None)
    mesh = load_mesh(tmp_path / 'graded.vtu')
    size = np.cbrt(mesh.volumes() / 0.1178)                        # the edge of a regular tet of that volume
    distance = np.linalg.norm(mesh.rest_positions[mesh.tetrahedra].mean(axis=1), axis=1)
    near = np.median(size[distance < 0.004])
    far = np.median(size[(distance > 0.016) & (distance < 0.024)])  # past the grading, off the surface
    assert near < 1.3 * 0.0025 and far > 2.5 * near
    assert report['options']['fine_m'] == 0.0025


def test_the_quality_measures_of_the_regular_tetrahedron():
    points = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
    tetrahedra = np.array([[0, 1, 2, 3]])
    if np.linalg.det(points[[1, 2, 3]] - points[0]) < 0:
        tetrahedra = tetrahedra[:, [0, 2, 1, 3]]
    assert np.allclose(dihedral_angles(points, tetrahedra), np.degrees(np.arccos(1.0 / 3.0)))
    report = quality_report(points, tetrahedra)
    assert report['mean_ratio']['min'] == pytest.approx(1.0)
    flat = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.01]])
    assert quality_report(flat, np.array([[0, 1, 2, 3]]))['slivers'] == 1
