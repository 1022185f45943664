"""Tetrahedral meshes: the validated :class:`TetMesh`, its quality measures and its faces.

Generators (box_mesh, graded_box_mesh) are in :mod:`.generators`, meshio files
(load_mesh, save_mesh) in :mod:`.files`. Every array is SI (metres) and every function is
vectorised with numpy: no Python loop runs over elements, so meshes of 5e5 tetrahedra build and
validate in a fraction of a second.

Conventions (docs/engine.md, "TetMesh"):

- positions ``(n, 3)`` float64; tetrahedra ``(m, 4)`` int64 node indices, positively oriented,
  i.e. ``det([p1 - p0, p2 - p0, p3 - p0]) > 0``;
- a degenerate element, ``|V| <= 1e-12 * (longest edge)**3``, is refused with its index;
- an inverted element is repaired on construction by swapping its vertices 2 and 3, its
  index is kept in :attr:`TetMesh.flipped_elements`, and a :class:`MeshOrientationWarning`
  says so once per mesh (count and first ids), so a mesh file written with the other
  orientation convention does not go unnoticed.
"""
from __future__ import annotations

import functools
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from tissue_sim_ros.errors import MeshError

__all__ = [
    'MeshOrientationWarning',
    'TetMesh',
    'make_mesh',
    'signed_volumes',
    'mean_ratio',
    'surface_triangles',
    'face_elements',
    'DEGENERATE_VOLUME_TOLERANCE',
]

#: An element with ``|V| <= DEGENERATE_VOLUME_TOLERANCE * (longest edge)**3`` is degenerate.
#: (A regular tetrahedron has V = L**3 / (6 sqrt 2) ~ 0.118 L**3.)
DEGENERATE_VOLUME_TOLERANCE = 1e-12

_MAX_LISTED = 10  # how many offending indices an error message lists

# A warning from make_mesh is the caller's, not the mesh package's.
_MESH_MODULES = (str(Path(__file__).parent) + os.sep,)

# Local vertex numbers of the four faces of a tetrahedron (a, b, c, d), face k being the one
# opposite vertex k; _OPPOSITE_VERTEX[k] == k.
_FACE_VERTICES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)
_OPPOSITE_VERTEX = np.array([0, 1, 2, 3], dtype=np.int64)
# The six edges of a tetrahedron as pairs of local vertex numbers.
_EDGE_VERTICES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


class MeshOrientationWarning(UserWarning):
    """Negatively oriented tetrahedra were re-oriented (vertices 2 and 3 swapped) on construction."""


# --------------------------------------------------------------------------------------------
# small helpers
# --------------------------------------------------------------------------------------------

def _list_indices(indices: np.ndarray) -> str:
    """'[3, 17, 42]', or the first 10 then '..., (1234 in all, first 10 shown)', for messages."""
    indices = np.asarray(indices).ravel()
    shown = ', '.join(str(int(i)) for i in indices[:_MAX_LISTED])
    if indices.size > _MAX_LISTED:
        return f'[{shown}, ...] ({indices.size} in all, first {_MAX_LISTED} shown)'
    return f'[{shown}]'


def _readonly(array: np.ndarray) -> np.ndarray:
    array.flags.writeable = False
    return array


def _as_positions(value, field: str, n_expected: int | None = None) -> np.ndarray:
    """A float64 (n, 3) C-contiguous copy of ``value``; refuses other shapes and NaN/inf."""
    try:
        positions = np.array(value, dtype=np.float64, order='C', copy=True)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: could not be read as a float array ({exc}); '
                        'expected an (n, 3) array of coordinates in metres') from exc
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise MeshError(f'{field}: shape {positions.shape}, expected (n, 3)')
    if n_expected is not None and positions.shape[0] != n_expected:
        raise MeshError(f'{field}: shape {positions.shape}, expected ({n_expected}, 3) '
                        '(one row per mesh node)')
    bad_rows = np.flatnonzero(~np.isfinite(positions).all(axis=1))
    if bad_rows.size:
        raise MeshError(f'{field}: non-finite coordinates (NaN or inf) at nodes '
                        f'{_list_indices(bad_rows)}; expected finite values')
    return positions


