"""The project's own organ-like surfaces: a lobed, liver-sized body with a tumour and a vessel,
for the organ example (``tissue-sim organ-example``) and the benchmarks at organ scale.

The organ is a star-shaped radial field over an icosphere's directions d: r(d) = 1 + a right
lobe's bulge - a notch + a ripple, then stretched to its half-axes, its underside flattened and
its left lobe thinned (x -> z scale > 0). Each step maps space one to one, so the surface never
crosses itself. It is written in millimetres as a segmentation would be, and the organ's STL has
a triangle left out on purpose (a segmentation's small hole, which ``tissue-sim mesh`` closes).
The tumour is a sphere, the vessel a capsule (a tube with round ends), both inside the organ.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ['APPROACH', 'HALF_AXES_MM', 'TUMOUR_MM', 'VESSEL_MM', 'entry_point', 'organ_surface', 'write_example',
           'write_example_surfaces']

#: the organ's half-axes x, y, z [mm] before its lobes
HALF_AXES_MM = (75.0, 55.0, 38.0)
#: the tumour: centre x, y, z and radius [mm]
TUMOUR_MM = (18.0, 6.0, 2.0, 9.0)
#: the vessel: the ends of its axis and its radius [mm]
VESSEL_MM = ((-45.0, -20.0, -8.0), (35.0, -22.0, -12.0), 3.0)


#: the planned needle's direction: 25 degrees from straight down, toward +x
APPROACH = (np.sin(np.radians(25.0)), 0.0, -np.cos(np.radians(25.0)))


def organ_surface(subdivisions=4):
    """(vertices [mm], triangles) of the organ (module docstring): 10 4^s + 2 vertices."""
    import trimesh
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    d = np.asarray(sphere.vertices, dtype=float)
    bulge = 0.22 * np.exp(-np.sum((d - [0.7, 0.3, 0.5]) ** 2, axis=1) / 0.4)
    notch = 0.15 * np.exp(-np.sum((d - [-0.2, 0.95, 0.1]) ** 2, axis=1) / 0.08)
    ripple = 0.03 * np.sin(3.0 * np.arctan2(d[:, 1], d[:, 0])) * (1.0 - d[:, 2] ** 2)
    x = d * (1.0 + bulge - notch + ripple)[:, None] * np.asarray(HALF_AXES_MM)
    x[:, 2] = np.where(x[:, 2] < 0.0, 0.55 * x[:, 2], x[:, 2])                   # the flatter underside
    x[:, 2] *= 1.0 - 0.35 * np.clip(-x[:, 0] / HALF_AXES_MM[0], 0.0, 1.0)        # the thinner left lobe
    return x, np.asarray(sphere.faces, dtype=np.int64)


def _tumour():
    import trimesh
    ball = trimesh.creation.icosphere(subdivisions=3, radius=TUMOUR_MM[3])
    return np.asarray(ball.vertices) + TUMOUR_MM[:3], np.asarray(ball.faces, dtype=np.int64)


def _vessel():
    import trimesh
    start, end, radius = (np.asarray(VESSEL_MM[0]), np.asarray(VESSEL_MM[1]), VESSEL_MM[2])
    axis = end - start
    tube = trimesh.creation.capsule(height=float(np.linalg.norm(axis)), radius=radius, count=[24, 12])
    tube.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / np.linalg.norm(axis)))
    return np.asarray(tube.vertices) + 0.5 * (start + end), np.asarray(tube.faces, dtype=np.int64)


def write_example_surfaces(folder, subdivisions=4) -> dict:
    """Write organ.stl (one triangle left out), tumour.stl and vessel.stl [mm] into ``folder``;
    returns {name: path}."""
    import trimesh
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    vertices, triangles = organ_surface(subdivisions)
    paths = {}
    for name, (v, t) in {'organ': (vertices, np.delete(triangles, len(triangles) // 3, axis=0)),
                         'tumour': _tumour(), 'vessel': _vessel()}.items():
        paths[name] = folder / f'{name}.stl'
        trimesh.Trimesh(v, t, process=False).export(paths[name])
    return paths


def entry_point(vertices, triangles, target, direction) -> np.ndarray:
    """Where the line to ``target`` along ``direction`` enters the closed surface: the last
    point outside before it, by bisection on the winding number (inclusions.winding_numbers)."""
    from tissue_sim_ros.meshing.inclusions import winding_numbers
    target, direction = np.asarray(target, dtype=float), np.asarray(direction, dtype=float)
    inside, outside = 0.0, float(np.ptp(vertices, axis=0).max()) * 2.0
    for _ in range(60):
        middle = 0.5 * (inside + outside)
        if winding_numbers(vertices, triangles, target - middle * direction)[0] > 0.5:
            inside = middle
        else:
            outside = middle
    return target - outside * direction


def write_example(folder, mesh=None, *, cell_m=0.012, fine_m=0.0025, radius_m=0.005, coarsen=True, threads=0,
                  echo=print) -> dict:
    """The organ example's files: the surfaces (:func:`write_example_surfaces`), the planned
    path (path.csv [mm]: from 5 mm outside the entry point to 10 mm past the tumour's centre,
    along :data:`APPROACH`), and the mesh graded along it (``mesh``, default
    FOLDER/organ_example.vtu, coarsened: a smaller file and a larger critical step) with its
    report; returns the report with the path's entry point,
    direction and length added."""
    from tissue_sim_ros.meshing.volume import mesh_surface
    folder = Path(folder)
    paths = write_example_surfaces(folder)
    vertices, triangles = organ_surface()
    direction = np.asarray(APPROACH)
    entry = entry_point(vertices, triangles, TUMOUR_MM[:3], direction)
    path = folder / 'path.csv'
    ends = np.array([entry - 5.0 * direction, np.asarray(TUMOUR_MM[:3]) + 10.0 * direction])
    np.savetxt(path, ends, delimiter=',', header='x_mm,y_mm,z_mm', comments='', fmt='%.4f')
    report = mesh_surface(paths['organ'], mesh or folder / 'organ_example.vtu', units='mm', cell_m=cell_m,
                          fine_m=fine_m, along=path, radius_m=radius_m, inclusions=[('tumour', paths['tumour']),
                                                                ('vessel', paths['vessel'])],
                          coarsen=coarsen, threads=threads, echo=echo)
    depth = float(np.linalg.norm(np.asarray(TUMOUR_MM[:3]) - entry))
    report['planned_path'] = {'entry_mm': entry.tolist(), 'direction': direction.tolist(),
                              'entry_to_tumour_centre_mm': depth}
    echo(f'planned path: enters at {np.round(entry, 3).tolist()} mm along {np.round(direction, 4).tolist()}, '
         f'{depth:.2f} mm to the tumour centre {list(TUMOUR_MM[:3])} mm')
    return report
