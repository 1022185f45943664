"""Mesh files through meshio: load_mesh reads any tetrahedral mesh meshio reads, with its region
tags; save_mesh writes a TetMesh with its tags named so that load_mesh reads them back."""
from pathlib import Path

import numpy as np

from tissue_sim_ros.engine.mesh.tetmesh import TetMesh, make_mesh
from tissue_sim_ros.errors import MeshError

__all__ = ['load_mesh', 'load_point_sets', 'save_mesh', 'ELEMENT_TAG_NAMES']

#: Cell-data names read as element (region) tags by :func:`load_mesh`, first found wins.
ELEMENT_TAG_NAMES = ('gmsh:physical', 'medit:ref', 'tag', 'region')


def _format_family(path: Path, file_format: str | None) -> str:
    """'gmsh', 'medit' or 'other' (the cell-data name used for the tags depends on it)."""
    if file_format is not None:
        if file_format.startswith('gmsh'):
            return 'gmsh'
        return 'medit' if file_format == 'medit' else 'other'
    suffix = path.suffix.lower()
    if suffix == '.msh':
        return 'gmsh'
    if suffix in ('.mesh', '.meshb'):
        return 'medit'
    return 'other'


def _python_scalars(values: np.ndarray) -> np.ndarray:
    """The same array as dtype=object holding Python ints/floats (see save_mesh)."""
    return np.array(np.asarray(values).tolist(), dtype=object)


def _rows_per_item(data, field: str, n_rows: int, item: str) -> dict:
    """{name: array} of ``data`` (None: empty), each array with one row per ``item``."""
    arrays = {}
    for name, values in (data or {}).items():
        values = np.asarray(values)
        if values.ndim < 1 or values.shape[0] != n_rows:
            raise MeshError(f'{field}[{name!r}]: shape {values.shape}, expected first '
                            f'dimension {n_rows} (one row per {item})')
        arrays[name] = values
    return arrays


def load_mesh(path) -> TetMesh:
    """Read a tetrahedral mesh from any file meshio reads (.vtu, .vtk, .msh, .mesh, ...).

    Only 'tetra' cells are used (all such blocks, in file order); other cell types are ignored.
    Element tags come from the first cell data found among ELEMENT_TAG_NAMES, else zeros.
    Nodes used by no tetrahedron are kept, not renumbered. Inverted elements are repaired
    (make_mesh) with one MeshOrientationWarning naming the file; a file without tetrahedra or
    with an invalid mesh raises MeshError naming it.
    """
    import meshio

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f'mesh file {str(path)!r} does not exist')
    try:
        source = meshio.read(path)
    except OSError:
        raise
    except (Exception, SystemExit) as exc:  # meshio 5.3.5 calls sys.exit(1) on a parse failure
        raise MeshError(f'{path}: meshio could not read it as a mesh ({type(exc).__name__}: '
                        f'{exc}); expected a file in a format meshio reads, e.g. .vtu, .vtk, '
                        '.msh, .mesh') from exc
    blocks = [b for b, block in enumerate(source.cells) if block.type == 'tetra']
    if not blocks:
        found = sorted({block.type for block in source.cells})
        raise MeshError(f'{path}: no tetra cells; expected a tetrahedral mesh, found cell types '
                        f'{found}')
    points = np.asarray(source.points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f'{path}: points have shape {points.shape}, expected (n, 3) (3-D nodes)')
    tetrahedra = np.concatenate([np.asarray(source.cells[b].data) for b in blocks])
    tags = None
    for name in ELEMENT_TAG_NAMES:
        if name in source.cell_data and len(source.cell_data[name]) == len(source.cells):
            tags = np.concatenate([np.asarray(source.cell_data[name][b]).reshape(-1)
                                   for b in blocks])
            break
    try:
        return make_mesh(points, tetrahedra, tags, source=f'{path}: tetrahedra')
    except MeshError as exc:
        raise MeshError(f'{path}: {exc}') from exc


def load_point_sets(path) -> dict:
    """{name: (n,) or (n, k) values} of a mesh file's point data (node sets: non-zero marks a
    node), meshio's own ``gmsh:`` entries left out."""
    import meshio

    try:
        source = meshio.read(Path(path))
    except Exception as exc:       # meshio raises ReadError and others on unknown content
        raise MeshError(f'{path}: meshio cannot read it ({exc})') from exc
    return {name: np.asarray(values) for name, values in source.point_data.items() if not name.startswith('gmsh:')}