def _as_tetrahedra(value, n_nodes: int, field: str = 'tetrahedra') -> np.ndarray:
    """An int64 (m, 4) C-contiguous copy of ``value`` with every index in [0, n_nodes)."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: could not be read as an array ({exc}); '
                        'expected an (m, 4) integer array of node indices') from exc
    if raw.ndim != 2 or raw.shape[1] != 4:
        raise MeshError(f'{field}: shape {raw.shape}, expected (m, 4)')
    if raw.shape[0] == 0:
        raise MeshError(f'{field}: shape {raw.shape}, expected at least one tetrahedron')
    if raw.dtype.kind not in 'iu':
        raise MeshError(f'{field}: dtype {raw.dtype}, expected an integer array of node indices')
    out_of_range = (raw < 0) | (raw >= n_nodes)
    bad = np.flatnonzero(out_of_range.any(axis=1))
    if bad.size:
        values = np.unique(raw[out_of_range])
        raise MeshError(f'{field}: node indices out of range {_list_indices(values)} in elements '
                        f'{_list_indices(bad)}; expected 0 <= index < {n_nodes} (the node count)')
    return np.array(raw, dtype=np.int64, order='C', copy=True)


def _as_element_tags(value, n_elements: int) -> np.ndarray:
    if value is None:
        return np.zeros(n_elements, dtype=np.int32)
    raw = np.asarray(value)
    if raw.shape != (n_elements,):
        raise MeshError(f'element_tags: shape {raw.shape}, expected ({n_elements},) '
                        '(one tag per tetrahedron)')
    if raw.dtype.kind == 'f':  # some formats store integer tags as floats
        integral = np.isfinite(raw) & (raw == np.round(raw))
        if not integral.all():
            bad = np.flatnonzero(~integral)
            raise MeshError(f'element_tags: non-integer values {raw[bad[:_MAX_LISTED]].tolist()} '
                            f'at elements {_list_indices(bad)}; expected integer region tags')
    elif raw.dtype.kind not in 'iub':
        raise MeshError(f'element_tags: dtype {raw.dtype}, expected integer region tags')
    info = np.iinfo(np.int32)
    outside = (raw < info.min) | (raw > info.max)
    if outside.any():
        bad = np.flatnonzero(outside)
        raise MeshError(f'element_tags: values {raw[bad[:_MAX_LISTED]].tolist()} at elements '
                        f'{_list_indices(bad)} do not fit in int32; expected |tag| < 2**31')
    return raw.astype(np.int32, order='C', copy=True)


def _check_positions_tetrahedra(positions, tetrahedra) -> tuple[np.ndarray, np.ndarray]:
    """Light validation for the public geometry functions (shape and index range)."""
    positions = np.asarray(positions, dtype=np.float64)
    if positions.ndim != 2 or positions.shape[1] != 3:
        raise MeshError(f'positions: shape {positions.shape}, expected (n, 3)')
    tetrahedra = np.asarray(tetrahedra)
    if tetrahedra.ndim != 2 or tetrahedra.shape[1] != 4 or tetrahedra.dtype.kind not in 'iu':
        raise MeshError(f'tetrahedra: shape {tetrahedra.shape} dtype {tetrahedra.dtype}, '
                        'expected an (m, 4) integer array')
    if tetrahedra.size and (tetrahedra.min() < 0 or tetrahedra.max() >= positions.shape[0]):
        raise MeshError(f'tetrahedra: node indices span [{tetrahedra.min()}, {tetrahedra.max()}], '
                        f'expected 0 <= index < {positions.shape[0]} (rows of positions)')
    return positions, tetrahedra


# --------------------------------------------------------------------------------------------
# geometry of tetrahedra
# --------------------------------------------------------------------------------------------

def _corners(positions: np.ndarray, tetrahedra: np.ndarray) -> np.ndarray:
    """(m, 4, 3) vertex positions of every element (one gather, reused below)."""
    return positions[tetrahedra]


def _triple_products(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Row-wise a . (b x c) = det([a, b, c])."""
    return (a[:, 0] * (b[:, 1] * c[:, 2] - b[:, 2] * c[:, 1])
            + a[:, 1] * (b[:, 2] * c[:, 0] - b[:, 0] * c[:, 2])
            + a[:, 2] * (b[:, 0] * c[:, 1] - b[:, 1] * c[:, 0]))


def _corner_volumes(corners: np.ndarray) -> np.ndarray:
    """(m,) signed volumes det([p1 - p0, p2 - p0, p3 - p0]) / 6 from (m, 4, 3) corners."""
    edges = corners[:, 1:] - corners[:, :1]
    return _triple_products(edges[:, 0], edges[:, 1], edges[:, 2]) / 6.0


