"""A layer's thickness in the mesh's elements along the needle (analysis.calibration.layer_resolution).

The truth: regular tetrahedra of a known edge stacked on the needle's line (and larger ones away
from it, which must not count), and thicknesses as differences of the boundaries' depths."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.calibration.layer_resolution import MIN_ELEMENTS_ACROSS, elements_across, \
    path_edge_length, resolution_warnings

REGULAR = np.array([[1.0, 0.0, -1 / np.sqrt(2)], [-1.0, 0.0, -1 / np.sqrt(2)], [0.0, 1.0, 1 / np.sqrt(2)],
                    [0.0, -1.0, 1 / np.sqrt(2)]]) / 2.0      # a regular tetrahedron of edge 1, centred at 0


def stacked(edge, count, x=0.0):
    return [REGULAR * edge + [x, 0.0, -k * edge] for k in range(count)]


def test_the_edge_along_the_path_is_that_of_the_elements_on_the_needles_line():
    cells = stacked(0.001, 20) + stacked(0.005, 40, x=0.03)
    points = np.concatenate(cells)
    tetrahedra = np.arange(len(points)).reshape(-1, 4)
    assert path_edge_length(points, tetrahedra, [0.0, 0.0, 0.01], [0.0, 0.0, -1.0]) == pytest.approx(0.001)
    assert path_edge_length(points, tetrahedra, [0.03, 0.0, 0.01], [0.0, 0.0, -1.0]) == pytest.approx(0.005)


def test_a_layer_is_as_thick_as_its_boundaries_are_apart_and_warned_under_the_least():
    rows = elements_across([0.012, 0.018], 0.024, 0.002)
    assert [r['thickness_m'] for r in rows] == pytest.approx([0.012, 0.006, 0.006])
    assert [r['elements_across'] for r in rows] == pytest.approx([6.0, 3.0, 3.0])
    assert resolution_warnings(rows, 0.002) == []
    thin = elements_across([0.012, 0.018], 0.024, 0.0025)
    warned = resolution_warnings(thin, 0.0025)
    assert len(warned) == 2 and warned[0].startswith('layer 1 is 6.0 mm thick, 2.4 elements of 2.50 mm')
    assert MIN_ELEMENTS_ACROSS > 2.4
    assert resolution_warnings(elements_across([], 0.004, 0.0025), 0.0025) == []     # one layer: nothing to blend
