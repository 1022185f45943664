"""A tetrahedral mesh's quality report: dihedral angles, the mean ratio, flat elements.

- Dihedral angles: the six of each element, pi minus the angle between the outward normals of
  the two faces that meet at an edge. Small ones stiffen the explicit step's critical time step
  (it scales with the element's smallest height) and spoil the stress; large ones (near 180
  degrees) spoil the interpolation (Shewchuk 2002, "What is a good linear finite element?").
- Mean ratio (Liu and Joe 1994): 12 (3 V)^(2/3) / sum of squared edge lengths, 1 for the
  regular tetrahedron, 0 for a flat one (:func:`~tissue_sim_ros.engine.mesh.tetmesh.mean_ratio`).
- Slivers: elements flat with no short edge (all four nodes near one plane): a dihedral angle
  below :data:`SLIVER_DEG` and another above 180 minus it. Flat elements of any kind: a
  dihedral angle below it, or a mean ratio below :data:`FLAT_MEAN_RATIO`.
"""
from __future__ import annotations

import numpy as np

from tissue_sim_ros.engine.mesh.tetmesh import mean_ratio

__all__ = ['FLAT_MEAN_RATIO', 'SLIVER_DEG', 'dihedral_angles', 'quality_report', 'report_lines']

SLIVER_DEG = 5.0
FLAT_MEAN_RATIO = 0.1
_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])     # face k is opposite node k
_PAIRS = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


def dihedral_angles(points, tetrahedra) -> np.ndarray:
    """(m, 6) dihedral angles [deg] of positively oriented elements."""
    corners = np.asarray(points)[np.asarray(tetrahedra)]
    faces = corners[:, _FACES]                                               # (m, 4, 3, 3)
    normals = np.cross(faces[:, :, 1] - faces[:, :, 0], faces[:, :, 2] - faces[:, :, 0])
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    cosine = np.einsum('mpi,mpi->mp', normals[:, _PAIRS[:, 0]], normals[:, _PAIRS[:, 1]])
    return 180.0 - np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


def quality_report(points, tetrahedra, tags=None, names=None) -> dict:
    """The report (module docstring): counts, volume (per tag too, named by ``names`` {tag:
    name}), edge lengths, dihedral and mean-ratio statistics, flat elements."""
    points, tetrahedra = np.asarray(points), np.asarray(tetrahedra)
    angles = dihedral_angles(points, tetrahedra)
    ratio = mean_ratio(points, tetrahedra)
    corners = points[tetrahedra]
    volumes = np.einsum('ij,ij->i', np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]),
                        corners[:, 3] - corners[:, 0]) / 6.0
    edges = np.linalg.norm(corners[:, _PAIRS[:, 1]] - corners[:, _PAIRS[:, 0]], axis=2)
    smallest, largest = angles.min(axis=1), angles.max(axis=1)
    report = {
        'nodes': int(len(np.unique(tetrahedra))), 'tetrahedra': int(len(tetrahedra)),
        'volume_m3': float(volumes.sum()),
        'edge_length_m': {'min': float(edges.min()), 'median': float(np.median(edges)), 'max': float(edges.max())},
        'dihedral_deg': {'min': float(angles.min()), 'median': float(np.median(angles)), 'max': float(angles.max()),
                         'elements_min_below_10': int((smallest < 10.0).sum())},
        'mean_ratio': {'min': float(ratio.min()), 'median': float(np.median(ratio)),
                       'percentiles': {str(p): float(np.percentile(ratio, p)) for p in (1, 5, 25, 50, 75)},
                       'histogram': {'edges': np.linspace(0.0, 1.0, 11).tolist(),
                                     'counts': np.histogram(ratio, bins=np.linspace(0.0, 1.0, 11))[0].tolist()}},
        'slivers': int(((smallest < SLIVER_DEG) & (largest > 180.0 - SLIVER_DEG)).sum()),
        'flat_elements': int(((smallest < SLIVER_DEG) | (ratio < FLAT_MEAN_RATIO)).sum()),
    }
    if tags is not None:
        tags = np.asarray(tags)
        report['regions'] = {str(int(t)): {'name': (names or {}).get(int(t), ''), 'tetrahedra': int((tags == t).sum()),
                                           'volume_m3': float(volumes[tags == t].sum())} for t in np.unique(tags)}
    return report


def report_lines(report: dict) -> list[str]:
    """The report as a few lines for the terminal."""
    d, q = report['dihedral_deg'], report['mean_ratio']
    lines = [f"{report['tetrahedra']} tetrahedra, {report['nodes']} nodes, {report['volume_m3'] * 1e6:.4g} cm^3; "
             f"edges {report['edge_length_m']['min'] * 1e3:.3g} / {report['edge_length_m']['median'] * 1e3:.3g} / "
             f"{report['edge_length_m']['max'] * 1e3:.3g} mm (min / median / max)",
             f"dihedral angles: min {d['min']:.2f} deg, median {d['median']:.1f} deg, max {d['max']:.1f} deg; "
             f"{d['elements_min_below_10']} elements with one below 10 deg",
             f"mean ratio: min {q['min']:.3f}, 1 % {q['percentiles']['1']:.3f}, 5 % {q['percentiles']['5']:.3f}, "
             f"median {q['median']:.3f}; slivers {report['slivers']}, flat elements {report['flat_elements']}"]
    for tag, region in report.get('regions', {}).items():
        lines.append(f"  tag {tag} {region['name'] or ''}: {region['tetrahedra']} tetrahedra, "
                     f"{region['volume_m3'] * 1e6:.4g} cm^3")
    return lines
