"""A segmented organ's surface read, put in metres, repaired where that is safe, refused where not.

Read: STL, OBJ, PLY and OFF through trimesh; VTK surfaces and any other triangle file meshio
reads through meshio. Units: ``units`` (mm, cm, m) times ``scale``; a surface larger than
:data:`LARGEST_M` or smaller than :data:`SMALLEST_M` across once in metres is refused, saying
which unit it more likely is (a segmentation's millimetres read as metres make a 150 m organ).

Repaired (each logged in :attr:`Surface.repairs`): vertices closer than 1e-9 of the size merged
(an STL is a triangle soup), degenerate and duplicate triangles dropped, windings made consistent
and outward, small holes (a boundary loop of at most :data:`MAX_FILLED_EDGES` edges: a few
triangles a segmentation dropped) closed by a fan around the loop's centroid.

Refused (:class:`~tissue_sim_ros.errors.MeshError` naming the reason and where): a larger open
boundary (a cut organ: no fill can know its shape), an edge shared by more than two triangles
(non-manifold), and a self-intersection (:mod:`.intersections`): the inside of such a surface is
ambiguous, and the tagged volumes would be wrong without a message.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tissue_sim_ros.errors import MeshError
from tissue_sim_ros.meshing.intersections import self_intersections

__all__ = ['LARGEST_M', 'MAX_FILLED_EDGES', 'SMALLEST_M', 'UNITS', 'Surface', 'boundary_loops', 'enclosed_volume',
           'read_surface', 'repair']

UNITS = {'m': 1.0, 'cm': 1e-2, 'mm': 1e-3}
#: an organ surface is between these sizes across (bounding-box diagonal) in metres
LARGEST_M, SMALLEST_M = 2.0, 2e-3
#: holes of at most this many edges are closed; larger open boundaries are refused
MAX_FILLED_EDGES = 12


@dataclass
class Surface:
    """A closed, consistently outward triangle surface in metres: ``vertices`` (n, 3),
    ``triangles`` (k, 3), the ``repairs`` made to it, and its ``source`` file."""
    vertices: np.ndarray
    triangles: np.ndarray
    source: str = ''
    repairs: list = field(default_factory=list)

    @property
    def volume(self) -> float:
        return enclosed_volume(self.vertices, self.triangles)

    @property
    def diagonal(self) -> float:
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))


def enclosed_volume(vertices, triangles) -> float:
    """The signed volume a closed surface bounds (divergence theorem; > 0 for outward windings)."""
    a, b, c = (vertices[triangles[:, k]] for k in range(3))
    return float(np.einsum('ij,ij->i', a, np.cross(b, c)).sum() / 6.0)


def _raw_triangles(path: Path):
    """(vertices, triangles) as the file holds them."""
    suffix = path.suffix.lower()
    if suffix in ('.stl', '.obj', '.ply', '.off'):
        import trimesh
        try:
            mesh = trimesh.load(path, force='mesh', process=False)
        except Exception as exc:       # trimesh raises many kinds on a broken file
            raise MeshError(f'{path}: trimesh cannot read it as a surface ({exc})') from exc
        return np.asarray(mesh.vertices, dtype=float), np.asarray(mesh.faces, dtype=np.int64)
    import meshio
    try:
        source = meshio.read(path)
    except Exception as exc:           # meshio raises ReadError and others on unknown content
        raise MeshError(f'{path}: cannot read it as a surface ({exc}); expected STL, OBJ, PLY, OFF or a '
                        'VTK surface') from exc
    blocks = [np.asarray(b.data) for b in source.cells if b.type == 'triangle']
    if not blocks:
        raise MeshError(f'{path}: no triangles; found cell types {sorted({b.type for b in source.cells})}')
    return np.asarray(source.points, dtype=float)[:, :3], np.concatenate(blocks).astype(np.int64)


def read_surface(path, units=None, scale=1.0, *, check_intersections=True) -> Surface:
    """The surface of file ``path`` in metres (``units`` 'mm', 'cm' or 'm', None: metres; times
    ``scale``), repaired or refused as the module docstring says."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(2, 'no such file', str(path))
    vertices, triangles = _raw_triangles(path)
    if len(triangles) == 0:
        raise MeshError(f'{path}: no triangles')
    if not np.isfinite(vertices).all():
        raise MeshError(f'{path}: {int((~np.isfinite(vertices)).any(axis=1).sum())} vertices are not finite')
    if units is not None and units not in UNITS:
        raise MeshError(f'units = {units!r}: expected one of {", ".join(UNITS)}')
    if not (np.isfinite(scale) and scale > 0):
        raise MeshError(f'scale = {scale!r}: expected a factor > 0')
    factor = UNITS[units or 'm'] * scale
    _check_size(np.linalg.norm(np.ptp(vertices, axis=0)), factor, units, path)
    surface = repair(Surface(vertices * factor, triangles, str(path)), check_intersections=check_intersections)
    return surface


def _check_size(diagonal, factor, units, path):
    size = diagonal * factor
    said = f'--units {units}' if units else 'no --units (metres)'
    if size > LARGEST_M:
        likely = next((u for u in ('mm', 'cm') if SMALLEST_M <= diagonal * UNITS[u] <= LARGEST_M), None)
        hint = f'; it is more likely in {likely}: give --units {likely}' if likely else ''
        raise MeshError(f'{path}: {diagonal:.4g} across in its own units, {size:.4g} m with {said}: larger than '
                        f'any organ ({LARGEST_M:g} m){hint}')
    if size < SMALLEST_M:
        likely = next((u for u in ('m', 'cm') if SMALLEST_M <= diagonal * UNITS[u] <= LARGEST_M), None)
        hint = f'; it is more likely in {likely}: give --units {likely}' if likely else ''
        raise MeshError(f'{path}: {diagonal:.4g} across in its own units, {size:.4g} m with {said}: smaller '
                        f'than an organ ({SMALLEST_M * 1e3:g} mm){hint}')


