"""Tests of tissue_sim_ros.engine.mesh.files: meshes round-tripped through every format meshio
writes (positions, elements and region tags back unchanged), data written beside them, each bad
file or argument refused with a MeshError naming it, and the one warning that says which
elements of a file were re-oriented. Truth: the mesh written (built here), volumes from
signed_volumes, and files written by meshio directly."""

import warnings

import meshio
import numpy as np
import pytest

from support.meshes import UNIT_CORNER
from tissue_sim_ros.engine.mesh.files import load_mesh, save_mesh
from tissue_sim_ros.engine.mesh.generators import box_mesh
from tissue_sim_ros.engine.mesh.tetmesh import MeshOrientationWarning, make_mesh, signed_volumes
from tissue_sim_ros.errors import MeshError


def tagged_box(uniform_tag=None):
    base = box_mesh((0.03, 0.02, 0.01), (3, 2, 2), origin=(0.1234567891, -0.2, 1 / 3))
    centroids = base.rest_positions[base.tetrahedra].mean(axis=1)
    tags = np.where(centroids[:, 0] < 0.14, 7, 3) if uniform_tag is None else uniform_tag
    return make_mesh(base.rest_positions, base.tetrahedra,
                     np.broadcast_to(tags, (base.n_elements,)))


@pytest.mark.parametrize('suffix, file_format, binary', [
    ('.vtu', None, True), ('.vtu', None, False),
    ('.vtk', None, True), ('.vtk', None, False),
    ('.msh', None, True), ('.msh', None, False),  # Gmsh 4.1
    ('.msh', 'gmsh22', True), ('.msh', 'gmsh22', False),
    ('.mesh', None, True), ('.meshb', None, True),  # Medit ASCII and binary
])
@pytest.mark.parametrize('uniform_tag', [None, 5, 0])
def test_round_trip_through_files(tmp_path, suffix, file_format, binary, uniform_tag):
    mesh = tagged_box(uniform_tag)
    path = tmp_path / f'tissue{suffix}'
    with warnings.catch_warnings():
        warnings.simplefilter('ignore')  # meshio warns that ASCII VTK is for debugging
        save_mesh(mesh, path, file_format=file_format, binary=binary)
    loaded = load_mesh(path)
    np.testing.assert_allclose(loaded.rest_positions, mesh.rest_positions, rtol=1e-12, atol=0)
    np.testing.assert_array_equal(loaded.tetrahedra, mesh.tetrahedra)
    np.testing.assert_array_equal(loaded.element_tags, mesh.element_tags)
    assert loaded.flipped_elements.size == 0


def test_gmsh41_with_one_region_writes_a_physical_group(tmp_path):
    path = tmp_path / 'one_region.msh'
    save_mesh(tagged_box(uniform_tag=4), path)
    assert (meshio.read(path).cell_data['gmsh:physical'][0] == 4).all()


@pytest.mark.parametrize('suffix', ['.vtu', '.msh'])
def test_save_mesh_writes_point_and_cell_data(tmp_path, suffix):
    mesh = tagged_box()
    path = tmp_path / f'data{suffix}'
    displacement = np.linspace(0, 1, 3 * mesh.n_nodes).reshape(-1, 3)
    save_mesh(mesh, path, point_data={'displacement': displacement},
              cell_data={'mean_ratio': mesh.mean_ratio()})
    written = meshio.read(path)
    np.testing.assert_allclose(written.point_data['displacement'], displacement, rtol=1e-15)
    np.testing.assert_allclose(written.cell_data['mean_ratio'][0], mesh.mean_ratio(), rtol=1e-15)


def test_save_mesh_refuses_data_of_the_wrong_length(tmp_path):
    mesh = tagged_box()
    with pytest.raises(MeshError, match=r"cell_data\['pressure'\]"):
        save_mesh(mesh, tmp_path / 'bad.vtu', cell_data={'pressure': np.zeros(mesh.n_nodes)})
    with pytest.raises(MeshError, match=r"point_data\['u'\]"):
        save_mesh(mesh, tmp_path / 'bad.vtu', point_data={'u': np.zeros(mesh.n_elements)})


def test_load_mesh_repairs_an_inverted_element(tmp_path):
    tets = np.array([[0, 1, 2, 3], [1, 4, 3, 2]])
    points = np.vstack([UNIT_CORNER, [[1.0, 1.0, 0.0]]])
    assert signed_volumes(points, tets).tolist() == pytest.approx([1 / 6, -1 / 6])
    path = tmp_path / 'inverted.vtu'
    meshio.write(path, meshio.Mesh(points, [('tetra', tets)]))
    with pytest.warns(MeshOrientationWarning, match=r'inverted\.vtu: tetrahedra: 1 negatively .* \[1\]'):
        loaded = load_mesh(path)
    assert loaded.flipped_elements.tolist() == [1]
    assert loaded.tetrahedra.tolist() == [[0, 1, 2, 3], [1, 4, 2, 3]]
    np.testing.assert_allclose(loaded.volumes(), [1 / 6, 1 / 6], rtol=1e-15)
    assert loaded.element_tags.tolist() == [0, 0]


def test_load_mesh_ignores_other_cells_and_reads_region_tags(tmp_path):
    points = np.vstack([UNIT_CORNER, [[1.0, 1.0, 0.0]]])
    path = tmp_path / 'mixed.vtu'
    meshio.write(path, meshio.Mesh(
        points,
        [('tetra', np.array([[0, 1, 2, 3]])), ('triangle', np.array([[0, 2, 1]])),
         ('tetra', np.array([[1, 4, 2, 3]]))],
        cell_data={'region': [np.array([11]), np.array([0]), np.array([12])]}))
    loaded = load_mesh(path)
    assert loaded.tetrahedra.tolist() == [[0, 1, 2, 3], [1, 4, 2, 3]]
    assert loaded.flipped_elements.size == 0
    assert loaded.element_tags.tolist() == [11, 12]


def test_load_mesh_refuses_a_file_without_tetrahedra(tmp_path):
    path = tmp_path / 'surface_only.vtu'
    meshio.write(path, meshio.Mesh(UNIT_CORNER, [('triangle', np.array([[0, 1, 2], [0, 1, 3]]))]))
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    assert 'surface_only.vtu' in str(info.value) and 'triangle' in str(info.value)


def test_load_mesh_names_the_file_of_an_invalid_mesh(tmp_path):
    points = np.vstack([UNIT_CORNER, [[1.0, 1.0, 0.0]]])
    path = tmp_path / 'flat.vtu'
    meshio.write(path, meshio.Mesh(points, [('tetra', np.array([[0, 1, 2, 3], [0, 1, 2, 4]]))]))
    with pytest.raises(MeshError) as info:
        load_mesh(path)
    assert 'flat.vtu' in str(info.value) and '[1]' in str(info.value)


def test_load_mesh_of_a_corrupt_file_raises_mesh_error_naming_it(tmp_path):
    path = tmp_path / 'garbage.vtu'
    path.write_text('this is not XML')
    with pytest.raises(MeshError, match='garbage.vtu'):  # not meshio's sys.exit(1)
        load_mesh(path)


def test_save_mesh_refuses_an_unknown_suffix(tmp_path):
    with pytest.raises(MeshError, match='tissue.unknown'):
        save_mesh(tagged_box(), tmp_path / 'tissue.unknown')


def test_load_mesh_of_a_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match='nowhere.vtu'):
        load_mesh(tmp_path / 'nowhere.vtu')


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