def _corner_squared_edge_lengths(corners: np.ndarray) -> np.ndarray:
    """(m, 6) squared lengths of the six edges, in the order of _EDGE_VERTICES."""
    d = corners[:, _EDGE_VERTICES[:, 1]] - corners[:, _EDGE_VERTICES[:, 0]]
    return np.einsum('ijk,ijk->ij', d, d)


def _signed_volumes(positions: np.ndarray, tetrahedra: np.ndarray) -> np.ndarray:
    return _corner_volumes(_corners(positions, tetrahedra))


def _mean_ratio(positions: np.ndarray, tetrahedra: np.ndarray) -> np.ndarray:
    corners = _corners(positions, tetrahedra)
    volumes = np.abs(_corner_volumes(corners))
    edge_sum = _corner_squared_edge_lengths(corners).sum(axis=1)
    numerator = 12.0 * np.cbrt((3.0 * volumes) ** 2)
    return np.divide(numerator, edge_sum, out=np.zeros_like(numerator), where=edge_sum > 0)


def _face_areas(positions: np.ndarray, tetrahedra: np.ndarray) -> np.ndarray:
    """(m, 4) areas |(b - a) x (c - a)| / 2 of the faces, face k opposite vertex k."""
    corners = _corners(positions, tetrahedra)
    areas = np.empty((tetrahedra.shape[0], 4))
    for k, (a, b, c) in enumerate(_FACE_VERTICES):  # four faces, not a loop over elements
        u = corners[:, b] - corners[:, a]
        v = corners[:, c] - corners[:, a]
        normal_x = u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1]
        normal_y = u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2]
        normal_z = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        areas[:, k] = 0.5 * np.sqrt(normal_x ** 2 + normal_y ** 2 + normal_z ** 2)
    return areas


def signed_volumes(positions, tetrahedra) -> np.ndarray:
    """(m,) signed volumes V = det([p1 - p0, p2 - p0, p3 - p0]) / 6, positive for a positively
    oriented tetrahedron (p1 - p0, p2 - p0, p3 - p0 a right-handed triple)."""
    positions, tetrahedra = _check_positions_tetrahedra(positions, tetrahedra)
    return _signed_volumes(positions, tetrahedra)


def mean_ratio(positions, tetrahedra) -> np.ndarray:
    """(m,) Liu-Joe mean ratio eta = 12 (3 |V|)**(2/3) / sum_{i<j} l_ij**2 (Liu and Joe 1994).

    1 for a regular tetrahedron, invariant under rotation, translation and uniform scaling, and
    tending to 0 as the element degenerates. Uses |V|, so an inverted element is measured like
    its mirror image (test the sign with :func:`signed_volumes`). 0 when all vertices coincide.
    """
    positions, tetrahedra = _check_positions_tetrahedra(positions, tetrahedra)
    return _mean_ratio(positions, tetrahedra)


def _sorted_face_keys(faces_sorted: np.ndarray, n_nodes: int) -> np.ndarray | None:
    """One int64 key (a n + b) n + c per sorted face triple (a, b, c), or None when n**3 does
    not fit an int64 (more than ~1.6e6 nodes; the caller then sorts the rows instead)."""
    if n_nodes ** 3 < 2 ** 62:
        n = np.int64(n_nodes)
        return (faces_sorted[:, 0] * n + faces_sorted[:, 1]) * n + faces_sorted[:, 2]
    return None


def _face_rows(faces_sorted: np.ndarray) -> np.ndarray:
    """(f,) one structured (a, b, c) record per sorted face row: compares lexicographically, so
    it sorts and searches where the int64 key of :func:`_sorted_face_keys` would overflow."""
    rows = np.ascontiguousarray(faces_sorted, dtype=np.int64)
    return rows.view(np.dtype([('a', np.int64), ('b', np.int64), ('c', np.int64)])).reshape(-1)


