"""Tetrahedral meshes: what the tissue is made of, in its rest configuration.

- :mod:`.tetmesh`: the validated :class:`TetMesh`, its quality measures (Liu-Joe mean ratio)
  and its faces, edges and surface;
- :mod:`.generators`: boxes of Kuhn-split hexahedra, uniform or graded toward a point;
- :mod:`.files`: any tetrahedral mesh file meshio reads or writes, with its element tags;
- :mod:`.selectors`: volumes of the rest configuration (all, half-spaces, boxes, spheres,
  element tags) that say where a region is.
"""
__all__ = ['files', 'generators', 'selectors', 'tetmesh']
