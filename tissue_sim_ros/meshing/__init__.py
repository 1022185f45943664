"""Surfaces to tetrahedral meshes (``tissue-sim mesh``), above the engine, which reads the meshes
through meshio only. The mesher, fTetWild through pytetwild, is imported where it is used
(:mod:`.tetwild` says how to install it when it is missing).

- :mod:`.surface`: a segmented surface read, put in metres, repaired or refused with its reason;
- :mod:`.intersections`: where a surface crosses itself;
- :mod:`.tetwild`: fTetWild's tetrahedralisation, with a background sizing field;
- :mod:`.sizing`: the sizing field that grades a mesh toward a focus or a planned path;
- :mod:`.inclusions`: inclusions (a tumour, a vessel) as tagged element regions;
- :mod:`.quality`: dihedral angles, mean ratio and flat elements, as a report;
- :mod:`.volume`: the whole command: surfaces in, mesh and quality report out;
- :mod:`.organ`: the project's own organ-like surfaces, for the organ example.
"""
__all__ = ['inclusions', 'intersections', 'organ', 'quality', 'sizing', 'surface', 'tetwild', 'volume']
