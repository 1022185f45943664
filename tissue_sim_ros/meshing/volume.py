"""``tissue-sim mesh``: a closed surface (and inclusions) -> a tagged tetrahedral mesh + report.

The steps: read and repair each surface (:mod:`.surface`; inclusions with the organ's units,
and refused unless inside it), mesh them together with fTetWild (:mod:`.tetwild`) so that every
inclusion's surface is a surface of the elements, graded by a sizing field when asked
(:mod:`.sizing`), tag the elements by inclusion (:mod:`.inclusions`), order them along a
space-filling curve (the element pass's chunks stay local in memory), write the mesh with
meshio (its tags as cell data, :func:`~tissue_sim_ros.engine.mesh.files.save_mesh`) and a
quality report as JSON beside it (:mod:`.quality`), with each region's volume against the
volume its surface encloses.

The envelope (how far the elements' boundary may lie from the input surfaces) is fTetWild's
1e-3 of the bounding-box diagonal, tightened for small inclusions to :data:`INCLUSION_ENVELOPE`
of the smallest inclusion's diagonal: a tumour's volume moves by about 8 envelopes over its
radius (2 % for a 9 mm tumour in a 22 cm organ at 1e-3; 0.4 % at its own 2e-3).

``cell`` is fTetWild's ideal edge length: the elements' edges gather around it (the median edge
comes out within about 10 % of it) and a volume V makes about V / (0.118 cell^3) tetrahedra
(0.118 cell^3: the regular tetrahedron's volume), more where the surface is curved or detailed
at a smaller scale. fTetWild has no element-count target; :func:`cell_for_count` inverts that
estimate.
"""
from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from tissue_sim_ros.engine.mesh.files import save_mesh
from tissue_sim_ros.engine.mesh.tetmesh import make_mesh
from tissue_sim_ros.meshing.inclusions import ORGAN_TAG, check_inside, element_tags
from tissue_sim_ros.meshing.quality import quality_report, report_lines
from tissue_sim_ros.meshing.sizing import read_path, sizing_field
from tissue_sim_ros.meshing.surface import UNITS, read_surface
from tissue_sim_ros.meshing.tetwild import tetrahedralize
from tissue_sim_ros.errors import MeshError

__all__ = ['INCLUSION_ENVELOPE', 'REGULAR_VOLUME', 'cell_for_count', 'default_envelope', 'mesh_surface',
           'spatial_order']

#: the envelope as a fraction of the smallest inclusion's bounding-box diagonal (at most)
INCLUSION_ENVELOPE = 2e-3

#: the regular tetrahedron's volume over its edge cubed
REGULAR_VOLUME = 1.0 / (6.0 * np.sqrt(2.0))


def cell_for_count(volume_m3, tetrahedra) -> float:
    """The ideal edge length [m] for about ``tetrahedra`` elements in ``volume_m3`` (module docstring)."""
    return float(np.cbrt(volume_m3 / (REGULAR_VOLUME * tetrahedra)))


def default_envelope(organ, inclusions) -> float:
    """fTetWild's epsilon (relative to the organ's diagonal) of the module docstring."""
    smallest = min((part.diagonal for part in inclusions), default=np.inf)
    return float(min(1e-3, INCLUSION_ENVELOPE * smallest / organ.diagonal))