def repair(surface: Surface, *, check_intersections=True) -> Surface:
    """``surface`` merged, cleaned, closed and oriented, or refused (module docstring)."""
    import trimesh
    where = surface.source or 'surface'
    tolerance = 1e-9 * float(np.linalg.norm(np.ptp(surface.vertices, axis=0)))
    keys = np.round(surface.vertices / tolerance).astype(np.int64)
    _, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    triangles = inverse.reshape(-1)[surface.triangles]
    vertices = surface.vertices[first]
    repairs = list(surface.repairs)
    if len(vertices) < len(surface.vertices):
        repairs.append(f'merged {len(surface.vertices) - len(vertices)} duplicate vertices')
    areas = 0.5 * np.linalg.norm(np.cross(vertices[triangles[:, 1]] - vertices[triangles[:, 0]],
                                          vertices[triangles[:, 2]] - vertices[triangles[:, 0]]), axis=1)
    degenerate = ((triangles[:, 0] == triangles[:, 1]) | (triangles[:, 1] == triangles[:, 2])
                  | (triangles[:, 0] == triangles[:, 2]) | (areas <= 1e-12 * areas.max()))
    _, unique_rows = np.unique(np.sort(triangles, axis=1), axis=0, return_index=True)
    duplicate = np.ones(len(triangles), dtype=bool)
    duplicate[unique_rows] = False
    drop = degenerate | duplicate
    if drop.any():
        repairs.append(f'dropped {int(degenerate.sum())} degenerate and {int((duplicate & ~degenerate).sum())} '
                       'duplicate triangles')
        triangles = triangles[~drop]
    _refuse_non_manifold(vertices, triangles, where)
    triangles, vertices, filled = _fill_small_holes(vertices, triangles, where)
    if filled:
        repairs.append(f'closed {filled} small holes (at most {MAX_FILLED_EDGES} edges each)')
    mesh = trimesh.Trimesh(vertices, triangles, process=False)
    trimesh.repair.fix_winding(mesh)
    if not mesh.is_winding_consistent:
        raise MeshError(f'{where}: the triangles cannot be given consistent windings (a one-sided surface)')
    vertices, triangles = np.asarray(mesh.vertices), np.asarray(mesh.faces, dtype=np.int64)
    if enclosed_volume(vertices, triangles) < 0.0:
        triangles = triangles[:, ::-1].copy()
        repairs.append('turned the windings outward')
    if check_intersections:
        crossing = self_intersections(vertices, triangles)
        if len(crossing):
            point = vertices[triangles[crossing[0, 0]]].mean(axis=0)
            raise MeshError(f'{where}: the surface intersects itself ({len(crossing)} pairs of triangles cross, '
                            f'the first near {np.round(point * 1e3, 2).tolist()} mm): its inside is ambiguous; '
                            'separate the touching parts in the segmentation')
    return Surface(vertices, triangles, surface.source, repairs)


def _edges(triangles):
    """(sorted edge keys (3k, 2), the triangle of each) of every triangle's three edges."""
    edges = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.sort(edges, axis=1), np.tile(np.arange(len(triangles)), 3)


def _refuse_non_manifold(vertices, triangles, where):
    edges, _ = _edges(triangles)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    over = unique[counts > 2]
    if len(over):
        point = vertices[over[0]].mean(axis=0)
        raise MeshError(f'{where}: {len(over)} edges are shared by more than two triangles (non-manifold), the '
                        f'first near {np.round(point * 1e3, 2).tolist()} mm; separate the touching parts')


def boundary_loops(triangles) -> list[np.ndarray]:
    """The open boundary's loops, each the vertex indices in order (edges used by one triangle,
    directed as their triangle has them)."""
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    keys, counts = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    single = {tuple(k) for k in keys[counts == 1]}
    following = {}
    for a, b in directed:
        if (min(a, b), max(a, b)) in single:
            following[int(b)] = int(a)          # walk the hole the other way round: fills face out
    loops = []
    while following:
        start, loop = next(iter(following)), []
        node = start
        while node in following:
            loop.append(node)
            node = following.pop(node)
        loops.append(np.array(loop, dtype=np.int64))
    return loops


def _fill_small_holes(vertices, triangles, where):
    loops = boundary_loops(triangles)
    if not loops:
        return triangles, vertices, 0
    large = [loop for loop in loops if len(loop) > MAX_FILLED_EDGES]
    if large:
        loop = max(large, key=len)
        perimeter = float(np.linalg.norm(vertices[np.roll(loop, -1)] - vertices[loop], axis=1).sum())
        centre = vertices[loop].mean(axis=0)
        raise MeshError(f'{where}: not closed: an open boundary of {len(loop)} edges ({perimeter * 1e3:.3g} mm '
                        f'round, centred near {np.round(centre * 1e3, 2).tolist()} mm){" and others" if len(large) > 1 else ""}; '
                        f'holes of at most {MAX_FILLED_EDGES} edges are closed, a larger opening is a cut organ whose '
                        'shape no fill can know: close it in the segmentation')
    new_vertices, new_triangles = [vertices], [triangles]
    next_index = len(vertices)
    for loop in loops:
        new_vertices.append(vertices[loop].mean(axis=0)[None])
        new_triangles.append(np.column_stack([loop, np.roll(loop, -1), np.full(len(loop), next_index)]))
        next_index += 1
    return np.concatenate(new_triangles), np.concatenate(new_vertices), len(loops)