def face_elements(tetrahedra, triangles, n_nodes: int | None = None) -> np.ndarray:
    """(k,) int64 index of the element of which each triangle (k, 3) is a face, matched by vertex
    set (the lowest-numbered such element where faces are shared).

    ``n_nodes``: the node count (default: the largest index + 1). Raises MeshError naming the
    triangles that are no element's face.
    """
    tetrahedra = np.asarray(tetrahedra).astype(np.int64, copy=False)
    wanted = np.sort(np.asarray(triangles).astype(np.int64, copy=False).reshape(-1, 3), axis=1)
    faces = np.sort(tetrahedra[:, _FACE_VERTICES], axis=2).reshape(-1, 3)  # face 4 e + k
    if n_nodes is None:
        n_nodes = int(max(tetrahedra.max(initial=-1), wanted.max(initial=-1))) + 1
    keys = _sorted_face_keys(faces, n_nodes)
    if keys is not None:
        wanted_keys = _sorted_face_keys(wanted, n_nodes)
    else:  # very large node counts: compare the rows lexicographically
        keys, wanted_keys = _face_rows(faces), _face_rows(wanted)
    order = np.argsort(keys, kind='stable')
    at = np.minimum(np.searchsorted(keys[order], wanted_keys), max(len(order) - 1, 0))
    found = order[at]
    missing = np.flatnonzero(keys[found] != wanted_keys)
    if missing.size:
        raise MeshError(f'triangles: rows {_list_indices(missing)} (first: '
                        f'{np.asarray(triangles).reshape(-1, 3)[missing[0]].tolist()}) are no face of '
                        'any tetrahedron; expected faces of the mesh')
    return found // 4


def element_neighbours(tetrahedra, n_nodes: int | None = None) -> np.ndarray:
    """(m, 4) int64: across face k of element e (the face opposite its vertex k), the element
    that shares it, or -1 on the boundary. For walking from element to element (point location)."""
    tetrahedra = np.asarray(tetrahedra).astype(np.int64, copy=False)
    m = len(tetrahedra)
    faces = np.sort(tetrahedra[:, _FACE_VERTICES], axis=2).reshape(-1, 3)   # face 4 e + k
    if n_nodes is None:
        n_nodes = int(tetrahedra.max(initial=-1)) + 1
    keys = _sorted_face_keys(faces, n_nodes)
    if keys is None:
        keys = _face_rows(faces)
    order = np.argsort(keys, kind='stable')
    same = keys[order[1:]] == keys[order[:-1]]          # an interior face: two consecutive rows
    first, second = order[:-1][same], order[1:][same]
    neighbours = np.full(4 * m, -1, dtype=np.int64)
    neighbours[first] = second // 4
    neighbours[second] = first // 4
    return neighbours.reshape(m, 4)


def _faces_seen_once(faces: np.ndarray, n_nodes: int) -> np.ndarray:
    """Indices (ascending) of the rows of ``faces`` (f, 3) whose vertex set occurs exactly once."""
    faces_sorted = np.sort(faces, axis=1)
    keys = _sorted_face_keys(faces_sorted, n_nodes)
    if keys is not None:
        order = np.argsort(keys, kind='stable')
        same_as_next = keys[order[1:]] == keys[order[:-1]]
    else:  # very large node counts: lexicographic sort of the three columns
        order = np.lexsort((faces_sorted[:, 2], faces_sorted[:, 1], faces_sorted[:, 0]))
        ordered = faces_sorted[order]
        same_as_next = (ordered[1:] == ordered[:-1]).all(axis=1)
    repeated = np.zeros(faces.shape[0], dtype=bool)
    repeated[:-1] |= same_as_next
    repeated[1:] |= same_as_next
    return np.sort(order[~repeated])