def spatial_order(points, tetrahedra):
    """(points, tetrahedra) renumbered along a Morton curve of the element centroids: elements
    near in space near in memory, nodes numbered in the order elements first use them."""
    centroids = points[tetrahedra].mean(axis=1)
    lo, span = centroids.min(axis=0), max(float(np.ptp(centroids, axis=0).max()), 1e-300)
    cells = np.minimum((centroids - lo) / span * 1024.0, 1023).astype(np.int64)
    code = np.zeros(len(cells), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
    tetrahedra = tetrahedra[np.argsort(code, kind='stable')]
    _, first = np.unique(tetrahedra.ravel(), return_index=True)
    used = tetrahedra.ravel()[np.sort(first)]
    renumber = np.full(len(points), -1, dtype=np.int64)
    renumber[used] = np.arange(len(used))
    return points[used], renumber[tetrahedra]


def mesh_surface(surface, out, *, units=None, scale=1.0, cell_m=None, fine_m=None, along=None, focus=None,
                 radius_m=None, inclusions=(), epsilon=None, coarsen=False, threads=0, echo=print) -> dict:
    """Mesh the closed ``surface`` file into ``out`` (any meshio volume format) and write the
    quality report beside it (``out`` with suffix .quality.json); returns the report.

    ``units``/``scale``: the surface files' units (mm, cm, m) and a factor; ``cell_m``: the ideal
    edge length [m] (None: the bounding-box diagonal / 20, fTetWild's default); ``fine_m`` with
    ``along`` (a CSV path) or ``focus`` (x, y, z in the surface's units) and ``radius_m``: the
    graded zone; ``inclusions``: (name, surface file) pairs, tagged 2, 3, ...; ``epsilon``: the
    envelope relative to the bounding-box diagonal (None: :func:`default_envelope`); ``coarsen``:
    fTetWild's coarsening pass (:func:`~.tetwild.tetrahedralize`).
    """
    start = time.perf_counter()
    factor = UNITS[units or 'm'] * scale
    organ = read_surface(surface, units, scale)
    parts = [(name, read_surface(path, units, scale)) for name, path in inclusions]
    names = {ORGAN_TAG: 'organ'}
    for k, (name, part) in enumerate(parts):
        check_inside(organ, part, name)
        names[ORGAN_TAG + 1 + k] = name
    read_s = time.perf_counter() - start
    cell = cell_m if cell_m is not None else organ.diagonal / 20.0
    if epsilon is None:
        epsilon = default_envelope(organ, [p for _, p in parts])
    sizing = None
    if fine_m is not None:
        if (along is None) == (focus is None):
            raise MeshError('--fine-mm: give exactly one of --along PATH.csv and --focus X,Y,Z')
        core = read_path(along, factor) if along is not None else np.asarray(focus, dtype=float)[None] * factor
        radius = radius_m if radius_m is not None else 4.0 * fine_m
        sizing = sizing_field(organ.vertices.min(axis=0), organ.vertices.max(axis=0), core, fine_m, cell, radius)
    elif along is not None or focus is not None:
        raise MeshError('--along and --focus grade the mesh toward --fine-mm: give --fine-mm too')
    vertices = np.concatenate([organ.vertices] + [p.vertices for _, p in parts])
    offsets = np.cumsum([0, len(organ.vertices)] + [len(p.vertices) for _, p in parts])
    triangles = np.concatenate([organ.triangles] + [p.triangles + offsets[k + 1] for k, (_, p) in enumerate(parts)])
    expected = organ.volume / (REGULAR_VOLUME * cell ** 3)
    echo(f'meshing {surface}: {len(organ.vertices)} vertices, {organ.volume * 1e6:.4g} cm^3, ideal edge '
         f'{cell * 1e3:.3g} mm (about {expected:.3g} tetrahedra ungraded)' + ''.join(
             f'; {r}' for r in organ.repairs))
    mesh_start = time.perf_counter()
    points, tetrahedra = tetrahedralize(vertices, triangles, cell, epsilon=epsilon, sizing=sizing, threads=threads,
                                        coarsen=coarsen)
    mesh_s = time.perf_counter() - mesh_start
    points, tetrahedra = spatial_order(points, tetrahedra)
    tags = element_tags(points, tetrahedra, [p for _, p in parts])
    mesh = make_mesh(points, tetrahedra, tags, source=f'{surface}: meshed')
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_mesh(mesh, out)
    report = quality_report(points, tetrahedra, tags, names)
    report['surface_volume_m3'] = {'organ': organ.volume, **{name: part.volume for name, part in parts}}
    inside = report['regions']
    whole = report['volume_m3']
    report['volume_error'] = {'organ': whole / organ.volume - 1.0, **{
        name: inside.get(str(ORGAN_TAG + 1 + k), {'volume_m3': 0.0})['volume_m3'] / part.volume - 1.0
        for k, (name, part) in enumerate(parts)}}
    report.update({
        'mesh': str(out), 'surface': str(surface), 'units': units or 'm', 'scale': scale,
        'tags': {name: tag for tag, name in names.items()},
        'repairs': {'organ': organ.repairs, **{name: part.repairs for name, part in parts}},
        'surface_vertices': int(len(organ.vertices)),
        'options': {'cell_m': cell, 'fine_m': fine_m, 'along': None if along is None else str(along),
                    'focus': None if focus is None else list(map(float, focus)),
                    'radius_m': None if fine_m is None else radius, 'epsilon': epsilon, 'coarsen': coarsen,
                    'threads': threads},
        'seconds': {'read_and_repair': read_s, 'mesher': mesh_s, 'total': time.perf_counter() - start},
    })
    report_path = out.with_suffix('.quality.json')
    report_path.write_text(json.dumps(report, indent=1) + '\n')
    for line in report_lines(report):
        echo(line)
    echo('volume against the surfaces: ' + ', '.join(f'{k} {v * 100:+.2f} %' for k, v in report['volume_error'].items()))
    echo(f"tags: {', '.join(f'{t} {n}' for t, n in names.items())}; mesher {mesh_s:.1f} s, total "
         f"{report['seconds']['total']:.1f} s; wrote {out} and {report_path}")
    return report
