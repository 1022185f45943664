"""Mesh faces and orientation (engine.mesh): the element holding each face against a brute-force
set count, with and without the int64 key overflow fallback, and the one warning that says which
elements of a mesh file were re-oriented (the count from the signed volumes)."""
import warnings

import meshio
import numpy as np
import pytest

from tissue_sim_ros.engine.mesh.tetmesh import (MeshOrientationWarning, face_elements, make_mesh,
                                                signed_volumes)
from tissue_sim_ros.errors import MeshError
from tissue_sim_ros.engine.mesh.generators import box_mesh, graded_box_mesh
from tissue_sim_ros.engine.mesh.files import load_mesh, save_mesh


def test_load_mesh_says_once_how_many_elements_it_reoriented_and_which(tmp_path):
    """A file written by meshio with 12 of 48 elements mirrored (vertices 1 and 2 swapped): one
    warning naming the file, the count and the first 10 ids, and none for a clean file."""
    reference = box_mesh((0.01, 0.01, 0.01), (2, 2, 2))
    tets = np.array(reference.tetrahedra)
    mirrored = np.arange(0, 48, 4)
    tets[mirrored] = tets[mirrored][:, [0, 2, 1, 3]]
    assert (signed_volumes(reference.rest_positions, tets) < 0).sum() == 12  # truth from the volumes
    path = tmp_path / 'mirrored.vtu'
    meshio.write(path, meshio.Mesh(reference.rest_positions, [('tetra', tets)]))
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter('always')
        loaded = load_mesh(path)
        make_mesh(loaded.rest_positions, loaded.tetrahedra)  # re-building a repaired mesh: silent
    said = [w for w in record if issubclass(w.category, MeshOrientationWarning)]
    assert len(said) == 1, [str(w.message) for w in record]
    assert said[0].filename == __file__      # the caller's line, not the mesh modules'
    text = str(said[0].message)
    assert 'mirrored.vtu' in text and '12 negatively oriented elements' in text
    assert '[0, 4, 8, 12, 16, 20, 24, 28, 32, 36, ...] (12 in all, first 10 shown)' in text
    assert loaded.flipped_elements.tolist() == mirrored.tolist()
    clean = tmp_path / 'clean.vtu'
    save_mesh(reference, clean)
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter('always')
        load_mesh(clean)
    assert not [w for w in record if issubclass(w.category, MeshOrientationWarning)]


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
