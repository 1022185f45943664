"""Where each region of a scene is: its selector as a volume in the rest configuration.

A region's ``select`` (scene key) is ``all``, ``{below_z_m: z}`` (the half-space under the plane
z), ``{above_z_m: z}``, ``{half_space_m: [x, y, z, nx, ny, nz]}`` (the points p with
(p - x) . n <= 0: behind the plane, the normal pointing out of the half-space), ``{box_m: [[x, y,
z], [x, y, z]]}``, ``{sphere_m: [x, y, z, radius]}`` or ``{tag: N}`` (the elements a mesh file
tagged N). Later regions override earlier ones. Three uses, one language:

- the material of each element is its centroid's region (:meth:`RegionSelectors.element_regions`);
- the needle meets a layer where its tip's material point (the tip located in the deformed mesh,
  taken back to rest coordinates) enters another region (:meth:`RegionSelectors.region_at`): the
  layer boundary is the selector's surface, a plane, box or sphere in metres, wherever the
  element faces happen to lie. A tagged region's boundary is the mesh's own tagged surface;
- the nodes a support holds (``boundary.fixed``, ``boundary.springs``, :func:`node_mask`): a
  volume's nodes (a tag's: its elements' nodes), and two selectors of nodes only: the surface
  within a distance of a point (``{surface_near_m: [x, y, z, d]}``, a ligament's attachment) and a
  mesh file's node set (``{node_set: NAME}``, point data marking the nodes non-zero).
"""
from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ['RegionSelectors', 'node_mask']


class RegionSelectors:
    """The scene's region selectors (``regions[i].select``); ``element_tags`` for ``tag``."""

    def __init__(self, regions, element_tags=None):
        self.selects = [region['select'] for region in regions]
        self.element_tags = None if element_tags is None else np.asarray(element_tags)
        encoded = [_encoded(select) for select in self.selects]
        self.kinds = np.array([kind for kind, _ in encoded], dtype=np.int64)
        self.params = np.array([params for _, params in encoded], dtype=np.float64).reshape(-1, 6)
        self.tags = (np.zeros(0, dtype=np.int64) if self.element_tags is None
                     else self.element_tags.astype(np.int64))

    @staticmethod
    def _inside(select, points, tags) -> np.ndarray:
        if select == 'all':
            return np.ones(len(points), dtype=bool)
        if 'tag' in select:
            return np.zeros(len(points), dtype=bool) if tags is None else tags == select['tag']
        if 'box_m' in select:
            lo, hi = np.array(select['box_m'][0]), np.array(select['box_m'][1])
            return np.all((points >= lo) & (points <= hi), axis=1)
        if 'sphere_m' in select:
            centre, radius = np.array(select['sphere_m'][:3]), select['sphere_m'][3]
            return np.sum((points - centre) ** 2, axis=1) <= radius * radius
        if 'above_z_m' in select:
            return points[:, 2] >= select['above_z_m']
        if 'half_space_m' in select:
            plane = np.asarray(select['half_space_m'], dtype=float)
            return (points - plane[:3]) @ plane[3:] <= 0.0
        return points[:, 2] <= select['below_z_m']

    def regions_of(self, rest_points, tags=None) -> np.ndarray:
        """(k,) the region index of each rest point (-1: none), ``tags``: the tag of the element
        each lies in (for tag selectors)."""
        points = np.atleast_2d(np.asarray(rest_points, dtype=float))
        index = np.full(len(points), -1)
        for k, select in enumerate(self.selects):
            index[self._inside(select, points, tags)] = k
        return index

    def element_regions(self, centroids) -> np.ndarray:
        """(m,) each element's region, by its centroid (its material)."""
        return self.regions_of(centroids, self.element_tags)

    def region_at(self, rest_point, element: int) -> int:
        """The region of one material point (rest coordinates) lying in ``element``: the compiled
        :func:`region_of_point` on the selectors as arrays (the needle asks this every step, also
        from inside its compiled substep)."""
        return int(region_of_point(self.kinds, self.params, self.tags, float(rest_point[0]),
                                   float(rest_point[1]), float(rest_point[2]), int(element)))


