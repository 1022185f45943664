"""The features of a force curve and the starting values they give (analysis/calibration/
layer_estimates.py), on a two-layer curve built from known values: the shaft's friction per
length on each layer's thickness, the cutting force at the tip, the deep layer's rise straight
after the outer puncture (no cut through the outer layer to read)."""
import numpy as np
import pytest

from tissue_sim_ros.analysis.calibration.layer_estimates import curve_features, starting_values, unread_cuts
from tissue_sim_ros.analysis.compare.force_events import Puncture

SPEED_M_S, RATE_HZ = 0.002, 100.0
OUTER_FRICTION, DEEP_FRICTION, CUTTING_N = 100.0, 150.0, 0.3     # N/m, N/m, N
PUNCTURES_M, BOUNDARY_M, DEPTH_M = (0.014, 0.018), 0.0155, 0.025


def insertion_force(x):
    """The load cell's force at travel x since contact: the outer layer loading to its puncture,
    the deep layer rising at once from the valley (0.4 N), steeper from its boundary on, and after the
    deep puncture the cutting force plus each layer's friction per length on the shaft inside it."""
    outer = 4.0 * (x / PUNCTURES_M[0]) ** 2
    deep = 0.4 + 300.0 * np.clip(x - PUNCTURES_M[0], 0.0, None) + 900.0 * np.clip(x - BOUNDARY_M, 0.0, None)
    inside = CUTTING_N + OUTER_FRICTION * BOUNDARY_M + DEEP_FRICTION * (x - BOUNDARY_M)
    return np.where(x <= PUNCTURES_M[0], outer, np.where(x <= PUNCTURES_M[1], deep, inside))


def the_curve():
    """Insert to DEPTH_M, hold 1 s, retract: time, travel, force and the two punctures."""
    inserting = np.arange(0.0, DEPTH_M, SPEED_M_S / RATE_HZ)
    travel = np.concatenate([inserting, np.full(int(RATE_HZ), DEPTH_M), inserting[::-1]])
    force = np.concatenate([insertion_force(inserting), np.full(int(RATE_HZ), insertion_force(DEPTH_M)),
                            -1.5 * np.ones(len(inserting))])
    time = np.arange(len(travel)) / RATE_HZ
    punctures = []
    for layer, depth in enumerate(PUNCTURES_M):
        index = int(np.searchsorted(inserting, depth, side='right')) - 1
        punctures.append(Puncture(index, float(inserting[index]), float(force[index]), 1.0, layer=layer))
    return time, travel, force, punctures


def test_an_unread_cut_takes_its_friction_from_the_line_after_the_last_puncture():
    """The deep layer rises straight after the outer puncture, so the outer layer's cut cannot be
    read there and its valley (0.4 N at 14 mm: 29 N/m) says nothing of its friction; the line
    after the deep puncture holds the outer friction on the outer layer's thickness. That line
    cannot tell the deep layer's cutting force from the outer friction, so the estimate is the
    truth plus at most that force over the thickness (19 N/m here), where the valley's is 71 %
    short; the deep layer's friction is the line's slope."""
    features = curve_features(*the_curve(), n_layers=2)
    assert unread_cuts(features) == [0]
    values = starting_values(features, 15000.0)
    outer, how = values['friction_n_per_m[0]']
    valley = features.valley_n[0] / features.valley_m[0]
    print(f'outer friction {outer:.1f} N/m ({how}); the valley reads {valley:.1f}; '
          f'deep {values["friction_n_per_m[1]"][0]:.1f} N/m; onset {features.onset_m[1] * 1e3:.2f} mm')
    assert valley < 0.35 * OUTER_FRICTION
    assert features.onset_m[1] == pytest.approx(BOUNDARY_M, abs=2e-4)
    assert OUTER_FRICTION - 2.0 <= outer <= OUTER_FRICTION + CUTTING_N / BOUNDARY_M + 2.0
    assert values['friction_n_per_m[1]'][0] == pytest.approx(DEEP_FRICTION, rel=0.02)


def test_a_deep_layer_left_soon_after_the_turn_is_bounded_by_the_strongest_pull():
    """The retraction as on a soft mesh: the force falls from the hold's level to the deep layer's
    pull (1.8 N) over the first 9 mm back (the tissue dragged along), holds it, and steps to the
    outer layer's (1.2 N) 4 mm later. The deep layer's window (back from the deepest travel to its
    onset, 9.5 mm) holds mostly the transition and its plateau reads low, so twice it is no bound
    for the pull; the strongest pull is the deep layer's, and the --fit bound takes
    fit_bounds.PULL_MARGIN times it."""
    from tissue_sim_ros.analysis.calibration.fit_bounds import PULL_MARGIN, fit_suggestions
    time, travel, force, punctures = the_curve()
    back = np.flatnonzero(np.arange(len(travel)) >= len(travel) - int(DEPTH_M / SPEED_M_S * RATE_HZ))
    since_turn = DEPTH_M - travel[back]
    hold = insertion_force(DEPTH_M)
    force = force.copy()
    force[back] = np.where(since_turn < 0.009, hold + (-1.8 - hold) * since_turn / 0.009,
                           np.where(since_turn < 0.013, -1.8, -1.2))
    features = curve_features(time, travel, force, punctures, n_layers=2)
    assert features.strongest_pull_n == pytest.approx(-1.8, abs=1e-9)
    assert -features.retraction_n[1] < 0.5 * 1.8        # the window reads the transition
    region = {'young_modulus_pa': 3e4, 'membrane': {'rupture_force_n': 3.0}, 'cutting_force_n': 0.3,
              'friction': {'insertion_coulomb_n_per_m': 0.0}}
    spec = {'regions': [dict(region, friction={'insertion_coulomb_n_per_m': 0.0, 'retraction_constant_n': -r})
                        for r in features.retraction_n], 'model': {'relaxation': []}}
    spec['regions'][1]['select'] = {'below_z_m': -BOUNDARY_M}
    layers = [None, type('Layer', (), {'depth_sd_m': 0.0003})()]
    bounds = {f['key']: f for f in fit_suggestions(spec, 2, layers, features.strongest_pull_n)}
    deep = bounds['regions[1].friction.retraction_constant_n']
    assert deep['high'] == pytest.approx(PULL_MARGIN * 1.8) and deep['low'] <= 1.8 <= deep['high']
    unbounded = {f['key']: f for f in fit_suggestions(spec, 2, layers)}
    assert unbounded['regions[1].friction.retraction_constant_n']['high'] < 1.8