def surface_triangles(tetrahedra, positions) -> np.ndarray:
    """(k, 3) int64 boundary faces: the faces that belong to exactly one tetrahedron, oriented so
    that the normal (p1 - p0) x (p2 - p0) points away from that tetrahedron's fourth vertex
    (outward for a valid mesh). Ordered by element, then by local face number.

    A face shared by three or more elements (a non-manifold mesh) is not a boundary face.
    """
    positions, tetrahedra = _check_positions_tetrahedra(positions, tetrahedra)
    tetrahedra = tetrahedra.astype(np.int64, copy=False)
    m = tetrahedra.shape[0]
    # faces[4 e + k] is the face of element e opposite its local vertex k
    faces = tetrahedra[:, _FACE_VERTICES].reshape(4 * m, 3)
    boundary = _faces_seen_once(faces, positions.shape[0])
    triangles = faces[boundary].copy()
    opposite = tetrahedra[boundary // 4, _OPPOSITE_VERTEX[boundary % 4]]
    p0 = positions[triangles[:, 0]]
    towards_opposite = _triple_products(positions[opposite] - p0,
                                        positions[triangles[:, 1]] - p0,
                                        positions[triangles[:, 2]] - p0) > 0
    triangles[towards_opposite, 1:] = triangles[towards_opposite, 2:0:-1]
    return triangles


# --------------------------------------------------------------------------------------------
# the mesh
# --------------------------------------------------------------------------------------------

@dataclass(frozen=True, eq=False, repr=False)
class TetMesh:
    """A validated tetrahedral mesh at rest. Build it with :func:`make_mesh` (or a generator or
    :func:`load_mesh`), which checks and orients the elements; the constructor itself only
    normalises dtypes and shapes. All arrays are read-only; derived quantities are cached.

    Attributes:
        rest_positions: (n, 3) float64 node positions at rest, metres.
        tetrahedra: (m, 4) int64 node indices, positively oriented (signed volume > 0).
        element_tags: (m,) int32 region tags (0 when the source has none).
        flipped_elements: (k,) int64 indices of the elements whose vertices 2 and 3 were swapped
            on construction because they were negatively oriented.
    """

    rest_positions: np.ndarray
    tetrahedra: np.ndarray
    element_tags: np.ndarray
    flipped_elements: np.ndarray

    def __post_init__(self):
        positions = np.array(self.rest_positions, dtype=np.float64, order='C', copy=True)
        if positions.ndim != 2 or positions.shape[1] != 3:
            raise MeshError(f'rest_positions: shape {positions.shape}, expected (n, 3)')
        tetrahedra = np.array(self.tetrahedra, dtype=np.int64, order='C', copy=True)
        if tetrahedra.ndim != 2 or tetrahedra.shape[1] != 4:
            raise MeshError(f'tetrahedra: shape {tetrahedra.shape}, expected (m, 4)')
        tags = np.array(self.element_tags, dtype=np.int32, order='C', copy=True)
        if tags.shape != (tetrahedra.shape[0],):
            raise MeshError(f'element_tags: shape {tags.shape}, '
                            f'expected ({tetrahedra.shape[0]},)')
        flipped = np.array(self.flipped_elements, dtype=np.int64, order='C', copy=True).ravel()
        object.__setattr__(self, 'rest_positions', _readonly(positions))
        object.__setattr__(self, 'tetrahedra', _readonly(tetrahedra))
        object.__setattr__(self, 'element_tags', _readonly(tags))
        object.__setattr__(self, 'flipped_elements', _readonly(flipped))

    def __repr__(self) -> str:
        regions = np.unique(self.element_tags).tolist()
        return (f'TetMesh(n_nodes={self.n_nodes}, n_elements={self.n_elements}, '
                f'regions={regions[:_MAX_LISTED]}, flipped={self.flipped_elements.size})')

    @property
    def n_nodes(self) -> int:
        return int(self.rest_positions.shape[0])

    @property
    def n_elements(self) -> int:
        return int(self.tetrahedra.shape[0])

    # cached_property writes into the instance __dict__ directly, which a frozen dataclass
    # allows; each cached array is read-only so that callers cannot corrupt the cache.
    @functools.cached_property
    def _volumes(self) -> np.ndarray:
        return _readonly(_signed_volumes(self.rest_positions, self.tetrahedra))

    @functools.cached_property
    def _surface_triangles(self) -> np.ndarray:
        return _readonly(surface_triangles(self.tetrahedra, self.rest_positions))

    @functools.cached_property
    def _surface_nodes(self) -> np.ndarray:
        return _readonly(np.unique(self._surface_triangles))

    @functools.cached_property
    def _rest_mean_ratio(self) -> np.ndarray:
        return _readonly(_mean_ratio(self.rest_positions, self.tetrahedra))

    @functools.cached_property
    def _edges(self) -> np.ndarray:
        pairs = np.sort(self.tetrahedra[:, _EDGE_VERTICES].reshape(-1, 2), axis=1)
        n = np.int64(self.n_nodes)
        keys = pairs[:, 0] * n + pairs[:, 1]  # n**2 fits int64 up to n ~ 3e9
        keys.sort()
        keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])]
        return _readonly(np.stack([keys // n, keys % n], axis=1))

    @functools.cached_property
    def _characteristic_lengths(self) -> np.ndarray:
        largest_face = _face_areas(self.rest_positions, self.tetrahedra).max(axis=1)
        return _readonly(3.0 * self._volumes / largest_face)

    def volumes(self) -> np.ndarray:
        """(m,) rest volumes, m**3 (all positive)."""
        return self._volumes

    def surface_triangles(self) -> np.ndarray:
        """(k, 3) int64 boundary triangles, outward oriented; see :func:`surface_triangles`."""
        return self._surface_triangles

    def surface_nodes(self) -> np.ndarray:
        """Sorted unique indices of the nodes on the boundary surface."""
        return self._surface_nodes

    def mean_ratio(self, positions=None) -> np.ndarray:
        """(m,) Liu-Joe mean ratio of each element at rest (``positions`` None) or at the given
        (n, 3) deformed positions; see :func:`mean_ratio`."""
        if positions is None:
            return self._rest_mean_ratio
        positions = _as_positions(positions, 'positions', self.n_nodes)
        return _mean_ratio(positions, self.tetrahedra)

    def edges(self) -> np.ndarray:
        """(E, 2) int64 unique undirected edges, each row (i, j) with i < j, rows sorted."""
        return self._edges

    def characteristic_lengths(self) -> np.ndarray:
        """(m,) smallest height of each element, h = 3 V / (largest face area), metres; the
        length in the explicit stability bound dt < h / sqrt((lambda + 2 mu) / rho)."""
        return self._characteristic_lengths


def make_mesh(rest_positions, tetrahedra, element_tags=None, *,
              fix_orientation: bool = True, source: str = 'tetrahedra') -> TetMesh:
    """Validate and orient a tetrahedral mesh.

    Refuses (MeshError): positions not (n, 3) or not finite; tetrahedra not (m, 4) integers,
    indices outside [0, n), a node repeated within an element; degenerate elements with
    |V| <= 1e-12 * (longest edge)**3; tags not (m,) integers. Negatively oriented elements are
    repaired by swapping their vertices 2 and 3 (indices recorded in ``flipped_elements``, and
    a MeshOrientationWarning with their count and first ids, prefixed by ``source``: load_mesh
    names the file), or refused when ``fix_orientation`` is False. Nodes used by no element are
    kept. The warning is attributed to the first caller outside the mesh modules.
    """
    positions = _as_positions(rest_positions, 'rest_positions')
    tets = _as_tetrahedra(tetrahedra, positions.shape[0])
    tags = _as_element_tags(element_tags, tets.shape[0])

    sorted_rows = np.sort(tets, axis=1)
    repeated = np.flatnonzero((sorted_rows[:, 1:] == sorted_rows[:, :-1]).any(axis=1))
    if repeated.size:
        raise MeshError(f'tetrahedra: elements {_list_indices(repeated)} repeat a node '
                        f'(first: {tets[repeated[0]].tolist()}); expected 4 distinct nodes each')

    corners = _corners(positions, tets)
    volumes = _corner_volumes(corners)
    longest_edge_cubed = _corner_squared_edge_lengths(corners).max(axis=1) ** 1.5
    degenerate = np.flatnonzero(np.abs(volumes) <= DEGENERATE_VOLUME_TOLERANCE * longest_edge_cubed)
    if degenerate.size:
        raise MeshError(
            f'tetrahedra: degenerate (flat) elements {_list_indices(degenerate)}, first volume '
            f'{volumes[degenerate[0]]:.3e} m^3; expected |V| > {DEGENERATE_VOLUME_TOLERANCE:g} '
            '* (longest edge)^3')

    inverted = np.flatnonzero(volumes < 0)
    if inverted.size:
        if not fix_orientation:
            raise MeshError(f'tetrahedra: negatively oriented elements {_list_indices(inverted)}; '
                            'expected det([p1-p0, p2-p0, p3-p0]) > 0 '
                            '(or call with fix_orientation=True to swap vertices 2 and 3)')
        tets[inverted, 2:4] = tets[inverted][:, [3, 2]]
        warnings.warn(f'{source}: {inverted.size} negatively oriented elements re-oriented (vertices 2 '
                      f'and 3 swapped): {_list_indices(inverted)}; check the orientation convention '
                      'of the mesh source', MeshOrientationWarning,
                      skip_file_prefixes=_MESH_MODULES)
    return TetMesh(positions, tets, tags, inverted.astype(np.int64))