def save_mesh(mesh: TetMesh, path, *, point_data=None, cell_data=None,
              file_format: str | None = None, binary: bool = True) -> None:
    """Write ``mesh`` with meshio, always with its element tags as cell data named so that
    :func:`load_mesh` reads them back: 'gmsh:physical' (+ 'gmsh:geometrical') for Gmsh,
    'medit:ref' for Medit, 'tag' otherwise.

    ``point_data``: {name: (n, ...) array}; ``cell_data``: {name: (m, ...) array}, one row per
    element. ``file_format`` is a meshio format name (default from the suffix: .msh is Gmsh 4.1,
    'gmsh22' asks for Gmsh 2.2); ``binary`` applies to Gmsh, VTU and VTK (Medit: .mesh is ASCII,
    .meshb binary).

    Gmsh 4.1 stores physical tags per entity, not per element: when the tags differ, they are
    written as ElementData 'tag' (one block, element order kept), which load_mesh reads back.
    """
    import meshio

    if not isinstance(mesh, TetMesh):
        raise MeshError(f'mesh: {type(mesh).__name__}, expected a TetMesh')
    path = Path(path)
    if file_format is None and path.suffix.lower() == '.msh':
        file_format = 'gmsh'
    family = _format_family(path, file_format)
    tags = mesh.element_tags

    cells = _rows_per_item(cell_data, 'cell_data', mesh.n_elements, 'element')
    for name in cells:
        if name in ELEMENT_TAG_NAMES or name.startswith('gmsh:'):
            raise MeshError(f'cell_data[{name!r}]: the name is reserved for the element tags; '
                            'expected another name (the tags are written from mesh.element_tags)')
    cells_out = {name: [values] for name, values in cells.items()}
    points_out = _rows_per_item(point_data, 'point_data', mesh.n_nodes, 'node')

    if family == 'gmsh' and file_format == 'gmsh22':
        # per-element tags: physical = region, elementary entity = region
        cells_out['gmsh:physical'] = [tags]
        cells_out['gmsh:geometrical'] = [tags]
    elif family == 'gmsh':  # 4.1: tags belong to entities; all elements in entity (3, 1)
        cells_out['gmsh:geometrical'] = [np.ones(mesh.n_elements, dtype=np.int32)]
        uniform = bool((tags == tags[0]).all())
        if uniform and tags[0] != 0:  # entity 1 carries the one physical tag
            cells_out['gmsh:physical'] = [tags]
            points_out['gmsh:dim_tags'] = np.tile(np.array([[3, 1]]), (mesh.n_nodes, 1))
        elif not uniform:  # per-element tags as ElementData
            cells_out['tag'] = [tags]
    elif family == 'medit':
        cells_out['medit:ref'] = [tags]
    else:
        cells_out['tag'] = [tags]

    if family == 'gmsh' and not binary:
        # meshio 5.3.5 writes ASCII Gmsh NodeData/ElementData values with repr(), which under
        # numpy 2 gives 'np.int32(1)' and an unreadable file; Python scalars repr cleanly.
        points_out = {name: _python_scalars(values) if not name.startswith('gmsh:') else values
                      for name, values in points_out.items()}
        cells_out = {name: [_python_scalars(values[0])] if not name.startswith('gmsh:')
                     else values for name, values in cells_out.items()}

    out = meshio.Mesh(np.asarray(mesh.rest_positions), [('tetra', np.asarray(mesh.tetrahedra))],
                      point_data=points_out, cell_data=cells_out)
    options = {}
    resolved = file_format
    if resolved is None:
        resolved = {'.vtu': 'vtu', '.vtk': 'vtk'}.get(path.suffix.lower())
    if resolved in ('gmsh', 'gmsh22', 'vtu', 'vtk'):
        options['binary'] = binary
    try:
        meshio.write(path, out, file_format=file_format, **options)
    except (meshio.ReadError, meshio.WriteError) as exc:  # unknown suffix or format name
        raise MeshError(f'{path}: meshio cannot write it ({exc}); expected a suffix such as '
                        ".vtu, .vtk, .msh, .mesh or a meshio file_format such as 'gmsh22'") from exc
