"""Reading an organ surface (meshing/surface.py): an opening too large to close, a surface that
crosses itself and millimetres read as metres are refused with their reason."""
import numpy as np
import pytest
import trimesh

from support.surfaces import R_MM, sphere_file
from tissue_sim_ros.errors import MeshError
from tissue_sim_ros.meshing.surface import read_surface


def test_a_surface_with_an_opening_is_refused_with_its_reason(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=3, radius=R_MM)
    cap = np.flatnonzero(np.asarray(ball.triangles_center)[:, 2] > 0.9 * R_MM)
    path = sphere_file(tmp_path / 'cut.stl', R_MM, drop=cap, subdivisions=3)
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
