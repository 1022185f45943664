"""Tetrahedral meshes: the validated :class:`TetMesh`, generators, quality measures, meshio I/O.

Every array is SI (metres) and every function is vectorised with numpy: no Python loop runs
over elements, so meshes of 5e5 tetrahedra build and validate in a fraction of a second.

Conventions (DESIGN.md):

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
import math
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    'MeshError',
    'MeshOrientationWarning',
    'TetMesh',
    'make_mesh',
    'signed_volumes',
    'mean_ratio',
    'surface_triangles',
    'face_elements',
    'box_mesh',
    'graded_box_mesh',
    'load_mesh',
    'save_mesh',
    'DEGENERATE_VOLUME_TOLERANCE',
    'ELEMENT_TAG_NAMES',
]

#: An element with ``|V| <= DEGENERATE_VOLUME_TOLERANCE * (longest edge)**3`` is degenerate.
#: (A regular tetrahedron has V = L**3 / (6 sqrt 2) ~ 0.118 L**3.)
DEGENERATE_VOLUME_TOLERANCE = 1e-12

#: Cell-data names read as element (region) tags by :func:`load_mesh`, first found wins.
ELEMENT_TAG_NAMES = ('gmsh:physical', 'medit:ref', 'tag', 'region')

_MAX_LISTED = 10  # how many offending indices an error message lists

# Local vertex numbers of the four faces of a tetrahedron (a, b, c, d), face k being the one
# opposite vertex k; _OPPOSITE_VERTEX[k] == k.
_FACE_VERTICES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)
_OPPOSITE_VERTEX = np.array([0, 1, 2, 3], dtype=np.int64)
# The six edges of a tetrahedron as pairs of local vertex numbers.
_EDGE_VERTICES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]], dtype=np.int64)


class MeshError(ValueError):
    """A mesh or a mesh parameter is invalid; the message names the field, the offending values
    or element indices, and what was expected."""


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


def _as_float_triple(value, field: str, *, positive: bool) -> np.ndarray:
    try:
        triple = np.array(value, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: {value!r} is not numeric; expected 3 numbers') from exc
    if triple.shape != (3,):
        raise MeshError(f'{field}: {value!r} has {triple.size} values, expected 3')
    if not np.isfinite(triple).all():
        raise MeshError(f'{field}: {value!r} is not finite, expected finite numbers')
    if positive and (triple <= 0).any():
        raise MeshError(f'{field}: {value!r}, expected 3 positive lengths in metres')
    return triple


def _as_divisions(value, field: str = 'divisions') -> tuple[int, int, int]:
    raw = np.asarray(value)
    if raw.shape != (3,) or raw.dtype.kind not in 'iu' or (raw < 1).any():
        raise MeshError(f'{field}: {value!r}, expected 3 integers >= 1 (cells along x, y, z)')
    return int(raw[0]), int(raw[1]), int(raw[2])


def _as_positive_scalar(value, field: str, *, allow_zero: bool = False,
                        minimum: float | None = None) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError) as exc:
        raise MeshError(f'{field}: {value!r} is not a number') from exc
    if not math.isfinite(number):
        raise MeshError(f'{field}: {value!r}, expected a finite number')
    if minimum is not None:
        if number < minimum:
            raise MeshError(f'{field}: {value!r}, expected a number >= {minimum}')
    elif number < 0 or (number == 0 and not allow_zero):
        expected = 'a number >= 0' if allow_zero else 'a positive number'
        raise MeshError(f'{field}: {value!r}, expected {expected}')
    return number


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
              fix_orientation: bool = True) -> TetMesh:
    """Validate and orient a tetrahedral mesh.

    Refuses (MeshError): positions not (n, 3) or not finite; tetrahedra not (m, 4) integers,
    indices outside [0, n), a node repeated within an element; degenerate elements with
    |V| <= 1e-12 * (longest edge)**3; tags not (m,) integers. Negatively oriented elements are
    repaired by swapping their vertices 2 and 3 (indices recorded in ``flipped_elements``, and
    a MeshOrientationWarning with their count and first ids), or refused when
    ``fix_orientation`` is False. Nodes used by no element are kept.
    """
    return _build_mesh(rest_positions, tetrahedra, element_tags, fix_orientation, 'tetrahedra')


def _build_mesh(rest_positions, tetrahedra, element_tags, fix_orientation: bool, label: str) -> TetMesh:
    """make_mesh, its orientation warning prefixed by ``label`` (the file for load_mesh) and
    attributed to the caller of make_mesh or load_mesh."""
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
        warnings.warn(f'{label}: {inverted.size} negatively oriented elements re-oriented (vertices 2 '
                      f'and 3 swapped): {_list_indices(inverted)}; check the orientation convention '
                      'of the mesh source', MeshOrientationWarning, stacklevel=3)
    return TetMesh(positions, tets, tags, inverted.astype(np.int64))


# --------------------------------------------------------------------------------------------
# generators
# --------------------------------------------------------------------------------------------

def _kuhn_template() -> np.ndarray:
    """(6, 4, 3) local corners (0/1 per axis) of the Kuhn split of the unit cube: one element per
    permutation s of the axes, the path (0,0,0) -> e_s0 -> e_s0 + e_s1 -> (1,1,1), with vertices
    2 and 3 swapped for odd permutations so that every element is positively oriented."""
    permutations = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    template = np.zeros((6, 4, 3), dtype=np.int64)
    for t, perm in enumerate(permutations):  # 6 template elements, built once
        for step in range(1, 4):
            template[t, step] = template[t, step - 1]
            template[t, step, perm[step - 1]] = 1
        if np.linalg.det((template[t, 1:] - template[t, 0]).astype(float)) < 0:
            template[t, [2, 3]] = template[t, [3, 2]]
    return template


_KUHN_TEMPLATE = _kuhn_template()


def _kuhn_grid_mesh(x_nodes: np.ndarray, y_nodes: np.ndarray, z_nodes: np.ndarray) -> TetMesh:
    """The Kuhn-split tetrahedral mesh of the rectilinear grid with the given increasing node
    coordinates. Node (i, j, k) has index i + (nx+1) (j + (ny+1) k); hexahedron (i, j, k) has
    index i + nx (j + ny k) and owns elements 6 h .. 6 h + 5, so memory order follows space."""
    nx, ny, nz = x_nodes.size - 1, y_nodes.size - 1, z_nodes.size - 1
    px, pxy = nx + 1, (nx + 1) * (ny + 1)
    gx, gy, gz = np.meshgrid(x_nodes, y_nodes, z_nodes, indexing='ij')
    positions = np.stack([gx.ravel(order='F'), gy.ravel(order='F'), gz.ravel(order='F')], axis=1)

    i, j, k = np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing='ij')
    base = (i.ravel(order='F') + px * j.ravel(order='F') + pxy * k.ravel(order='F'))
    offsets = (_KUHN_TEMPLATE[..., 0] + px * _KUHN_TEMPLATE[..., 1]
               + pxy * _KUHN_TEMPLATE[..., 2])  # (6, 4)
    tetrahedra = (base[:, None, None] + offsets[None]).reshape(-1, 4)
    # Valid by construction; make_mesh re-checks (cheap) and would refuse an inverted element.
    return make_mesh(positions, tetrahedra, fix_orientation=False)


def box_mesh(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0)) -> TetMesh:
    """A box [origin, origin + size] (metres) of nx * ny * nz equal hexahedra, each split into 6
    tetrahedra of volume (hexahedron volume) / 6 sharing its diagonal (0,0,0)-(1,1,1) (Kuhn /
    Freudenthal split). Every hexahedron is split alike, so the mesh is conforming.

    Node (i, j, k) has index i + (nx+1) (j + (ny+1) k); elements come hexahedron by hexahedron,
    x fastest. (nx+1)(ny+1)(nz+1) nodes, 6 nx ny nz elements.
    """
    size = _as_float_triple(size, 'size', positive=True)
    nx, ny, nz = _as_divisions(divisions)
    origin = _as_float_triple(origin, 'origin', positive=False)
    axes = [origin[a] + size[a] * (np.arange(n + 1) / n) for a, n in enumerate((nx, ny, nz))]
    for a, n in enumerate((nx, ny, nz)):
        axes[a][-1] = origin[a] + size[a]  # exact far face
    return _kuhn_grid_mesh(*axes)


def _graded_axis(lower: float, upper: float, focus: float, fine_size: float, growth: float,
                 max_size: float, fine_radius: float) -> np.ndarray:
    """Increasing node coordinates on [lower, upper], finest at ``focus``.

    Target cell width as a function of the distance d = |x - focus|:
        s(d) = fine_size                                          for d <= fine_radius,
        s(d) = min(fine_size + ln(growth) (d - fine_radius), max_size) beyond.
    The local cell count N(x) = integral of dx / s is the continuous form of "widths grow by
    `growth` per cell": in the growing zone ln s rises by ln(growth) per unit of N, so cells
    laid at equal steps of N have widths in exact geometric progression. The n = ceil(N_total)
    nodes are placed at equal steps c = N_total / n <= 1 of N, hence every width is at most
    s, the smallest is c * fine_size in (fine_size (1 - 1/n), fine_size], the largest at most
    max_size, and neighbouring widths differ by a factor of at most growth**c <= growth (since
    |d ln s / dN| <= ln(growth) everywhere). The cell that contains ``focus`` is the smallest.
    """
    rate = math.log(growth)
    n_fine = fine_radius / fine_size
    if rate > 0:
        growth_length = (max_size - fine_size) / rate  # distance over which s reaches max_size
        n_growth = math.log(max_size / fine_size) / rate

    def count(distance):  # N from the focus to `distance` >= 0
        beyond = np.maximum(distance - fine_radius, 0.0)
        near = np.minimum(distance, fine_radius) / fine_size
        if rate == 0:
            return near + beyond / fine_size
        growing = np.log1p(rate * np.minimum(beyond, growth_length) / fine_size) / rate
        capped = np.maximum(beyond - growth_length, 0.0) / max_size
        return near + growing + capped

    def distance_at(cells):  # inverse of count
        near = np.minimum(cells, n_fine) * fine_size
        beyond = np.maximum(cells - n_fine, 0.0)
        if rate == 0:
            return near + beyond * fine_size
        growing = fine_size / rate * np.expm1(rate * np.minimum(beyond, n_growth))
        capped = np.maximum(beyond - n_growth, 0.0) * max_size
        return near + growing + capped

    def signed_count(x):
        return np.sign(x - focus) * count(np.abs(x - focus))

    n_lower, n_upper = float(signed_count(lower)), float(signed_count(upper))
    total = n_upper - n_lower
    n_cells = max(1, math.ceil(total - 1e-9))
    steps = n_lower + total * (np.arange(n_cells + 1) / n_cells)
    nodes = focus + np.sign(steps) * distance_at(np.abs(steps))
    nodes[0], nodes[-1] = lower, upper
    return nodes


def graded_box_mesh(size=(0.1, 0.1, 0.05), divisions=(20, 20, 10), origin=(0.0, 0.0, 0.0), *,
                    focus=None, focus_radius: float = 0.0, growth: float = 1.2,
                    fine_size: float | None = None, grade_z: bool = False) -> TetMesh:
    """A Kuhn-split box like :func:`box_mesh` whose x and y node coordinates are graded toward
    ``focus`` (an (x, y) point in metres, default the centre of the x-y extent, e.g. where a
    needle enters the top face).

    Per graded axis (see :func:`_graded_axis` for the exact law):
      - within ``focus_radius`` (m) of the focus, cells have the smallest width ``fine_size``
        (m; default a quarter of the smallest coarse width of the graded axes);
      - farther away widths grow geometrically by ``growth`` (>= 1) per cell,
      - up to the coarse width size / divisions of that axis (``divisions`` sets the far-field
        resolution, as in box_mesh);
      - the number of cells follows, and all widths are scaled by one common factor in
        (1 - 1/n, 1] so that they fill the box exactly.
    z is uniform (divisions[2] cells) unless ``grade_z``, which grades it the same way toward the
    top face z = origin_z + size_z (fine layer of thickness ``focus_radius``).
    Node and element numbering as box_mesh, with nx, ny, nz the resulting cell counts.
    """
    size = _as_float_triple(size, 'size', positive=True)
    divisions = _as_divisions(divisions)
    origin = _as_float_triple(origin, 'origin', positive=False)
    coarse = size / np.array(divisions)
    upper = origin + size
    if focus is None:
        focus_xy = origin[:2] + 0.5 * size[:2]
    else:
        try:
            focus_xy = np.array(focus, dtype=np.float64).reshape(-1)
        except (TypeError, ValueError) as exc:
            raise MeshError(f'focus: {focus!r} is not numeric; expected (x, y) in metres') from exc
        if focus_xy.shape != (2,) or not np.isfinite(focus_xy).all():
            raise MeshError(f'focus: {focus!r}, expected 2 finite numbers (x, y) in metres')
        if ((focus_xy < origin[:2]) | (focus_xy > upper[:2])).any():
            raise MeshError(f'focus: {focus!r} lies outside the box, expected x in '
                            f'[{origin[0]}, {upper[0]}] and y in [{origin[1]}, {upper[1]}]')
    focus_radius = _as_positive_scalar(focus_radius, 'focus_radius', allow_zero=True)
    growth = _as_positive_scalar(growth, 'growth', minimum=1.0)
    graded_axes = [0, 1, 2] if grade_z else [0, 1]
    if fine_size is None:
        fine_size = 0.25 * float(coarse[graded_axes].min())
    fine_size = _as_positive_scalar(fine_size, 'fine_size')
    for a in graded_axes:
        if fine_size > coarse[a] * (1 + 1e-12):
            raise MeshError(f'fine_size: {fine_size!r} m exceeds the coarse width {coarse[a]!r} m '
                            f'(size / divisions) along {"xyz"[a]}; expected fine_size <= it')
    focus_point = [focus_xy[0], focus_xy[1], upper[2]]
    axes = []
    for a in range(3):
        if a in graded_axes:
            axes.append(_graded_axis(origin[a], upper[a], focus_point[a], fine_size, growth,
                                     max(coarse[a], fine_size), focus_radius))
        else:
            n = divisions[a]
            nodes = origin[a] + size[a] * (np.arange(n + 1) / n)
            nodes[-1] = upper[a]
            axes.append(nodes)
    return _kuhn_grid_mesh(*axes)


# --------------------------------------------------------------------------------------------
# files
# --------------------------------------------------------------------------------------------

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


def load_mesh(path) -> TetMesh:
    """Read a tetrahedral mesh from any file meshio reads (.vtu, .vtk, .msh, .mesh, ...).

    Only 'tetra' cells are used (all such blocks, in file order); other cell types are ignored.
    Element tags come from the first cell data found among ELEMENT_TAG_NAMES, else zeros.
    Nodes used by no tetrahedron are kept, not renumbered. Inverted elements are repaired
    (make_mesh) with one MeshOrientationWarning naming the file; a file without tetrahedra or with an invalid mesh raises MeshError naming it.
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
        return _build_mesh(points, tetrahedra, tags, True, f'{path}: tetrahedra')
    except MeshError as exc:
        raise MeshError(f'{path}: {exc}') from exc


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

    cells_out = {}
    for name, values in (cell_data or {}).items():
        values = np.asarray(values)
        if values.ndim < 1 or values.shape[0] != mesh.n_elements:
            raise MeshError(f'cell_data[{name!r}]: shape {values.shape}, expected first '
                            f'dimension {mesh.n_elements} (one row per element)')
        if name in ELEMENT_TAG_NAMES or name.startswith('gmsh:'):
            raise MeshError(f'cell_data[{name!r}]: the name is reserved for the element tags; '
                            'expected another name (the tags are written from mesh.element_tags)')
        cells_out[name] = [values]
    points_out = {}
    for name, values in (point_data or {}).items():
        values = np.asarray(values)
        if values.ndim < 1 or values.shape[0] != mesh.n_nodes:
            raise MeshError(f'point_data[{name!r}]: shape {values.shape}, expected first '
                            f'dimension {mesh.n_nodes} (one row per node)')
        points_out[name] = values

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