ALL, TAG, BOX, SPHERE, ABOVE_Z, BELOW_Z, HALF_SPACE = range(7)


def _encoded(select):
    """(kind, six parameters) of one selector, for :func:`region_of_point`."""
    if select == 'all':
        return ALL, [0.0] * 6
    if 'tag' in select:
        return TAG, [float(select['tag'])] + [0.0] * 5
    if 'box_m' in select:
        return BOX, [float(v) for v in (*select['box_m'][0], *select['box_m'][1])]
    if 'sphere_m' in select:
        return SPHERE, [float(v) for v in select['sphere_m'][:4]] + [0.0, 0.0]
    if 'above_z_m' in select:
        return ABOVE_Z, [float(select['above_z_m'])] + [0.0] * 5
    if 'half_space_m' in select:
        return HALF_SPACE, [float(v) for v in select['half_space_m']]
    return BELOW_Z, [float(select['below_z_m'])] + [0.0] * 5


@njit(cache=True)
def region_of_point(kinds, params, tags, x, y, z, element):
    """The last selector (later ones override) whose volume holds the rest point (x, y, z) in
    ``element``, -1 for none: ``kinds`` (k,) and ``params`` (k, 6) as :func:`_encoded` writes them
    (a box's corners, a sphere's centre and radius, a plane's z), ``tags`` each element's tag
    ((0,): the mesh has none, a tag selector holds nothing)."""
    found = -1
    for k in range(kinds.shape[0]):
        kind = kinds[k]
        p = params[k]
        if kind == ALL:
            inside = True
        elif kind == TAG:
            inside = tags.shape[0] > 0 and tags[element] == p[0]
        elif kind == BOX:
            inside = p[0] <= x <= p[3] and p[1] <= y <= p[4] and p[2] <= z <= p[5]
        elif kind == SPHERE:
            inside = (x - p[0]) ** 2 + (y - p[1]) ** 2 + (z - p[2]) ** 2 <= p[3] * p[3]
        elif kind == ABOVE_Z:
            inside = z >= p[0]
        elif kind == HALF_SPACE:
            inside = (x - p[0]) * p[3] + (y - p[1]) * p[4] + (z - p[2]) * p[5] <= 0.0
        else:
            inside = z <= p[0]
        if inside:
            found = k
    return found


def node_mask(select, mesh, point_sets=None, field='boundary.fixed') -> np.ndarray:
    """(n,) the nodes of ``mesh`` (a TetMesh) that a support's selector holds (module docstring):
    ``point_sets`` {name: (n,) values} of the mesh file, for ``node_set``. Raises SceneError
    naming ``field`` for a node set the file does not have."""
    from tissue_sim_ros.errors import SceneError
    points = np.asarray(mesh.rest_positions)
    if isinstance(select, dict) and 'surface_near_m' in select:
        centre, distance = np.asarray(select['surface_near_m'][:3], dtype=float), float(select['surface_near_m'][3])
        mask = np.zeros(len(points), dtype=bool)
        surface = np.asarray(mesh.surface_nodes())
        mask[surface[np.linalg.norm(points[surface] - centre, axis=1) <= distance]] = True
        return mask
    if isinstance(select, dict) and 'node_set' in select:
        name = select['node_set']
        if not point_sets or name not in point_sets:
            known = ', '.join(point_sets or {}) or 'none'
            raise SceneError(f"{field}.node_set = {name!r}: the mesh file has no point data of that name (it has: "
                             f'{known})')
        values = np.asarray(point_sets[name])
        return (values.reshape(len(points), -1) != 0).any(axis=1)
    if isinstance(select, dict) and 'tag' in select:
        mask = np.zeros(len(points), dtype=bool)
        mask[np.asarray(mesh.tetrahedra)[np.asarray(mesh.element_tags) == select['tag']].ravel()] = True
        return mask
    return RegionSelectors._inside(select, points, None)
