"""The --fit bounds a proposal suggests (analysis/calibration/fit_bounds.py) for a deeper boundary,
against the proposal's own simulation: where its layer starts loading deeper in travel than the
data's, the boundary at rest lies shallower, and the bounds reach that far toward the surface."""
import math

import pytest

from tissue_sim_ros.analysis.calibration.fit_bounds import fit_suggestions


class Layer:
    depth_sd_m = 0.0003


def scene(boundary_z):
    region = {'young_modulus_pa': 3e4, 'membrane': {'rupture_force_n': 3.0}, 'cutting_force_n': 0.3,
              'friction': {'insertion_coulomb_n_per_m': 0.0, 'retraction_constant_n': 1.0}}
    return {'regions': [dict(region), dict(region, select={'below_z_m': boundary_z})], 'model': {'relaxation': []}}


def bounds(miss):
    rows = fit_suggestions(scene(-0.0147), 2, [Layer(), Layer()], onset_miss_m=[math.nan, miss])
    row = next(r for r in rows if r['key'] == 'regions[1].select.below_z_m')
    return row['low'], row['high']


@pytest.mark.parametrize('miss', [0.00095, -0.00095])
def test_a_boundary_whose_simulated_onset_misses_the_datas_is_bounded_past_that_miss(miss):
    """The three-layer phantom on the fine mesh: the proposal's middle boundary 14.7 mm down, its
    simulated loading starting 0.95 mm of travel after the data's, the boundary that made the data
    at 12.1 mm (2.6 mm up: the last step was short). The bounds reach 2 mm plus the miss on the side
    the miss points to, 2 mm on the other; unknown (NaN), 2 mm both ways."""
    low, high = bounds(miss)
    plain_low, plain_high = bounds(math.nan)
    assert (plain_low, plain_high) == pytest.approx((-0.0167, -0.0127))
    if miss > 0:      # the simulation loads late: the boundary lies shallower
        assert (low, high) == pytest.approx((-0.0167, -0.0127 + miss)) and low < -0.0121 < high
    else:
        assert (low, high) == pytest.approx((-0.0167 + miss, -0.0127))
