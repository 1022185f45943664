"""Where each region of a scene is: its selector as a volume in the rest configuration.

A region's ``select`` (scene key) is ``all``, ``{below_z_m: z}`` (the half-space under the plane
z), ``{above_z_m: z}``, ``{box_m: [[x, y, z], [x, y, z]]}``, ``{sphere_m: [x, y, z, radius]}``
or ``{tag: N}`` (the elements a mesh file tagged N). Later regions override earlier ones. Two
uses, one rule:

- the material of each element is its centroid's region (:meth:`RegionSelectors.element_regions`);
- the needle meets a layer where its tip's material point (the tip located in the deformed mesh,
  taken back to rest coordinates) enters another region (:meth:`RegionSelectors.region_at`): the
  layer boundary is the selector's surface, a plane, box or sphere in metres, wherever the
  element faces happen to lie. A tagged region's boundary is the mesh's own tagged surface.
"""
from __future__ import annotations

import numpy as np

__all__ = ['RegionSelectors']


class RegionSelectors:
    """The scene's region selectors (``regions[i].select``); ``element_tags`` for ``tag``."""

    def __init__(self, regions, element_tags=None):
        self.selects = [region['select'] for region in regions]
        self.element_tags = None if element_tags is None else np.asarray(element_tags)

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
        """The region of one material point (rest coordinates) lying in ``element`` (plain
        arithmetic: the needle asks this every step)."""
        x, y, z = float(rest_point[0]), float(rest_point[1]), float(rest_point[2])
        found = -1
        for k, select in enumerate(self.selects):
            if select == 'all':
                inside = True
            elif 'tag' in select:
                inside = self.element_tags is not None and int(self.element_tags[element]) == select['tag']
            elif 'box_m' in select:
                (x0, y0, z0), (x1, y1, z1) = select['box_m']
                inside = x0 <= x <= x1 and y0 <= y <= y1 and z0 <= z <= z1
            elif 'sphere_m' in select:
                cx, cy, cz, radius = select['sphere_m']
                inside = (x - cx) ** 2 + (y - cy) ** 2 + (z - cz) ** 2 <= radius * radius
            elif 'above_z_m' in select:
                inside = z >= select['above_z_m']
            else:
                inside = z <= select['below_z_m']
            if inside:
                found = k
        return found
