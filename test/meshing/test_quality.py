"""The quality measures (meshing/quality.py) against the regular tetrahedron and a flat one."""
import numpy as np
import pytest

from tissue_sim_ros.meshing.quality import dihedral_angles, quality_report


def test_the_quality_measures_of_the_regular_tetrahedron():
    points = np.array([[1.0, 1.0, 1.0], [1.0, -1.0, -1.0], [-1.0, 1.0, -1.0], [-1.0, -1.0, 1.0]])
    tetrahedra = np.array([[0, 1, 2, 3]])
    if np.linalg.det(points[[1, 2, 3]] - points[0]) < 0:
        tetrahedra = tetrahedra[:, [0, 2, 1, 3]]
    assert np.allclose(dihedral_angles(points, tetrahedra), np.degrees(np.arccos(1.0 / 3.0)))
    report = quality_report(points, tetrahedra)
    assert report['mean_ratio']['min'] == pytest.approx(1.0)
    flat = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 0.01]])
    assert quality_report(flat, np.array([[0, 1, 2, 3]]))['slivers'] == 1
